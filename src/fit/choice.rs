//! Which of two full fits of one recording is the better (docs/physics.md,
//! "Which of the two fits is better"): both are judged by their chi² at one
//! common noise, so that the comparison means the same for both and does not
//! collapse when the recording has (almost) no noise.
//!
//! The noise per channel is, in this order, the one the user gives
//! (`--noise-um`), the recording's own standard errors, or the noise floor the
//! fits' residuals show (the smaller of the two fits' second-difference
//! floors: a misfit can only add to it). An estimated floor is bounded below by
//! what a residual can mean at all: the readings' resolution (the step the
//! recording's numbers are written to, as a uniform rounding error) and a
//! hundredth of the worse fit's RMS misfit (so that a noiseless recording of one
//! model, whose residuals under that model are numerical dust, does not divide
//! by zero, and the other model's misfit counts in units it cannot hide in).

use serde::Serialize;
use sim::recording::{Phase, Recording};

use super::full::{FullFit, FullOptions};
use super::weights::SampleSd;
use crate::numerics::stats::noise_from_second_differences;

/// Where a channel's noise in the comparison came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseSource {
    /// Given by the user (`--noise-um`, or the fit options).
    Given,
    /// The recording's per-sample standard errors.
    Recorded,
    /// The noise floor of the fits' residuals.
    Estimated,
    /// The estimated floor lay below the readings' resolution.
    Resolution,
    /// The estimated floor lay below a hundredth of the worse fit's misfit.
    MisfitFraction,
}

/// The noise of one channel the fits are judged by.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ChannelNoise {
    /// The noise (its median over the samples when per sample), mm or degrees.
    pub sigma: f64,
    pub source: NoiseSource,
}

/// How the fit chose between two fits: the common noise, each fit's chi² at
/// it, the degrees of freedom the comparison counts, and the rule that decided.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Judgement {
    pub gamma1_mm: ChannelNoise,
    pub theta1_deg: ChannelNoise,
    /// chi² of the first and the second fit at the common noise.
    pub chi2: [f64; 2],
    /// Observations less fitted parameters (the larger count of the two fits').
    pub dof: usize,
    /// Whether the first fit is kept.
    pub first_kept: bool,
    /// `misfit` (the other's chi² exceeds the kept one's by more than both the
    /// kept one's chi² and the degrees of freedom), `bound` (comparable
    /// residuals; the kept fit is interior, the other on a bound of nu1) or
    /// `chi2` (comparable residuals, the smaller chi²).
    pub rule: &'static str,
}

/// Below the smaller residual floor, the noise is never taken under this
/// fraction of the worse fit's RMS misfit (see the module's documentation).
const MISFIT_FRACTION: f64 = 0.01;

/// The noise of each observation the comparison counts, and how it was set.
struct Noise {
    gamma1: Vec<f64>,
    theta1: Vec<f64>,
    gamma1_mm: ChannelNoise,
    theta1_deg: ChannelNoise,
}

/// Residuals, each with the index of its sample.
type Indexed = Vec<(usize, f64)>;

/// One fit's residuals per channel, each with its sample's index: gamma1 of
/// every sample off the dead band (a reading of exactly zero is "no contact
/// seen", not a depth), theta1 of every torsion sample.
fn residuals(rec: &Recording, f: &FullFit) -> (Indexed, Indexed) {
    let (mut g, mut t) = (Vec::new(), Vec::new());
    for (i, (s, p)) in rec.samples.iter().zip(&f.predictions).enumerate() {
        if s.gamma1_mm != 0.0 {
            g.push((i, s.gamma1_mm - p.gamma1_mm));
        }
        if s.phase == Phase::Torsion {
            t.push((i, s.theta1_deg - p.theta1_deg));
        }
    }
    (g, t)
}

fn rms(v: &[(usize, f64)]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|(_, r)| r * r).sum::<f64>() / v.len() as f64).sqrt()
}

/// The step the channel's readings are written to (a power of ten from 1 down
/// to 1e-9, the coarsest that every non-zero reading is a multiple of), if any.
pub fn reading_step(values: &[f64]) -> Option<f64> {
    let live: Vec<f64> = values.iter().copied().filter(|v| *v != 0.0).collect();
    if live.len() < 3 {
        return None;
    }
    (0..=9).map(|k| 10f64.powi(-k)).find(|q| {
        live.iter().all(|v| {
            let x = v / q;
            (x - x.round()).abs() < 1e-6
        })
    })
}

