//! Where residuals are systematic rather than noise. The recording is cut into
//! segments (normal load / unload per repeat, the torsion hold's depth trace,
//! twist out / back); each segment's residuals are tested against the noise
//! floor for excess variance (chi²) and for whiteness (runs test), and a
//! systematic one is described by the range it covers and its shape.

use serde::Serialize;
use sim::effects::Reading;
use sim::recording::{Direction, Phase, Recording};

use crate::fit::weights::SampleSd;
use crate::numerics::stats::normal_quantile_upper;

/// Significance of every test here: |z| beyond this is systematic (p ~ 1e-4
/// one-sided), so a clean recording's ~6 segments x 2 tests false-alarm rarely.
pub const Z_SYSTEMATIC: f64 = 3.7;

/// Which reading a segment's residuals are of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    Gamma1,
    Theta1,
}

/// A run of consecutive samples of one sweep branch.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// "normal/load", "normal/unload", "torsion/hold", "torsion/out" or "torsion/back".
    pub phase: &'static str,
    pub quantity: Quantity,
    /// Sample indices, in time order.
    pub idx: Vec<usize>,
    /// The recorded standard error of each sample in `idx` (mm for gamma1,
    /// degrees for theta1), when the recording carries them: residuals are
    /// then judged in units of these, and the segment's floor is a factor on them.
    pub sd: Option<Vec<f64>>,
}

impl Segment {
    /// The variable the range of a mismatch is given in, with its unit.
    pub fn axis(&self) -> &'static str {
        match self.phase {
            "torsion/hold" => "t_s",
            "torsion/out" | "torsion/back" => "rot_deg",
            _ => "gamma1_mm",
        }
    }
    fn axis_value(&self, rec: &Recording, i: usize) -> f64 {
        let s = &rec.samples[i];
        match self.axis() {
            "t_s" => s.t_s,
            "rot_deg" => s.rot_deg,
            _ => s.gamma1_mm,
        }
    }
}

/// Cut a recording into sweep branches. Directions come from the `dir` column
/// when present, otherwise from the sign of the stage (mount) step.
pub fn segments(rec: &Recording) -> Vec<Segment> {
    let mut out: Vec<Segment> = Vec::new();
    let push = |phase: &'static str, q: Quantity, i: usize, out: &mut Vec<Segment>, split: bool| match out
        .iter_mut()
        .rev()
        .find(|s| s.quantity == q)
    {
        Some(last) if last.phase == phase && !split && last.idx.last().is_some_and(|&j| j + 1 == i) => last.idx.push(i),
        _ => out.push(Segment { phase, quantity: q, idx: vec![i], sd: None }),
    };
    let (mut prev_stage, mut prev_rot) = (None::<f64>, None::<f64>);
    let (mut load, mut out_dir) = (true, true);
    let mut prev_rep = None;
    for (i, s) in rec.samples.iter().enumerate() {
        match s.phase {
            Phase::Normal => {
                load = match (s.dir, prev_stage) {
                    (Some(d), _) => d == Direction::Load,
                    (None, Some(p)) if s.stage_mm > p => true,
                    (None, Some(p)) if s.stage_mm < p => false,
                    _ => load,
                };
                prev_stage = Some(s.stage_mm);
                let split = prev_rep.is_some() && s.rep != prev_rep;
                prev_rep = s.rep;
                push(if load { "normal/load" } else { "normal/unload" }, Quantity::Gamma1, i, &mut out, split);
            }
            Phase::Torsion => {
                push("torsion/hold", Quantity::Gamma1, i, &mut out, false);
                out_dir = match prev_rot {
                    Some(p) if s.rot_deg > p => true,
                    Some(p) if s.rot_deg < p => false,
                    _ => match s.dir {
                        Some(d) => d == Direction::Load,
                        None => out_dir,
                    },
                };
                prev_rot = Some(s.rot_deg);
                push(if out_dir { "torsion/out" } else { "torsion/back" }, Quantity::Theta1, i, &mut out, false);
            }
        }
    }
    out
}

/// Give each segment its samples' recorded standard errors (those of the
/// channels `sd` has).
pub fn attach_standard_errors(segs: &mut [Segment], sd: &SampleSd) {
    for seg in segs {
        let per_sample = match seg.quantity {
            Quantity::Gamma1 => sd.gamma1_mm.as_ref(),
            Quantity::Theta1 => sd.theta1_deg.as_ref(),
        };
        seg.sd = per_sample.map(|v| seg.idx.iter().map(|&i| v[i]).collect());
    }
}

