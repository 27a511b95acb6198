//! Change detection and trends over one sensor's calibrations (docs/history.md).
//!
//! Model: a calibration's value is x_i = mu(t_i) + e_i with
//! Var e_i = s_i^2 + tau^2, where s_i is the fit's own standard error (its
//! 95 % interval / 3.92) and tau the rig's repeatability beyond it (remounting,
//! temperature, the gel's day-to-day state), estimated from the sensor's own
//! history by the method of moments about a straight line (so a steady drift is
//! not mistaken for scatter).
//!
//! A new calibration is tested against the reference (the up to `window`
//! calibrations before it) twice, for E1 and for nu1:
//! - step: z = (x_new - m) / sqrt(s_new^2 + tau^2 + var m), m the weighted mean;
//! - trend: the weighted slope over reference + new, z = b / se(b).
//!
//! Each of the four z is compared with the two-sided normal quantile of
//! alpha/4 (Bonferroni), so a stable sensor raises an alarm on a calibration
//! with probability at most `false_alarm_rate` (0.2 % by default).

use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

use crate::CalibrationRecord;

/// Seconds in a mean Gregorian month.
pub const MONTH_S: f64 = 365.2425 / 12.0 * 86_400.0;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Probability that a calibration of a stable sensor raises an alarm.
    pub false_alarm_rate: f64,
    /// How many earlier calibrations form the reference.
    pub window: usize,
    /// A floor for the repeatability, as a fraction of the value (E1, nu1);
    /// the history's own estimate is used when it is larger.
    pub repeatability_floor: [f64; 2],
    /// Calibrations needed before the repeatability is estimated from the history.
    pub min_for_repeatability: usize,
    /// Calibrations needed for a trend.
    pub min_for_trend: usize,
    /// Time the calibrations must span for a trend, days.
    pub min_trend_span_days: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            false_alarm_rate: 0.002,
            window: 50,
            repeatability_floor: [0.0, 0.0],
            min_for_repeatability: 4,
            min_for_trend: 4,
            min_trend_span_days: 7.0,
        }
    }
}

impl Settings {
    /// The critical |z| of each of the four tests.
    pub fn z_critical(&self) -> f64 {
        let a = (self.false_alarm_rate / 4.0).clamp(1e-12, 0.5);
        Normal::standard().inverse_cdf(1.0 - a / 2.0)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    E1,
    Nu1,
}

impl Quantity {
    pub fn label(self) -> &'static str {
        match self {
            Quantity::E1 => "E1",
            Quantity::Nu1 => "nu1",
        }
    }
    fn index(self) -> usize {
        match self {
            Quantity::E1 => 0,
            Quantity::Nu1 => 1,
        }
    }
    fn point(self, r: &CalibrationRecord) -> Option<Point> {
        let (x, ci) = match self {
            Quantity::E1 => (r.e1_mpa, r.e1_ci95),
            Quantity::Nu1 => (r.nu1, r.nu1_ci95),
        };
        let [lo, hi] = ci?;
        let s = (hi - lo) / (2.0 * 1.959_964);
        (x.is_finite() && s.is_finite() && s > 0.0).then_some(Point { t: r.time_unix_s, x, s })
    }
}

#[derive(Debug, Clone, Copy)]
struct Point {
    t: f64,
    x: f64,
    s: f64,
}

/// One quantity of one calibration against its reference.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Verdict {
    pub quantity: Quantity,
    pub n_reference: usize,
    /// The reference level (weighted mean of the reference).
    pub reference: f64,
    /// New value minus the reference, and the same in percent of it.
    pub change: f64,
    pub change_pct: f64,
    /// The repeatability used (standard deviation, the quantity's units).
    pub repeatability_sd: f64,
    pub z_step: f64,
    pub z_trend: Option<f64>,
    pub alarm: bool,
}

/// A calibration against the ones before it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Assessment {
    pub e1: Option<Verdict>,
    pub nu1: Option<Verdict>,
    pub alarm: bool,
    pub z_critical: f64,
    pub false_alarm_rate: f64,
}

/// A straight line through one quantity's history.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Trend {
    pub quantity: Quantity,
    pub n: usize,
    pub span_days: f64,
    /// Rate, the quantity's units per month, with its 95 % interval.
    pub rate_per_month: f64,
    pub rate_ci95: [f64; 2],
    /// The same in percent (of the line's value at the first calibration) per month.
    pub rate_pct_per_month: f64,
    pub rate_pct_ci95: [f64; 2],
    pub repeatability_sd: f64,
}

