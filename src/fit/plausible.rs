//! Plausibility of a recording before anything is fitted (docs/recording-format.md,
//! "Plausibility"). The reader checks each value on its own; these checks look at
//! the sweeps as a whole and refuse data no rig could have produced — a stage
//! column that is zero, negated or rescaled, a twist larger than any mount makes —
//! so that nonsense ends in an error naming the column and the sample, never in a
//! converged fit.

use sim::recording::{Direction, Phase, Recording, Sample};

/// Longest time a recording may span, s (a calibration takes minutes; an aging
/// study records each calibration separately).
pub const MAX_SPAN_S: f64 = 1e6;
/// Largest mount angle a torsion sweep may report, degrees.
pub const MAX_ROT_DEG: f64 = 180.0;
/// Stage travel past contact, in indenter radii, beyond which the indenter would be buried.
pub const MAX_TRAVEL_R2: f64 = 4.0;
/// Stage jitter tolerated against the sweep direction, mm (an encoder reading).
const STAGE_JITTER_MM: f64 = 5e-4;

/// What is implausible, and where.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("implausible recording: {what} ({location})")]
pub struct Implausible {
    pub what: String,
    pub location: String,
}

fn at(i: usize, s: &Sample, column: &str) -> String {
    format!("column `{column}`, sample {} at t_s = {}", i + 1, s.t_s)
}

fn implausible(what: impl Into<String>, location: impl Into<String>) -> Implausible {
    Implausible { what: what.into(), location: location.into() }
}

/// Every check, in the order a reader would want them: time, stage, twist.
pub fn check(rec: &Recording) -> Result<(), Implausible> {
    check_time(rec)?;
    check_stage(rec)?;
    check_twist(rec)
}

fn check_time(rec: &Recording) -> Result<(), Implausible> {
    let (Some(first), Some(last)) = (rec.samples.first(), rec.samples.last()) else {
        return Ok(());
    };
    let span = last.t_s - first.t_s;
    if span > MAX_SPAN_S {
        return Err(implausible(
            format!("the samples span {span:.3e} s; one calibration spans at most {MAX_SPAN_S:.0e} s"),
            at(rec.samples.len() - 1, last, "t_s"),
        ));
    }
    Ok(())
}

/// The normal sweep: the stage advances on loading, gamma1 grows with it and never
/// exceeds the stage's travel (gamma1 + gamma2 = travel past contact, docs/physics.md 1.1),
/// and the travel stays within a few indenter radii.
fn check_stage(rec: &Recording) -> Result<(), Implausible> {
    let normal: Vec<(usize, &Sample)> =
        rec.samples.iter().enumerate().filter(|(_, s)| s.phase == Phase::Normal).collect();
    if normal.is_empty() {
        return Ok(());
    }
    // Experiments (a dwell, a reload) move on their own paths; the sweep's direction holds for the sweep.
    let sweep: Vec<(usize, &Sample)> = normal.iter().copied().filter(|(_, s)| s.in_sweep()).collect();
    check_monotone(&sweep)?;
    let lo = normal.iter().map(|(_, s)| s.stage_mm).fold(f64::INFINITY, f64::min);
    let hi = normal.iter().map(|(_, s)| s.stage_mm).fold(f64::NEG_INFINITY, f64::max);
    let travel = hi - lo;
    let Some(&(ig, g_max)) = normal.iter().max_by(|a, b| a.1.gamma1_mm.total_cmp(&b.1.gamma1_mm)) else {
        return Ok(());
    };
    // Sensor noise may put a reading a few micrometres above a tiny travel.
    let slack = 0.02 + 0.05 * g_max.gamma1_mm.abs();
    if g_max.gamma1_mm > travel + slack {
        return Err(implausible(
            format!(
                "gamma1 reaches {:.4} mm but the stage travels only {travel:.4e} mm over the normal sweep; \
                 the elastomer cannot deflect further than the stage pushes (is the stage column zero or rescaled?)",
                g_max.gamma1_mm
            ),
            at(ig, g_max, "gamma1_mm"),
        ));
    }
    if let Some(&(il, g_min)) = normal.iter().min_by(|a, b| a.1.gamma1_mm.total_cmp(&b.1.gamma1_mm))
        && g_min.gamma1_mm < -slack
    {
        return Err(implausible(
            format!("gamma1 is {:.4} mm: the elastomer cannot be pulled out of its surface", g_min.gamma1_mm),
            at(il, g_min, "gamma1_mm"),
        ));
    }
    let r2 = rec.meta.indenter.r_mm;
    if travel > MAX_TRAVEL_R2 * r2 {
        let (i, s) = normal.iter().max_by(|a, b| a.1.stage_mm.total_cmp(&b.1.stage_mm)).copied().unwrap_or(normal[0]);
        return Err(implausible(
            format!(
                "the stage travels {travel:.4e} mm over the normal sweep, more than {MAX_TRAVEL_R2} indenter radii \
                 (R2 = {r2} mm): the indenter would be buried (is the stage column rescaled?)"
            ),
            at(i, s, "stage_mm"),
        ));
    }
    // gamma1 must rise with the stage: a negated column makes them move apart.
    let live: Vec<(f64, f64)> =
        normal.iter().filter(|(_, s)| s.gamma1_mm != 0.0).map(|(_, s)| (s.stage_mm, s.gamma1_mm)).collect();
    if let Some(r) = correlation(&live)
        && r < 0.0
    {
        return Err(implausible(
            format!(
                "gamma1 falls as stage_mm rises (correlation {r:+.3}); stage_mm must grow as the indenter \
                 presses in (is the stage column negated?)"
            ),
            "column `stage_mm`, normal sweep".to_string(),
        ));
    }
    Ok(())
}

