//! Renderer configuration: every constant of the reference renderer plus the ablation and
//! improvement switches. The defaults are the paper code's configuration.

use serde::{Deserialize, Serialize};

pub use neurofluid_core::neighbors::NeighborSelection;

/// Which particle-derived encoding terms enter the networks (the paper's Table 5 ablations).
///
/// A switched-off term is removed from its input; the other blocks keep their order:
/// `e_x = [γ(x), γ(σ_p)?, γ(p_c)?, γ(v_d)?]`, `e_d = [γ(d), γ(d_c)?]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EncodingTerms {
    /// γ₁₀(p_c), the fictitious particle centre.
    pub pc: bool,
    /// γ₄(σ_p), the particle density.
    pub sigma_p: bool,
    /// γ₁₀(v_d), the per-axis variance of the neighbour offsets.
    pub vd: bool,
    /// γ₄(d_c), the direction from the camera to p_c (colour branch).
    pub dc: bool,
}

impl Default for EncodingTerms {
    fn default() -> Self {
        Self::all()
    }
}

impl EncodingTerms {
    /// Every term on (the paper code).
    pub fn all() -> Self {
        Self {
            pc: true,
            sigma_p: true,
            vd: true,
            dc: true,
        }
    }

    /// Every particle term off: e_x = γ(x), e_d = γ(d).
    pub fn none() -> Self {
        Self {
            pc: false,
            sigma_p: false,
            vd: false,
            dc: false,
        }
    }
}

/// Where the position-like inputs of the density are measured from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Positions {
    /// γ(x) and γ(p_c) in world coordinates (the paper code): the field can tie what it learned
    /// on the warm-up's frame to where that frame's fluid was.
    #[default]
    World,
    /// No γ(x), and p_c as the offset p_c − x: every input of the networks but the directions
    /// is the particles' geometry seen from the sample, so the field moves with its particles
    /// (shifting the particles and the cameras together shifts the picture, nothing else).
    Relative,
}

/// How a network's raw density output becomes the density σ ≥ 0 that is composited.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DensityActivation {
    /// `relu(σ)` (the paper code, as in the original NeRF). A network whose raw output is
    /// negative on every sample renders nothing and receives no gradient: it can start dead.
    #[default]
    Relu,
    /// `softplus(σ − 1)` (mip-NeRF's choice): positive everywhere, so a gradient always reaches
    /// the density, and a network cannot start dead.
    Softplus,
}

impl DensityActivation {
    /// The raw density `sigma` after this activation's part that comes before any gate or box
    /// mask: softplus(σ − 1), or σ itself for ReLU (which volume rendering applies, the
    /// reference's place).
    pub fn before_mask(self, sigma: burn::tensor::Tensor<2>) -> burn::tensor::Tensor<2> {
        match self {
            DensityActivation::Relu => sigma,
            DensityActivation::Softplus => {
                burn::tensor::activation::softplus(sigma.sub_scalar(1.0), 1.0)
            }
        }
    }
}

/// Positional-encoding frequency counts L of each encoded term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Frequencies {
    /// Sample position x (10).
    pub x: usize,
    /// Density σ_p (4).
    pub sigma_p: usize,
    /// Centre p_c (10).
    pub pc: usize,
    /// Variance v_d (10).
    pub vd: usize,
    /// Ray direction d (4).
    pub d: usize,
    /// Centre direction d_c (4).
    pub dc: usize,
}

impl Default for Frequencies {
    fn default() -> Self {
        Self {
            x: 10,
            sigma_p: 4,
            pc: 10,
            vd: 10,
            d: 4,
            dc: 4,
        }
    }
}

/// Everything the renderer needs besides its weights. Serde-friendly (TOML/JSON, the
/// experiment's `[physnerf]` table); missing fields take the defaults of the paper code and
/// unknown fields are rejected.
///
/// The ray segment `near`/`far` belongs to the scene's cameras, not to the model: it is not
/// read from or written to files, and whoever builds the renderer for a scene sets it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhysNerfConfig {
    /// Near bound of the ray segment (world units; 9.0 in the released scenes).
    #[serde(skip)]
    pub near: f64,
    /// Far bound of the ray segment (13.0 in the released scenes).
    #[serde(skip)]
    pub far: f64,
    /// Coarse samples per ray (64), `z = near·(1−t) + far·t`, `t = linspace(0, 1, n)`.
    pub n_samples: usize,
    /// Importance (fine) samples per ray (128); 0 renders coarse only.
    pub n_importance: usize,
    /// Ball-query radius r_s (9 × particle radius 0.025 = 0.225).
    pub search_radius: f64,
    /// Neighbour slots K (20).
    pub k: usize,
    /// Which K particles the ball query keeps.
    pub selection: NeighborSelection,
    /// Stratified jitter of the coarse depths and random u in the fine sampling (off in the
    /// paper code). Needs an RNG at render time.
    pub stratified: bool,
    /// Composite on a white background (true in the paper code).
    pub white_background: bool,
    /// The density activation (ReLU in the paper code).
    pub density: DensityActivation,
    /// Encoding-term switches (the paper's Table 5 ablations).
    pub encoding: EncodingTerms,
    /// World or sample-relative positions (world in the paper code).
    pub positions: Positions,
    /// Encoding frequency counts.
    pub frequencies: Frequencies,
    /// MLP depth D (8).
    pub depth: usize,
    /// MLP width W (256).
    pub width: usize,
    /// Layer index whose input is `cat[e_x, h]` (4).
    pub skip: usize,
    /// Evaluate the MLPs only on gated samples (all K slots filled). Masked samples contribute
    /// exactly zero colour, density and gradient, so this gives the same numbers with less work.
    pub gated_only: bool,
    /// Rays per chunk when a whole image is rendered (a memory knob; results do not depend on
    /// it).
    pub chunk: usize,
}