/// One value per recording (a run and a `fit --record` of the same file are
/// one measurement): the diagnosis's corrected values first, then the run's.
/// One sensor, one model: a change of model is not a change of the gel.
pub fn series<'a>(history: &'a [CalibrationRecord], sensor: &str, model: &str) -> Vec<&'a CalibrationRecord> {
    use crate::Source::*;
    let rank = |r: &CalibrationRecord| match r.source {
        Diagnose => 0,
        Run => 1,
        Fit => 2,
        Import => 3,
    };
    let mut best: std::collections::HashMap<&str, &CalibrationRecord> = Default::default();
    for r in history.iter().filter(|r| r.model == model && r.sensor == sensor) {
        let e = best.entry(r.recording_sha256.as_str()).or_insert(r);
        if rank(r) < rank(e) {
            *e = r;
        }
    }
    let mut out: Vec<&CalibrationRecord> = best.into_values().collect();
    out.sort_by(|a, b| a.time_unix_s.total_cmp(&b.time_unix_s).then(a.recording_sha256.cmp(&b.recording_sha256)));
    out
}

/// Assess calibration `k` of `series` (see [`series`]) against the ones before it.
pub fn assess(series: &[&CalibrationRecord], k: usize, settings: &Settings) -> Assessment {
    let z_crit = settings.z_critical();
    let lo = k.saturating_sub(settings.window);
    let verdict = |q: Quantity| -> Option<Verdict> {
        let new = q.point(series.get(k)?)?;
        let reference: Vec<Point> = series[lo..k].iter().filter_map(|r| q.point(r)).collect();
        verdict_of(q, &reference, new, settings, z_crit)
    };
    let (e1, nu1) = (verdict(Quantity::E1), verdict(Quantity::Nu1));
    let alarm = e1.as_ref().is_some_and(|v| v.alarm) || nu1.as_ref().is_some_and(|v| v.alarm);
    Assessment { e1, nu1, alarm, z_critical: z_crit, false_alarm_rate: settings.false_alarm_rate }
}

/// Every calibration of `series` assessed against the ones before it.
pub fn assess_all(series: &[&CalibrationRecord], settings: &Settings) -> Vec<Assessment> {
    (0..series.len()).map(|k| assess(series, k, settings)).collect()
}

fn verdict_of(q: Quantity, reference: &[Point], new: Point, settings: &Settings, z_crit: f64) -> Option<Verdict> {
    if reference.is_empty() {
        return None;
    }
    let floor = settings.repeatability_floor[q.index()] * new.x.abs();
    let mut tau2 = floor * floor;
    if reference.len() >= settings.min_for_repeatability.max(3) {
        tau2 = tau2.max(tau2_about_line(reference).unwrap_or(0.0));
    }
    let (mut sw, mut swx) = (0.0, 0.0);
    for p in reference {
        let w = 1.0 / (p.s * p.s + tau2);
        sw += w;
        swx += w * p.x;
    }
    let m = swx / sw;
    let z_step = (new.x - m) / (new.s * new.s + tau2 + 1.0 / sw).sqrt();
    let mut all = reference.to_vec();
    all.push(new);
    let z_trend = (all.len() >= 3).then(|| line(&all, tau2)).flatten().map(|l| l.slope / l.var_slope.sqrt());
    let alarm = z_step.abs() > z_crit || z_trend.is_some_and(|z| z.abs() > z_crit);
    Some(Verdict {
        quantity: q,
        n_reference: reference.len(),
        reference: m,
        change: new.x - m,
        change_pct: 100.0 * (new.x - m) / m,
        repeatability_sd: (new.s * new.s + tau2).sqrt(),
        z_step,
        z_trend,
        alarm,
    })
}

/// The trend of one quantity over `series`, once there are enough calibrations
/// spread over time.
pub fn trend(series: &[&CalibrationRecord], q: Quantity, settings: &Settings) -> Option<Trend> {
    let pts: Vec<Point> = series.iter().filter_map(|r| q.point(r)).collect();
    if pts.len() < settings.min_for_trend.max(3)
        || pts[pts.len() - 1].t - pts[0].t < settings.min_trend_span_days * 86_400.0
    {
        return None;
    }
    let floor = settings.repeatability_floor[q.index()] * pts[0].x.abs();
    let tau2 = tau2_about_line(&pts)?.max(floor * floor);
    let l = line(&pts, tau2)?;
    let dof = (pts.len() - 2) as f64;
    let t = StudentsT::new(0.0, 1.0, dof).ok()?.inverse_cdf(0.975);
    let se = l.var_slope.sqrt();
    let rate = l.slope * MONTH_S;
    let ci = [rate - t * se * MONTH_S, rate + t * se * MONTH_S];
    // Percent of the line's value at the first calibration.
    let level0 = l.value_at(pts[0].t);
    let pct = |v: f64| 100.0 * v / level0;
    Some(Trend {
        quantity: q,
        n: pts.len(),
        span_days: (pts[pts.len() - 1].t - pts[0].t) / 86_400.0,
        rate_per_month: rate,
        rate_ci95: ci,
        rate_pct_per_month: pct(rate),
        rate_pct_ci95: [pct(ci[0]), pct(ci[1])],
        repeatability_sd: (pts.iter().map(|p| p.s * p.s).sum::<f64>() / pts.len() as f64 + tau2).sqrt(),
    })
}

struct Line {
    t0: f64,
    intercept: f64,
    slope: f64,
    var_slope: f64,
}

