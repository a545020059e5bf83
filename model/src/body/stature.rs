//! A subject's stature and the shape β of a given height: the rest mesh's vertical extent
//! (sole to crown on a standing body, the stature `lfit model import-makehuman` reports), and
//! the β of least norm that tall — `lfit fit --known-shape height:M`.

use crate::error::{ModelError, Result};
use crate::pose::SHAPE_BOUND;
use crate::template::Template;

/// The rest height at shape coefficients `beta` (expression at zero): the vertical (y)
/// extent of the rest mesh, sole to crown on a standing body — the stature
/// `lfit model import-makehuman` reports. Also the highest and the lowest vertex.
pub fn rest_height(template: &Template, beta: &[f64]) -> (f64, usize, usize) {
    let mut coeffs = vec![0.0; template.morph.coefficients()];
    for (c, b) in coeffs.iter_mut().zip(beta) {
        *c = *b;
    }
    let (mut top, mut sole) = ((f64::MIN, 0), (f64::MAX, 0));
    for (v, base) in template.vertices.iter().enumerate() {
        let y = template
            .morph
            .rest_vertex(v, base.as_dvec3(), &coeffs, &[])
            .y;
        if y > top.0 {
            top = (y, v);
        }
        if y < sole.0 {
            sole = (y, v);
        }
    }
    (top.0 - sole.0, top.1, sole.1)
}

/// The shape β of a subject `height_m` metres tall ([`rest_height`]) that the
/// shape prior makes most likely: the β of least norm whose rest mesh is that tall. With
/// unit-variance coefficients (the shape prior `Σ β²`) that is the prior's mode under the
/// height — the mean proportions, scaled along the directions that change the stature.
/// The height is linear in β while the highest and lowest vertices stay the same ones, so
/// each step solves it exactly for the current pair and stops once the pair holds.
///
/// A one-line error where the model has no shape coefficients, the height is not a finite
/// positive number, or it needs a coefficient beyond ±[`SHAPE_BOUND`] (the
/// shape box of every fit).
pub fn shape_for_height(template: &Template, height_m: f64) -> Result<Vec<f64>> {
    let b = template.morph.shape;
    if b == 0 {
        return Err(ModelError::Config(format!(
            "a height gives β only to a model with shape coefficients: '{}' has none",
            template.id
        )));
    }
    positive_metres("height", height_m)?;
    let mut beta = vec![0.0; b];
    let mut pair = None;
    for _ in 0..32 {
        let (_, top, sole) = rest_height(template, &beta);
        if pair == Some((top, sole)) {
            break;
        }
        pair = Some((top, sole));
        // y_top − y_sole = h0 + g·β for this pair; the least-norm β with it equal to height.
        let y = |v: usize| {
            template
                .morph
                .rest_vertex(v, template.vertices[v].as_dvec3(), &[], &[])
                .y
        };
        let h0 = y(top) - y(sole);
        let g = height_gradient(template, top, sole);
        let gg: f64 = g.iter().map(|x| x * x).sum();
        if gg <= 0.0 {
            return Err(ModelError::Config(format!(
                "model '{}': no shape coefficient changes its height",
                template.id
            )));
        }
        let scale = (height_m - h0) / gg;
        beta = g.iter().map(|x| x * scale).collect();
    }
    let (reached, ..) = rest_height(template, &beta);
    let bound = SHAPE_BOUND;
    if beta.iter().any(|x| x.abs() > bound) || (reached - height_m).abs() > 1e-6 {
        let (mean, ..) = rest_height(template, &[]);
        return Err(ModelError::Config(format!(
            "height {height_m} m is out of reach of model '{}' within its shape box (±{bound}; its mean shape is {mean:.3} m tall)",
            template.id
        )));
    }
    Ok(beta)
}

/// `value` where it is a finite positive number of metres; else the one-line error "`what`
/// `value`: must be a positive number of metres".
pub(crate) fn positive_metres(what: &str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(ModelError::Config(format!(
            "{what} {value}: must be a positive number of metres"
        )))
    }
}

/// The vertices that can be the highest or the lowest of the rest mesh for some β in the shape
/// box (every |β_k| ≤ [`SHAPE_BOUND`], expression at zero), so that [`StatureVertices::height`]
/// measures the rest height on a few vertices instead of the whole mesh. A vertex `v` is
/// left out where another vertex `u` stays above it over the whole box: `y_v(β) − y_u(β) =
/// y_v(0) − y_u(0) + Σ_k (d_vk − d_uk) β_k` is at most `y_v(0) − y_u(0) + SHAPE_BOUND Σ_k
/// |d_vk − d_uk|`, and where that is negative `v` is never the top (the sole likewise). The
/// vertices `u` tried are the highest (lowest) at the mean shape and at each coefficient's two
/// bounds.
#[derive(Debug, Clone, PartialEq)]
pub struct StatureVertices {
    top: Vec<usize>,
    sole: Vec<usize>,
}

