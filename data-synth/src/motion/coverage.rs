//! How well a set of training motions covers an evaluation motion, axis by axis
//! (`lfit motion coverage`).
//!
//! A *joint axis* is one of the three axis-angle components of one joint's rotation relative to
//! its parent (the entries `3..3 + 3J` of a pose vector, named `Joint.rx` / `.ry` / `.rz`). For
//! every joint axis the 1st and 99th percentiles of the training frames are taken (linear
//! interpolation between order statistics, numpy's default); an evaluation frame is *covered*
//! when every body joint axis lies in `[p1 − tol, p99 + tol]` (`tol` absorbs rounding noise on
//! joints that are constant, e.g. unmapped ones). The root joint's orientation (joint 0) is left
//! out of the covered fraction — it holds the heading, which says nothing about the body's pose —
//! and reported on its own; the root translation and the shape and expression blocks are not
//! looked at. The covered fraction may be restricted to some joints (e.g. those that both the
//! training and the evaluation motions' joint maps drive: a joint one importer leaves at the
//! identity and the other drives is "uncovered" by construction); statistics are kept for all.

use lfit_model::layout::Layout;

/// Statistics of one joint axis.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisCoverage {
    /// `Joint.rx` etc.
    pub name: String,
    /// Joint index (0 = the root) and axis (0 = x).
    pub joint: usize,
    pub axis: usize,
    /// Percentiles of the training frames (radians).
    pub p1: f64,
    pub p99: f64,
    /// Fraction of the evaluation frames outside `[p1 − tol, p99 + tol]`.
    pub outside: f64,
}

/// The result of [`coverage`].
#[derive(Debug, Clone, PartialEq)]
pub struct Coverage {
    pub train_frames: usize,
    pub eval_frames: usize,
    /// Fraction of evaluation frames whose every counted non-root joint axis lies within its
    /// range.
    pub covered: f64,
    /// The same with the root orientation's three axes included.
    pub covered_with_root: f64,
    /// The joints counted in `covered` (root excluded).
    pub counted: Vec<usize>,
    /// Every joint axis, root first, in layout order.
    pub axes: Vec<AxisCoverage>,
}

