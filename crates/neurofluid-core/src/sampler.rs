//! The trainer's random stream and what it samples: a small seedable generator whose whole
//! state is one `u64` (SplitMix64), so a checkpoint stores it exactly, and the ray-batch (pixel)
//! sampler built on it (spec §4.4).
//!
//! The stream of a given seed is fixed by this file alone (no dependency's algorithm can change
//! under us), so runs are reproducible across versions and machines.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

/// Errors of the samplers.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SampleError {
    /// More samples were asked than there are candidates (no replacement).
    #[error(
        "cannot draw {count} distinct pixels from {population} candidates \
         (lower the ray count or the precrop, or use a larger image)"
    )]
    TooMany {
        /// Samples asked for.
        count: usize,
        /// Candidates available.
        population: usize,
    },
    /// A checkpoint's `state.json` holds no random stream.
    #[error("{}: state.json holds no `rng` (an unsigned 64-bit integer)", dir.display())]
    NoState {
        /// The checkpoint.
        dir: std::path::PathBuf,
    },
    /// The image is empty or larger than 2³² pixels.
    #[error("invalid image size {width}×{height}")]
    BadImage {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
}

/// SplitMix64 (Steele, Lea & Flood 2014): state += golden gamma, output = mix(state).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rng {
    /// The full state, as a hex string in files (TOML cannot hold u64 above 2⁶³).
    #[serde(with = "hex_u64")]
    state: u64,
}

const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// An independent stream for (`seed`, `stream`), e.g. one per purpose (`"warmup-rays"`).
    pub fn stream(seed: u64, stream: &str) -> Self {
        // FNV-1a of the name, mixed with the seed.
        let mut h: u64 = 0xCBF2_9CE4_8422_2325;
        for b in stream.bytes() {
            h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3);
        }
        Self {
            state: mix(seed ^ mix(h)),
        }
    }

    /// The full state (store it in a checkpoint).
    pub fn state(&self) -> u64 {
        self.state
    }

    /// A generator continuing from a stored state.
    pub fn from_state(state: u64) -> Self {
        Self { state }
    }

    /// The state as a stage stores it in its checkpoint (`"rng": <u64>`).
    pub fn to_state(&self) -> serde_json::Map<String, serde_json::Value> {
        let mut m = serde_json::Map::new();
        m.insert("rng".into(), self.state.into());
        m
    }

    /// The generator stored by [`Rng::to_state`] in the checkpoint `dir`.
    pub fn from_stage_state(
        state: &serde_json::Map<String, serde_json::Value>,
        dir: &std::path::Path,
    ) -> Result<Self, SampleError> {
        state
            .get("rng")
            .and_then(serde_json::Value::as_u64)
            .map(Self::from_state)
            .ok_or_else(|| SampleError::NoState {
                dir: dir.to_path_buf(),
            })
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GAMMA);
        mix(self.state)
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [0, 1) with 24 random bits.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Standard normal (Box–Muller from two uniforms; one of the pair is used, so a stream's
    /// k-th normal is fixed by its state alone).
    pub fn normal(&mut self) -> f64 {
        // 1 − u ∈ (0, 1]: the logarithm is finite
        let r = (-2.0 * (1.0 - self.next_f64()).ln()).sqrt();
        r * (std::f64::consts::TAU * self.next_f64()).cos()
    }

    /// Uniform integer in [0, n), unbiased (Lemire's multiply-and-reject). `n` must be > 0.
    pub fn below(&mut self, n: u64) -> u64 {
        assert!(n > 0, "Rng::below(0)");
        let threshold = n.wrapping_neg() % n;
        loop {
            let m = u128::from(self.next_u64()) * u128::from(n);
            if (m as u64) >= threshold {
                return (m >> 64) as u64;
            }
        }
    }

    /// `count` distinct indices of `0..n` in random order (partial Fisher–Yates over a virtual
    /// array; memory O(count)). Every ordered selection is equally likely.
    pub fn sample_indices(&mut self, count: usize, n: usize) -> Result<Vec<usize>, SampleError> {
        if count > n {
            return Err(SampleError::TooMany {
                count,
                population: n,
            });
        }
        let mut swapped: HashMap<usize, usize> = HashMap::with_capacity(count);
        let mut out = Vec::with_capacity(count);
        for i in 0..count {
            let j = i + self.below((n - i) as u64) as usize;
            let vi = *swapped.get(&i).unwrap_or(&i);
            let vj = *swapped.get(&j).unwrap_or(&j);
            swapped.insert(j, vi);
            out.push(vj);
        }
        Ok(out)
    }

    /// `count` distinct pixels (row-major index `row·width + col`) of a `width`×`height` image,
    /// from the whole image or, with `precrop = Some(frac)`, from the central window of
    /// [`precrop_window`]. Like `np.random.choice(coords, count, replace=False)`.
    pub fn sample_pixels(
        &mut self,
        count: usize,
        width: u32,
        height: u32,
        precrop: Option<f64>,
    ) -> Result<Vec<u32>, SampleError> {
        let total = u64::from(width) * u64::from(height);
        if total == 0 || total > u64::from(u32::MAX) {
            return Err(SampleError::BadImage { width, height });
        }
        let win = match precrop {
            Some(frac) => precrop_window(width, height, frac),
            None => PixelWindow {
                row0: 0,
                rows: height,
                col0: 0,
                cols: width,
            },
        };
        let picks = self.sample_indices(count, win.len())?;
        Ok(picks
            .into_iter()
            .map(|k| {
                let r = win.row0 + (k / win.cols as usize) as u32;
                let c = win.col0 + (k % win.cols as usize) as u32;
                r * width + c
            })
            .collect())
    }
}

