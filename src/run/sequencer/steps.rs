//! The procedure's steps: connect, open the recording, home, approach and find contact,
//! the normal sweep, the return to the torsion depth, the torsion sweep, retract
//! (the experiment steps after the torsion sweep are in `experiments.rs`).

use super::*;

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    pub(super) async fn connect(&mut self) -> Step<()> {
        self.checkpoint().await?;
        for (name, x) in
            [("limits.retract_mm", self.script.limits.retract_mm), ("approach.start_mm", self.script.approach.start_mm)]
        {
            if !self.guard.stage_in_travel(x) {
                let l = self.guard.limits();
                return Err(Halt {
                    culprit: Culprit::Safety,
                    message: format!(
                        "soft limit: script {name} = {x} mm lies outside the stage's travel [{}, {}] mm",
                        l.stage_min_mm, l.stage_max_mm
                    ),
                });
            }
        }
        let info = Identify::identify(&mut self.stage).await.map_err(|e| self.stage_fault("identify", e))?;
        self.stage_name = format!("stage {} SN {}", info.model, info.serial).trim().to_string();
        self.log(LogLevel::Info, format!("{} firmware {}", self.stage_name, info.firmware));
        let info = Identify::identify(&mut self.mount).await.map_err(|e| self.mount_fault("identify", e))?;
        self.mount_name = format!("rotation mount {} SN {}", info.model, info.serial).trim().to_string();
        self.log(LogLevel::Info, format!("{} firmware {}", self.mount_name, info.firmware));
        self.gauge.start().await.map_err(|e| self.sensor_fault("start", e))?;
        self.log(LogLevel::Info, format!("sensor {} streaming", self.gauge.describe()));
        self.open_recording()
    }

    pub(super) fn open_recording(&mut self) -> Step<()> {
        let fail = |e: std::io::Error, path: &Path| Halt {
            culprit: Culprit::Recording,
            message: format!("cannot write the recording {}: {e}", path.display()),
        };
        if let Some(dir) = self.recording_path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| fail(e, &self.recording_path))?;
        }
        let file =
            crate::run::outdir::create_nofollow(&self.recording_path).map_err(|e| fail(e, &self.recording_path))?;
        self.recording_file = Some(file);
        Ok(())
    }

    /// Write the recording's header: what the run knows of the rig, and how
    /// well it found the first contact (`contact_sd_mm`, docs/recording-format.md).
    pub(super) fn start_recording(&mut self, contact_sd_mm: Option<f64>) -> Step<()> {
        let Some(file) = self.recording_file.take() else {
            return Err(Halt { culprit: Culprit::Recording, message: "recording is not open".into() });
        };
        let mut extra =
            vec![("stage".to_string(), sanitize(&self.stage_name)), ("mount".to_string(), sanitize(&self.mount_name))];
        if let Some(sd) = contact_sd_mm.filter(|v| v.is_finite() && *v > 0.0) {
            extra.push((CONTACT_SD_KEY.to_string(), format!("{sd:.6}")));
        }
        extra.extend(self.extra_meta.iter().map(|(k, v)| (sanitize(k), sanitize(v))));
        let meta = Metadata {
            sensor: Some(sanitize(self.script.sensor.name.as_deref().unwrap_or(&self.gauge.describe()))),
            indenter: self.script.indenter,
            elastomer_r_mm: self.script.sensor.elastomer_r_mm,
            // Checked with the script before the run: a fault cannot reach here.
            layer: self.script.sensor.layer().ok().flatten(),
            created: Some(crate::report::rfc3339_utc(SystemTime::now())),
            extra,
        };
        self.meta = Some(meta.clone());
        let w = RecordingWriter::with_standard_errors(BufWriter::new(file), &meta).map_err(|e| Halt {
            culprit: Culprit::Recording,
            message: format!("cannot write the recording {}: {e}", self.recording_path.display()),
        })?;
        self.writer = Some(w);
        Ok(())
    }

    /// Find the contact from `rest`, the readings taken at the approach's
    /// start with the sensor tared (the elastomer untouched there).
    pub(super) async fn approach(&mut self, rest: Vec<GaugeReading>) -> Step<()> {
        let a = self.script.approach;
        self.noise.gamma1_mm = std_dev(rest.iter().map(|r| r.gamma1_mm));
        self.noise.theta1_deg = std_dev(rest.iter().map(|r| r.theta1_deg));
        let offset = mean(&rest).gamma1_mm;
        let threshold = (a.contact_sigmas * self.noise.gamma1_mm).max(a.contact_min_mm) + offset.abs();
        self.log(
            LogLevel::Info,
            format!(
                "gamma1 noise {:.2} um, theta1 noise {:.4} deg; contact threshold {:.2} um",
                self.noise.gamma1_mm * 1e3,
                self.noise.theta1_deg,
                threshold * 1e3
            ),
        );
        // Step in until two consecutive readings rise above the threshold.
        let mut pos = a.start_mm;
        let mut last_clear = pos;
        loop {
            let next = pos + a.search_step_mm;
            if !self.guard.stage_in_travel(next) {
                return Err(Halt {
                    culprit: Culprit::Procedure,
                    message: format!(
                        "approach: no contact found up to the stage limit {:.3} mm (gamma1 {:.4} mm, threshold {:.4} mm)",
                        pos, self.gamma1_mm, threshold
                    ),
                });
            }
            self.move_stage(next, "approach").await?;
            pos = next;
            let r1 = self.read().await?;
            let r2 = self.read().await?;
            if r1.gamma1_mm > threshold && r2.gamma1_mm > threshold {
                break;
            }
            last_clear = pos;
            self.progress_fraction((pos - a.start_mm) / (self.guard.limits().stage_max_mm - a.start_mm));
        }
        // Refine: settled readings deeper in, where the grid resolves the
        // contact, and a line through them back to gamma1 = 0.
        let mut pts = Vec::new();
        let first = self.settle().await?;
        pts.push((pos, first.gamma1_mm));
        for _ in 0..a.refine_steps {
            if pts.last().is_some_and(|p| p.1 >= a.refine_to_gamma1_mm) {
                break;
            }
            let next = pos + a.step_mm;
            if self.guard.check_stage(self.stage_mm, self.gamma1_bound_mm, next).is_err() {
                break;
            }
            self.move_stage(next, "contact refinement").await?;
            pos = next;
            pts.push((pos, self.settle().await?.gamma1_mm));
        }
        let window: Vec<(f64, f64)> =
            pts.iter().copied().filter(|p| (a.refine_from_gamma1_mm..=a.refine_to_gamma1_mm).contains(&p.1)).collect();
        let line = if window.len() >= 2 { contact_from_line(&window, threshold) } else { None };
        let provisional = line
            .or_else(|| contact_from_line(&pts, threshold))
            .unwrap_or(0.5 * (last_clear + pts[0].0))
            .clamp(last_clear - a.step_mm, pts[0].0);
        // The first pass's readings were taken while the sensing was still
        // learning the contact's shape; the second pass's stand alone when
        // there are enough of them.
        let second = self.reapproach(provisional).await?;
        let second: Vec<_> = second.into_iter().filter(|p| p.1 > threshold).collect();
        let shallow = second.iter().filter(|p| p.1 < a.refine_from_gamma1_mm).count();
        let found = if shallow >= 2 { contact_from_eq22(&second) } else { None };
        let (contact, contact_sd_mm) = match found {
            Some((c, sd)) => (c, Some(sd)),
            _ => (provisional, if line.is_some() { contact_uncertainty(&window, threshold) } else { None }),
        };
        self.contact_mm = Some(contact);
        let sd_text = contact_sd_mm.map(|sd| format!(" (± {:.1} um)", sd * 1e3)).unwrap_or_default();
        self.log(LogLevel::Info, format!("first contact at stage {contact:.4} mm{sd_text}"));
        self.start_recording(contact_sd_mm)?;
        // Back off to the normal sweep's start (the same direction of travel as loading follows).
        let start = (contact - a.pre_contact_mm).max(self.guard.limits().stage_min_mm);
        self.move_stage(start, "back to the normal sweep start").await?;
        Ok(())
    }

    /// Step in again from just above `provisional`, now that the sensing has
    /// learnt the contact's place and shape on the deep readings
    /// (docs/sensing.md, "Small contacts"): the settled (stage, gamma1,
    /// standard error) readings up to `refine_to_gamma1_mm`. The shallow ones
    /// pin the contact point; on the way the sensing learns the contact's
    /// curvature at the sizes the sweep's first samples have.
    async fn reapproach(&mut self, provisional: f64) -> Step<Vec<(f64, f64, Option<f64>)>> {
        let a = self.script.approach;
        let mut pos = (provisional - a.step_mm).max(self.guard.limits().stage_min_mm);
        self.move_stage(pos, "above the contact").await?;
        let mut pts = Vec::new();
        for _ in 0..a.refine_steps {
            let next = pos + a.step_mm;
            if self.guard.check_stage(self.stage_mm, self.gamma1_bound_mm, next).is_err() {
                break;
            }
            self.move_stage(next, "contact refinement").await?;
            pos = next;
            let r = self.settle().await?;
            pts.push((pos, r.gamma1_mm, r.gamma1_sd_mm));
            if r.gamma1_mm >= a.refine_to_gamma1_mm {
                break;
            }
        }
        Ok(pts)
    }

    /// One load/unload cycle. Returns the two load points around the target
    /// depth: ((stage_mm, beta) before, (stage_mm, beta) at/after).
    pub(super) async fn normal_sweep(&mut self, rep: u32) -> Step<((f64, f64), (f64, f64))> {
        let contact = self.contact_mm.unwrap_or(self.stage_mm);
        let n = self.script.normal;
        let r2 = self.script.indenter.r_mm;
        let start = (contact - self.script.approach.pre_contact_mm).max(self.guard.limits().stage_min_mm);
        let mut path: Vec<(f64, f64)> = Vec::new();
        let mut k = 0usize;
        let mut pos = start;
        if self.track.sweep_start.is_none() {
            self.track.sweep_start = Some((self.clock.t_last, self.samples.len()));
        }
        loop {
            let beta_now = path.last().map(|p| p.1).unwrap_or(0.0);
            if let Err(v) = self.guard.check_stage(self.stage_mm, self.gamma1_bound_mm, pos) {
                return Err(self.safety(
                    &format!(
                        "normal sweep {} stopped at beta {beta_now:.4} before the target {}",
                        rep + 1,
                        n.target_beta
                    ),
                    v,
                ));
            }
            self.move_stage(pos, "normal sweep").await?;
            let r = self.settle_frames(n.frames).await?;
            let beta = ((pos - contact) - r.gamma1_mm) / r2;
            self.track.cursor = Cursor::Load { rep, k, beta };
            self.record(Phase::Normal, pos, r, Some(rep), Some(Direction::Load), None)?;
            path.push((pos, beta));
            if beta >= n.target_beta {
                break;
            }
            pos += next_load_step(&n, pos - contact, r.gamma1_mm);
            k += 1;
        }
        if rep == 0 {
            self.track.loads_rep0 = Some(path.len());
        }
        self.log(
            LogLevel::Info,
            format!(
                "normal sweep {}: beta {:.4} reached at stage {:.4} mm",
                rep + 1,
                path.last().map(|p| p.1).unwrap_or(0.0),
                path.last().map(|p| p.0).unwrap_or(0.0)
            ),
        );
        let crossing = match path.as_slice() {
            [.., a, b] => (*a, *b),
            [b] => ((start, 0.0), *b),
            [] => unreachable_path()?,
        };
        let back: Vec<f64> = path.iter().rev().skip(1).map(|p| p.0).collect();
        for (i, pos) in back.iter().enumerate() {
            self.track.cursor = Cursor::Unload { rep, left: back.len() - i };
            self.move_stage(*pos, "normal unload").await?;
            let r = self.settle_frames(n.frames).await?;
            self.record(Phase::Normal, *pos, r, Some(rep), Some(Direction::Unload), None)?;
        }
        Ok(crossing)
    }

    pub(super) async fn torsion_depth(&mut self, crossing: ((f64, f64), (f64, f64))) -> Step<()> {
        self.track.cursor = Cursor::Depth;
        let target = self.script.normal.target_beta;
        let beta = self.seek_depth(crossing, target, 4).await?;
        self.torsion_beta = Some(beta);
        self.log(
            LogLevel::Info,
            format!("holding beta {beta:.4} at stage {:.4} mm for the torsion sweep", self.stage_mm),
        );
        Ok(())
    }

    /// Move the stage to where the measured depth beta = (approach - gamma1) / R2
    /// is `target`, starting from the line through the two load points
    /// `crossing` ((stage_mm, beta) each) and correcting on the readings, at
    /// most `tries` moves. Returns the beta reached.
    pub(super) async fn seek_depth(
        &mut self,
        crossing: ((f64, f64), (f64, f64)),
        target: f64,
        tries: usize,
    ) -> Step<f64> {
        let contact = self.contact_mm.unwrap_or(self.stage_mm);
        let r2 = self.script.indenter.r_mm;
        let ((p0, b0), (p1, b1)) = crossing;
        let slope = if (p1 - p0).abs() > 0.0 && b1 > b0 { (b1 - b0) / (p1 - p0) } else { 1.0 / r2 };
        let mut pos = if b1 > b0 { p0 + (target - b0) / slope } else { p1 };
        let step = self.script.normal.step_mm;
        let mut beta = f64::NAN;
        for _ in 0..tries {
            self.move_stage(pos, "return to depth").await?;
            let r = self.settle().await?;
            beta = ((pos - contact) - r.gamma1_mm) / r2;
            // Good to a quarter of a percent of the target, or as good as the step allows.
            if (beta - target).abs() <= 0.0025 * target {
                break;
            }
            pos += ((target - beta) / slope).clamp(-step, step);
        }
        Ok(beta)
    }

    pub(super) async fn torsion_sweep(&mut self) -> Step<()> {
        self.twist_zero = self.mount_deg;
        self.guard.set_twist_zero(self.mount_deg);
        let angles = self.script.twist_angles();
        let half = angles.len() / 2;
        let hold = self.stage_mm;
        for (i, angle) in angles.iter().enumerate() {
            self.track.cursor = Cursor::Twist { left: angles.len() - i };
            let target = self.twist_zero + angle;
            self.move_mount(target, "torsion sweep").await?;
            let r = self.settle_frames(self.script.torsion.frames).await?;
            let dir = if i <= half { Direction::Load } else { Direction::Unload };
            self.record(Phase::Torsion, hold, r, None, Some(dir), None)?;
        }
        Ok(())
    }

    pub(super) async fn retract(&mut self) -> Step<()> {
        let retract = self.script.limits.retract_mm;
        self.move_stage(retract, "retract").await?;
        if (self.mount_deg - self.twist_zero).abs() > 1e-9 {
            self.move_mount(self.twist_zero, "retract").await?;
        }
        self.device_status().await
    }
}

