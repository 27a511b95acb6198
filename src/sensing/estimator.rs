//! The estimator a run reads its frames through: [`measure`] plus what the
//! run's own frames teach it. Contacts smaller than about one marker pitch
//! cannot tell their depth from their radius (docs/sensing.md, "Small
//! contacts"); contacts a few pitches wide measure the field's curvature
//! inside the contact, gamma1 / a^2, directly. In a Hertz contact that
//! curvature is the same at every depth (gamma1 = f1 delta and a^2 = R delta,
//! so gamma1 / a^2 = f1 / R, f1 the elastomer's share of the approach), so
//! the curvature learnt on resolved contacts settles the small ones.

use devices::sensor::SensorFrame;

use super::{Measurement, SensingConfig, SensingError, measure};
use crate::numerics::stats::MAD_TO_SIGMA;

/// Resolved frames whose curvature is kept: the approach and the start of
/// the sweep give them; the curvature is learnt by then.
const MAX_ESTIMATES: usize = 400;

/// Fewest resolved frames before the curvature is used.
const MIN_ESTIMATES: usize = 5;

/// Estimates from contacts up to this multiple of the smallest resolved ones
/// are averaged: the curvature is applied below that size, and in a real
/// (layered, large-strain) contact it drifts slowly with depth.
const RADIUS_SPAN: f64 = 1.5;

/// An estimate further than this many robust sigmas from the others' median
/// (curvature or centre) is a frame that only looked resolved (a noisy
/// paraboloid over a small contact) and is left out.
const OUTLIER_SIGMAS: f64 = 4.0;

/// One resolved frame: contact radius mm, curvature 1/mm, its standard
/// error 1/mm, centre mm.
type Estimate = (f64, f64, f64, [f64; 2]);

/// The field's curvature inside the contact and where the contact is, learnt
/// from resolved frames.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CurvatureLearner {
    estimates: Vec<Estimate>,
    /// (curvature, its standard error, centre) from the estimates so far.
    learnt: Option<(f64, f64, [f64; 2])>,
}

impl CurvatureLearner {
    /// Take one resolved frame's curvature `per_mm` (standard error
    /// `sd_per_mm`) at contact radius `radius_mm`, centred at `centre_mm`;
    /// non-physical ones are ignored.
    pub fn add(&mut self, radius_mm: f64, per_mm: f64, sd_per_mm: f64, centre_mm: [f64; 2]) {
        let ok = [radius_mm, per_mm, sd_per_mm].iter().all(|v| v.is_finite() && *v > 0.0)
            && centre_mm.iter().all(|v| v.is_finite());
        if ok && self.estimates.len() < MAX_ESTIMATES {
            self.estimates.push((radius_mm, per_mm, sd_per_mm, centre_mm));
            self.learnt = learn(&self.estimates);
        }
    }

    /// The curvature and its standard error (see [`learn`]); `None` before
    /// enough frames.
    pub fn estimate(&self) -> Option<(f64, f64)> {
        self.learnt.map(|l| (l.0, l.1))
    }

    /// Where the smallest resolved contacts were centred.
    pub fn centre(&self) -> Option<[f64; 2]> {
        self.learnt.map(|l| l.2)
    }
}

/// The inverse-variance weighted curvature of the smallest resolved contacts
/// (those within [`RADIUS_SPAN`] of the lower fifth of the radii), with its
/// standard error widened by the Birge ratio when they disagree beyond their
/// errors (a drift with depth, a model the frames do not follow), and their
/// mean centre. Frames far from the others' median are left out first.
fn learn(estimates: &[Estimate]) -> Option<(f64, f64, [f64; 2])> {
    let mut radii: Vec<f64> = estimates.iter().map(|e| e.0).collect();
    let smallest = quantile(&mut radii, 0.2)?;
    let near: Vec<&Estimate> = estimates.iter().filter(|e| e.0 <= RADIUS_SPAN * smallest).collect();
    let robust = |v: Vec<f64>| -> Option<(f64, f64)> {
        let mut v = v;
        let med = quantile(&mut v, 0.5)?;
        let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
        Some((med, MAD_TO_SIGMA * quantile(&mut dev, 0.5)?))
    };
    let (c_med, c_sigma) = robust(near.iter().map(|e| e.1).collect())?;
    let (x_med, x_sigma) = robust(near.iter().map(|e| e.3[0]).collect())?;
    let (y_med, y_sigma) = robust(near.iter().map(|e| e.3[1]).collect())?;
    // A hundredth of a millimetre of centre, a percent of curvature: below
    // that, agreement is not worth a test.
    let within = |x: f64, med: f64, sigma: f64, floor: f64| (x - med).abs() <= OUTLIER_SIGMAS * sigma.max(floor);
    let kept: Vec<&&Estimate> = near
        .iter()
        .filter(|e| {
            within(e.1, c_med, c_sigma, 0.01 * c_med)
                && within(e.3[0], x_med, x_sigma, 0.01)
                && within(e.3[1], y_med, y_sigma, 0.01)
        })
        .collect();
    if kept.len() < MIN_ESTIMATES {
        return None;
    }
    let w: f64 = kept.iter().map(|e| 1.0 / (e.2 * e.2)).sum();
    let mean = kept.iter().map(|e| e.1 / (e.2 * e.2)).sum::<f64>() / w;
    let chi2 = kept.iter().map(|e| ((e.1 - mean) / e.2).powi(2)).sum::<f64>();
    let birge = (chi2 / (kept.len() - 1) as f64).sqrt().max(1.0);
    let n = kept.len() as f64;
    let centre = [kept.iter().map(|e| e.3[0]).sum::<f64>() / n, kept.iter().map(|e| e.3[1]).sum::<f64>() / n];
    Some((mean, birge / w.sqrt(), centre))
}

