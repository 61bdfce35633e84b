//! Evaluation metrics: particle distances (spec §6.1) and image quality (PSNR, SSIM, LPIPS;
//! §6.3).

mod fluid;
mod image;
mod lpips;
mod particles;

pub use fluid::{EnergyGains, SUPPORT_RADII, energy_gains, mean_density};
pub use image::{ImageError, RgbImage, error_share_on, psnr, ssim};
pub use lpips::{Lpips, LpipsError};
pub use particles::{
    FarSplit, ParticleDistance, alone_share, far_split, gt_to_pred_distance,
    index_matched_distance, nearest_distances, nearest_others,
};
