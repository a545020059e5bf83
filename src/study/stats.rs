//! The statistics of the papers' comparisons (SPEC §9), written here on statrs' distributions:
//!
//! - Wilcoxon signed-rank test (papers/000 Table 3): zeros dropped (Wilcoxon's method), ranks of
//!   |d| with ties averaged; exact null distribution when there are at most 50 non-zero
//!   differences and no ties among them (zeros dropped first), otherwise the normal
//!   approximation with the tie correction (no continuity correction) — what
//!   `scipy.stats.wilcoxon` 1.17.1 chooses by default, two-sided;
//! - Friedman test with average within-block ranks and the tie correction
//!   (`scipy.stats.friedmanchisquare`), and Holm's step-down post-hoc test of every method against
//!   the best-ranked one with `z = (R_i − R_0) / sqrt(k (k + 1) / (6 n))` (papers/001 Table 4);
//! - relative performance `RP = (loss − best) / best` (papers/000 Table 2).

use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};

/// Average ranks (1-based) of `values`, ties sharing the mean of their positions; also returns
/// the sizes of the tie groups.
pub fn average_ranks(values: &[f64]) -> (Vec<f64>, Vec<usize>) {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut ranks = vec![0.0; values.len()];
    let mut ties = Vec::new();
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && values[order[j + 1]] == values[order[i]] {
            j += 1;
        }
        let rank = (i + j) as f64 / 2.0 + 1.0;
        for &o in &order[i..=j] {
            ranks[o] = rank;
        }
        ties.push(j - i + 1);
        i = j + 1;
    }
    (ranks, ties)
}

/// Result of a two-sided Wilcoxon signed-rank test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wilcoxon {
    /// `min(W+, W−)`.
    pub statistic: f64,
    pub p: f64,
    /// Non-zero differences used.
    pub n: usize,
    pub exact: bool,
    /// `W+ − W−`: positive when `x` tends to be larger than `y`.
    pub direction: f64,
}

/// Number of subsets of {1..n} with each rank sum, for the exact null distribution of W+.
fn signed_rank_counts(n: usize) -> Vec<f64> {
    let max = n * (n + 1) / 2;
    let mut c = vec![0.0f64; max + 1];
    c[0] = 1.0;
    for k in 1..=n {
        for s in (k..=max).rev() {
            c[s] += c[s - k];
        }
    }
    c
}

/// Two-sided Wilcoxon signed-rank test of paired samples `x` and `y`; `None` when they differ in
/// length or every difference is zero.
pub fn wilcoxon(x: &[f64], y: &[f64]) -> Option<Wilcoxon> {
    if x.len() != y.len() {
        return None;
    }
    let d: Vec<f64> = x
        .iter()
        .zip(y)
        .map(|(a, b)| a - b)
        .filter(|d| *d != 0.0)
        .collect();
    // Zero differences are dropped (scipy's default zero_method "wilcox"); the exact
    // distribution then applies to the rest as in scipy 1.17 (n ≤ 50, no ties).
    let n = d.len();
    if n == 0 {
        return None;
    }
    let abs: Vec<f64> = d.iter().map(|v| v.abs()).collect();
    let (ranks, ties) = average_ranks(&abs);
    let w_plus: f64 = d
        .iter()
        .zip(&ranks)
        .filter(|(v, _)| **v > 0.0)
        .map(|(_, r)| r)
        .sum();
    let total = (n * (n + 1)) as f64 / 2.0;
    let w_minus = total - w_plus;
    let has_ties = ties.iter().any(|&t| t > 1);
    let statistic = w_plus.min(w_minus);
    if n <= 50 && !has_ties {
        let counts = signed_rank_counts(n);
        let all = 2f64.powi(n as i32);
        let k = w_plus.round() as usize;
        let cdf: f64 = counts[..=k].iter().sum::<f64>() / all;
        let sf: f64 = counts[k..].iter().sum::<f64>() / all;
        let p = (2.0 * cdf.min(sf)).min(1.0);
        return Some(Wilcoxon {
            statistic,
            p,
            n,
            exact: true,
            direction: w_plus - w_minus,
        });
    }
    let nf = n as f64;
    let mean = nf * (nf + 1.0) / 4.0;
    let tie: f64 = ties.iter().map(|&t| (t * t * t - t) as f64).sum();
    let se = ((nf * (nf + 1.0) * (2.0 * nf + 1.0) - tie / 2.0) / 24.0).sqrt();
    let z = (w_plus - mean) / se;
    let normal = Normal::standard();
    let p = (2.0 * normal.sf(z.abs())).min(1.0);
    Some(Wilcoxon {
        statistic,
        p,
        n,
        exact: false,
        direction: w_plus - w_minus,
    })
}