impl StatureVertices {
    /// The candidates of `template` (ascending vertex order, as [`rest_height`] scans).
    pub fn of(template: &Template) -> Self {
        let morph = &template.morph;
        let (b, k) = (morph.shape, morph.coefficients());
        let n = template.vertices.len();
        let y0: Vec<f64> = (0..n)
            .map(|v| {
                morph
                    .rest_vertex(v, template.vertices[v].as_dvec3(), &[], &[])
                    .y
            })
            .collect();
        let dirs = |v: usize| -> &[f64] {
            if k > 0 {
                &morph.dirs[(3 * v + 1) * k..(3 * v + 1) * k + b]
            } else {
                &[]
            }
        };
        // The extremes at the mean shape and at each coefficient's bounds.
        let mut shapes = vec![vec![0.0; b]];
        for i in 0..b {
            for sign in [-1.0, 1.0] {
                let mut beta = vec![0.0; b];
                beta[i] = sign * SHAPE_BOUND;
                shapes.push(beta);
            }
        }
        let (mut tops, mut soles): (Vec<usize>, Vec<usize>) = shapes
            .iter()
            .map(|beta| {
                let (_, t, s) = rest_height(template, beta);
                (t, s)
            })
            .unzip();
        for set in [&mut tops, &mut soles] {
            set.sort_unstable();
            set.dedup();
        }
        // `v` may exceed `u` somewhere in the box (upward: the top; `sign` −1: below, the sole).
        let may_pass = |v: usize, u: usize, sign: f64| {
            let reach: f64 = dirs(v)
                .iter()
                .zip(dirs(u))
                .map(|(a, c)| (a - c).abs())
                .sum();
            // A margin of rounding: the bound must not drop a tie.
            sign * (y0[v] - y0[u]) + SHAPE_BOUND * reach >= -1e-9
        };
        // Then the same test between the candidates left: a flat crown or sole leaves many
        // vertices that the few extremes tried do not rule out. Where two rows are equal (the
        // same height at every β), [`rest_height`] takes the lower index: the other is dropped.
        let prune = |sign: f64, tried: &[usize]| -> Vec<usize> {
            let near: Vec<usize> = (0..n)
                .filter(|&v| tried.iter().all(|&u| may_pass(v, u, sign)))
                .collect();
            near.iter()
                .copied()
                .filter(|&v| {
                    near.iter().all(|&u| {
                        let same = y0[u] == y0[v] && dirs(u) == dirs(v);
                        u == v || if same { u > v } else { may_pass(v, u, sign) }
                    })
                })
                .collect()
        };
        Self {
            top: prune(1.0, &tops),
            sole: prune(-1.0, &soles),
        }
    }

    /// How many vertices can be the top and the sole.
    pub fn counts(&self) -> (usize, usize) {
        (self.top.len(), self.sole.len())
    }

    /// [`rest_height`] at `beta` — the same height, highest and lowest vertex — from the
    /// candidates alone where `beta` lies in the shape box, from the whole mesh otherwise.
    pub fn height(&self, template: &Template, beta: &[f64]) -> (f64, usize, usize) {
        if beta.iter().any(|b| !(b.abs() <= SHAPE_BOUND)) {
            return rest_height(template, beta);
        }
        let mut coeffs = vec![0.0; template.morph.coefficients()];
        for (c, b) in coeffs.iter_mut().zip(beta) {
            *c = *b;
        }
        let y = |v: usize| {
            template
                .morph
                .rest_vertex(v, template.vertices[v].as_dvec3(), &coeffs, &[])
                .y
        };
        let (mut top, mut sole) = ((f64::MIN, 0), (f64::MAX, 0));
        for &v in &self.top {
            let h = y(v);
            if h > top.0 {
                top = (h, v);
            }
        }
        for &v in &self.sole {
            let h = y(v);
            if h < sole.0 {
                sole = (h, v);
            }
        }
        (top.0 - sole.0, top.1, sole.1)
    }
}