/// One channel's common noise: given, recorded, or the floor estimated from
/// both fits' residuals, bounded below as the module's documentation says.
fn channel(
    given: Option<f64>,
    recorded: Option<&Vec<f64>>,
    floors: [Option<f64>; 2],
    step: Option<f64>,
    worse_rms: f64,
) -> (ChannelNoise, Option<Vec<f64>>) {
    if let Some(s) = given.filter(|s| s.is_finite() && *s > 0.0) {
        return (ChannelNoise { sigma: s, source: NoiseSource::Given }, None);
    }
    if let Some(v) = recorded {
        let mut sorted = v.clone();
        let sigma = crate::numerics::stats::median(&mut sorted);
        return (ChannelNoise { sigma, source: NoiseSource::Recorded }, Some(v.clone()));
    }
    let floor = floors.into_iter().flatten().filter(|f| f.is_finite()).fold(f64::INFINITY, f64::min);
    let resolution = step.map_or(0.0, |q| q / 12f64.sqrt());
    let fraction = MISFIT_FRACTION * worse_rms;
    let mut noise = ChannelNoise { sigma: floor, source: NoiseSource::Estimated };
    if !floor.is_finite() {
        noise.sigma = 0.0;
    }
    if resolution > noise.sigma {
        noise = ChannelNoise { sigma: resolution, source: NoiseSource::Resolution };
    }
    if fraction > noise.sigma {
        noise = ChannelNoise { sigma: fraction, source: NoiseSource::MisfitFraction };
    }
    (noise, None)
}

/// The common noise of fits `a` and `b` of `rec`.
fn common_noise(rec: &Recording, opts: &FullOptions, a: &FullFit, b: &FullFit) -> Noise {
    let (ra, rb) = (residuals(rec, a), residuals(rec, b));
    let mut sd = SampleSd::of(rec);
    if opts.gamma1_sigma_mm.is_some() {
        sd.gamma1_mm = None;
    }
    if opts.theta1_sigma_deg.is_some() {
        sd.theta1_deg = None;
    }
    // The floors as the fit estimates them: over the normal sweep's live
    // readings and over the torsion sweep, in time order.
    let normal = |f: &FullFit| -> Vec<f64> {
        rec.samples
            .iter()
            .zip(&f.predictions)
            .filter(|(s, _)| s.phase == Phase::Normal && s.gamma1_mm != 0.0)
            .map(|(s, p)| s.gamma1_mm - p.gamma1_mm)
            .collect()
    };
    let twist = |r: &[(usize, f64)]| r.iter().map(|(_, v)| *v).collect::<Vec<f64>>();
    let (g, g_per) = channel(
        opts.gamma1_sigma_mm,
        sd.gamma1_mm.as_ref(),
        [noise_from_second_differences(&normal(a)), noise_from_second_differences(&normal(b))],
        reading_step(&rec.samples.iter().map(|s| s.gamma1_mm).collect::<Vec<_>>()),
        rms(&ra.0).max(rms(&rb.0)),
    );
    let (t, t_per) = channel(
        opts.theta1_sigma_deg,
        sd.theta1_deg.as_ref(),
        [noise_from_second_differences(&twist(&ra.1)), noise_from_second_differences(&twist(&rb.1))],
        reading_step(&rec.phase(Phase::Torsion).map(|s| s.theta1_deg).collect::<Vec<_>>()),
        rms(&ra.1).max(rms(&rb.1)),
    );
    let n = rec.samples.len();
    Noise {
        gamma1: g_per.unwrap_or_else(|| vec![g.sigma; n]),
        theta1: t_per.unwrap_or_else(|| vec![t.sigma; n]),
        gamma1_mm: g,
        theta1_deg: t,
    }
}

/// chi² of a fit's residuals at the common noise (a channel whose noise is
/// zero, because both fits leave exactly nothing in it, adds nothing).
fn chi2(rec: &Recording, f: &FullFit, noise: &Noise) -> (f64, usize) {
    let (g, t) = residuals(rec, f);
    let term = |r: f64, s: f64| if s > 0.0 { (r / s).powi(2) } else { 0.0 };
    let c = g.iter().map(|&(i, r)| term(r, noise.gamma1[i])).sum::<f64>()
        + t.iter().map(|&(i, r)| term(r, noise.theta1[i])).sum::<f64>();
    (c, g.len() + t.len())
}

fn pinned(f: &FullFit) -> bool {
    f.warnings.iter().any(|w| w.code == "nu1_at_bound")
}

/// Fitted parameters: E1, nu1, z0 and the friction where the model has one.
fn parameters(f: &FullFit) -> usize {
    3 + usize::from(f.contact_friction.is_some())
}