impl Line {
    fn value_at(&self, t: f64) -> f64 {
        self.intercept + self.slope * (t - self.t0)
    }
}

/// Weighted least-squares line with weights 1/(s^2 + tau^2); None when the
/// times do not spread.
fn line(pts: &[Point], tau2: f64) -> Option<Line> {
    let t0 = pts.iter().map(|p| p.t).sum::<f64>() / pts.len() as f64;
    let (mut sw, mut swt, mut swtt, mut swx, mut swtx) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in pts {
        let w = 1.0 / (p.s * p.s + tau2);
        let t = p.t - t0;
        sw += w;
        swt += w * t;
        swtt += w * t * t;
        swx += w * p.x;
        swtx += w * t * p.x;
    }
    let det = sw * swtt - swt * swt;
    let spread = det.is_finite() && swtt > 0.0 && det > 1e-12 * sw * swtt;
    if !spread {
        return None;
    }
    let slope = (sw * swtx - swt * swx) / det;
    let intercept = (swx - slope * swt) / sw;
    Some(Line { t0, intercept, slope, var_slope: sw / det })
}

/// Between-calibration variance beyond the fits' own errors, by the method of
/// moments about a weighted straight line (DerSimonian–Laird for a
/// meta-regression with two parameters): Q = sum w r^2 with w = 1/s^2 has
/// expectation (n - 2) + tau^2 (sum w - tr((X'WX)^-1 X'W^2X)).
fn tau2_about_line(pts: &[Point]) -> Option<f64> {
    if pts.len() < 3 {
        return None;
    }
    let l = line(pts, 0.0)?;
    let (mut q, mut sw, mut swt, mut swtt, mut s2, mut s2t, mut s2tt) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for p in pts {
        let w = 1.0 / (p.s * p.s);
        let t = p.t - l.t0;
        let r = p.x - l.value_at(p.t);
        q += w * r * r;
        sw += w;
        swt += w * t;
        swtt += w * t * t;
        s2 += w * w;
        s2t += w * w * t;
        s2tt += w * w * t * t;
    }
    let det = sw * swtt - swt * swt;
    // tr(A^-1 B) for A = [[sw, swt], [swt, swtt]], B = [[s2, s2t], [s2t, s2tt]].
    let trace = (swtt * s2 - 2.0 * swt * s2t + sw * s2tt) / det;
    let denom = sw - trace;
    let excess = q - (pts.len() as f64 - 2.0);
    Some(if denom > 0.0 && excess > 0.0 { excess / denom } else { 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pts(xs: &[(f64, f64)], s: f64) -> Vec<Point> {
        xs.iter().map(|&(t, x)| Point { t, x, s }).collect()
    }

    #[test]
    fn a_repeatability_floor_explains_what_the_intervals_alone_do_not() {
        let reference = pts(&[(0.0, 1.0), (86_400.0, 1.0005), (2.0 * 86_400.0, 0.9995)], 0.001);
        let new = Point { t: 3.0 * 86_400.0, x: 1.006, s: 0.001 };
        let bare = Settings::default();
        let v = verdict_of(Quantity::E1, &reference, new, &bare, bare.z_critical()).unwrap();
        // 0.6 % against fits good to 0.1 %: a change.
        assert!(v.alarm && v.z_step > 5.0, "{v:?}");
        let floored = Settings { repeatability_floor: [0.005, 0.005], ..bare };
        let v = verdict_of(Quantity::E1, &reference, new, &floored, floored.z_critical()).unwrap();
        // With a rig that scatters 0.5 % between calibrations it is not.
        assert!(!v.alarm && v.z_step < 1.5, "{v:?}");
        assert!((v.repeatability_sd - (0.001f64.powi(2) + 0.00503f64.powi(2)).sqrt()).abs() < 1e-4, "{v:?}");
    }

    #[test]
    fn the_critical_value_is_the_bonferroni_normal_quantile() {
        // alpha = 0.2 % over four tests: 0.05 % each, two-sided: z = 3.4808.
        assert!((Settings::default().z_critical() - 3.4808).abs() < 1e-3);
    }

    #[test]
    fn a_line_is_recovered_and_scatter_about_it_is_not_repeatability() {
        let xs: Vec<(f64, f64)> = (0..10).map(|i| (i as f64 * 1e5, 1.0 + 2e-7 * i as f64 * 1e5)).collect();
        let p = pts(&xs, 0.01);
        let l = line(&p, 0.0).unwrap();
        assert!((l.slope - 2e-7).abs() < 1e-15);
        assert_eq!(tau2_about_line(&p), Some(0.0));
        // Alternating +-0.05 about the line with s = 0.01: tau ~ 0.05.
        let noisy: Vec<(f64, f64)> =
            xs.iter().enumerate().map(|(i, &(t, x))| (t, x + 0.05 * (-1f64).powi(i as i32))).collect();
        let tau = tau2_about_line(&pts(&noisy, 0.01)).unwrap().sqrt();
        assert!((tau - 0.05).abs() < 0.01, "{tau}");
    }
}
