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
        let w = RecordingWriter::for_rig(BufWriter::new(file), &meta).map_err(|e| Halt {
            culprit: Culprit::Recording,
            message: format!("cannot write the recording {}: {e}", self.recording_path.display()),
        })?;
        self.writer = Some(w);
        // What moved before the recording began is not a sample's move.
        self.clock.pending = PendingTiming::default();
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
            // A step the soft limits would refuse (a reading right after a
            // move may lag it by the whole move) is halved, down to step_mm.
            let mut step = a.search_step_mm;
            while step > a.step_mm && self.guard.check_stage(self.stage_mm, self.gamma1_bound_mm, pos + step).is_err() {
                step = (0.5 * step).max(a.step_mm);
            }
            let next = pos + step;
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
        // Settled (its two readings may lag the move), the first point in contact.
        let mut pts = vec![(pos, self.settle().await?.gamma1_mm)];
        for _ in 0..a.refine_steps {
            if pts.last().is_some_and(|p| p.1 >= a.refine_to_gamma1_mm) {
                break;
            }
            let next = pos + a.refine_step_mm.max(a.step_mm);
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
            .clamp(last_clear - a.refine_step_mm.max(a.step_mm), pts[0].0);
        // The first pass's readings were taken while the sensing was still
        // learning the contact's shape. The second pass is the normal sweep's
        // own start: it steps in by approach.step_mm from before the
        // provisional contact, and its shallow samples place the contact
        // (held back from the recording until then, `PendingContact`).
        let fallback_sd = if line.is_some() { contact_uncertainty(&window, threshold) } else { None };
        self.contact_mm = Some(provisional);
        // How fast gamma1 grows with the approach over the pass (for the estimate of time left).
        self.track.gamma1_ratio = match pts.as_slice() {
            [p, .., q] if q.0 > p.0 => Some((q.1 - p.1) / (q.0 - p.0)).filter(|r| r.is_finite() && *r > 0.0),
            _ => None,
        };
        self.pending = Some(PendingContact { threshold, fallback_sd, held: Vec::new() });
        self.log(LogLevel::Info, format!("provisional contact at stage {provisional:.4} mm"));
        let start = (provisional - a.pre_contact_mm).max(self.guard.limits().stage_min_mm);
        self.move_stage(start, "to the normal sweep start").await?;
        Ok(())
    }

    /// Place the contact from the held samples of the sweep's start (the
    /// paper's depth relation through the settled points in contact, Eq. 22,
    /// when at least two are shallow), write the recording's header, and
    /// record the held samples against it. The provisional contact stands
    /// when they cannot place it.
    pub(super) fn place_contact(&mut self) -> Step<()> {
        let Some(p) = self.pending.take() else { return Ok(()) };
        let a = self.script.approach;
        let pts: Vec<(f64, f64, Option<f64>)> = p
            .held
            .iter()
            .filter(|h| h.reading.gamma1_mm > p.threshold)
            .map(|h| (h.stage_mm, h.reading.gamma1_mm, h.reading.gamma1_sd_mm))
            .collect();
        let shallow = pts.iter().filter(|q| q.1 < a.refine_from_gamma1_mm).count();
        let found = if shallow >= 2 { contact_from_eq22(&pts) } else { None };
        let provisional = self.contact_mm.unwrap_or(self.stage_mm);
        let (contact, contact_sd_mm) = match found {
            Some((c, sd)) => (c, Some(sd)),
            None => (provisional, p.fallback_sd),
        };
        self.contact_mm = Some(contact);
        let sd_text = contact_sd_mm.map(|sd| format!(" (± {:.1} um)", sd * 1e3)).unwrap_or_default();
        self.log(LogLevel::Info, format!("first contact at stage {contact:.4} mm{sd_text}"));
        self.start_recording(contact_sd_mm)?;
        for h in p.held {
            self.clock.pending = PendingTiming::restore(h.timing);
            self.record(Phase::Normal, h.stage_mm, h.reading, h.rep, Some(Direction::Load), None)?;
        }
        Ok(())
    }

    /// The loading branch of one normal sweep: step in until the measured
    /// depth beta reaches the target (the last step shortened to land on
    /// it). Returns the (stage_mm, gamma1_mm) of its samples.
    pub(super) async fn normal_load(&mut self, rep: u32) -> Step<Vec<(f64, f64)>> {
        let n = self.script.normal;
        let a = self.script.approach;
        let r2 = self.script.indenter.r_mm;
        let contact0 = self.contact_mm.unwrap_or(self.stage_mm);
        let start = (contact0 - a.pre_contact_mm).max(self.guard.limits().stage_min_mm);
        let mut path: Vec<(f64, f64)> = Vec::new();
        let mut pos = start;
        if self.track.sweep_start.is_none() {
            self.track.sweep_start = Some(self.clock.t_last);
        }
        let tol = DEPTH_TOLERANCE * n.target_beta;
        loop {
            let contact = self.contact_mm.unwrap_or(contact0);
            let beta_of = |p: &(f64, f64)| ((p.0 - contact) - p.1) / r2;
            let beta_now = path.last().map(beta_of).unwrap_or(0.0);
            if !path.is_empty() {
                pos = self.within_depth_limit(pos, &format!("normal sweep {}", rep + 1));
            }
            if let Err(v) = self.guard.check_stage(self.stage_mm, self.gamma1_bound_mm, pos) {
                let depth_limit = matches!(v, LimitViolation::Gamma1 { .. });
                let mut halt = self.safety(
                    &format!(
                        "normal sweep {} stopped at beta {beta_now:.4} before the target {}",
                        rep + 1,
                        n.target_beta
                    ),
                    v,
                );
                // The target is out of reach of this pair within the limit
                // (a stiff indenter on a soft or thin gel): say what would
                // make the run possible.
                if depth_limit {
                    halt.message.push_str(&format!(
                        "; this indenter reaches the target depth only past the limit: lower [normal] target_beta \
                         (to {:.2} or less) or, where the gel and the indenter allow it, raise [limits] max_gamma1_mm",
                        (beta_now * 100.0).floor() / 100.0
                    ));
                }
                return Err(halt);
            }
            self.move_stage(pos, "normal sweep").await?;
            // Past the paper's window the samples average `frames`; the
            // contact and window stretches take the settling's own.
            let coarse = path.last().is_some_and(|p| p.1 >= crate::fit::regression::PAPER_WINDOW_MM[1]);
            let frames = if coarse { n.frames } else { 0 };
            let r = if let Some(p) = self.pending.as_ref() {
                let threshold = p.threshold;
                if path.is_empty() {
                    // The sweep's first stop follows the move back out of the
                    // first pass's deepest contact: the elastomer recovers
                    // slowest from there; a settling more before it counts.
                    self.settle().await?;
                }
                let r = self.settle().await?;
                // The sweep must start out of contact, or its samples cannot
                // place the contact: a provisional contact placed too deep
                // moves the start back.
                if path.is_empty() && r.gamma1_mm > threshold {
                    let back = (pos - a.pre_contact_mm.max(a.step_mm) * 2.0).max(self.guard.limits().stage_min_mm);
                    if back < pos && pos - back > 0.0 && contact0 - back < MAX_START_BACK_MM {
                        self.log(
                            LogLevel::Info,
                            format!(
                                "gamma1 {:.4} mm at the sweep's start {pos:.4} mm: starting from {back:.4} mm",
                                r.gamma1_mm
                            ),
                        );
                        pos = back;
                        continue;
                    }
                }
                pos = self.at_stop(pos);
                let last = r.gamma1_mm >= a.refine_to_gamma1_mm || path.len() + 1 >= a.refine_steps.max(4) * 2;
                if let Some(p) = self.pending.as_mut() {
                    p.held.push(Held { stage_mm: pos, reading: r, rep: Some(rep), timing: self.clock.pending.take() });
                }
                if last {
                    self.place_contact()?;
                }
                r
            } else {
                let r = self.sample(Phase::Normal, pos, frames, Some(rep), Some(Direction::Load)).await?;
                pos = self.at_stop(pos);
                r
            };
            let contact = self.contact_mm.unwrap_or(contact0);
            let beta = ((pos - contact) - r.gamma1_mm) / r2;
            self.track.cursor = Cursor::Load { rep, beta };
            self.progress();
            path.push((pos, r.gamma1_mm));
            if beta >= n.target_beta - tol && self.pending.is_none() {
                break;
            }
            let approach = pos - contact;
            let mut step = next_load_step(&n, approach, r.gamma1_mm);
            if r.gamma1_mm < a.refine_to_gamma1_mm {
                step = step.min(a.step_mm);
            }
            // Land on the target (see `Landing::step`).
            let local = match path.as_slice() {
                [.., p0, p1] => (beta_of(p1) - beta_of(p0)) / (p1.0 - p0.0),
                _ => f64::NAN,
            };
            let landing = Landing { target_beta: n.target_beta, tol, min_step_mm: a.step_mm };
            pos += landing.step(step, beta, local, approach);
        }
        if rep == 0 {
            self.track.loads_rep0 = Some(path.len());
        }
        let contact = self.contact_mm.unwrap_or(contact0);
        let top = path.last().copied().unwrap_or((start, 0.0));
        self.log(
            LogLevel::Info,
            format!(
                "normal sweep {}: beta {:.4} reached at stage {:.4} mm",
                rep + 1,
                ((top.0 - contact) - top.1) / r2,
                top.0
            ),
        );
        Ok(path)
    }

    /// `target_mm`, or, when the depth limit refuses the move there (its
    /// worst case, all of the step going into the gel, passes the limit),
    /// the deepest target it allows, logged as a warning of `what`: the gel
    /// takes only part of a step, so a sweep near the limit closes on it by
    /// shrinking steps and lands on its target depth if that lies inside.
    /// Unchanged for any other refusal, when what is left of the step is
    /// under [`MIN_LIMITED_STEP_MM`] (the target lies at or past the limit:
    /// the move is then refused) or when the guard still refuses the
    /// shorter one.
    pub(super) fn within_depth_limit(&self, target_mm: f64, what: &str) -> f64 {
        let here = self.stage_mm;
        let refused = self.guard.check_stage(here, self.gamma1_bound_mm, target_mm);
        let Err(v @ LimitViolation::Gamma1 { bound_mm, max_mm, .. }) = refused else {
            return target_mm;
        };
        // The bound grows with the target one for one past the current position.
        let allowed = target_mm - (bound_mm - max_mm) - LIMIT_CLEARANCE_MM;
        if !(allowed.is_finite()
            && allowed - here >= MIN_LIMITED_STEP_MM
            && self.guard.check_stage(here, self.gamma1_bound_mm, allowed).is_ok())
        {
            return target_mm;
        }
        self.log(LogLevel::Warn, format!("{what}: {v}: shortened to {allowed:.4} mm"));
        allowed
    }

    /// A stop of a path back through depths the sweeps reached (an
    /// experiment's reload, slow repeat or approach at another speed) at
    /// `target_mm`: shortened to the depth limit ([`Self::within_depth_limit`]),
    /// and where the limit leaves no step in (a frame drifting into the gel
    /// since the sweep went there), held where the stage stands, logged as a
    /// warning. Returns the stop's commanded position.
    pub(super) async fn move_stage_limited(&mut self, target_mm: f64, context: &str) -> Step<f64> {
        let pos = self.within_depth_limit(target_mm, context);
        if pos > self.stage_mm
            && let Err(v @ LimitViolation::Gamma1 { .. }) =
                self.guard.check_stage(self.stage_mm, self.gamma1_bound_mm, pos)
        {
            self.log(LogLevel::Warn, format!("{context}: {v}: held at stage {:.4} mm", self.stage_mm));
            return Ok(self.at_stop(self.stop_mm));
        }
        self.move_stage(pos, context).await?;
        Ok(pos)
    }

    /// The unloading branch: from the top of `path` back out, by
    /// `normal.unload_step_mm` to the last stop in contact (0: through the
    /// loading positions, to the sweep's start).
    pub(super) async fn normal_unload(&mut self, rep: u32, path: &[(f64, f64)]) -> Step<()> {
        let n = self.script.normal;
        let Some(&(top, _)) = path.last() else { return unreachable_path() };
        let start = path.first().map_or(top, |p| p.0);
        let back: Vec<f64> = if n.unload_step_mm > 0.0 {
            // Stops in contact only: one out of it reads nothing the fit can use.
            let contact = self.contact_mm.unwrap_or(start);
            let count = ((top - start) / n.unload_step_mm).ceil().max(1.0) as usize;
            (1..=count).map(|i| top - i as f64 * n.unload_step_mm).filter(|p| *p > contact).collect()
        } else {
            path.iter().rev().skip(1).map(|p| p.0).collect()
        };
        let backoffs = self.depth_backoffs;
        for (i, pos) in back.iter().enumerate() {
            // The depth watch backed a stop off past this one: the branch goes on from there.
            if self.depth_backoffs != backoffs && *pos >= self.stage_mm {
                continue;
            }
            self.track.cursor = Cursor::Unload { rep, left: back.len() - i };
            self.move_stage(*pos, "normal unload").await?;
            self.sample(Phase::Normal, *pos, n.frames, Some(rep), Some(Direction::Unload)).await?;
        }
        Ok(())
    }

    /// Settle at a stop and record what it reads: `frames` settled frames
    /// (0: the settling's own), as consecutive samples of at most
    /// `settle.max_sample_frames` each (replicates at one stop: the same
    /// information, more residuals to judge the fit by). Returns the mean of
    /// them all.
    pub(super) async fn sample(
        &mut self,
        phase: Phase,
        stage_abs: f64,
        frames: usize,
        rep: Option<u32>,
        dir: Option<Direction>,
    ) -> Step<GaugeReading> {
        let parts = self.script.sample_parts(frames);
        let mut all = Vec::with_capacity(parts.len());
        let rest = if parts.len() == 1 {
            let first = self.settle_frames(parts[0]).await?;
            self.record(phase, stage_abs, first, rep, dir, None)?;
            all.push(first);
            &parts[1..]
        } else {
            // A long stop: its samples start after the settling, whose
            // windows may still carry what relaxation the tolerance allows.
            self.settle().await?;
            &parts[..]
        };
        for &f in rest {
            let mut rs = Vec::with_capacity(f);
            while rs.len() < f {
                self.checkpoint().await?;
                rs.push(self.read().await?);
            }
            let m = mean(&rs);
            self.frames_from(&rs);
            self.record(phase, stage_abs, m, rep, dir, None)?;
            all.push(m);
        }
        Ok(mean(&all))
    }

    /// At the top of the loading branch, when the torsion sweep follows it
    /// there: keep the depth if it is within tolerance of the target, else
    /// correct it on the readings.
    pub(super) async fn hold_depth(&mut self, path: &[(f64, f64)]) -> Step<()> {
        self.track.cursor = Cursor::Depth;
        let target = self.script.normal.target_beta;
        let contact = self.contact_mm.unwrap_or(self.stage_mm);
        let r2 = self.script.indenter.r_mm;
        let beta_of = |p: &(f64, f64)| ((p.0 - contact) - p.1) / r2;
        let crossing = match path {
            [.., a, b] => ((a.0, beta_of(a)), (b.0, beta_of(b))),
            _ => return unreachable_path(),
        };
        let mut beta = crossing.1.1;
        if (beta - target).abs() > DEPTH_TOLERANCE * target {
            beta = self.seek_depth(crossing, target, 4).await?;
        }
        self.torsion_beta = Some(beta);
        self.log(
            LogLevel::Info,
            format!("holding beta {beta:.4} at stage {:.4} mm for the torsion sweep", self.stage_mm),
        );
        Ok(())
    }

    /// The two load points around the target depth: ((stage_mm, beta) before, (stage_mm, beta) at/after).
    pub(super) fn load_crossing_of(&self, path: &[(f64, f64)]) -> Step<((f64, f64), (f64, f64))> {
        let contact = self.contact_mm.unwrap_or(self.stage_mm);
        let r2 = self.script.indenter.r_mm;
        let at = |p: &(f64, f64)| (p.0, ((p.0 - contact) - p.1) / r2);
        match path {
            [.., a, b] => Ok((at(a), at(b))),
            [b] => {
                let start = (contact - self.script.approach.pre_contact_mm).max(self.guard.limits().stage_min_mm);
                Ok(((start, 0.0), at(b)))
            }
            [] => unreachable_path(),
        }
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
            // Near the depth limit, as close as it allows: where the limit
            // leaves no step at all towards the target (a frame drifting
            // into the gel makes the measured depth lag the stage's), the
            // stage holds where it stands, the deepest the limit allows,
            // rather than commanding a move the guard refuses.
            pos = self.within_depth_limit(pos, "return to depth");
            if let Err(v @ LimitViolation::Gamma1 { .. }) =
                self.guard.check_stage(self.stage_mm, self.gamma1_bound_mm, pos)
            {
                if beta.is_nan() {
                    let r = self.settle().await?;
                    beta = ((self.stage_mm - contact) - r.gamma1_mm) / r2;
                }
                self.log(
                    LogLevel::Warn,
                    format!(
                        "return to depth: {v}: held at stage {:.4} mm (beta {beta:.4}, target {target})",
                        self.stage_mm
                    ),
                );
                break;
            }
            self.move_stage(pos, "return to depth").await?;
            let r = self.settle().await?;
            pos = self.at_stop(pos);
            beta = ((pos - contact) - r.gamma1_mm) / r2;
            // Good to a quarter of a percent of the target, or as good as the step allows.
            if (beta - target).abs() <= DEPTH_TOLERANCE * target {
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
            let dir = if i <= half { Direction::Load } else { Direction::Unload };
            self.sample(Phase::Torsion, hold, self.script.twist_frames(*angle), None, Some(dir)).await?;
        }
        Ok(())
    }

    /// Out of contact to the park position (inside the clear zone), the mount back to the twist zero.
    pub(super) async fn retract(&mut self) -> Step<()> {
        self.move_stage(self.script.park_mm(), "retract").await?;
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

/// Where the loading branch stops: within `tol` of `target_beta`, the last
/// step no shorter than `min_step_mm`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Landing {
    pub target_beta: f64,
    pub tol: f64,
    pub min_step_mm: f64,
}

