//! Shared helpers of the benchmarks.

use lfit::model::pose::{POSE_DIM, Pose};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` poses with every entry uniform in `[−spread, spread)`, from a fixed seed.
pub fn random_poses(n: usize, spread: f64) -> Vec<Pose> {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    (0..n)
        .map(|_| {
            let mut p = [0.0; POSE_DIM];
            for v in p.iter_mut() {
                *v = rng.random_range(-spread..spread);
            }
            p
        })
        .collect()
}
