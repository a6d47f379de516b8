//! Statistics of the paired design: intervals whose coverage holds across processes and the
//! comparison of two campaigns' paired cells (the report of `mpm-bench paired` is
//! [`super::paired_report`]'s).
//!
//! # The data
//!
//! A paired cell of a campaign (model, strategy, optimisation level, threads) is measured by
//! `m` separate processes (its repetitions); process `i` times `n_i` blocks of its one-thread
//! and `T`-thread solvers, block `j` giving the ratio `r_ij = t1_ij / (T tT_ij)`.
//!
//! # Why blocks alone are not enough
//!
//! Blocks of one process share that process's host: the CPUs it was pinned to, what ran on
//! their SMT siblings and neighbouring tenants for its whole life, its page placement. On the
//! development VM two paired measurements of AE on Model 1 back to back gave 0.62
//! [0.60, 0.82] and 0.94 [0.88, 0.96]: each interval, from the spread of its blocks, excludes
//! the other's value. The spread between processes is a component of its own, and an
//! interval must be built from it.
//!
//! # The interval: two stages ([`two_stage`])
//!
//! 1. Within each process, the blocks are summarised by the mean of their logarithms,
//!    `y_i = mean_j ln r_ij` (the process's geometric-mean efficiency, in logs: ratios are
//!    symmetric there, a block twice as fast weighs as one twice as slow).
//! 2. Across processes, the `y_i` are independent (separate processes, interleaved in a
//!    seeded order with the campaign's other runs) with a variance that contains both the
//!    process-to-process spread and the block noise (`var y_i = s_b^2 + s_w^2 / n_i`). Their
//!    mean `ybar` has standard error `s_y / sqrt(m)`, and Student's t with `m - 1` degrees of
//!    freedom gives the interval: `exp(ybar +- t_{m-1} s_y / sqrt(m))`, point estimate
//!    `exp(ybar)`.
//!
//! This is the classical two-stage (summary-statistics) analysis of a nested design; it is
//! exact when the `y_i` are normal, and robust to unequal block counts. A bootstrap that
//! resamples processes and then blocks within them estimates the same variance but at the
//! few processes a CI job can afford (3-15) its percentile interval is too narrow (about
//! `sqrt((m-1)/m) z` where `t_{m-1}` is needed: nominal 95 % covers about 75 % at `m = 3`);
//! the t quantile is that small-sample correction. With one process only, the interval falls
//! back to the blocks (`within_process_only`): it describes that process, not the host, and
//! every command marks it indicative.
//!
//! The tests below check the coverage on synthetic data with a known answer and a process
//! effect (drift between processes): the two-stage interval covers at its nominal rate, an
//! interval from the pooled blocks does not.
//!
//! # Comparing two campaigns ([`compare`])
//!
//! Welch's t on the two campaigns' `y_i`: `d = ybar_cur - ybar_base`, standard error
//! `sqrt(s_c^2/m_c + s_b^2/m_b)`, Welch-Satterthwaite degrees of freedom; the ratio of
//! efficiencies `exp(d)` with its interval, and one-sided p-values of "lower" and "higher".
//!
//! # Pooling cells ([`compare_pooled`])
//!
//! A change of the code that costs every cell a little (a slower assembly, a lost
//! overlap) moves each cell by less than its own noise: on the development VM a 10 %
//! injected loss, measured by 12 processes a cell, was found in no single cell of 3 of 21
//! comparisons, although every cell was 3-13 % down. The mean of the cells' changes,
//! `d = (1/K) sum_k d_k`, has the variance `(1/K^2) sum_k se_k^2` when the cells are measured
//! by separate processes (their errors independent), so over K = 4 cells its standard error
//! is half a cell's: the gate tests it beside the cells (`regress`: one more check in the
//! Holm family, so the family-wise level holds). Degrees of freedom: Welch-Satterthwaite over
//! all `2K` samples, `(sum v)^2 / sum v^2 / (m - 1)`.
//!
//! # Pairs of two builds ([`compare_pairs`])
//!
//! `mpm-bench ab` runs a baseline build's process and a candidate build's process of the same
//! cell back to back, pair after pair. Each pair gives a log ratio `d_i = ln(B_i / A_i)` in
//! which whatever the host did to both runs cancels: the interval is Student's t over the
//! pairs (`n - 1` degrees of freedom), exact for normal `d_i`; the pooled check is the mean
//! of the cells' means, as above. The test below checks its coverage with drift between
//! pairs.