/// Verdict of papers/000 Table 3 for "row vs column" on losses (lower is better) at level `alpha`:
/// `+` row better, `-` row worse, `≈` no significant difference.
pub fn verdict(row: &[f64], col: &[f64], alpha: f64) -> (&'static str, Option<f64>) {
    match wilcoxon(row, col) {
        Some(w) if w.p < alpha => (if w.direction < 0.0 { "+" } else { "-" }, Some(w.p)),
        Some(w) => ("≈", Some(w.p)),
        None => ("≈", None),
    }
}

/// Friedman test over `blocks` (rows: problem instances; columns: methods; lower is better).
#[derive(Debug, Clone, PartialEq)]
pub struct Friedman {
    pub statistic: f64,
    pub p: f64,
    /// Average rank of every method (1 = best).
    pub ranks: Vec<f64>,
    /// Holm post-hoc against the best-ranked method, in rank order (the control excluded).
    pub holm: Vec<HolmRow>,
    pub control: usize,
}

#[derive(Debug, Clone, PartialEq)]
pub struct HolmRow {
    pub method: usize,
    pub rank: f64,
    /// Unadjusted two-sided p of `z = (R_i − R_0)/SE`.
    pub p: f64,
    /// papers/001's threshold `α / (position − 1)` for the method at 1-based rank position
    /// `position` (the control is position 1).
    pub threshold: f64,
    /// Holm-adjusted p (step-down, monotone).
    pub p_adjusted: f64,
    /// Rejected by Holm's step-down procedure at `alpha`.
    pub significant: bool,
}

/// Friedman test and Holm post-hoc at level `alpha`. `None` with fewer than 2 methods or blocks,
/// or ragged rows.
pub fn friedman(blocks: &[Vec<f64>], alpha: f64) -> Option<Friedman> {
    let n = blocks.len();
    let k = blocks.first()?.len();
    if n < 2 || k < 2 || blocks.iter().any(|b| b.len() != k) {
        return None;
    }
    let mut sums = vec![0.0; k];
    let mut tie_sum = 0.0;
    for b in blocks {
        let (r, ties) = average_ranks(b);
        for (s, v) in sums.iter_mut().zip(&r) {
            *s += v;
        }
        tie_sum += ties.iter().map(|&t| (t * t * t - t) as f64).sum::<f64>();
    }
    let (nf, kf) = (n as f64, k as f64);
    let ranks: Vec<f64> = sums.iter().map(|s| s / nf).collect();
    let ssq: f64 = sums.iter().map(|s| s * s).sum();
    let mut statistic = 12.0 / (nf * kf * (kf + 1.0)) * ssq - 3.0 * nf * (kf + 1.0);
    let correction = 1.0 - tie_sum / (nf * (kf * kf * kf - kf));
    if correction > 0.0 {
        statistic /= correction;
    }
    let p = ChiSquared::new(kf - 1.0)
        .ok()
        .map_or(f64::NAN, |c| c.sf(statistic));

    let (control, holm) = holm_post_hoc(&ranks, n, alpha);
    Some(Friedman {
        statistic,
        p,
        ranks,
        holm,
        control,
    })
}

/// Holm's step-down post-hoc test of every method against the best-ranked one (the control),
/// from average ranks over `n` instances: `z = (R_i − R_0) / sqrt(k (k + 1) / (6 n))`, two-sided
/// normal p-values (papers/001 Table 4). Rows come in rank order, the control excluded.
pub fn holm_post_hoc(ranks: &[f64], n: usize, alpha: f64) -> (usize, Vec<HolmRow>) {
    let k = ranks.len();
    let (nf, kf) = (n as f64, k as f64);
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| ranks[a].total_cmp(&ranks[b]).then(a.cmp(&b)));
    let control = order[0];
    let se = (kf * (kf + 1.0) / (6.0 * nf)).sqrt();
    let normal = Normal::standard();
    let mut holm: Vec<HolmRow> = order[1..]
        .iter()
        .enumerate()
        .map(|(i, &m)| {
            let z = (ranks[m] - ranks[control]) / se;
            HolmRow {
                method: m,
                rank: ranks[m],
                p: (2.0 * normal.sf(z.abs())).min(1.0),
                threshold: alpha / (i + 1) as f64,
                p_adjusted: 0.0,
                significant: false,
            }
        })
        .collect();
    // Holm step-down on the p-values sorted ascending.
    let m = holm.len();
    let mut by_p: Vec<usize> = (0..m).collect();
    by_p.sort_by(|&a, &b| holm[a].p.total_cmp(&holm[b].p));
    let mut running = 0.0f64;
    let mut still_rejecting = true;
    for (i, &h) in by_p.iter().enumerate() {
        let factor = (m - i) as f64;
        running = running.max((factor * holm[h].p).min(1.0));
        holm[h].p_adjusted = running;
        still_rejecting = still_rejecting && holm[h].p <= alpha / factor;
        holm[h].significant = still_rejecting;
    }
    (control, holm)
}

