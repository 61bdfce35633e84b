//! Positional encodings (spec §2.5) and the assembly of the network inputs e_x and e_d.

use burn::prelude::*;

use crate::config::{PhysNerfConfig, Positions};
use crate::features::LocalFeatures;

pub use neurofluid_core::posenc::{posenc, posenc_cat};

/// `e_x = [γ(x), γ(σ_p)?, γ(p_c)?, γ(v_d)?]` and `e_d = [γ(d), γ(d_c)?]` (switched-off terms
/// are left out, the others keep their order); with relative positions
/// `e_x = [γ(σ_p)?, γ(p_c − x)?, γ(v_d)?]`. `x` and `d` are `[Q, 3]`.
pub fn encode_inputs(
    x: Tensor<2>,
    d: Tensor<2>,
    feats: &LocalFeatures,
    config: &PhysNerfConfig,
) -> (Tensor<2>, Tensor<2>) {
    let f = &config.frequencies;
    let t = &config.encoding;
    let relative = config.positions == Positions::Relative;
    let mut ex = Vec::with_capacity(4);
    if !relative {
        ex.push((x.clone(), f.x));
    }
    if t.sigma_p {
        ex.push((feats.sigma_p.clone(), f.sigma_p));
    }
    if t.pc {
        let pc = if relative {
            feats.pc.clone() - x
        } else {
            feats.pc.clone()
        };
        ex.push((pc, f.pc));
    }
    if t.vd {
        ex.push((feats.vd.clone(), f.vd));
    }
    let mut ed = vec![(d, f.d)];
    if t.dc {
        ed.push((feats.dc.clone(), f.dc));
    }
    (posenc_cat(ex), posenc_cat(ed))
}