/// The loading step after a sample at `approach_mm` past the contact that read
/// `gamma1_mm`: `window_step_mm` (when finer) if the next sample's gamma1 (at
/// this sample's ratio of gamma1 to approach) would lie in the paper's window,
/// and this one is not past it; else `step_mm`.
pub(super) fn next_load_step(n: &crate::run::script::NormalSection, approach_mm: f64, gamma1_mm: f64) -> f64 {
    let [lo, hi] = crate::fit::regression::PAPER_WINDOW_MM;
    if n.window_step_mm <= 0.0 || approach_mm <= 0.0 || gamma1_mm <= 0.0 {
        return n.step_mm;
    }
    let next = gamma1_mm * (1.0 + n.step_mm / approach_mm);
    if next >= lo && gamma1_mm < hi { n.window_step_mm.min(n.step_mm) } else { n.step_mm }
}

pub(super) fn unreachable_path<T>() -> Step<T> {
    Err(Halt { culprit: Culprit::Procedure, message: "normal sweep recorded no load point".into() })
}

/// The stage position of first contact and its standard error, mm, from
/// settled (stage, gamma1, gamma1's standard error) points in contact: the
/// paper's depth relation (Eq. 22, docs/physics.md 1.3) with the contact
/// point free, stage = s0 + (1 + H1) gamma1 + H2 gamma1^1.5, fitted by least
/// squares with each point weighted by its reading's error (a point without
/// one takes the others' median). The bend of gamma1 with depth is then the
/// model's, not a line's, and the shallow points pin s0. `None` with fewer
/// than four points or a singular fit.
pub(super) fn contact_from_eq22(pts: &[(f64, f64, Option<f64>)]) -> Option<(f64, f64)> {
    use nalgebra::{Matrix3, Vector3};
    if pts.len() < 4 {
        return None;
    }
    let mut known: Vec<f64> = pts.iter().filter_map(|p| p.2).filter(|v| v.is_finite() && *v > 0.0).collect();
    let fallback = if known.is_empty() { 1.0 } else { crate::numerics::stats::median(&mut known) };
    let weight = |p: &(f64, f64, Option<f64>)| {
        let sd = p.2.filter(|v| v.is_finite() && *v > 0.0).unwrap_or(fallback);
        1.0 / (sd * sd)
    };
    let row = |g: f64| Vector3::new(1.0, g, g * g.sqrt());
    let (mut ata, mut atb) = (Matrix3::zeros(), Vector3::zeros());
    for p in pts {
        let (r, w) = (row(p.1.max(0.0)), weight(p));
        ata += w * r * r.transpose();
        atb += w * r * p.0;
    }
    let inv = ata.try_inverse()?;
    let coef = inv * atb;
    let chi2: f64 = pts.iter().map(|p| weight(p) * (p.0 - coef.dot(&row(p.1.max(0.0)))).powi(2)).sum();
    // The readings' errors set the scale unless the points scatter more.
    let scale = (chi2 / (pts.len() - 3) as f64).max(1.0);
    let se = (scale * inv[(0, 0)]).sqrt();
    (coef[0].is_finite() && se.is_finite()).then_some((coef[0], se.max(1e-6)))
}

