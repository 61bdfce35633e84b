//! Questions about a module's parameters that every weights reader and writer asks: are they
//! all finite, and which are they.

use burn::module::{Module, ModuleVisitor, Param};
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
}
