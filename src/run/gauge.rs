//! The deformation gauge: what the sequencer reads from the sensor. A gauge
//! turns the sensor's frames into the two numbers the calibration needs
//! (gamma1, theta1), so the sequencer never sees marker fields.
//!
//! [`SensorGauge`] builds a gauge from any [`SensorLink`] plus a measuring
//! function (frame -> gamma1, theta1, contact radius), so this module does not
//! depend on how frames are processed.

use std::time::Duration;

use async_trait::async_trait;
use devices::motion::{DeviceFault, FaultKind};
use devices::sensor::{BadReason, SensorError, SensorFrame, SensorLink};

use super::events::SensorStatus;

/// One measurement of the elastomer's deformation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GaugeReading {
    /// Sensor-side timestamp, s (monotonic within a run).
    pub t_s: f64,
    /// Maximum normal displacement of the elastomer, mm (positive into the elastomer).
    pub gamma1_mm: f64,
    /// Rotation of the contact region relative to the elastomer, degrees.
    pub theta1_deg: f64,
    /// Radius of the contact region, mm (0 out of contact).
    pub contact_radius_mm: f64,
    /// Standard error of `gamma1_mm` as the frame's estimator reports it, mm
    /// (`None`: the gauge cannot say, or no contact).
    pub gamma1_sd_mm: Option<f64>,
    /// Standard error of `theta1_deg`, degrees.
    pub theta1_sd_deg: Option<f64>,
    /// The part of `gamma1_sd_mm` shared with the readings around it (the
    /// estimator's learnt curvature), mm: a mean of readings keeps it whole.
    pub gamma1_common_sd_mm: Option<f64>,
}

impl GaugeReading {
    /// A reading without standard errors.
    pub fn new(t_s: f64, gamma1_mm: f64, theta1_deg: f64, contact_radius_mm: f64) -> Self {
        Self {
            t_s,
            gamma1_mm,
            theta1_deg,
            contact_radius_mm,
            gamma1_sd_mm: None,
            theta1_sd_deg: None,
            gamma1_common_sd_mm: None,
        }
    }

    /// The same reading with the shared part of gamma1's error (kept only
    /// when positive and not above the whole error).
    pub fn with_common_error(self, gamma1_common_sd_mm: f64) -> Self {
        let ok = gamma1_common_sd_mm.is_finite()
            && gamma1_common_sd_mm > 0.0
            && self.gamma1_sd_mm.is_some_and(|sd| gamma1_common_sd_mm <= sd);
        Self { gamma1_common_sd_mm: ok.then_some(gamma1_common_sd_mm), ..self }
    }