/// Judge fit `a` against fit `b` of the same recording at their common noise.
///
/// A fit whose chi² exceeds the other's by more than both the other's chi² and
/// the degrees of freedom loses whatever else holds: its residual variance is
/// more than twice the other's, and its misfit beyond the other's is larger
/// than the noise itself (what a model at the noise leaves is chi² ≈ dof).
/// Between fits of comparable residuals an interior optimum beats one on a
/// bound of nu1, and otherwise the smaller chi² wins.
pub fn judge(rec: &Recording, opts: &FullOptions, a: &FullFit, b: &FullFit) -> Judgement {
    let noise = common_noise(rec, opts, a, b);
    let ((ca, n), (cb, _)) = (chi2(rec, a, &noise), chi2(rec, b, &noise));
    let dof = n.saturating_sub(parameters(a).max(parameters(b))).max(1);
    let (first_kept, rule) = decide([ca, cb], [pinned(a), pinned(b)], dof);
    Judgement { gamma1_mm: noise.gamma1_mm, theta1_deg: noise.theta1_deg, chi2: [ca, cb], dof, first_kept, rule }
}

/// The rule of [`judge`] on the two fits' chi² at the common noise, whether
/// each ended on a bound of nu1, and the degrees of freedom: whether the first
/// is kept, and by which rule.
fn decide(chi2: [f64; 2], pinned: [bool; 2], dof: usize) -> (bool, &'static str) {
    let [ca, cb] = chi2;
    let misfits = |x: f64, y: f64| x - y > y.max(dof as f64);
    if misfits(cb, ca) {
        (true, "misfit")
    } else if misfits(ca, cb) {
        (false, "misfit")
    } else {
        match pinned {
            [false, true] => (true, "bound"),
            [true, false] => (false, "bound"),
            _ => (ca <= cb, "chi2"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reading_step_is_the_coarsest_power_of_ten_of_the_written_numbers() {
        assert_eq!(reading_step(&[0.0, 0.0254, 0.0555, 1.2]), Some(1e-4));
        assert_eq!(reading_step(&[0.12345, 0.5, 0.00001]), Some(1e-5));
        assert_eq!(reading_step(&[0.1, 0.2, 0.3]), Some(0.1));
        // Full double precision: no step, and too few readings to tell.
        assert_eq!(reading_step(&[0.1 / 3.0, 0.2 / 7.0, 0.3 / 11.0]), None);
        assert_eq!(reading_step(&[0.0, 0.1]), None);
    }

    #[test]
    fn an_estimated_floor_is_bounded_below_by_the_resolution_and_the_worse_misfit() {
        // Noiseless: both floors are numerical dust; the resolution decides.
        let (n, _) = channel(None, None, [Some(1e-12), Some(3e-9)], Some(1e-5), 1e-4);
        assert_eq!(n.source, NoiseSource::Resolution);
        assert!((n.sigma - 1e-5 / 12f64.sqrt()).abs() < 1e-18);
        // Without a resolution, a hundredth of the worse fit's misfit.
        let (n, _) = channel(None, None, [Some(1e-12), None], None, 2e-3);
        assert_eq!((n.sigma, n.source), (2e-5, NoiseSource::MisfitFraction));
        // A real noise floor stands; the smaller of the two fits' is taken.
        let (n, _) = channel(None, None, [Some(2.1e-3), Some(2.0e-3)], Some(1e-4), 5e-3);
        assert_eq!((n.sigma, n.source), (2.0e-3, NoiseSource::Estimated));
        // A given noise wins over recorded errors, which win over the floor.
        let rec = vec![1e-3, 3e-3, 2e-3];
        let (n, per) = channel(Some(4e-3), Some(&rec), [Some(1e-9), None], None, 1.0);
        assert_eq!((n.sigma, n.source, per), (4e-3, NoiseSource::Given, None));
        let (n, per) = channel(None, Some(&rec), [Some(1e-9), None], None, 1.0);
        assert_eq!((n.sigma, n.source, per), (2e-3, NoiseSource::Recorded, Some(rec.clone())));
    }

    #[test]
    fn a_misfit_decides_before_a_bound_and_a_bound_before_a_smaller_chi2() {
        // At the noise (chi² about the 44 degrees of freedom), a fit on the
        // bound with a little less chi² loses to an interior one...
        assert_eq!(decide([47.0, 40.0], [false, true], 44), (true, "bound"));
        assert_eq!(decide([40.0, 47.0], [true, false], 44), (false, "bound"));
        // ...but not once its rival's residual variance is twice its own and
        // the excess is more than the noise.
        assert_eq!(decide([95.0, 44.0], [false, true], 44), (false, "misfit"));
        assert_eq!(decide([44.0, 95.0], [true, false], 44), (true, "misfit"));
        // Both interior, comparable: the smaller chi² wins.
        assert_eq!(decide([50.0, 45.0], [false, false], 44), (false, "chi2"));
        // Far below the noise (a noiseless recording judged at a given noise):
        // an excess smaller than the degrees of freedom is not a misfit, so the
        // bound decides; one far larger is.
        assert_eq!(decide([1e-4, 30.0], [true, false], 44), (false, "bound"));
        assert_eq!(decide([1e-4, 300.0], [true, false], 44), (true, "misfit"));
    }
}