/// A segment's residuals: axis values, residuals in reading units, and the
/// same divided by each sample's recorded standard error (unchanged without).
fn segment_residuals(rec: &Recording, pred: &[Reading], seg: &Segment) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut out = (Vec::new(), Vec::new(), Vec::new());
    for (k, &i) in seg.idx.iter().enumerate() {
        if let Some(r) = residual(rec, pred, i, seg.quantity) {
            out.0.push(seg.axis_value(rec, i));
            out.1.push(r);
            out.2.push(seg.sd.as_ref().map_or(r, |sd| r / sd[k]));
        }
    }
    out
}

/// `rs` (one per sample of `seg` with a residual, as [`segment_residuals`]
/// gives them) averaged over each stop: consecutive samples at the same stage
/// position and twist.
fn stop_means(rec: &Recording, pred: &[Reading], seg: &Segment, rs: &[f64]) -> Vec<f64> {
    let keys: Vec<(u64, u64)> = seg
        .idx
        .iter()
        .filter(|&&i| residual(rec, pred, i, seg.quantity).is_some())
        .map(|&i| (rec.samples[i].stage_mm.to_bits(), rec.samples[i].rot_deg.to_bits()))
        .collect();
    let mut out: Vec<f64> = Vec::new();
    let mut count = 0.0;
    for (k, &r) in rs.iter().enumerate() {
        if k > 0 && keys.get(k) == keys.get(k - 1) {
            let last = out.len() - 1;
            out[last] = (out[last] * count + r) / (count + 1.0);
            count += 1.0;
        } else {
            out.push(r);
            count = 1.0;
        }
    }
    out
}

/// Per-sample residuals (observed - model) in reading units: gamma1 mm, theta1 deg.
/// `None` where there is nothing to compare (dead band on both sides, or a
/// zero that is "no contact seen", [`super::model::zeros_unseen`]; theta1 in the normal phase).
pub fn residual(rec: &Recording, pred: &[Reading], i: usize, q: Quantity) -> Option<f64> {
    let (s, p) = (&rec.samples[i], &pred[i]);
    match q {
        Quantity::Gamma1 => {
            if s.gamma1_mm == 0.0 && (p.gamma1_mm == 0.0 || super::model::zeros_unseen(rec)) {
                None
            } else {
                Some(s.gamma1_mm - p.gamma1_mm)
            }
        }
        Quantity::Theta1 => (s.phase == Phase::Torsion).then_some(s.theta1_deg - p.theta1_deg),
    }
}

/// A noise floor and how well it is known.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Floor {
    /// Noise standard deviation (mm for gamma1, degrees for theta1).
    pub sigma: f64,
    /// Degrees of freedom of the estimate (infinite when the floor is given).
    pub dof: f64,
}

impl Floor {
    /// A floor known exactly (given by the user).
    pub fn known(sigma: f64) -> Self {
        Self { sigma, dof: f64::INFINITY }
    }
}

/// Noise standard deviation from second differences within segments, robust
/// to steps and kinks: a median-based first guess rejects outlying
/// differences, then the mean square of the rest gives an efficient estimate.
pub fn noise_floor(series: &[Vec<f64>]) -> Option<f64> {
    noise_floor_dof(series).map(|f| f.sigma)
}

/// [`noise_floor`] with its degrees of freedom. Second differences of white
/// noise are correlated (lag 1: -4/6, lag 2: 1/6), so m of them estimate the
/// variance like a chi² with 2m / (140/36) ~ 0.51 m degrees of freedom: about
/// 40 for the ~80 theta1 samples of a torsion sweep, a floor uncertain by ~11 %.
pub fn noise_floor_dof(series: &[Vec<f64>]) -> Option<Floor> {
    let d: Vec<f64> = series.iter().flat_map(|v| v.windows(3).map(|w| w[0] - 2.0 * w[1] + w[2])).collect();
    floor_of_differences(d, 6.0)
}