/// Relative performance of papers/000 Table 2: `(value − best) / best`, as a fraction.
pub fn relative_performance(value: f64, best: f64) -> f64 {
    if best == 0.0 {
        if value == 0.0 { 0.0 } else { f64::INFINITY }
    } else {
        (value - best) / best.abs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // Reference values computed once with SciPy 1.17.1 (`scipy.stats.wilcoxon`,
    // `scipy.stats.friedmanchisquare`, `scipy.stats.norm.sf`) on exactly these inputs.

    #[test]
    fn wilcoxon_exact_matches_scipy() {
        let x = [
            12.0, 14.125, 9.75, 16.0, 11.25, 13.5, 10.5, 16.75, 13.0, 14.5,
        ];
        let y = [
            12.5, 14.0, 11.0, 17.5, 11.0, 15.75, 10.125, 18.375, 14.75, 15.875,
        ];
        let w = wilcoxon(&x, &y).expect("test");
        assert!(w.exact);
        assert_eq!(w.statistic, 6.0);
        // scipy.stats.wilcoxon(x, y) (no ties, n = 10: exact) -> statistic 6.0, pvalue 0.02734375
        assert!((w.p - 0.02734375).abs() < 1e-12, "{}", w.p);
        assert!(w.direction < 0.0, "x is mostly lower");
        assert_eq!(verdict(&x, &y, 0.05).0, "+");
        assert_eq!(verdict(&y, &x, 0.05).0, "-");
    }

    /// Zero differences without other ties: scipy 1.17.1 drops the zeros and stays exact.
    #[test]
    fn wilcoxon_with_zeros_but_no_ties_is_exact_as_in_scipy() {
        let x = [
            12.0, 14.125, 9.75, 16.0, 11.25, 13.5, 10.5, 16.75, 13.0, 14.5, 3.0, 4.0,
        ];
        let y = [
            12.5, 14.0, 11.0, 17.5, 11.0, 15.75, 10.125, 18.375, 14.75, 15.875, 3.0, 4.0,
        ];
        let w = wilcoxon(&x, &y).expect("test");
        // scipy.stats.wilcoxon(x, y) -> statistic 6.0, pvalue 0.02734375 (the asymptotic
        // p-value would be 0.02841686417486375).
        assert!(w.exact);
        assert_eq!((w.statistic, w.n), (6.0, 10));
        assert!((w.p - 0.02734375).abs() < 1e-12, "{}", w.p);
    }

    #[test]
    fn wilcoxon_with_ties_and_zeros_matches_scipy_asymptotic() {
        let a: Vec<f64> = (1..=16).map(f64::from).collect();
        let b = [
            1.5, 2.0, 2.0, 5.0, 4.0, 8.0, 6.0, 6.0, 12.0, 9.0, 11.0, 14.0, 10.0, 13.0, 16.0, 20.0,
        ];
        let w = wilcoxon(&a, &b).expect("test");
        assert!(!w.exact);
        // scipy.stats.wilcoxon(a, b, method='asymptotic') -> 47.5, 0.749948406918076
        assert_eq!(w.statistic, 47.5);
        assert!((w.p - 0.749948406918076).abs() < 1e-9, "{}", w.p);
        assert_eq!(verdict(&a, &b, 0.05).0, "≈");
    }

    #[test]
    fn wilcoxon_large_sample_uses_the_normal_approximation_like_scipy() {
        let u = [
            2.040919, -2.555665, 0.418099, -0.56777, -0.452649, -0.215597, -2.019986, -0.231932,
            -0.865213, 3.323, 0.225787, -0.352631, -0.281287, -0.668046, -1.055151, -0.390801,
            0.481945, -0.238554, 0.957759, -0.199802, 0.02426, 1.545821, 0.545106, -0.505229,
            -0.182839, 0.540525, 1.935088, -0.26962, -0.243559, 1.002314, -0.88646, -0.29172,
            0.882539, 0.58035, 0.091517, 0.670104, -2.828162, 1.021307, -0.959645, -1.66862,
            0.276446, 0.700545, -0.444767, -1.076406, 0.026125, -0.052747, 1.405598, 0.747408,
            0.193816, 1.111633, -0.205523, -0.9259, 0.584058, 0.582538, -0.214829, -0.782809,
            0.229154, -2.493894, 0.690125, 0.491368,
        ];
        let v = [
            1.421491, -2.324988, 0.136049, 0.010841, -1.269733, -0.472844, -1.465196, 0.546268,
            -1.744216, 3.27398, 0.589797, -0.457239, 0.714033, -1.06366, -0.677885, -0.715004,
            1.384927, -0.049379, 0.971633, -0.858895, 1.065172, 2.12221, 1.121887, 0.263712,
            0.191774, 0.420902, 1.734967, -0.46972, 0.641477, 0.472123, -0.984645, -0.252342,
            1.194848, 1.068025, -0.333032, 0.005098, -2.630369, 1.828089, -0.381116, -1.360794,
            0.317868, 1.047162, -0.366435, -0.467803, -0.171099, 0.214373, 1.550208, 1.219088,
            0.506135, 2.586651, 0.743804, 0.022469, -0.235694, 0.61238, -0.319134, -0.316448,
            -0.710359, -1.706645, 1.423616, 0.040333,
        ];
        let w = wilcoxon(&u, &v).expect("test");
        assert!(!w.exact);
        // scipy.stats.wilcoxon(u, v) (n = 60 > 50: asymptotic) -> 607.0, 0.023367405214037344
        assert_eq!(w.statistic, 607.0);
        assert!((w.p - 0.023367405214037344).abs() < 1e-9, "{}", w.p);
    }

    #[test]
    fn friedman_matches_scipy_and_holm_matches_papers001_table4() {
        let data = vec![
            vec![0.31, 0.29, 0.40, 0.35],
            vec![0.27, 0.30, 0.41, 0.33],
            vec![0.30, 0.30, 0.39, 0.36],
            vec![0.25, 0.28, 0.45, 0.31],
            vec![0.33, 0.31, 0.38, 0.40],
            vec![0.29, 0.27, 0.42, 0.34],
        ];
        let f = friedman(&data, 0.05).expect("test");
        // scipy.stats.friedmanchisquare(*data.T) -> 15.508474576271187, 0.0014298638363596451
        assert!(
            (f.statistic - 15.508474576271187).abs() < 1e-9,
            "{}",
            f.statistic
        );
        assert!((f.p - 0.0014298638363596451).abs() < 1e-9, "{}", f.p);
        let want = [1.58333333333, 1.41666666667, 3.83333333333, 3.16666666667];
        for (r, w) in f.ranks.iter().zip(want) {
            assert!((r - w).abs() < 1e-9);
        }
        assert_eq!(f.control, 1);

        // papers/001 Table 4, 39 DOF, 500 evaluations: k = 8 methods, n = 9 instances, average
        // ranks 11/9 (control), 21/9, 27/9, 32/9, 46/9, 53/9, 63/9, 71/9. p-values from
        // scipy.stats.norm.sf; the paper prints them rounded (0.335, 0.123, 0.043, 7.57E-4, ...).
        let ranks = [11.0f64, 21.0, 27.0, 32.0, 46.0, 53.0, 63.0, 71.0].map(|r| r / 9.0);
        let (control, holm) = holm_post_hoc(&ranks, 9, 0.05);
        assert_eq!(control, 0);
        let want_p = [
            0.3359238131517356,
            0.12365771040283347,
            0.043308142810791976,
            0.0007574950058146071,
            5.312128159411714e-05,
            5.623957756679217e-07,
            7.764036537930667e-09,
        ];
        for (h, w) in holm.iter().zip(want_p) {
            assert!(
                (h.p - w).abs() < 1e-6 * w.max(1e-300) + 1e-15,
                "method {}: {} vs {w}",
                h.method,
                h.p
            );
        }
        // The paper's thresholds α/(position − 1): 0.050, 0.025, 0.016, 0.012, 0.010, 0.008, 0.007.
        assert!((holm[2].threshold - 0.05 / 3.0).abs() < 1e-15);
        // Holm rejects DE, PSO, APF, PSAPF (the last four) and keeps H-PSO, CMAES, H-DE, as in the paper.
        let sig: Vec<bool> = holm.iter().map(|h| h.significant).collect();
        assert_eq!(sig, [false, false, false, true, true, true, true]);
    }

    #[test]
    fn ranks_average_ties_and_rp_is_relative_to_the_best() {
        let (r, t) = average_ranks(&[3.0, 1.0, 3.0, 2.0]);
        assert_eq!(r, vec![3.5, 1.0, 3.5, 2.0]);
        assert_eq!(t, vec![1, 1, 2]);
        assert!(
            (relative_performance(0.03681, 0.03540) - 0.03983).abs() < 1e-4,
            "papers/000 Table 2: Disc 1+1 +3.99%"
        );
    }
}