/// Within each repeat the stage moves one way per direction: forward while loading,
/// back while unloading; without a `dir` column, at most one reversal per repeat.
fn check_monotone(normal: &[(usize, &Sample)]) -> Result<(), Implausible> {
    let mut reps: Vec<Option<u32>> = normal.iter().map(|(_, s)| s.rep).collect();
    reps.dedup();
    reps.sort_unstable();
    reps.dedup();
    for rep in reps {
        let rows: Vec<(usize, &Sample)> = normal.iter().copied().filter(|(_, s)| s.rep == rep).collect();
        let mut reversals = 0;
        let mut trend = 0.0f64;
        for w in rows.windows(2) {
            let (_, a) = w[0];
            let (ib, b) = w[1];
            let step = b.stage_mm - a.stage_mm;
            let wrong_way = match b.dir {
                Some(Direction::Load) => step < -STAGE_JITTER_MM && a.dir == Some(Direction::Load),
                Some(Direction::Unload) => step > STAGE_JITTER_MM && a.dir == Some(Direction::Unload),
                None => false,
            };
            if wrong_way {
                let d = if b.dir == Some(Direction::Load) { "loading" } else { "unloading" };
                return Err(implausible(
                    format!(
                        "the stage moves {step:+.4} mm against the sweep while {d}: the normal sweep must be monotone"
                    ),
                    at(ib, b, "stage_mm"),
                ));
            }
            if b.dir.is_none() && step.abs() > STAGE_JITTER_MM {
                if trend != 0.0 && step.signum() != trend.signum() {
                    reversals += 1;
                    if reversals > 1 {
                        return Err(implausible(
                            "the stage changes direction more than once in one repeat of the normal sweep \
                             (load then unload expected; number repeats in a `rep` column)",
                            at(ib, b, "stage_mm"),
                        ));
                    }
                }
                trend = step;
            }
        }
    }
    Ok(())
}

/// The torsion sweep: mount angles a rotation mount makes, and an elastomer twist
/// that never exceeds the mount's largest (theta1 + theta2 = mount angle,
/// docs/physics.md 1.4; compared with the sweep's amplitude, not sample by sample, since
/// hysteresis may leave a twist at zero angle on the way back).
fn check_twist(rec: &Recording) -> Result<(), Implausible> {
    let mut amplitude = 0.0f64;
    for (i, s) in rec.samples.iter().enumerate().filter(|(_, s)| s.phase == Phase::Torsion) {
        if s.rot_deg.abs() > MAX_ROT_DEG {
            return Err(implausible(
                format!("the mount angle is {:.4e}°, beyond the ±{MAX_ROT_DEG}° of a torsion sweep", s.rot_deg),
                at(i, s, "rot_deg"),
            ));
        }
        amplitude = amplitude.max(s.rot_deg.abs());
    }
    let slack = 0.05 + 0.05 * amplitude;
    if let Some((i, s)) = rec
        .samples
        .iter()
        .enumerate()
        .filter(|(_, s)| s.phase == Phase::Torsion)
        .find(|(_, s)| s.theta1_deg.abs() > amplitude + slack)
    {
        return Err(implausible(
            format!(
                "theta1 = {:.4}° exceeds the largest mount angle of the sweep, {amplitude:.4}°: the elastomer \
                 cannot twist more than the mount",
                s.theta1_deg
            ),
            at(i, s, "theta1_deg"),
        ));
    }
    Ok(())
}

fn correlation(pts: &[(f64, f64)]) -> Option<f64> {
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let syy: f64 = pts.iter().map(|p| (p.1 - my).powi(2)).sum();
    (sxx > 0.0 && syy > 0.0).then(|| sxy / (sxx * syy).sqrt())
}