/// How far the recorded standard errors understate what varies between
/// samples: second differences of the residuals along each segment, each
/// divided by the standard error the recorded errors give it
/// (sqrt(s0² + 4 s1² + s2²)), have unit variance when the errors are right;
/// the returned floor's `sigma` is the factor k they are off by (robust as
/// [`noise_floor_dof`]). `None` without recorded errors or with too few samples.
pub fn standard_error_factor(rec: &Recording, pred: &[Reading], segs: &[Segment], q: Quantity) -> Option<Floor> {
    let mut d = Vec::new();
    for seg in segs.iter().filter(|s| s.quantity == q) {
        seg.sd.as_ref()?;
        let mut pairs = Vec::new();
        for (k, &i) in seg.idx.iter().enumerate() {
            if let (Some(r), Some(sd)) = (residual(rec, pred, i, q), seg.sd.as_ref()) {
                pairs.push((r, sd[k]));
            }
        }
        d.extend(pairs.windows(3).map(|w| {
            let se = (w[0].1.powi(2) + 4.0 * w[1].1.powi(2) + w[2].1.powi(2)).sqrt();
            (w[0].0 - 2.0 * w[1].0 + w[2].0) / se
        }));
    }
    floor_of_differences(d, 1.0)
}

/// The noise floor from second differences `d` whose variance is `unit_var`
/// times the floor's square.
fn floor_of_differences(d: Vec<f64>, unit_var: f64) -> Option<Floor> {
    if d.len() < 5 {
        return None;
    }
    let mut abs: Vec<f64> = d.iter().map(|x| x.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let s0 = abs[abs.len() / 2] / 0.674_489_750;
    let kept: Vec<f64> = d.into_iter().filter(|x| x.abs() <= 4.0 * s0.max(1e-300)).collect();
    if kept.is_empty() {
        return None;
    }
    let sigma = (kept.iter().map(|x| x * x).sum::<f64>() / (unit_var * kept.len() as f64)).sqrt();
    Some(Floor { sigma, dof: kept.len() as f64 * 36.0 / 70.0 })
}

/// Statistics of one segment against the noise floor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SegmentReport {
    pub phase: &'static str,
    pub quantity: Quantity,
    pub axis: &'static str,
    pub n: usize,
    /// RMS residual in reading units (µm for gamma1, degrees for theta1).
    pub rms: f64,
    /// Mean residual, same units.
    pub mean: f64,
    /// Excess variance against the noise floor, as a normal deviate (Wilson–Hilferty).
    pub chi2_z: f64,
    /// Wald–Wolfowitz runs test on the residual signs (negative: too few runs, i.e. structure).
    pub runs_z: f64,
    /// Lag-1 autocorrelation of the residuals.
    pub lag1: f64,
    pub systematic: bool,
    /// Range of the axis variable over which the smoothed residual stands out.
    pub from: f64,
    pub to: f64,
    pub shape: String,
}

/// Excess variance of `n` residuals with sum of squares `chi2` (in units of a
/// floor estimated with `dof` degrees of freedom) as a normal deviate: the
/// ratio is F(n, dof) distributed, turned into z by Paulson's cube-root
/// approximation (Wilson–Hilferty when the floor is known). An estimated floor
/// that happens to be low must not make a clean branch look systematic.
fn excess_z(chi2: f64, n: usize, dof: f64) -> f64 {
    if !dof.is_finite() {
        return chi2_z(chi2, n);
    }
    let (a, b) = (2.0 / (9.0 * n as f64), 2.0 / (9.0 * dof.max(1.0)));
    let f = (chi2 / n as f64).max(0.0).cbrt();
    ((1.0 - b) * f - (1.0 - a)) / (b * f * f + a).sqrt()
}

fn chi2_z(chi2: f64, k: usize) -> f64 {
    let k = k as f64;
    let c = 2.0 / (9.0 * k);
    ((chi2 / k).cbrt() - (1.0 - c)) / c.sqrt()
}

fn runs_z(r: &[f64]) -> f64 {
    let signs: Vec<bool> = r.iter().filter(|v| **v != 0.0).map(|v| *v > 0.0).collect();
    let n = signs.len();
    let n1 = signs.iter().filter(|s| **s).count() as f64;
    let n2 = n as f64 - n1;
    if n < 8 {
        return 0.0;
    }
    if n1 == 0.0 || n2 == 0.0 {
        // All one sign: probability 2^(1-n); its normal deviate.
        let p = 2f64.powi(1 - n as i32);
        return -normal_quantile_upper(p);
    }
    let runs = 1 + signs.windows(2).filter(|w| w[0] != w[1]).count();
    let nf = n as f64;
    let mu = 2.0 * n1 * n2 / nf + 1.0;
    let var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - nf) / (nf * nf * (nf - 1.0));
    if var <= 0.0 { 0.0 } else { (runs as f64 - mu) / var.sqrt() }
}

