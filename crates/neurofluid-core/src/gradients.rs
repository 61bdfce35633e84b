//! Gradients of a Burn module: a parameter group's global L2 norm (its squares summed on the
//! device and read back with whatever else a step reads), and a loss's gradients, or none when it
//! depends on no parameter.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

use crate::square_sums::square_sums;
use crate::transfer::read_together;

/// The global L2 norm of the gradients `grads` holds for `module`'s parameters (0 when it holds
/// none: the loss did not depend on the module), with one read from the device.
pub fn grad_norm<M: Module>(grads: &GradientsParams, module: &M) -> f64 {
    let sums = grad_square_sums(grads, module);
    if sums.is_empty() {
        return 0.0;
    }
    norm_of(&read_together(sums).expect("float gradients"))
}

/// The sums of the squares of the gradients `grads` holds for `module`'s parameters, one value
/// per parameter in the module's visiting order, on the device (none when it holds none;
/// [`crate::square_sums`]: one kernel for many parameters on a GPU): read them back
/// together with whatever else the step reads ([`crate::transfer::read_together`]; they hold
/// `square_sums::count` values), then [`norm_of`].
pub fn grad_square_sums<M: Module>(grads: &GradientsParams, module: &M) -> Vec<Tensor<1>> {
    struct Flat<'a> {
        grads: &'a GradientsParams,
        flat: Vec<Tensor<1>>,
    }
    impl ModuleVisitor for Flat<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(g) = self.grads.get::<D>(param.id) {
                let n = g.shape().num_elements();
                self.flat.push(g.reshape([n]));
            }
        }
    }
    let mut v = Flat {
        grads,
        flat: Vec::new(),
    };
    module.visit(&mut v);
    square_sums(v.flat)
}

/// The L2 norm from [`grad_square_sums`] read back: their sum in order, in f64, and its root.
pub fn norm_of(square_sums: &[f64]) -> f64 {
    square_sums.iter().fold(0.0, |sum, s| sum + s).sqrt()
}

/// The loss's gradients, or none when the loss depends on no parameter (every sample was
/// masked out): such a step has nothing to update.
pub fn backward(loss: Tensor<1>) -> Option<burn::tensor::Gradients> {
    loss.is_tracked().then(|| loss.backward())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_norm_of_a_module() {
        use burn::nn::LinearConfig;
        let device = crate::device::cpu().autodiff();
        let layer = LinearConfig::new(2, 1).init(&device);
        let x = Tensor::<2>::from_data([[3.0f32, 4.0]], &device);
        let loss = layer.forward(x).sum();
        let grads = GradientsParams::from_grads(loss.backward(), &layer);
        // d/dw = x, d/db = 1: |(3, 4, 1)| = √26
        assert!((grad_norm(&grads, &layer) - 26f64.sqrt()).abs() < 1e-6);
        assert_eq!(grad_norm(&GradientsParams::new(), &layer), 0.0);
        let untracked = Tensor::<1>::from_data([1.0f32], &device);
        assert!(backward(untracked).is_none());
    }

    #[test]
    fn the_gradient_norm_of_many_parameters_is_one_read() {
        use crate::transfer::counts;
        use burn::nn::{Linear, LinearConfig};
        let device = crate::device::cpu().autodiff();
        let layers: Vec<Linear> = vec![
            LinearConfig::new(2, 3).init(&device),
            LinearConfig::new(3, 3).init(&device),
            LinearConfig::new(3, 1).init(&device),
        ];
        let x = Tensor::<2>::from_data([[3.0f32, 4.0], [-1.0, 0.5]], &device);
        let y = layers.iter().fold(x, |h, l| l.forward(h).tanh());
        let grads = GradientsParams::from_grads(y.sum().backward(), &layers);
        // the norm written out: every gradient read on its own, squared and summed in f64
        let mut want = 0.0f64;
        for l in &layers {
            let mut each = vec![grads.get::<2>(l.weight.id).unwrap().into_data()];
            each.push(
                grads
                    .get::<1>(l.bias.as_ref().unwrap().id)
                    .unwrap()
                    .into_data(),
            );
            for d in each {
                want += d.iter::<f64>().map(|v| v * v).sum::<f64>();
            }
        }
        let before = counts();
        let norm = grad_norm(&grads, &layers);
        assert_eq!(counts().since(before).reads, 1, "six parameters, one read");
        assert!(
            (norm - want.sqrt()).abs() <= 1e-6 * want.sqrt(),
            "{norm} vs {}",
            want.sqrt()
        );
    }
}
