//! Questions about a module's parameters that every weights reader and writer asks: are they
//! all finite, and which are they.

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::prelude::*;

/// The path (e.g. `coarse.sigma.weight`) of the first parameter of `module` holding a NaN or an
/// infinity.
pub fn first_non_finite<M: Module>(module: &M) -> Option<String> {
    #[derive(Default)]
    struct Find {
        path: Vec<String>,
        found: Option<String>,
    }
    impl ModuleVisitor for Find {
        fn enter_module(&mut self, name: &str, _container_type: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container_type: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if self.found.is_none()
                && !crate::transfer::read_data(param.val())
                    .iter::<f64>()
                    .all(|v: f64| v.is_finite())
            {
                self.found = Some(self.path.join("."));
            }
        }
    }
    let mut v = Find::default();
    module.visit(&mut v);
    v.found
}

/// The ids of `module`'s float parameters, in visiting order.
pub fn ids<M: Module>(module: &M) -> Vec<u64> {
    #[derive(Default)]
    struct Ids(Vec<u64>);
    impl ModuleVisitor for Ids {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.push(param.id.val());
        }
    }
    let mut v = Ids::default();
    module.visit(&mut v);
    v.0
}

/// Draws every float parameter of `module` that is still lazy (Burn initialises a parameter on
/// its first use), in visiting order, so the draws follow the module's layout rather than the
/// order in which later code happens to touch the parameters.
pub fn initialise_all<M: Module>(module: &M) {
    struct Touch;
    impl ModuleVisitor for Touch {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            drop(param.val());
        }
    }
    module.visit(&mut Touch);
}

/// Two modules whose parameters do not pair up (what differs).
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("the two modules differ in layout: {0}")]
pub struct LayoutMismatch(pub String);

/// The module `from + fraction · (to − from)`, parameter by parameter (weight-space
/// interpolation: 0 gives `from`'s parameters, 1 gives `to`'s). The two must have the same
/// layout: the same float parameters, in the same visiting order, of the same shapes.
pub fn interpolate<M: Module>(from: &M, to: M, fraction: f64) -> Result<M, LayoutMismatch> {
    #[derive(Default)]
    struct Collect(Vec<(Vec<usize>, Tensor<1>)>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let t = param.val();
            self.0.push((t.dims().to_vec(), t.flatten(0, D - 1)));
        }
    }
    struct Blend {
        from: std::vec::IntoIter<(Vec<usize>, Tensor<1>)>,
        fraction: f64,
        mismatch: Option<String>,
    }
    impl ModuleMapper for Blend {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let next = self.from.next();
            let fraction = self.fraction;
            let mut mismatch = None;
            let param = param.map(|t| match next {
                Some((dims, a)) if dims == t.dims().to_vec() => {
                    let a: Tensor<D> = a.reshape(t.shape());
                    a.clone() + (t - a).mul_scalar(fraction)
                }
                other => {
                    mismatch = Some(format!(
                        "a parameter of shape {:?} against {:?}",
                        t.dims(),
                        other.map(|(d, _)| d)
                    ));
                    t
                }
            });
            if self.mismatch.is_none() {
                self.mismatch = mismatch;
            }
            param
        }
    }
    let mut collect = Collect::default();
    from.visit(&mut collect);
    let (count, to_count) = (collect.0.len(), ids(&to).len());
    if count != to_count {
        return Err(LayoutMismatch(format!(
            "{count} float parameters against {to_count}"
        )));
    }
    let mut blend = Blend {
        from: collect.0.into_iter(),
        fraction,
        mismatch: None,
    };
    let out = to.map(&mut blend);
    match blend.mismatch {
        Some(m) => Err(LayoutMismatch(m)),
        None => Ok(out),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;

    #[test]
    fn a_non_finite_parameter_is_found_by_its_path() {
        let device = crate::device::cpu();
        let layer = LinearConfig::new(2, 1).init(&device);
        assert_eq!(ids(&layer).len(), 2);
        assert_eq!(first_non_finite(&layer), None);
        let mut bad = layer.clone();
        bad.bias = bad.bias.map(|b| b.map(|t| t.mul_scalar(f32::NAN)));
        assert_eq!(first_non_finite(&bad).as_deref(), Some("bias"));
        let mut inf = layer;
        inf.weight = inf.weight.map(|t| t.mul_scalar(f32::INFINITY));
        assert_eq!(first_non_finite(&inf).as_deref(), Some("weight"));
    }

    #[test]
    fn interpolation_is_linear_in_every_parameter() {
        let device = crate::device::cpu();
        let a = LinearConfig::new(3, 2).init(&device);
        let b = LinearConfig::new(3, 2).init(&device);
        let values = |l: &burn::nn::Linear| {
            let mut v = crate::transfer::read_data(l.weight.val())
                .try_to_vec::<f32>()
                .unwrap();
            v.extend(
                crate::transfer::read_data(l.bias.as_ref().unwrap().val())
                    .try_to_vec::<f32>()
                    .unwrap(),
            );
            v
        };
        let (va, vb) = (values(&a), values(&b));
        for fraction in [0.0, 0.25, 1.0] {
            let mid = interpolate(&a, b.clone(), fraction).unwrap();
            assert_eq!(ids(&mid), ids(&b), "the parameters keep their ids");
            for ((x, y), m) in va.iter().zip(&vb).zip(values(&mid)) {
                let want = f64::from(*x) + fraction * f64::from(y - x);
                assert!((f64::from(m) - want).abs() < 1e-6, "{m} against {want}");
            }
        }
        let other = LinearConfig::new(2, 3).init(&device);
        let err = interpolate(&a, other, 0.5).unwrap_err().to_string();
        assert!(err.contains("differ in layout"), "{err}");
        let no_bias = LinearConfig::new(3, 2).with_bias(false).init(&device);
        let err = interpolate(&a, no_bias, 0.5).unwrap_err().to_string();
        assert!(err.contains("2 float parameters against 1"), "{err}");
    }
}
