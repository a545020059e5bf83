//! Standard test functions, nevergrad-style: domain `[-5, 5]^d`, start 0, scale 1, each
//! shifted so that the optimum is at `x = (1, …, 1)` with value 0 (Rosenbrock natively).

use super::{Bounds, Problem};

/// `Σ (x_i − 1)²`.
pub fn sphere(x: &[f64]) -> f64 {
    x.iter().map(|&v| (v - 1.0) * (v - 1.0)).sum()
}

/// Axis-aligned ellipsoid with condition number 1e6: `Σ 10^(6(i−1)/(d−1)) (x_i − 1)²`.
pub fn ellipsoid(x: &[f64]) -> f64 {
    ellipsoid_cond(x, 1e6)
}

/// Axis-aligned ellipsoid with condition number `cond`: `Σ cond^((i−1)/(d−1)) (x_i − 1)²`
/// (coefficient 1 when d = 1).
pub fn ellipsoid_cond(x: &[f64], cond: f64) -> f64 {
    let d = x.len();
    if d <= 1 {
        return sphere(x);
    }
    let l = cond.log10();
    x.iter()
        .enumerate()
        .map(|(i, &v)| 10f64.powf(l * i as f64 / (d - 1) as f64) * (v - 1.0) * (v - 1.0))
        .sum()
}

/// Rosenbrock: `Σ 100 (x_{i+1} − x_i²)² + (1 − x_i)²`; optimum at 1 natively.
pub fn rosenbrock(x: &[f64]) -> f64 {
    x.windows(2)
        .map(|w| 100.0 * (w[1] - w[0] * w[0]).powi(2) + (1.0 - w[0]).powi(2))
        .sum()
}

/// Rastrigin shifted to 1: `10 d + Σ (y_i² − 10 cos 2π y_i)`, `y = x − 1`.
pub fn rastrigin(x: &[f64]) -> f64 {
    let tau = 2.0 * std::f64::consts::PI;
    10.0 * x.len() as f64
        + x.iter()
            .map(|&v| {
                let y = v - 1.0;
                y * y - 10.0 * (tau * y).cos()
            })
            .sum::<f64>()
}

/// A test function.
pub type TestFn = fn(&[f64]) -> f64;

/// The four functions with their names.
pub const ALL: [(&str, TestFn); 4] = [
    ("sphere", sphere),
    ("ellipsoid", ellipsoid),
    ("rosenbrock", rosenbrock),
    ("rastrigin", rastrigin),
];

/// `[-5, 5]^d`, start 0, scale 1 (nevergrad's standard benchmark setting).
pub fn problem(d: usize) -> Problem {
    Problem {
        bounds: Bounds {
            lower: vec![-5.0; d],
            upper: vec![5.0; d],
        },
        start: vec![0.0; d],
        scale: vec![1.0; d],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn optima_are_at_one_with_value_zero() {
        for d in [1usize, 2, 10] {
            let one = vec![1.0; d];
            for (name, f) in ALL {
                assert!(f(&one).abs() < 1e-12, "{name} d={d}");
                if name == "rosenbrock" && d == 1 {
                    continue; // Rosenbrock has no term in one dimension
                }
                let mut off = one.clone();
                off[0] += 0.1;
                assert!(f(&off) > 0.0, "{name} d={d}");
            }
        }
        assert!(problem(4).validate().is_ok());
    }

    #[test]
    fn known_values() {
        assert_eq!(sphere(&[0.0, 0.0]), 2.0);
        assert!((ellipsoid(&[0.0, 0.0, 0.0]) - (1.0 + 1e3 + 1e6)).abs() < 1e-6);
        assert_eq!(rosenbrock(&[0.0, 0.0]), 1.0);
        // y = -1 → 1 - 10 cos(-2π) = -9 per coordinate.
        assert!((rastrigin(&[0.0, 0.0]) - (20.0 - 18.0)).abs() < 1e-12);
    }
}