impl Landing {
    /// The next loading step, mm: `step_mm`, shortened to land on the target
    /// when beta (now `beta`, at `approach_mm` past the contact) would pass
    /// it. beta grows along the stage at the slope of the last two samples
    /// (`local_slope`, per mm; NaN before two); a slope that noise or a
    /// drifting frame has flattened or turned negative would let a full step
    /// run past the target (toward the depth limit), so a slope under half
    /// the sweep's mean (beta over the approach, from zero at contact) is
    /// taken as the mean.
    pub fn step(&self, step_mm: f64, beta: f64, local_slope: f64, approach_mm: f64) -> f64 {
        let mean = if approach_mm > 0.0 && beta > 0.0 { beta / approach_mm } else { f64::NAN };
        let slope = match (local_slope.is_finite(), mean.is_finite()) {
            (true, true) if local_slope >= 0.5 * mean => local_slope,
            (_, true) => mean,
            (true, false) if local_slope > 0.0 => local_slope,
            _ => return step_mm,
        };
        if beta + slope * step_mm > self.target_beta + self.tol {
            step_mm.min(((self.target_beta - beta) / slope + 0.5 * self.tol / slope).max(self.min_step_mm))
        } else {
            step_mm
        }
    }
}

/// The shortest loading step the depth limit may leave (see
/// `Sequencer::within_depth_limit`), mm: below it the sweep stops.
const MIN_LIMITED_STEP_MM: f64 = 0.01;

/// How far under the depth limit a shortened step's worst case stays, mm.
const LIMIT_CLEARANCE_MM: f64 = 1e-6;

/// How far before the provisional contact the normal sweep may start, mm.
const MAX_START_BACK_MM: f64 = 2.0;

/// How close to the target depth the torsion sweep is held, as a fraction of it.
pub(super) const DEPTH_TOLERANCE: f64 = 0.0025;

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
