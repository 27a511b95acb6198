//! The per-sample standard errors a recording may carry (`gamma1_sd_mm`,
//! `theta1_sd_deg`; docs/recording-format.md), as the full-model fit and the
//! diagnosis weigh the readings by them (docs/physics.md, "Weighted fit").

use sim::recording::{Phase, Recording};

use crate::numerics::stats::median;

/// The standard error of every sample's reading, per channel, when the
/// recording carries them. A sample without one, in a recording where others
/// have one, gets the channel's median.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SampleSd {
    /// gamma1 standard error of every sample (recording order), mm.
    pub gamma1_mm: Option<Vec<f64>>,
    /// theta1 standard error of every sample (recording order; only the
    /// torsion samples' mean anything), degrees.
    pub theta1_deg: Option<Vec<f64>>,
}

impl SampleSd {
    /// The recording's standard errors (a value that is not a positive number counts as missing).
    pub fn of(rec: &Recording) -> Self {
        let usable = |v: Option<f64>| v.filter(|x| x.is_finite() && *x > 0.0);
        let gamma1 = filled(rec.samples.iter().map(|s| (usable(s.gamma1_sd_mm), true)));
        let theta1 = filled(rec.samples.iter().map(|s| (usable(s.theta1_sd_deg), s.phase == Phase::Torsion)));
        Self { gamma1_mm: gamma1, theta1_deg: theta1 }
    }

    /// Whether either channel is weighted by its standard errors.
    pub fn any(&self) -> bool {
        self.gamma1_mm.is_some() || self.theta1_deg.is_some()
    }

    /// Median gamma1 standard error over `keep`'s samples (mm), if the recording has them.
    pub fn gamma1_median_mm(&self, keep: impl Fn(usize) -> bool) -> Option<f64> {
        self.gamma1_mm.as_ref().map(|v| {
            let mut k: Vec<f64> = v.iter().enumerate().filter(|(i, _)| keep(*i)).map(|(_, s)| *s).collect();
            median(&mut k)
        })
    }

    /// Median theta1 standard error over `keep`'s samples (degrees), if the recording has them.
    pub fn theta1_median_deg(&self, keep: impl Fn(usize) -> bool) -> Option<f64> {
        self.theta1_deg.as_ref().map(|v| {
            let mut k: Vec<f64> = v.iter().enumerate().filter(|(i, _)| keep(*i)).map(|(_, s)| *s).collect();
            median(&mut k)
        })
    }
}

/// Every sample's value, the median of the counted ones standing in for a
/// missing one; `None` when no counted sample has a value.
fn filled(values: impl Iterator<Item = (Option<f64>, bool)>) -> Option<Vec<f64>> {
    let values: Vec<(Option<f64>, bool)> = values.collect();
    let mut known: Vec<f64> = values.iter().filter(|(_, counted)| *counted).filter_map(|(v, _)| *v).collect();
    if known.is_empty() {
        return None;
    }
    let mid = median(&mut known);
    Some(values.iter().map(|(v, counted)| if *counted { v.unwrap_or(mid) } else { mid }).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::recording::Sample;

    fn sample(phase: Phase, g: Option<f64>, t: Option<f64>) -> Sample {
        Sample { gamma1_sd_mm: g, theta1_sd_deg: t, ..Sample::new(0.0, phase, 0.0, 0.0, 0.0, 0.0) }
    }

    #[test]
    fn missing_errors_take_the_channel_median() {
        let meta = sim::generator::generate(&Default::default()).unwrap().meta;
        let rec = Recording {
            meta: meta.clone(),
            samples: vec![
                sample(Phase::Normal, Some(0.004), None),
                sample(Phase::Normal, None, None),
                sample(Phase::Normal, Some(0.002), None),
                sample(Phase::Normal, Some(0.001), Some(9.0)),
                sample(Phase::Torsion, Some(-1.0), Some(0.01)),
                sample(Phase::Torsion, None, None),
                sample(Phase::Torsion, Some(0.003), Some(0.03)),
            ],
        };
        let sd = SampleSd::of(&rec);
        // Known gamma1 errors 4, 2, 1, 3 µm (the negative one is missing): median 2.5 µm.
        assert_eq!(sd.gamma1_mm, Some(vec![0.004, 0.0025, 0.002, 0.001, 0.0025, 0.0025, 0.003]));
        // theta1 counts the torsion samples only: median of 0.01 and 0.03.
        assert_eq!(sd.theta1_deg, Some(vec![0.02, 0.02, 0.02, 0.02, 0.01, 0.02, 0.03]));
        let none = SampleSd::of(&Recording { meta, samples: vec![sample(Phase::Normal, None, None)] });
        assert!(!none.any());
    }
}
