//! Small shared helpers (random numbers, value sanitising, sampling around the start).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::Problem;

/// The generator every optimizer uses: ChaCha8 (fast, reproducible across platforms).
pub(crate) type OptRng = ChaCha8Rng;

/// Generator for `seed`.
pub(crate) fn rng(seed: u64) -> OptRng {
    OptRng::seed_from_u64(seed)
}

/// A well-mixed seed for sub-stream `stream` of `seed` (splitmix64), used by wrappers that own
/// several optimizers.
pub(crate) fn sub_seed(seed: u64, stream: u64) -> u64 {
    let mut z = seed
        ^ stream
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// One standard normal draw.
#[inline]
pub(crate) fn normal(rng: &mut OptRng) -> f64 {
    rng.sample(StandardNormal)
}

/// One uniform draw in `[0, 1)`.
#[inline]
pub(crate) fn uniform(rng: &mut OptRng) -> f64 {
    rng.random::<f64>()
}

/// NaN counts as +inf for every optimizer.
#[inline]
pub(crate) fn sanitize(v: f64) -> f64 {
    if v.is_nan() { f64::INFINITY } else { v }
}

/// `start + factor · scale ⊙ N(0, I)`, clipped into the bounds.
pub(crate) fn gaussian_around(problem: &Problem, factor: f64, rng: &mut OptRng) -> Vec<f64> {
    let mut x: Vec<f64> = problem
        .start
        .iter()
        .zip(&problem.scale)
        .map(|(&s, &sc)| s + factor * sc * normal(rng))
        .collect();
    problem.bounds.clip(&mut x);
    x
}

/// Index of the smallest value (NaN-safe via total order; first on ties). `None` if empty.
pub(crate) fn argmin(values: &[f64]) -> Option<usize> {
    let mut best: Option<usize> = None;
    for (i, v) in values.iter().enumerate() {
        match best {
            None => best = Some(i),
            Some(b) if v.total_cmp(&values[b]).is_lt() => best = Some(i),
            _ => {}
        }
    }
    best
}