/// How far the stage position of first contact from [`contact_from_line`]
/// may be off, mm: the line's own statistical error, and how far the lines
/// through the shallower and the deeper half of the points disagree (gamma1
/// bends away from a line as the contact deepens, so extrapolating to zero
/// carries that bend). `None` with fewer than three points.
pub(super) fn contact_uncertainty(pts: &[(f64, f64)], threshold: f64) -> Option<f64> {
    let mut p: Vec<(f64, f64)> = pts.iter().copied().filter(|&(_, g)| g > threshold).collect();
    if p.len() < 3 {
        return None;
    }
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Two overlapping halves (the middle point in both when the count is odd).
    let half = p.len().div_ceil(2);
    let (lo, hi) = (contact_from_line(&p[..half], threshold)?, contact_from_line(&p[p.len() - half..], threshold)?);
    let x0 = contact_from_line(&p, threshold)?;
    // Statistical: the intercept's standard error from the line's residuals.
    let n = p.len() as f64;
    let mx = p.iter().map(|q| q.0).sum::<f64>() / n;
    let sxx: f64 = p.iter().map(|q| (q.0 - mx).powi(2)).sum();
    let my = p.iter().map(|q| q.1).sum::<f64>() / n;
    let slope = my / (mx - x0);
    let ssr: f64 = p.iter().map(|q| (q.1 - slope * (q.0 - x0)).powi(2)).sum();
    let s2 = ssr / (n - 2.0);
    let se = (s2 * (1.0 / n + (x0 - mx).powi(2) / sxx)).sqrt() / slope;
    let sd = se.hypot(hi - lo);
    (sd.is_finite() && sd > 0.0).then_some(sd)
}

/// Stage position where a line through the in-contact points (gamma1 above
/// `threshold`) reaches gamma1 = 0. Near contact gamma1 is proportional to the
/// approach (Hertz: both are a^2 terms), so the line is the right shape.
pub(super) fn contact_from_line(pts: &[(f64, f64)], threshold: f64) -> Option<f64> {
    let p: Vec<(f64, f64)> = pts.iter().copied().filter(|&(_, g)| g > threshold).collect();
    if p.len() < 2 {
        return None;
    }
    let n = p.len() as f64;
    let mx = p.iter().map(|q| q.0).sum::<f64>() / n;
    let my = p.iter().map(|q| q.1).sum::<f64>() / n;
    let sxx: f64 = p.iter().map(|q| (q.0 - mx) * (q.0 - mx)).sum();
    let sxy: f64 = p.iter().map(|q| (q.0 - mx) * (q.1 - my)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    if slope.is_nan() || slope <= 0.0 {
        return None;
    }
    let x0 = mx - my / slope;
    x0.is_finite().then_some(x0)
}