/// The `q` quantile (0..=1) of sorted values, by linear interpolation.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    let n = sorted.len();
    if n == 0 {
        return f64::NAN;
    }
    let h = (n - 1) as f64 * q.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(n - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// Coverage of `eval` by the frames of all `train` clips (module docs), counting the joints
/// `joints` (default: every joint but the root; the root is never counted in `covered`). Every
/// pose must have at least `layout.pose_dim()` finite numbers.
pub fn coverage(
    layout: &Layout,
    train: &[&[Vec<f64>]],
    eval: &[Vec<f64>],
    tolerance: f64,
    joints: Option<&[usize]>,
) -> Result<Coverage, String> {
    let nj = layout.num_joints();
    let dim = layout.pose_dim();
    let counted: Vec<usize> = match joints {
        None => (1..nj).collect(),
        Some(js) => {
            if let Some(j) = js.iter().find(|&&j| j >= nj) {
                return Err(format!("joint {j} is out of range (the layout has {nj})"));
            }
            let mut c: Vec<usize> = js.iter().copied().filter(|&j| j != 0).collect();
            c.sort_unstable();
            c.dedup();
            if c.is_empty() {
                return Err("no joint to count (the root is never counted)".into());
            }
            c
        }
    };
    let mut is_counted = vec![false; nj];
    for &j in &counted {
        is_counted[j] = true;
    }
    let train_frames: usize = train.iter().map(|c| c.len()).sum();
    if train_frames == 0 {
        return Err("no training frames".into());
    }
    if eval.is_empty() {
        return Err("no evaluation frames".into());
    }
    fn check(what: &str, poses: &[Vec<f64>], dim: usize) -> Result<(), String> {
        for (t, p) in poses.iter().enumerate() {
            if p.len() < dim {
                return Err(format!(
                    "{what} frame {t} has {} numbers; the layout needs {dim}",
                    p.len()
                ));
            }
            if p[..dim].iter().any(|v| !v.is_finite()) {
                return Err(format!("{what} frame {t} is not finite"));
            }
        }
        Ok(())
    }
    for (i, clip) in train.iter().enumerate() {
        check(&format!("training clip {i}"), clip, dim)?;
    }
    check("evaluation", eval, dim)?;
    let mut axes = Vec::with_capacity(3 * nj);
    // Per evaluation frame: whether some body axis / the root lies outside.
    let mut body_out = vec![false; eval.len()];
    let mut root_out = vec![false; eval.len()];
    let mut values = Vec::with_capacity(train_frames);
    for joint in 0..nj {
        for axis in 0..3 {
            let i = 3 + 3 * joint + axis;
            values.clear();
            values.extend(train.iter().flat_map(|c| c.iter().map(|p| p[i])));
            values.sort_by(f64::total_cmp);
            let (p1, p99) = (percentile(&values, 0.01), percentile(&values, 0.99));
            let mut outside = 0usize;
            for (t, p) in eval.iter().enumerate() {
                if p[i] < p1 - tolerance || p[i] > p99 + tolerance {
                    outside += 1;
                    if joint == 0 {
                        root_out[t] = true;
                    } else if is_counted[joint] {
                        body_out[t] = true;
                    }
                }
            }
            axes.push(AxisCoverage {
                name: layout.name(i),
                joint,
                axis,
                p1,
                p99,
                outside: outside as f64 / eval.len() as f64,
            });
        }
    }
    let n = eval.len() as f64;
    let covered = body_out.iter().filter(|o| !**o).count() as f64 / n;
    let covered_with_root = body_out
        .iter()
        .zip(&root_out)
        .filter(|(b, r)| !**b && !**r)
        .count() as f64
        / n;
    Ok(Coverage {
        train_frames,
        eval_frames: eval.len(),
        covered,
        covered_with_root,
        counted,
        axes,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn layout() -> Layout {
        Layout {
            joints: vec!["root".into(), "knee".into()],
            shape: 1,
            expression: 0,
        }
    }

    /// A pose of the 2-joint layout: translation, root (r0, 0, 0), knee (k, 0, 0), β.
    fn pose(root: f64, knee: f64) -> Vec<f64> {
        vec![5.0, 5.0, 5.0, root, 0.0, 0.0, knee, 0.0, 0.0, 9.0]
    }

    #[test]
    fn percentiles_interpolate_like_numpy() {
        let v: Vec<f64> = (0..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.01), 1.0);
        assert_eq!(percentile(&v, 0.99), 99.0);
        // numpy.percentile([0, 10], [1, 99]) = [0.1, 9.9]
        assert!((percentile(&[0.0, 10.0], 0.01) - 0.1).abs() < 1e-12);
        assert!((percentile(&[0.0, 10.0], 0.99) - 9.9).abs() < 1e-12);
        assert_eq!(percentile(&[3.0], 0.5), 3.0);
        assert!(percentile(&[], 0.5).is_nan());
    }

    #[test]
    fn known_coverage() {
        // Knee x over two training clips: 0, 1, ..., 100 (split 40 / 61): p1 = 1, p99 = 99.
        // Root x constant 0.5 in training.
        let a: Vec<Vec<f64>> = (0..40).map(|k| pose(0.5, f64::from(k))).collect();
        let b: Vec<Vec<f64>> = (40..=100).map(|k| pose(0.5, f64::from(k))).collect();
        let eval = vec![
            pose(0.5, 0.0),  // knee below p1
            pose(0.5, 1.0),  // on p1: inside
            pose(0.5, 50.0), // inside
            pose(2.0, 50.0), // inside for the body, root outside
            pose(0.5, 99.0), // on p99: inside
            pose(0.5, 99.5), // above p99
            pose(0.5, 100.0),
            pose(0.5, 42.0),
        ];
        let c = coverage(&layout(), &[&a[..], &b[..]], &eval, 1e-9, None).unwrap();
        assert_eq!(c.train_frames, 101);
        assert_eq!(c.eval_frames, 8);
        assert_eq!(c.covered, 5.0 / 8.0);
        assert_eq!(c.covered_with_root, 4.0 / 8.0);
        assert_eq!(c.axes.len(), 6);
        let knee_x = &c.axes[3];
        assert_eq!(knee_x.name, "knee.rx");
        assert_eq!((knee_x.joint, knee_x.axis), (1, 0));
        assert_eq!((knee_x.p1, knee_x.p99), (1.0, 99.0));
        assert_eq!(knee_x.outside, 3.0 / 8.0);
        let root_x = &c.axes[0];
        assert_eq!(
            (root_x.p1, root_x.p99, root_x.outside),
            (0.5, 0.5, 1.0 / 8.0)
        );
        // Constant axes (knee y, z) are inside everywhere.
        assert_eq!(c.axes[4].outside, 0.0);
        // The tolerance widens the range to [0.25, 99.75]: 99.5 comes inside, 0 and 100 do not.
        let wide = coverage(&layout(), &[&a[..], &b[..]], &eval, 0.75, None).unwrap();
        assert_eq!(wide.axes[3].outside, 2.0 / 8.0);
        // The evaluation clip against itself: all but the tails are covered.
        let same = coverage(&layout(), &[&a[..], &b[..]], &b, 0.0, None).unwrap();
        assert_eq!(same.covered, 60.0 / 61.0); // only 100 > p99 = 99
        // Counting only the root (never counted) or a joint the layout lacks is refused.
        assert!(coverage(&layout(), &[&a[..], &b[..]], &eval, 1e-9, Some(&[0])).is_err());
        assert!(coverage(&layout(), &[&a[..], &b[..]], &eval, 1e-9, Some(&[2])).is_err());
        let knee = coverage(&layout(), &[&a[..], &b[..]], &eval, 1e-9, Some(&[1, 1])).unwrap();
        assert_eq!(knee.counted, [1]);
        assert_eq!(knee.covered, c.covered);
    }

    #[test]
    fn counting_some_joints() {
        // Three joints; the elbow never moves in training and is bent in every evaluation frame.
        let layout = Layout {
            joints: vec!["root".into(), "knee".into(), "elbow".into()],
            shape: 0,
            expression: 0,
        };
        let pose = |knee: f64, elbow: f64| {
            let mut p = vec![0.0; 12];
            p[6] = knee;
            p[9] = elbow;
            p
        };
        let train: Vec<Vec<f64>> = (0..=100).map(|k| pose(f64::from(k), 0.0)).collect();
        let eval = vec![
            pose(50.0, 1.0),
            pose(0.0, 1.0),
            pose(20.0, 1.0),
            pose(30.0, 1.0),
        ];
        let all = coverage(&layout, &[&train[..]], &eval, 1e-9, None).unwrap();
        assert_eq!(all.counted, [1, 2]);
        assert_eq!(all.covered, 0.0);
        assert_eq!(all.axes[6].outside, 1.0); // elbow.rx
        // Counting the knee only: 0 is below p1 = 1, the rest inside.
        let knee = coverage(&layout, &[&train[..]], &eval, 1e-9, Some(&[0, 1])).unwrap();
        assert_eq!(knee.counted, [1]);
        assert_eq!(knee.covered, 0.75);
        assert_eq!(knee.axes[6].outside, 1.0); // still reported
    }

    #[test]
    fn bad_inputs_are_errors() {
        let a = vec![pose(0.0, 1.0)];
        assert!(coverage(&layout(), &[], &a, 0.0, None).is_err());
        let empty: Vec<Vec<f64>> = Vec::new();
        assert!(coverage(&layout(), &[&empty[..]], &a, 0.0, None).is_err());
        assert!(coverage(&layout(), &[&a[..]], &[], 0.0, None).is_err());
        let short = vec![vec![0.0; 5]];
        assert!(coverage(&layout(), &[&short[..]], &a, 0.0, None).is_err());
        let nan = vec![pose(f64::NAN, 0.0)];
        assert!(coverage(&layout(), &[&a[..]], &nan, 0.0, None).is_err());
    }
}
