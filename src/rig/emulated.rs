//! The built-in emulated rig as the controller meets it: the emulators of
//! [`sim::emulator::served`] (every simulated value from one
//! [`sim::setup::SimSetup`]), how the real drivers reach them ([`RigSpec`]),
//! and the truth a run on them should recover. The run opens the rig with the
//! real drivers from its [`RigSpec`], exactly as a real rig.

use std::ops::Deref;
use std::time::Duration;

use devices::apt::AptConfig;
use devices::grbl::GrblConfig;
use sim::setup::SimSetup;

pub use sim::emulator::served::{
    CONTACT_STAGE_MM, EmulatedSensor, STAGE_TRAVEL_MM, SensorEndpoint, ServeError, ServeOptions, ServedRig,
    StageEmulator,
};

use super::connect::{RigSpec, SensorSpec};
use super::drivers::{RotationSpec, StageSpec};
use crate::report::Truth;

/// Feed of the emulated GRBL stage's moves, mm/min: its stepper's 2 mm/s.
const GRBL_FEED_MM_PER_MIN: f64 = 120.0;

/// A running emulated rig (the served emulators, which it dereferences to
/// for fault injection and the device paths). Dropping it stops every emulator.
#[derive(Debug)]
pub struct EmulatedRig(ServedRig);

impl EmulatedRig {
    /// Start the emulators for `setup`. Needs a tokio runtime.
    pub async fn start(setup: SimSetup, opts: ServeOptions) -> Result<EmulatedRig, ServeError> {
        Ok(EmulatedRig(ServedRig::start(setup, opts).await?))
    }

    /// How the real drivers reach this rig. Poll periods are shortened to
    /// the rig's time acceleration (moves finish `speedup` times sooner);
    /// every timeout stays a real wall-clock one.
    pub fn spec(&self) -> RigSpec {
        let speedup = self.speedup();
        let poll = |base: Duration| base.div_f64(speedup.max(1.0)).max(Duration::from_millis(2));
        let stage = if self.is_grbl() {
            let cfg = GrblConfig {
                travel_mm: (0.0, STAGE_TRAVEL_MM),
                feed_mm_per_min: GRBL_FEED_MM_PER_MIN,
                poll_interval: poll(Duration::from_millis(100)),
                ..GrblConfig::default()
            };
            StageSpec::new(self.stage().path().to_path_buf(), cfg)
        } else {
            let base = AptConfig::kdc101_z825b();
            let cfg = AptConfig { poll_period: poll(base.poll_period), ..base };
            StageSpec::new(self.stage().path().to_path_buf(), cfg)
        };
        let base = AptConfig::k10cr1();
        let rotation = RotationSpec::new(
            self.rotation().path().to_path_buf(),
            AptConfig { poll_period: poll(base.poll_period), ..base },
        );
        let sensor = match self.sensor_endpoint() {
            SensorEndpoint::Pty(path) => SensorSpec::LinkSerial { path: path.clone(), baud: 115_200 },
            SensorEndpoint::Udp(to) => SensorSpec::Tac3d { bind: *to, source: None },
        };
        RigSpec { stage, rotation, sensor, sensor_name: "sim-sensor".into() }
    }

    /// One calibration on this rig with `script`, its files in `out_dir`,
    /// diagnosed at the end, the truth in its report; the run's events are
    /// read and dropped. What the CLI's `run` does, for tests and studies.
    pub async fn calibrate(
        &self,
        script: crate::run::Script,
        out_dir: &std::path::Path,
    ) -> Result<super::RunResult, super::StartError> {
        let req = super::RunRequest {
            spec: self.spec(),
            script,
            out_dir: out_dir.to_path_buf(),
            truth: Some(self.truth()),
            metadata: vec![],
            diagnose: true,
        };
        let (ev_tx, mut ev_rx) = tokio::sync::mpsc::unbounded_channel();
        let (_ctl_tx, ctl_rx) = tokio::sync::mpsc::unbounded_channel();
        let drain = tokio::spawn(async move { while ev_rx.recv().await.is_some() {} });
        let result = super::run_calibration_with(req, ev_tx, ctl_rx, Some(self.indenter_mount())).await;
        let _ = drain.await;
        if let Ok(r) = &result
            && let Some(w) = self.note_effect_failures(r.report.as_ref())
        {
            eprintln!("warning: {w}");
        }
        result
    }

    /// When the simulated sensor drew the clean contact for some frames
    /// because the set-up's effect model failed there (gross slip, a
    /// contact beyond the model's range), the warning to give: appended to
    /// the run's report.md (when there is one) and returned for stderr.
    /// `None` when the run saw every effect it was given.
    pub fn note_effect_failures(&self, report: Option<&crate::report::ReportFiles>) -> Option<String> {
        let n = self.effect_failures();
        if n == 0 {
            return None;
        }
        let w = format!(
            "the emulated rig's effect model failed on {n} sensor frame(s) and drew the clean contact there: \
the recording does not carry all of the profile's effect"
        );
        if let Some(files) = report {
            use std::io::Write;
            let appended = std::fs::OpenOptions::new()
                .append(true)
                .open(&files.markdown)
                .and_then(|mut f| writeln!(f, "\n## Simulator\n\nWarning: {w}."));
            if let Err(e) = appended {
                return Some(format!("{w} (not written to {}: {e})", files.markdown.display()));
            }
        }
        Some(w)
    }

    /// The simulated elastomer's true E1 and nu1: the set-up's, as it was given.
    pub fn truth(&self) -> Truth {
        let t = self.setup().truth();
        Truth { e1_mpa: t.e1_mpa, nu1: t.nu1 }
    }
}

/// `setup` on a declared gel layer (docs/physics.md, "The layer in the
/// generator and the emulated rig"): the linear FE layer model pressed and
/// twisted with friction, as `simulate --thickness-mm` simulates it, wrapped by
/// the set-up's rig-level effects. The error says why the rig cannot simulate
/// that layer (a domed gel, a contact effect in the profile).
pub fn on_declared_layer(setup: SimSetup, layer: sim::physics::Layer) -> Result<SimSetup, String> {
    let (gel, indenter) = (setup.pair().elastomer, setup.pair().indenter);
    if gel.r_mm.is_finite() {
        return Err(format!(
            "a layer is simulated flat: set [sensor] elastomer_r_mm = \"inf\" (it is {} mm)",
            gel.r_mm
        ));
    }
    let law = crate::fit::fe_law::frictional_truth(layer, indenter, gel.e_mpa, gel.nu, sim::defaults::GEL_FRICTION)
        .map_err(|e| format!("cannot simulate it: {e}"))?;
    // The simulated sensor draws the layer's own field (docs/sensing.md, "On
    // a layer"): built now, so a layer it cannot draw is refused here rather
    // than drawn as Hertz's.
    if law.surface().is_none() {
        return Err("cannot simulate it: the layer's surface field could not be computed".into());
    }
    setup.on_layer(layer, law).map_err(|e| e.to_string())
}

impl Deref for EmulatedRig {
    type Target = ServedRig;

    fn deref(&self) -> &ServedRig {
        &self.0
    }
}
