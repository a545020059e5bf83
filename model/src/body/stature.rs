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
    let k = template.morph.coefficients();
    if b == 0 {
        return Err(ModelError::Config(format!(
            "a height gives β only to a model with shape coefficients: '{}' has none",
            template.id
        )));
    }
    if !(height_m.is_finite() && height_m > 0.0) {
        return Err(ModelError::Config(format!(
            "height {height_m}: must be a positive number of metres"
        )));
    }
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
        let g: Vec<f64> = (0..b)
            .map(|i| {
                template.morph.dirs[(3 * top + 1) * k + i]
                    - template.morph.dirs[(3 * sole + 1) * k + i]
            })
            .collect();
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
}