use super::estimate::Estimate;
use serde::Serialize;

// ---------------------------------------------------------------------------------------
// Student's t
// ---------------------------------------------------------------------------------------

/// `ln Gamma(x)` for `x > 0` (Lanczos, g = 7, 9 terms: about 15 digits).
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection.
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let s = G[1..].iter().enumerate().fold(G[0], |s, (i, g)| s + g / (x + i as f64 + 1.0));
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + s.ln()
}

/// The continued fraction of the regularised incomplete beta function (modified Lentz).
fn beta_fraction(a: f64, b: f64, x: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    if d.abs() < TINY {
        d = TINY;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..1000 {
        let m = m as f64;
        let m2 = 2.0 * m;
        let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1.0 + aa * d;
        d = if d.abs() < TINY { TINY } else { d };
        c = 1.0 + aa / c;
        c = if c.abs() < TINY { TINY } else { c };
        d = 1.0 / d;
        h *= d * c;
        let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1.0 + aa * d;
        d = if d.abs() < TINY { TINY } else { d };
        c = 1.0 + aa / c;
        c = if c.abs() < TINY { TINY } else { c };
        d = 1.0 / d;
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

/// The regularised incomplete beta function `I_x(a, b)`.
fn incomplete_beta(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let front = (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln()).exp();
    if x < (a + 1.0) / (a + b + 2.0) {
        front * beta_fraction(a, b, x) / a
    } else {
        1.0 - front * beta_fraction(b, a, 1.0 - x) / b
    }
}

/// `P(T <= t)` for Student's t with `df > 0` degrees of freedom (not necessarily whole).
pub fn student_t_cdf(t: f64, df: f64) -> f64 {
    if t.is_nan() || df.is_nan() || df <= 0.0 {
        return f64::NAN;
    }
    if t.is_infinite() {
        return if t > 0.0 { 1.0 } else { 0.0 };
    }
    let tail = 0.5 * incomplete_beta(0.5 * df, 0.5, df / (df + t * t));
    if t > 0.0 {
        1.0 - tail
    } else {
        tail
    }
}

/// The `p` quantile of Student's t with `df` degrees of freedom (`0 < p < 1`), by bisection
/// on [`student_t_cdf`].
pub fn student_t_quantile(p: f64, df: f64) -> f64 {
    if !(p > 0.0 && p < 1.0 && df > 0.0) {
        return f64::NAN;
    }
    if p < 0.5 {
        return -student_t_quantile(1.0 - p, df);
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    while student_t_cdf(hi, df) < p && hi < 1e12 {
        lo = hi;
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if student_t_cdf(mid, df) < p {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-12 * hi.max(1.0) {
            break;
        }
    }
    0.5 * (lo + hi)
}

// ---------------------------------------------------------------------------------------
// The two-stage interval
// ---------------------------------------------------------------------------------------

/// A paired efficiency estimated over processes ([`two_stage`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ProcessInterval {
    /// `exp(ybar)` with its interval; `reps` is the number of processes.
    pub estimate: Estimate,
    /// Processes.
    pub processes: usize,
    /// Blocks over all processes.
    pub blocks: usize,
    /// `ybar`, the mean log efficiency.
    pub mean_log: f64,
    /// Its standard error (logs).
    pub se_log: f64,
    /// Degrees of freedom of the t quantile.
    pub df: f64,
    /// One process only: the interval is its blocks' and says nothing of the spread between
    /// processes (indicative).
    pub within_process_only: bool,
}

/// Mean and sample standard deviation.
fn mean_sd(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = if x.len() > 1 { x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) } else { 0.0 };
    (mean, var.sqrt())
}

/// A process's summary: the mean log of its blocks' ratios (`None` without a positive
/// finite ratio).
pub fn process_log_mean(ratios: &[f64]) -> Option<f64> {
    let logs: Vec<f64> = ratios.iter().filter(|r| r.is_finite() && **r > 0.0).map(|r| r.ln()).collect();
    (!logs.is_empty()).then(|| logs.iter().sum::<f64>() / logs.len() as f64)
}

/// The two-stage interval (module docs) of the processes' block ratios `processes` at
/// `confidence` (e.g. 0.95). `None` without any block. With one process of one block the
/// interval is the point.
pub fn two_stage(processes: &[Vec<f64>], confidence: f64) -> Option<ProcessInterval> {
    let ys: Vec<f64> = processes.iter().filter_map(|p| process_log_mean(p)).collect();
    let blocks: usize = processes.iter().map(Vec::len).sum();
    let (values, within) = match ys.len() {
        0 => return None,
        1 => {
            let p = processes.iter().find(|p| process_log_mean(p).is_some())?;
            (p.iter().filter(|r| r.is_finite() && **r > 0.0).map(|r| r.ln()).collect::<Vec<f64>>(), true)
        }
        _ => (ys.clone(), false),
    };
    let (mean, sd) = mean_sd(&values);
    let n = values.len();
    let (se, df) = (sd / (n as f64).sqrt(), (n as f64 - 1.0).max(0.0));
    let (lo, hi) = if n >= 2 && se > 0.0 {
        let t = student_t_quantile(0.5 + 0.5 * confidence, df);
        ((mean - t * se).exp(), (mean + t * se).exp())
    } else {
        (mean.exp(), mean.exp())
    };
    Some(ProcessInterval {
        estimate: Estimate { value: mean.exp(), lo, hi, reps: ys.len() },
        processes: ys.len(),
        blocks,
        mean_log: mean,
        se_log: se,
        df,
        within_process_only: within,
    })
}

/// Two campaigns' paired cells compared ([`compare`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Comparison {
    /// `exp(ybar_cur - ybar_base)`: the current efficiency over the baseline's, with its
    /// interval; `reps` the fewer processes.
    pub ratio: Estimate,
    /// Standard error of the difference of mean logs.
    pub se_log: f64,
    /// Welch-Satterthwaite degrees of freedom.
    pub df: f64,
    /// One-sided p-value of "the current efficiency is lower".
    pub p_lower: f64,
    /// One-sided p-value of "the current efficiency is higher".
    pub p_higher: f64,
}

/// Welch's t on the processes' mean logs `base` and `cur` (module docs). `None` unless
/// both sides have at least two processes (one process says nothing of the spread between
/// processes).
pub fn compare(base: &[f64], cur: &[f64], confidence: f64) -> Option<Comparison> {
    compare_pooled(&[(base, cur)], confidence)
}

/// The mean change over several cells (module docs, "Pooling cells"): `d = mean_k d_k` of
/// each cell's difference of mean logs, standard error `sqrt(sum_k se_k^2) / K`,
/// Welch-Satterthwaite degrees of freedom over every cell's two samples. The cells must be
/// measured by separate processes (they are: every process measures one cell). `None`
/// without cells or when a cell has fewer than two processes a side. One cell is
/// [`compare`].
pub fn compare_pooled(cells: &[(&[f64], &[f64])], confidence: f64) -> Option<Comparison> {
    if cells.is_empty() || cells.iter().any(|(b, c)| b.len() < 2 || c.len() < 2) {
        return None;
    }
    let terms: Vec<Term> = cells
        .iter()
        .map(|(base, cur)| {
            let ((mb, sb), (mc, sc)) = (mean_sd(base), mean_sd(cur));
            let (vb, vc) = (sb * sb / base.len() as f64, sc * sc / cur.len() as f64);
            let df_den = vb * vb / (base.len() as f64 - 1.0) + vc * vc / (cur.len() as f64 - 1.0);
            Term { d: mc - mb, var: vb + vc, df_den, reps: base.len().min(cur.len()) }
        })
        .collect();
    Some(combine(&terms, confidence))
}

/// Pairs of two builds (`mpm-bench ab`): each cell's pair-by-pair log ratios `d_i = ln(B_i /
/// A_i)` of two processes run back to back. A host's drift moves both members of a pair, so
/// the ratio leaves it out; what is left is the pairs' own scatter. One cell: Student's t on
/// the `d_i`, `d = mean d_i`, standard error `s_d / sqrt(n)`, `n - 1` degrees of freedom;
/// several cells: the mean of their means, as [`compare_pooled`] (variance `sum_k se_k^2 /
/// K^2`, Welch-Satterthwaite degrees of freedom). The ratio `exp(d)` (candidate over
/// baseline) with its interval and the one-sided p-values. `None` without cells or when a
/// cell has fewer than two pairs.
pub fn compare_pairs(cells: &[&[f64]], confidence: f64) -> Option<Comparison> {
    if cells.is_empty() || cells.iter().any(|d| d.len() < 2) {
        return None;
    }
    let terms: Vec<Term> = cells
        .iter()
        .map(|d| {
            let (m, s) = mean_sd(d);
            let v = s * s / d.len() as f64;
            Term { d: m, var: v, df_den: v * v / (d.len() as f64 - 1.0), reps: d.len() }
        })
        .collect();
    Some(combine(&terms, confidence))
}

/// One cell's part of a pooled comparison: its difference of mean logs, that difference's
/// variance, its share of the Welch-Satterthwaite denominator, and its count.
struct Term {
    d: f64,
    var: f64,
    df_den: f64,
    reps: usize,
}

/// The mean of the cells' differences with its t interval and p-values.
fn combine(terms: &[Term], confidence: f64) -> Comparison {
    let k = terms.len() as f64;
    let d = terms.iter().map(|t| t.d).sum::<f64>() / k;
    let var: f64 = terms.iter().map(|t| t.var).sum();
    let df_den: f64 = terms.iter().map(|t| t.df_den).sum();
    let reps = terms.iter().map(|t| t.reps).min().unwrap_or(0);
    // The 1/K^2 of the mean's variance cancels in the degrees of freedom.
    let se = var.sqrt() / k;
    if se == 0.0 {
        let p = |x: bool| if x { 0.0 } else { 1.0 };
        return Comparison {
            ratio: Estimate { value: d.exp(), lo: d.exp(), hi: d.exp(), reps },
            se_log: 0.0,
            df: f64::INFINITY,
            p_lower: p(d < 0.0),
            p_higher: p(d > 0.0),
        };
    }
    let df = var * var / df_den.max(f64::MIN_POSITIVE);
    let t = student_t_quantile(0.5 + 0.5 * confidence, df);
    let z = d / se;
    Comparison {
        ratio: Estimate { value: d.exp(), lo: (d - t * se).exp(), hi: (d + t * se).exp(), reps },
        se_log: se,
        df,
        p_lower: student_t_cdf(z, df),
        p_higher: 1.0 - student_t_cdf(z, df),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::SplitMix64;

    #[test]
    fn t_distribution_matches_tables() {
        // Two-sided 95 % quantiles (t_{0.975, df}) from the standard tables.
        for (df, want) in [(1.0, 12.706_205), (2.0, 4.302_653), (4.0, 2.776_445), (10.0, 2.228_139), (30.0, 2.042_272)]
        {
            let got = student_t_quantile(0.975, df);
            assert!((got - want).abs() < 1e-5 * want, "df {df}: {got} vs {want}");
            assert!((student_t_cdf(want, df) - 0.975).abs() < 1e-7, "df {df}");
        }
        assert!((student_t_quantile(0.9, 1e6) - 1.281_552).abs() < 1e-4, "large df: the normal's");
        assert_eq!(student_t_cdf(0.0, 3.0), 0.5);
        assert!((student_t_quantile(0.025, 4.0) + 2.776_445).abs() < 1e-5);
        assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-12);
    }

    /// A standard normal variate (Box-Muller).
    fn normal(rng: &mut SplitMix64) -> f64 {
        let u = |r: &mut SplitMix64| ((r.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        let (a, b) = (u(rng), u(rng));
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }

    /// Synthetic paired cells with a known efficiency `e0`: `m` processes, each with its own
    /// effect (log-normal, `sd_process`: the drift between processes) and `n` blocks of noise
    /// (`sd_block`).
    fn cell(rng: &mut SplitMix64, e0: f64, m: usize, n: usize, sd_process: f64, sd_block: f64) -> Vec<Vec<f64>> {
        (0..m)
            .map(|_| {
                let u = sd_process * normal(rng);
                (0..n).map(|_| (e0.ln() + u + sd_block * normal(rng)).exp()).collect()
            })
            .collect()
    }

    /// The coverage of the two-stage interval on synthetic data whose answer is known, with
    /// a process effect three times the block noise (as on the development VM: blocks agree
    /// within a process, processes do not): at 3, 5 and 10 processes it covers the true
    /// efficiency at its nominal 95 % (within the Monte Carlo error of 1,500 trials); an
    /// interval built from every block pooled as if independent (what `mpm-bench paired`'s
    /// single process, or a block bootstrap, gives) covers far less.
    #[test]
    fn two_stage_intervals_cover_the_drift_between_processes() {
        let mut rng = SplitMix64(2008);
        let e0 = 0.8;
        for m in [3, 5, 10] {
            let trials = 1500;
            let (mut two, mut pooled) = (0, 0);
            for _ in 0..trials {
                let c = cell(&mut rng, e0, m, 8, 0.06, 0.02);
                let iv = two_stage(&c, 0.95).unwrap();
                assert!(!iv.within_process_only && iv.processes == m);
                two += usize::from(iv.estimate.lo <= e0 && e0 <= iv.estimate.hi);
                let all: Vec<f64> = c.into_iter().flatten().collect();
                let p = two_stage(&[all], 0.95).unwrap();
                pooled += usize::from(p.estimate.lo <= e0 && e0 <= p.estimate.hi);
            }
            let (two, pooled) = (two as f64 / trials as f64, pooled as f64 / trials as f64);
            // 95 % with a binomial standard error of 0.56 %: 3.5 of them either side.
            assert!((0.93..=0.97).contains(&two), "{m} processes: two-stage coverage {two}");
            assert!(pooled < 0.7, "{m} processes: pooled blocks cover {pooled}: the test shows no drift");
        }
    }

    /// Pairs of two builds (`ab`) on synthetic data with a known answer and drift between
    /// pairs: every pair has its own host speed (log-normal, 10 %, the drift between runs
    /// minutes apart), shared by both its members, and each run its own noise (2 %). The
    /// true ratio B / A is 1.05. The interval over the pairs' log ratios covers 1.05 at its
    /// nominal 95 % and excludes no change in most trials; Welch's t on the two sides taken
    /// apart (what separate campaigns give) covers too but, the drift in its variance,
    /// rarely sees the 5 %. Pooled over four such cells the interval still covers.
    #[test]
    fn pair_ratios_cancel_the_drift_between_pairs() {
        let mut rng = SplitMix64(39);
        let (truth, trials, n) = (1.05f64, 1500, 12);
        let (mut covered, mut found, mut found_apart, mut pooled_covered) = (0, 0, 0, 0);
        for _ in 0..trials {
            let mut cells: Vec<Vec<f64>> = Vec::new();
            let mut apart = (Vec::new(), Vec::new());
            for _ in 0..4 {
                let mut d = Vec::new();
                for _ in 0..n {
                    let host = 0.10 * normal(&mut rng);
                    let a = host + 0.02 * normal(&mut rng);
                    let b = host + truth.ln() + 0.02 * normal(&mut rng);
                    d.push(b - a);
                    if cells.is_empty() {
                        apart.0.push(a);
                        apart.1.push(b);
                    }
                }
                cells.push(d);
            }
            let one = compare_pairs(&[&cells[0]], 0.95).unwrap();
            assert_eq!(one.ratio.reps, n);
            assert!((one.df - (n - 1) as f64).abs() < 1e-9, "one cell: n - 1 degrees of freedom, got {}", one.df);
            covered += usize::from(one.ratio.lo <= truth && truth <= one.ratio.hi);
            found += usize::from(one.ratio.lo > 1.0);
            found_apart += usize::from(compare(&apart.0, &apart.1, 0.95).unwrap().ratio.lo > 1.0);
            let refs: Vec<&[f64]> = cells.iter().map(Vec::as_slice).collect();
            let all = compare_pairs(&refs, 0.95).unwrap();
            pooled_covered += usize::from(all.ratio.lo <= truth && truth <= all.ratio.hi);
        }
        let rate = |x: usize| x as f64 / trials as f64;
        assert!((0.93..=0.97).contains(&rate(covered)), "pairs cover {}", rate(covered));
        assert!((0.93..=0.97).contains(&rate(pooled_covered)), "pooled pairs cover {}", rate(pooled_covered));
        assert!(rate(found) > 0.95, "pairs find the 5 % in {}", rate(found));
        assert!(rate(found_apart) < 0.5, "the sides apart find it in {}: no drift in the test", rate(found_apart));
        // A pair alone is no test.
        assert!(compare_pairs(&[&[0.1]], 0.95).is_none() && compare_pairs(&[], 0.95).is_none());
    }

    /// Welch's comparison: no difference is called a change at about its level over many
    /// A/A pairs; a 10 % loss with little noise is found; one process a side gives no test.
    #[test]
    fn comparisons_keep_their_level_and_find_a_loss() {
        let mut rng = SplitMix64(7);
        let mut alarms = 0;
        let trials = 2000;
        let logs = |c: &[Vec<f64>]| c.iter().filter_map(|p| process_log_mean(p)).collect::<Vec<f64>>();
        for _ in 0..trials {
            let a = logs(&cell(&mut rng, 0.8, 5, 8, 0.06, 0.02));
            let b = logs(&cell(&mut rng, 0.8, 5, 8, 0.06, 0.02));
            alarms += usize::from(compare(&a, &b, 0.95).unwrap().p_lower <= 0.025);
        }
        let rate = alarms as f64 / trials as f64;
        assert!((0.015..=0.035).contains(&rate), "one-sided level 2.5 %, got {rate}");
        let a = logs(&cell(&mut rng, 0.8, 10, 8, 0.01, 0.01));
        let b = logs(&cell(&mut rng, 0.72, 10, 8, 0.01, 0.01));
        let c = compare(&a, &b, 0.95).unwrap();
        assert!(c.p_lower < 1e-6 && c.ratio.hi < 0.95 && c.ratio.lo > 0.85, "{c:?}");
        assert!(compare(&a[..1], &b, 0.95).is_none());
    }

    /// Pooling: over many A/A pairs of four cells the mean change is called lower at about
    /// its level (the variance of a mean of independent cells is right); a 10 % loss in
    /// every cell at the development VM's noise (process sd 0.12, 12 processes a cell) is
    /// found by the pooled test far more often than by the best single cell at the Holm
    /// level over five checks; one cell pooled is [`compare`].
    #[test]
    fn pooled_cells_keep_their_level_and_find_a_loss_spread_over_cells() {
        let mut rng = SplitMix64(26);
        let logs = |rng: &mut SplitMix64, e: f64| -> Vec<f64> {
            cell(rng, e, 12, 8, 0.11, 0.14).iter().filter_map(|p| process_log_mean(p)).collect()
        };
        let trials = 2000;
        let (mut alarms, mut pooled_found, mut cell_found) = (0, 0, 0);
        for _ in 0..trials {
            let aa: Vec<(Vec<f64>, Vec<f64>)> = (0..4).map(|_| (logs(&mut rng, 0.9), logs(&mut rng, 0.9))).collect();
            let pairs: Vec<(&[f64], &[f64])> = aa.iter().map(|(a, b)| (a.as_slice(), b.as_slice())).collect();
            alarms += usize::from(compare_pooled(&pairs, 0.95).unwrap().p_lower <= 0.025);
            let lost: Vec<(Vec<f64>, Vec<f64>)> = (0..4).map(|_| (logs(&mut rng, 0.9), logs(&mut rng, 0.81))).collect();
            let pairs: Vec<(&[f64], &[f64])> = lost.iter().map(|(a, b)| (a.as_slice(), b.as_slice())).collect();
            pooled_found += usize::from(compare_pooled(&pairs, 0.95).unwrap().p_lower <= 0.025 / 5.0);
            cell_found += usize::from(pairs.iter().any(|(a, b)| compare(a, b, 0.95).unwrap().p_lower <= 0.025 / 5.0));
        }
        let rate = alarms as f64 / trials as f64;
        assert!((0.015..=0.035).contains(&rate), "one-sided level 2.5 %, got {rate}");
        let (pooled, single) = (pooled_found as f64 / trials as f64, cell_found as f64 / trials as f64);
        assert!(pooled > 0.9 && pooled > single + 0.2, "pooled finds {pooled}, the best single cell {single}");
        let (a, b) = (logs(&mut rng, 0.9), logs(&mut rng, 0.8));
        assert_eq!(compare_pooled(&[(&a, &b)], 0.95), compare(&a, &b, 0.95));
        assert!(compare_pooled(&[(&a, &b), (&a[..1], &b)], 0.95).is_none(), "one process a side: no test");
        assert!(compare_pooled(&[], 0.95).is_none());
    }

    /// One process: the blocks' interval, marked as such; no block: nothing.
    #[test]
    fn one_process_is_within_process_only() {
        let iv = two_stage(&[vec![0.8, 0.82, 0.78, 0.81]], 0.95).unwrap();
        assert!(iv.within_process_only && iv.processes == 1 && iv.blocks == 4);
        assert!(iv.estimate.lo < 0.8 && iv.estimate.hi > 0.8);
        assert!(two_stage(&[vec![]], 0.95).is_none());
        let point = two_stage(&[vec![0.8]], 0.95).unwrap();
        assert_eq!((point.estimate.lo, point.estimate.hi), (point.estimate.value, point.estimate.value));
    }
}