    /// The same reading with standard errors.
    pub fn with_errors(self, gamma1_sd_mm: f64, theta1_sd_deg: f64) -> Self {
        let ok = |v: f64| (v.is_finite() && v > 0.0).then_some(v);
        Self { gamma1_sd_mm: ok(gamma1_sd_mm), theta1_sd_deg: ok(theta1_sd_deg), ..self }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum GaugeError {
    /// No reading within the timeout (the sequencer counts these towards a dropout).
    #[error("no sensor reading within {waited:?}")]
    Timeout { waited: Duration },
    /// A frame arrived but could not be measured (counted, the next frame is tried).
    #[error("sensor frame {index} could not be measured: {reason}")]
    Measure { index: u64, reason: String },
    /// The sensor link failed.
    #[error(transparent)]
    Link(SensorError),
}

impl DeviceFault for GaugeError {
    fn kind(&self) -> FaultKind {
        match self {
            GaugeError::Timeout { .. } => FaultKind::Timeout,
            GaugeError::Measure { .. } => FaultKind::Protocol,
            GaugeError::Link(e) => e.kind(),
        }
    }
}

/// A source of deformation readings.
#[async_trait]
pub trait Gauge: Send {
    /// Start streaming (connect step).
    async fn start(&mut self) -> Result<(), GaugeError>;
    /// The next reading, waiting at most `timeout` (real time).
    async fn read(&mut self, timeout: Duration) -> Result<GaugeReading, GaugeError>;
    /// Drop the readings the sensor delivered but the run has not read yet
    /// (the rig just moved: they show it before or during the move); how many.
    fn discard_queued(&mut self) -> usize;
    /// Take the current deformation as zero (elastomer untouched).
    async fn tare(&mut self) -> Result<(), GaugeError>;
    /// Health of the stream so far.
    fn link_stats(&self) -> SensorStatus;
    /// What the sensor is, for messages and the recording (e.g. a serial number).
    fn describe(&self) -> String;
}

/// The measuring function a [`SensorGauge`] applies to each frame, in order
/// (it may learn from the frames it has seen): the reading, stamped with the
/// frame's time, or why it failed. A frame without contact is a valid reading
/// of zero, not an error: the sequencer needs readings out of contact to find
/// the contact, and it aborts after 50 unmeasurable frames in a row.
pub trait Measure: FnMut(&SensorFrame) -> Result<GaugeReading, String> + Send {}
impl<F: FnMut(&SensorFrame) -> Result<GaugeReading, String> + Send> Measure for F {}

/// A gauge made of a sensor link and a frame-measuring function.
pub struct SensorGauge<L: SensorLink, F: Measure> {
    link: L,
    measure: F,
    name: String,
    /// Frames that arrived but could not be measured.
    unmeasured: u64,
}

impl<L: SensorLink, F: Measure> SensorGauge<L, F> {
    /// End the link's background work (see [`SensorLink::close`]); dropping
    /// the gauge afterwards releases the sensor's port at once.
    pub async fn close(&mut self) {
        self.link.close().await
    }

    pub fn new(link: L, measure: F, name: impl Into<String>) -> Self {
        Self { link, measure, name: name.into(), unmeasured: 0 }
    }

    pub fn into_link(self) -> L {
        self.link
    }
}

#[async_trait]
impl<L: SensorLink, F: Measure> Gauge for SensorGauge<L, F> {
    async fn start(&mut self) -> Result<(), GaugeError> {
        self.link.start().await.map_err(GaugeError::Link)
    }

    async fn read(&mut self, timeout: Duration) -> Result<GaugeReading, GaugeError> {
        let frame = self.link.next_frame(timeout).await.map_err(|e| match e {
            SensorError::Timeout { waited } => GaugeError::Timeout { waited },
            other => GaugeError::Link(other),
        })?;
        match (self.measure)(&frame) {
            Ok(r) if r.gamma1_mm.is_finite() && r.theta1_deg.is_finite() && r.contact_radius_mm.is_finite() => {
                Ok(GaugeReading { t_s: frame.t_s, ..r })
            }
            Ok(r) => {
                self.unmeasured += 1;
                Err(GaugeError::Measure {
                    index: frame.index,
                    reason: format!(
                        "non-finite result gamma1 {}, theta1 {}, radius {}",
                        r.gamma1_mm, r.theta1_deg, r.contact_radius_mm
                    ),
                })
            }
            Err(reason) => {
                self.unmeasured += 1;
                Err(GaugeError::Measure { index: frame.index, reason })
            }
        }
    }

    fn discard_queued(&mut self) -> usize {
        self.link.discard_queued()
    }

    async fn tare(&mut self) -> Result<(), GaugeError> {
        self.link.tare().await.map_err(GaugeError::Link)
    }

    fn link_stats(&self) -> SensorStatus {
        let s = self.link.stats();
        // The consumer's own skips are not losses of the link.
        let skipped =
            s.bad_count(BadReason::Overrun) + s.bad_count(BadReason::Stale) + s.bad_count(BadReason::Superseded);
        SensorStatus {
            rate_hz: s.rate_hz,
            frames: s.frames,
            dropped: s.dropped + s.bad_total() - skipped,
            skipped,
            unmeasured: self.unmeasured,
        }
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use devices::sensor::LinkStats;
    use std::collections::VecDeque;

    /// A link that replays a fixed queue of outcomes.
    struct Replay {
        queue: VecDeque<Result<SensorFrame, SensorError>>,
        started: bool,
        tared: bool,
    }

    #[async_trait]
    impl SensorLink for Replay {
        async fn start(&mut self) -> Result<(), SensorError> {
            self.started = true;
            Ok(())
        }
        async fn stop(&mut self) -> Result<(), SensorError> {
            Ok(())
        }
        async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError> {
            self.queue.pop_front().unwrap_or(Err(SensorError::Timeout { waited: timeout }))
        }
        fn discard_queued(&mut self) -> usize {
            0
        }
        async fn tare(&mut self) -> Result<(), SensorError> {
            self.tared = true;
            Ok(())
        }
        fn stats(&self) -> LinkStats {
            let bad = [(BadReason::Overrun, 40), (BadReason::Stale, 1), (BadReason::Checksum, 1)].into_iter().collect();
            LinkStats { frames: 7, rate_hz: 30.0, dropped: 2, bad }
        }
    }

    fn frame(index: u64, dz: f64) -> SensorFrame {
        SensorFrame { index, t_s: index as f64 / 30.0, positions: vec![[0.0; 3]], displacements: vec![[0.0, 0.0, dz]] }
    }

    /// Peak inward displacement; refuses empty frames.
    fn peak(f: &SensorFrame) -> Result<GaugeReading, String> {
        let g = f.displacements.iter().map(|d| -d[2]).fold(f64::NAN, f64::max);
        if f.displacements.is_empty() { Err("no markers".into()) } else { Ok(GaugeReading::new(0.0, g, 0.0, 0.0)) }
    }

    #[tokio::test]
    async fn sensor_gauge_measures_frames_and_maps_errors() {
        let empty = SensorFrame { index: 3, t_s: 0.1, positions: vec![], displacements: vec![] };
        let link = Replay {
            queue: VecDeque::from(vec![
                Ok(frame(1, -0.25)),
                Ok(empty),
                Err(SensorError::Closed { reason: "cable".into() }),
            ]),
            started: false,
            tared: false,
        };
        let mut g = SensorGauge::new(link, peak, "sim-sensor");
        g.start().await.unwrap();
        g.tare().await.unwrap();
        let r = g.read(Duration::from_millis(5)).await.unwrap();
        assert_eq!(r.gamma1_mm, 0.25);
        assert!((r.t_s - 1.0 / 30.0).abs() < 1e-12);
        let e = g.read(Duration::from_millis(5)).await.unwrap_err();
        assert!(matches!(e, GaugeError::Measure { index: 3, .. }), "{e}");
        assert_eq!(e.kind(), FaultKind::Protocol);
        let e = g.read(Duration::from_millis(5)).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Disconnected);
        let e = g.read(Duration::from_millis(5)).await.unwrap_err();
        assert!(matches!(e, GaugeError::Timeout { .. }));
        let st = g.link_stats();
        // Lost on the link: 2 gaps + 1 bad checksum; skipped by the consumer:
        // 40 overrun + 1 stale; not measurable: 1.
        assert_eq!((st.frames, st.dropped, st.skipped, st.unmeasured), (7, 3, 41, 1));
        assert_eq!(g.describe(), "sim-sensor");
        let link = g.into_link();
        assert!(link.started && link.tared);
    }
}