impl Default for PhysNerfConfig {
    fn default() -> Self {
        Self {
            near: 9.0,
            far: 13.0,
            n_samples: 64,
            n_importance: 128,
            search_radius: 0.225,
            k: 20,
            selection: NeighborSelection::LowestIndex,
            stratified: false,
            white_background: true,
            density: DensityActivation::Relu,
            encoding: EncodingTerms::all(),
            positions: Positions::World,
            frequencies: Frequencies::default(),
            depth: 8,
            width: 256,
            skip: 4,
            gated_only: true,
            chunk: 1024,
        }
    }
}

/// Width of γ_L applied to a `c`-channel input: c·(1 + 2L).
pub fn encoded_width(channels: usize, freqs: usize) -> usize {
    channels * (1 + 2 * freqs)
}

impl PhysNerfConfig {
    /// Width of the position-like network input e_x (198 with every term on, 135 with
    /// relative positions).
    pub fn in_xyz(&self) -> usize {
        let f = &self.frequencies;
        let t = &self.encoding;
        usize::from(self.positions == Positions::World) * encoded_width(3, f.x)
            + usize::from(t.sigma_p) * encoded_width(1, f.sigma_p)
            + usize::from(t.pc) * encoded_width(3, f.pc)
            + usize::from(t.vd) * encoded_width(3, f.vd)
    }

    /// Width of the view-like network input e_d (54 with every term on).
    pub fn in_dir(&self) -> usize {
        let f = &self.frequencies;
        encoded_width(3, f.d) + usize::from(self.encoding.dc) * encoded_width(3, f.dc)
    }

    /// The segment and sample counts of a ray.
    pub fn depth_plan(&self) -> crate::hierarchical::DepthPlan {
        crate::hierarchical::DepthPlan {
            near: self.near,
            far: self.far,
            n_samples: self.n_samples,
            n_importance: self.n_importance,
        }
    }

    /// The shape of its networks.
    pub fn mlp_shape(&self) -> crate::mlp::MlpShape {
        crate::mlp::MlpShape {
            depth: self.depth,
            width: self.width,
            skip: self.skip,
            in_xyz: self.in_xyz(),
            in_dir: self.in_dir(),
        }
    }

    /// Checks the values for consistency.
    pub fn validate(&self) -> Result<(), String> {
        match self.problem() {
            Some((field, message)) => Err(format!("{field}: {message}")),
            None => Ok(()),
        }
    }

    /// The first field with an invalid value, and what was expected.
    pub fn problem(&self) -> Option<(&'static str, String)> {
        let ok = |v: f64| v.is_finite();
        if let Some(p) = self.depth_plan().problem() {
            return Some(p);
        }
        if !(ok(self.search_radius) && self.search_radius > 0.0) {
            return Some((
                "search_radius",
                format!("expected a positive radius, got {}", self.search_radius),
            ));
        }
        if self.k == 0 {
            return Some(("k", "expected at least 1 neighbour slot".into()));
        }
        if self.chunk == 0 {
            return Some(("chunk", "expected at least 1 ray per chunk".into()));
        }
        let t = &self.encoding;
        if self.positions == Positions::Relative && !(t.sigma_p || t.pc || t.vd) {
            return Some((
                "positions",
                "\"relative\" drops γ(x): it needs one of the encoding terms sigma_p, pc, vd on"
                    .into(),
            ));
        }
        self.mlp_shape().problem()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn widths_follow_the_flags() {
        let mut c = PhysNerfConfig::default();
        assert_eq!((c.in_xyz(), c.in_dir()), (198, 54));
        c.encoding.pc = false;
        assert_eq!(c.in_xyz(), 135);
        c.encoding = EncodingTerms {
            sigma_p: false,
            ..EncodingTerms::all()
        };
        assert_eq!(c.in_xyz(), 189);
        c.encoding = EncodingTerms {
            dc: false,
            ..EncodingTerms::all()
        };
        assert_eq!((c.in_xyz(), c.in_dir()), (198, 27));
        c.encoding = EncodingTerms::none();
        assert_eq!((c.in_xyz(), c.in_dir()), (63, 27));
        c.positions = Positions::Relative;
        assert!(c.validate().unwrap_err().starts_with("positions:"));
        c.encoding = EncodingTerms::all();
        assert_eq!((c.in_xyz(), c.in_dir()), (135, 54));
        assert!(c.validate().is_ok());
    }

    #[test]
    fn serde_defaults_fill_missing_fields() {
        let c: PhysNerfConfig =
            serde_json::from_str(r#"{"k": 12, "encoding": {"vd": false}}"#).unwrap();
        assert_eq!(c.k, 12);
        assert_eq!(c.n_samples, 64);
        assert!(!c.encoding.vd && c.encoding.pc);
        assert!(c.validate().is_ok());
        // unknown keys are errors, and the ray segment is the scene's, not a setting
        assert!(serde_json::from_str::<PhysNerfConfig>(r#"{"radius": 0.2}"#).is_err());
        assert!(serde_json::from_str::<PhysNerfConfig>(r#"{"near": 3.0}"#).is_err());
    }
}