/// The `p` quantile (nearest rank) of `v`, reordering it; `None` when empty.
fn quantile(v: &mut [f64], p: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let k = ((v.len() - 1) as f64 * p).round() as usize;
    let (_, x, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    Some(*x)
}

/// [`measure`] with the curvature learnt from this run's resolved frames
/// (unless the configuration fixes one).
#[derive(Debug, Clone)]
pub struct FrameEstimator {
    cfg: SensingConfig,
    learner: CurvatureLearner,
}

impl FrameEstimator {
    pub fn new(cfg: SensingConfig) -> Self {
        Self { cfg, learner: CurvatureLearner::default() }
    }

    /// The curvature small contacts are fitted with now, if any.
    pub fn curvature(&self) -> Option<(f64, f64)> {
        self.cfg.contact_curvature_per_mm.or_else(|| self.learner.estimate())
    }

    /// Where small contacts are fitted now, if known.
    pub fn centre(&self) -> Option<[f64; 2]> {
        self.cfg.contact_centre_mm.or_else(|| self.learner.centre())
    }

    /// Measure one frame, and learn from it when it resolves its contact.
    pub fn measure(&mut self, frame: &SensorFrame) -> Result<Measurement, SensingError> {
        let cfg =
            SensingConfig { contact_curvature_per_mm: self.curvature(), contact_centre_mm: self.centre(), ..self.cfg };
        let m = measure(frame, &cfg)?;
        if let Some((c, sd)) = m.contact_curvature_per_mm {
            self.learner.add(m.contact_radius_mm, c, sd, m.contact_centre_mm);
        }
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_learner_averages_the_smallest_contacts_and_leaves_out_strays() {
        let mut l = CurvatureLearner::default();
        let jitter = [-0.002, 0.001, 0.0, 0.002, -0.001, 0.001];
        for (k, j) in jitter.iter().enumerate().take(4) {
            l.add(1.6 + 0.02 * k as f64, 0.18 + j, 0.002, [0.1 + j, -0.2]);
        }
        assert_eq!((l.estimate(), l.centre()), (None, None));
        l.add(1.7, 0.18 + jitter[4], 0.002, [0.1 + jitter[4], -0.2]);
        // A contact three times larger is beyond the span; a frame that only
        // looked resolved (another centre, another curvature) is a stray.
        l.add(4.8, 0.30, 0.001, [5.0, 5.0]);
        l.add(1.62, 0.25, 0.002, [-0.3, 0.2]);
        let (c, sd) = l.estimate().unwrap();
        let centre = l.centre().unwrap();
        assert!((c - 0.18).abs() < 1e-9 && (sd - 0.002 / 5f64.sqrt()).abs() < 1e-12, "{c} {sd}");
        assert!((centre[0] - 0.1).abs() < 1e-9 && (centre[1] + 0.2).abs() < 1e-12, "{centre:?}");
        // Estimates further apart than their errors widen the error.
        l.add(1.65, 0.19, 0.0005, [0.1, -0.2]);
        let (_, sd2) = l.estimate().unwrap();
        assert!(sd2 > 2.0 * 0.0005 / 6f64.sqrt(), "{sd2}");
        // Non-physical input is ignored.
        let before = l.estimates.len();
        l.add(f64::NAN, 0.2, 0.01, [0.0, 0.0]);
        l.add(1.6, -0.2, 0.01, [0.0, 0.0]);
        l.add(1.6, 0.2, 0.01, [f64::NAN, 0.0]);
        assert_eq!(l.estimates.len(), before);
    }
}