/// Least-squares polynomial of degree `deg` through (x, y); returns the residual sum of squares and coefficients.
fn poly_fit(x: &[f64], y: &[f64], deg: usize) -> (f64, Vec<f64>) {
    let n = deg + 1;
    let a = nalgebra::DMatrix::from_fn(x.len(), n, |i, j| x[i].powi(j as i32));
    let b = nalgebra::DVector::from_column_slice(y);
    let svd = a.clone().svd(true, true);
    let c = svd.solve(&b, 1e-12).unwrap_or_else(|_| nalgebra::DVector::zeros(n));
    let ssr = (&a * &c - &b).iter().map(|v| v * v).sum();
    (ssr, c.iter().copied().collect())
}

/// Describe a segment's residuals `r` (units of `sigma`) along axis values `x`.
fn shape_of(seg: &Segment, x: &[f64], r: &[f64], sigma: f64) -> String {
    let (lo, hi) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(*v), b.max(*v)));
    let span = (hi - lo).max(1e-12);
    let u: Vec<f64> = x.iter().map(|v| (v - lo) / span).collect();
    let y: Vec<f64> = r.iter().map(|v| v / sigma).collect();
    let fits: Vec<(f64, Vec<f64>)> = (0..=2).map(|d| poly_fit(&u, &y, d.min(u.len().saturating_sub(1)))).collect();
    let ss0: f64 = y.iter().map(|v| v * v).sum();
    // Smallest degree beyond which a higher one gains nothing significant (chi² 1 dof, p 1e-3).
    let gain = |a: f64, b: f64| a - b > 10.83;
    let deg = if gain(fits[1].0, fits[2].0) {
        2
    } else if gain(fits[0].0, fits[1].0) {
        1
    } else if gain(ss0, fits[0].0) {
        0
    } else {
        3
    };
    let what = match seg.quantity {
        Quantity::Gamma1 => "gamma1",
        Quantity::Theta1 => "theta1",
    };
    let along = match seg.axis() {
        "t_s" => "with time",
        "rot_deg" => "with twist",
        _ => "with depth",
    };
    let sign = |v: f64| if v > 0.0 { "above" } else { "below" };
    let leftover = fits[2].0 / (y.len().saturating_sub(3).max(1)) as f64;
    let wiggle = chi2_z(fits[2].0, y.len().saturating_sub(3).max(1)) > Z_SYSTEMATIC;
    let mut s = match deg {
        0 => format!("offset: {what} {} the model by a constant", sign(fits[0].1[0])),
        1 => {
            let c = &fits[1].1;
            let end = c[0] + c[1];
            format!("ramp: {what} drifts {} the model {along} ({:+.1} to {:+.1} sigma)", sign(end), c[0], end)
        }
        2 => {
            let c = &fits[2].1;
            let mid = c[0] + 0.5 * c[1] + 0.25 * c[2];
            let ends = 0.5 * (c[0] + (c[0] + c[1] + c[2]));
            if (mid - ends).abs() > 0.5 * (c[1] + c[2]).abs().max(c[1].abs()) {
                format!("bow: {what} {} the model mid-range {along}", sign(mid - ends))
            } else {
                let end = c[0] + c[1] + c[2];
                format!("curved ramp: {what} bends {} the model {along}", sign(end - c[0]))
            }
        }
        _ => format!("scatter: {what} residuals correlated but without a smooth trend"),
    };
    if wiggle && deg < 3 {
        s += &format!("; structure beyond a smooth curve ({leftover:.1} x noise variance left)");
    }
    s
}