/// The renderer's stratified jitter draws from the same stream as the pixel sampler, so one
/// saved state restores both.
impl rand::RngCore for Rng {
    fn next_u32(&mut self) -> u32 {
        (Rng::next_u64(self) >> 32) as u32
    }

    fn next_u64(&mut self) -> u64 {
        Rng::next_u64(self)
    }

    fn fill_bytes(&mut self, dst: &mut [u8]) {
        for chunk in dst.chunks_mut(8) {
            let v = Rng::next_u64(self).to_le_bytes();
            chunk.copy_from_slice(&v[..chunk.len()]);
        }
    }
}

/// A rectangle of pixels: rows `row0..row0+rows`, columns `col0..col0+cols`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelWindow {
    /// First row.
    pub row0: u32,
    /// Number of rows.
    pub rows: u32,
    /// First column.
    pub col0: u32,
    /// Number of columns.
    pub cols: u32,
}

impl PixelWindow {
    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.rows as usize * self.cols as usize
    }

    /// True when the window holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// True when (row, col) lies inside.
    pub fn contains(&self, row: u32, col: u32) -> bool {
        (self.row0..self.row0 + self.rows).contains(&row)
            && (self.col0..self.col0 + self.cols).contains(&col)
    }
}

/// The precrop window (NeRF's convention): dH = ⌊(H div 2)·frac⌋, rows H/2−dH … H/2+dH−1, the
/// same for columns; for 400×400 and 0.5, rows/cols 100…299. At least one pixel per axis.
pub fn precrop_window(width: u32, height: u32, frac: f64) -> PixelWindow {
    let axis = |n: u32| {
        let half = n / 2;
        let d = ((f64::from(half) * frac).floor() as u32).min(half);
        if d == 0 {
            (half.min(n.saturating_sub(1)), 1.min(n))
        } else {
            (half - d, 2 * d)
        }
    };
    let (row0, rows) = axis(height);
    let (col0, cols) = axis(width);
    PixelWindow {
        row0,
        rows,
        col0,
        cols,
    }
}

mod hex_u64 {
    use serde::{Deserialize, Deserializer, Serializer, de::Error};

