//! What the model crate's benches share.

use lfit_model::Template;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// `n` random parameter vectors of `template` (fixed seed): rotations and translation uniform in
/// ±0.3 (rad, m), shape and expression coefficients ~ N(0, 0.5²).
pub fn params(template: &Template, n: usize) -> Vec<Vec<f64>> {
    let layout = template.layout();
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    (0..n)
        .map(|_| {
            let mut p: Vec<f64> = (0..layout.pose_dim())
                .map(|_| rng.random_range(-0.3..0.3))
                .collect();
            for _ in 0..layout.shape + layout.expression {
                let z: f64 = StandardNormal.sample(&mut rng);
                p.push(0.5 * z);
            }
            p
        })
        .collect()
}