/// Test one segment's residuals against the noise floor.
pub fn assess(rec: &Recording, pred: &[Reading], seg: &Segment, floor: Floor) -> Option<SegmentReport> {
    let sigma = floor.sigma;
    // `raw` in reading units for the figures; `rs` in the floor's units for the tests.
    let (xs, raw, rs) = segment_residuals(rec, pred, seg);
    let n = rs.len();
    if n < 5 {
        return None;
    }
    let chi2: f64 = rs.iter().map(|r| (r / sigma).powi(2)).sum();
    let cz = excess_z(chi2, n, floor.dof);
    // Samples recorded at one stop (a long stop's consecutive replicates)
    // share that stop's error, so the signs' test counts stops, not samples.
    let rz = runs_z(&stop_means(rec, pred, seg, &rs));
    let mean = raw.iter().sum::<f64>() / n as f64;
    let rms = (raw.iter().map(|r| r * r).sum::<f64>() / n as f64).sqrt();
    let lag1 = {
        let num: f64 = rs.windows(2).map(|w| w[0] * w[1]).sum();
        let den: f64 = rs.iter().map(|r| r * r).sum();
        if den > 0.0 { num / den } else { 0.0 }
    };
    let systematic = cz > Z_SYSTEMATIC || rz < -Z_SYSTEMATIC;
    // Where the moving average stands out from what noise alone gives it.
    let w = 7.min(n);
    let thresh = 2.5 * sigma / (w as f64).sqrt();
    let mut marked: Vec<f64> = Vec::new();
    for (k, &x) in xs.iter().enumerate() {
        let a = k.saturating_sub(w / 2).min(n - w);
        let ma = rs[a..a + w].iter().sum::<f64>() / w as f64;
        if ma.abs() > thresh {
            marked.push(x);
        }
    }
    let pool = if marked.is_empty() { &xs } else { &marked };
    let from = pool.iter().copied().fold(f64::INFINITY, f64::min);
    let to = pool.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let shape = if systematic { shape_of(seg, &xs, &rs, sigma) } else { "noise".to_string() };
    let unit = if seg.quantity == Quantity::Gamma1 { 1e3 } else { 1.0 };
    Some(SegmentReport {
        phase: seg.phase,
        quantity: seg.quantity,
        axis: seg.axis(),
        n,
        rms: rms * unit,
        mean: mean * unit,
        chi2_z: cz,
        runs_z: rz,
        lag1,
        systematic,
        from,
        to,
        shape,
    })
}

/// Where a correction removed structure: for each segment, the chi² (against
/// the floor) of the residuals under `before` minus under `after`. The same
/// floor divides both, so its uncertainty scales the gain but cannot create
/// one; a gain beyond a chi² quantile locates a mismatch that the branch test
/// alone (against an uncertain floor) may leave below its threshold.
pub fn chi2_gain(rec: &Recording, before: &[Reading], after: &[Reading], seg: &Segment, floor: Floor) -> f64 {
    let ss = |pred: &[Reading]| -> f64 {
        segment_residuals(rec, pred, seg).2.iter().map(|r| (r / floor.sigma).powi(2)).sum()
    };
    ss(before) - ss(after)
}

/// The report of `seg` under `pred`, with its shape described even when the
/// branch test alone does not call it systematic.
pub fn describe(rec: &Recording, pred: &[Reading], seg: &Segment, floor: Floor) -> Option<SegmentReport> {
    let mut r = assess(rec, pred, seg, floor)?;
    if !r.systematic {
        let (xs, _, rs) = segment_residuals(rec, pred, seg);
        r.shape = shape_of(seg, &xs, &rs, floor.sigma);
    }
    Some(r)
}

/// Assess every segment against the noise floors of gamma1 (mm) and theta1 (degrees).
pub fn locate(rec: &Recording, pred: &[Reading], segs: &[Segment], gamma1: Floor, theta1: Floor) -> Vec<SegmentReport> {
    segs.iter()
        .filter_map(|s| assess(rec, pred, s, if s.quantity == Quantity::Gamma1 { gamma1 } else { theta1 }))
        .collect()
}

/// Residual series per segment (for the noise floor), gamma1 in mm and theta1 in degrees.
pub fn series(rec: &Recording, pred: &[Reading], segs: &[Segment], q: Quantity) -> Vec<Vec<f64>> {
    segs.iter()
        .filter(|s| s.quantity == q)
        .map(|s| s.idx.iter().filter_map(|&i| residual(rec, pred, i, q)).collect())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_and_chi2_separate_noise_from_structure() {
        let mut rng = sim::rng::Rng::seed_from(7);
        let noise: Vec<f64> = (0..200).map(|_| rng.gaussian(1.0)).collect();
        assert!(runs_z(&noise).abs() < 3.0);
        assert!(chi2_z(noise.iter().map(|v| v * v).sum(), 200).abs() < 3.0);
        let bow: Vec<f64> =
            (0..200).map(|i| 1.5 * (i as f64 / 200.0 * 2.0 * std::f64::consts::PI).cos() + rng.gaussian(1.0)).collect();
        assert!(runs_z(&bow) < -Z_SYSTEMATIC, "{}", runs_z(&bow));
        let floor = noise_floor(std::slice::from_ref(&bow)).unwrap();
        assert!((floor - 1.0).abs() < 0.15, "{floor}");
        let mut step = noise.clone();
        for v in step.iter_mut().skip(100) {
            *v += 20.0;
        }
        assert!((noise_floor(&[step]).unwrap() - 1.0).abs() < 0.15);
    }
}