    pub fn serialize<S: Serializer>(v: &u64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&format!("{v:#018x}"))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        let s = String::deserialize(d)?;
        let digits = s.strip_prefix("0x").unwrap_or(&s);
        u64::from_str_radix(digits, 16).map_err(|e| {
            D::Error::custom(format!(
                "RNG state `{s}`: expected 0x + 16 hex digits ({e})"
            ))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    /// The normal's moments and its share within one and two standard deviations against the
    /// standard normal's (0, 1, 3; 68.27 %, 95.45 %), over 200 000 draws.
    #[test]
    fn normal_draws_have_the_standard_normals_moments() {
        let mut r = Rng::stream(7, "normal");
        let n = 200_000;
        let x: Vec<f64> = (0..n).map(|_| r.normal()).collect();
        let mean = x.iter().sum::<f64>() / n as f64;
        let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
        let kurt = x.iter().map(|v| (v - mean).powi(4)).sum::<f64>() / n as f64 / var.powi(2);
        let within = |k: f64| x.iter().filter(|v| v.abs() < k).count() as f64 / n as f64;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "variance {var}");
        assert!((kurt - 3.0).abs() < 0.05, "kurtosis {kurt}");
        assert!(
            (within(1.0) - 0.6827).abs() < 0.005,
            "within 1σ {}",
            within(1.0)
        );
        assert!(
            (within(2.0) - 0.9545).abs() < 0.003,
            "within 2σ {}",
            within(2.0)
        );
    }

    #[test]
    fn splitmix64_matches_the_published_reference_values() {
        // First outputs of SplitMix64 seeded with 1234567 (the reference C implementation).
        let mut r = Rng::new(1_234_567);
        let expect = [
            6_457_827_717_110_365_317u64,
            3_203_168_211_198_807_973,
            9_817_491_932_198_370_423,
            4_593_380_528_125_082_431,
            16_408_922_859_458_223_821,
        ];
        for e in expect {
            assert_eq!(r.next_u64(), e);
        }
    }

    #[test]
    fn state_round_trips_through_json_and_toml() {
        let mut a = Rng::stream(10, "warmup-rays");
        for _ in 0..17 {
            a.next_u64();
        }
        let json = serde_json::to_string(&a).unwrap();
        let mut b: Rng = serde_json::from_str(&json).unwrap();
        #[derive(Serialize, Deserialize)]
        struct Holder {
            rng: Rng,
        }
        let toml_text = toml::to_string(&Holder { rng: a.clone() }).unwrap();
        let mut c = toml::from_str::<Holder>(&toml_text).unwrap().rng;
        let mut d = Rng::from_state(a.state());
        for _ in 0..100 {
            let x = a.next_u64();
            assert_eq!(x, b.next_u64());
            assert_eq!(x, c.next_u64());
            assert_eq!(x, d.next_u64());
        }
        let pa = a.sample_pixels(64, 40, 30, None).unwrap();
        assert_eq!(pa, b.sample_pixels(64, 40, 30, None).unwrap());
    }

    #[test]
    fn streams_differ() {
        let a = Rng::stream(10, "warmup").next_u64();
        let b = Rng::stream(10, "joint").next_u64();
        let c = Rng::stream(11, "warmup").next_u64();
        assert!(a != b && a != c && b != c);
    }

    #[test]
    fn below_is_in_range_and_roughly_uniform() {
        let mut r = Rng::new(3);
        let n = 7u64;
        let mut counts = [0usize; 7];
        let draws = 70_000;
        for _ in 0..draws {
            let k = r.below(n);
            counts[k as usize] += 1;
        }
        // chi² with 6 dof: 99.9% quantile ≈ 22.5
        let e = draws as f64 / n as f64;
        let chi2: f64 = counts.iter().map(|&c| (c as f64 - e).powi(2) / e).sum();
        assert!(chi2 < 22.5, "chi² {chi2}, counts {counts:?}");
        let f = r.next_f64();
        assert!((0.0..1.0).contains(&f));
        let f = r.next_f32();
        assert!((0.0..1.0).contains(&f));
    }

    #[test]
    fn sampling_without_replacement_is_distinct_and_uniform() {
        let mut r = Rng::new(10);
        let n = 50;
        let mut hits = vec![0usize; n];
        for _ in 0..4000 {
            let s = r.sample_indices(10, n).unwrap();
            assert_eq!(s.len(), 10);
            assert_eq!(s.iter().collect::<HashSet<_>>().len(), 10);
            for k in s {
                hits[k] += 1;
            }
        }
        // each index is picked with probability 10/50: expected 800 of 4000
        let e = 800.0;
        let chi2: f64 = hits.iter().map(|&c| (c as f64 - e).powi(2) / e).sum();
        assert!(chi2 < 90.0, "chi² {chi2} (49 dof)"); // 99.9% quantile ≈ 85.4 for the binomial-ish case
        // the full permutation
        let all = r.sample_indices(n, n).unwrap();
        let mut sorted = all.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..n).collect::<Vec<_>>());
        assert_eq!(
            r.sample_indices(n + 1, n),
            Err(SampleError::TooMany {
                count: n + 1,
                population: n
            })
        );
    }

    #[test]
    fn precrop_window_matches_the_reference_for_400() {
        let w = precrop_window(400, 400, 0.5);
        assert_eq!(
            w,
            PixelWindow {
                row0: 100,
                rows: 200,
                col0: 100,
                cols: 200
            }
        );
        // rows 100..=299 inclusive
        assert!(w.contains(100, 100) && w.contains(299, 299));
        assert!(!w.contains(99, 150) && !w.contains(300, 150) && !w.contains(150, 300));
        let w = precrop_window(100, 60, 0.5);
        assert_eq!((w.row0, w.rows, w.col0, w.cols), (15, 30, 25, 50));
        let w = precrop_window(3, 3, 0.1);
        assert_eq!((w.row0, w.rows), (1, 1));
        assert_eq!(precrop_window(400, 400, 1.0).len(), 400 * 400);
    }

    #[test]
    fn pixel_samples_stay_in_the_precrop_window_and_cover_it() {
        let mut r = Rng::new(10);
        let (w, h) = (400u32, 400u32);
        let win = precrop_window(w, h, 0.5);
        let mut seen = HashSet::new();
        for _ in 0..60 {
            let px = r.sample_pixels(1024, w, h, Some(0.5)).unwrap();
            assert_eq!(px.iter().collect::<HashSet<_>>().len(), 1024);
            for &p in &px {
                let (row, col) = (p / w, p % w);
                assert!(
                    win.contains(row, col),
                    "pixel ({row}, {col}) outside the precrop"
                );
                seen.insert(p);
            }
        }
        // 61 440 draws over 40 000 pixels: most of the window is hit, including its corners' rows
        assert!(seen.len() > 30_000, "{}", seen.len());
        let full = r.sample_pixels(4000, w, h, None).unwrap();
        assert!(full.iter().any(|&p| !win.contains(p / w, p % w)));
        assert!(full.iter().all(|&p| p < w * h));
        assert!(matches!(
            r.sample_pixels(300, 20, 20, Some(0.5)),
            Err(SampleError::TooMany {
                count: 300,
                population: 100
            })
        ));
        assert!(matches!(
            r.sample_pixels(1, 0, 5, None),
            Err(SampleError::BadImage { .. })
        ));
    }
}