/// The gradient of the rest height with respect to β (one entry per shape coefficient) where
/// `top` and `sole` are the highest and the lowest vertex: `d_top,y − d_sole,y` — the height is
/// linear in β while that pair holds ([`rest_height`]).
pub fn height_gradient(template: &Template, top: usize, sole: usize) -> Vec<f64> {
    let morph = &template.morph;
    let k = morph.coefficients();
    (0..morph.shape)
        .map(|i| morph.dirs[(3 * top + 1) * k + i] - morph.dirs[(3 * sole + 1) * k + i])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`shape_for_height`]: the β it gives is that tall (the rest mesh measured again),
    /// and of least norm — along the height's gradient for the highest and lowest vertices of
    /// the result, the only direction a least-norm solution of one linear equation can take;
    /// a height out of the shape box, a bad height and a model without shape are refused.
    #[test]
    fn the_shape_for_a_height_is_that_tall_and_of_least_norm() {
        let (t, _) = crate::body::procedural::morphable_default_template().unwrap();
        let (mean, ..) = rest_height(&t, &[]);
        let (b, k) = (t.morph.shape, t.morph.coefficients());
        for h in [mean - 0.04, mean + 0.03, mean] {
            let beta = shape_for_height(&t, h).unwrap();
            assert_eq!(beta.len(), b);
            let (got, top, sole) = rest_height(&t, &beta);
            assert!((got - h).abs() < 1e-9, "{h}: {got}");
            let g: Vec<f64> = (0..b)
                .map(|i| t.morph.dirs[(3 * top + 1) * k + i] - t.morph.dirs[(3 * sole + 1) * k + i])
                .collect();
            let c = beta.iter().zip(&g).map(|(x, y)| x * y).sum::<f64>()
                / g.iter().map(|y| y * y).sum::<f64>();
            for (x, y) in beta.iter().zip(&g) {
                assert!((x - c * y).abs() < 1e-12, "{h}: β {beta:?} not along {g:?}");
            }
            // Another β of the same height (a step orthogonal to g keeps this pair's height)
            // is longer.
            let mut other = beta.clone();
            let (i, j) = (0, 1);
            other[i] += g[j] * 0.1;
            other[j] -= g[i] * 0.1;
            let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>();
            assert!(norm(&other) > norm(&beta));
        }
        assert!(
            shape_for_height(&t, mean)
                .unwrap()
                .iter()
                .all(|x| x.abs() < 1e-9)
        );
        let far = shape_for_height(&t, mean * 2.0).unwrap_err().to_string();
        assert!(far.contains("out of reach") && far.contains("±3"), "{far}");
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = shape_for_height(&t, bad).unwrap_err().to_string();
            assert!(e.contains("positive number of metres"), "{bad}: {e}");
        }
        let rigid =
            shape_for_height(&crate::body::procedural::default_template(), mean).unwrap_err();
        assert!(rigid.to_string().contains("has none"), "{rigid}");
    }

    /// [`StatureVertices`] measures what [`rest_height`] measures over the whole mesh — the
    /// same height, highest and lowest vertex, to the bit — at shapes spread over the box
    /// (its corners included) from a few of the vertices, and falls back to the whole mesh
    /// outside the box; [`height_gradient`] is the height's derivative (central differences).
    #[test]
    fn the_stature_candidates_measure_the_whole_mesh_s_height() {
        let (procedural, _) = crate::body::procedural::morphable_default_template().unwrap();
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-cmu_mb.npz");
        let makehuman = crate::modelfile::load(&path).unwrap();
        for t in [&procedural, &makehuman] {
            let s = StatureVertices::of(t);
            let (tops, soles) = s.counts();
            // MakeHuman: 5 and 86 of 13,380 (its soles are flat).
            assert!(tops >= 1 && soles >= 1);
            assert!(
                tops + soles < t.vertices.len() / 100,
                "{}: {tops} + {soles} candidates",
                t.id
            );
            candidates_measure(t, &s);
        }
    }

    fn candidates_measure(t: &Template, s: &StatureVertices) {
        let b = t.morph.shape;
        let mut shapes: Vec<Vec<f64>> = (0..40)
            .map(|n| {
                (0..b)
                    .map(|i| SHAPE_BOUND * ((n * 7 + i * 13) as f64 * 0.731).sin())
                    .collect()
            })
            .collect();
        shapes.push(vec![SHAPE_BOUND; b]);
        shapes.push(vec![-SHAPE_BOUND; b]);
        shapes.push(
            (0..b)
                .map(|i| if i % 2 == 0 { 3.0 } else { -3.0 })
                .collect(),
        );
        for beta in &shapes {
            assert_eq!(s.height(t, beta), rest_height(t, beta), "β {beta:?}");
        }
        let outside = vec![4.5; b];
        assert_eq!(s.height(t, &outside), rest_height(t, &outside));
        let beta = &shapes[3];
        let (_, top, sole) = s.height(t, beta);
        let g = height_gradient(t, top, sole);
        assert_eq!(g.len(), b);
        for i in 0..b {
            let h = 1e-6;
            let mut up = beta.clone();
            up[i] += h;
            let mut down = beta.clone();
            down[i] -= h;
            let d = (rest_height(t, &up).0 - rest_height(t, &down).0) / (2.0 * h);
            assert!((d - g[i]).abs() < 1e-6, "entry {i}: {d} vs {}", g[i]);
        }
    }
}
