//! The core crate's integration tests, a module per file, in one test binary: one build and one
//! link instead of one per file.
mod backends;
mod dense_layer;
mod device_pairs;
mod device_search;
mod half_matmul;
mod image_metrics_reference;
mod indexed_rows;
mod posenc;
mod row_sum_scale;
mod square_sums;
mod sum_all;
