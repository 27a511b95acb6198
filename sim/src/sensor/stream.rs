//! The simulated sensor as a live stream: a task that reads the rig at the
//! sensor's frame rate (in rig time) and hands every frame to a [`FrameSink`]
//! — a Tac3D or link-protocol sender, or an in-process channel for tests.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use devices::sensor::SensorFrame;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::rig::{RigSensor, SensorSimConfig};
use crate::effects::EffectError;
use crate::emulator::rig::Rig;

/// Why a sink refused a frame; the stream ends with it.
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    /// The receiving side is gone.
    #[error("frame sink closed")]
    Closed,
    #[error("frame sink I/O: {0}")]
    Io(#[from] std::io::Error),
    /// The sensor protocol's sender failed (a link or Tac3D write).
    #[error("frame sink: {0}")]
    Device(#[from] devices::sensor::SensorError),
    /// Anything else, e.g. a frame the wire format cannot carry.
    #[error("frame sink: {0}")]
    Other(String),
}

/// Somewhere frames go.
pub trait FrameSink: Send + 'static {
    fn send(&mut self, frame: &SensorFrame) -> impl Future<Output = Result<(), SinkError>> + Send;
}

/// Frames into an in-process channel (tests, or an in-process consumer).
#[derive(Debug, Clone)]
pub struct ChannelSink(pub mpsc::Sender<SensorFrame>);

/// A [`ChannelSink`] and the receiver of its frames.
pub fn channel_sink(capacity: usize) -> (ChannelSink, mpsc::Receiver<SensorFrame>) {
    let (tx, rx) = mpsc::channel(capacity.max(1));
    (ChannelSink(tx), rx)
}

impl FrameSink for ChannelSink {
    async fn send(&mut self, frame: &SensorFrame) -> Result<(), SinkError> {
        self.0.send(frame.clone()).await.map_err(|_| SinkError::Closed)
    }
}

/// How a stream ended.
#[derive(Debug)]
pub enum StreamEnd {
    /// [`SensorStream::stop`] was called.
    Stopped { frames_sent: u64 },
    /// The sink failed; the stream stopped at that frame.
    SinkFailed { frames_sent: u64, error: SinkError },
    /// The task panicked or was cancelled.
    Aborted { reason: String },
}

/// Handle to a running sensor stream. Dropping it stops the stream.
#[derive(Debug)]
pub struct SensorStream {
    stop: watch::Sender<bool>,
    silenced: Arc<AtomicBool>,
    sent: Arc<AtomicU64>,
    generated: Arc<AtomicU64>,
    effect_failures: Arc<AtomicU64>,
    mount: super::rig::IndenterMount,
    task: Option<JoinHandle<StreamEnd>>,
}

impl SensorStream {
    /// While silenced the sensor keeps running (its frame counter advances)
    /// but nothing is sent: a receiver sees a link dropout and, when the
    /// stream resumes, a gap in the frame counter.
    pub fn set_silenced(&self, on: bool) {
        self.silenced.store(on, Ordering::SeqCst);
    }

    pub fn is_silenced(&self) -> bool {
        self.silenced.load(Ordering::SeqCst)
    }

    /// Frames handed to the sink so far.
    pub fn frames_sent(&self) -> u64 {
        self.sent.load(Ordering::SeqCst)
    }

    /// Frames the sensor produced so far, sent or not.
    pub fn frames_generated(&self) -> u64 {
        self.generated.load(Ordering::SeqCst)
    }

    /// Frames for which the set-up's effect model failed and the clean
    /// contact was drawn instead ([`RigSensor::effect_failures`]): a run on
    /// such a stream did not see all of the effect it was given.
    pub fn effect_failures(&self) -> u64 {
        self.effect_failures.load(Ordering::SeqCst)
    }

    /// The streaming sensor's indenter mount: what an operator step mounts
    /// on the emulated rig ([`super::rig::IndenterMount`]).
    pub fn indenter_mount(&self) -> super::rig::IndenterMount {
        self.mount.clone()
    }

    /// True once the task has ended (sink failure or stop).
    pub fn is_finished(&self) -> bool {
        self.task.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Stop the stream and wait for the task to end.
    pub async fn stop(mut self) -> StreamEnd {
        let _ = self.stop.send(true);
        match self.task.take() {
            Some(task) => task.await.unwrap_or_else(|e| StreamEnd::Aborted { reason: e.to_string() }),
            None => StreamEnd::Aborted { reason: "stream task already taken".into() },
        }
    }
}

impl Drop for SensorStream {
    fn drop(&mut self) {
        if let Some(task) = self.task.take() {
            task.abort();
        }
    }
}

/// Stream frames of a simulated sensor looking at `rig` into `sink`, at
/// `cfg.frame_rate_hz` of rig time (so `rig.clock()`'s speed-up applies).
/// Must be called inside a tokio runtime.
pub fn spawn_sensor_stream<S: FrameSink>(rig: Rig, cfg: SensorSimConfig, sink: S) -> Result<SensorStream, EffectError> {
    let sensor = RigSensor::new(rig, cfg)?;
    Ok(spawn_rig_sensor(sensor, sink))
}

/// As [`spawn_sensor_stream`], for a sensor already built.
pub fn spawn_rig_sensor<S: FrameSink>(sensor: RigSensor, sink: S) -> SensorStream {
    let (stop_tx, stop_rx) = watch::channel(false);
    let silenced = Arc::new(AtomicBool::new(false));
    let sent = Arc::new(AtomicU64::new(0));
    let generated = Arc::new(AtomicU64::new(0));
    let effect_failures = Arc::new(AtomicU64::new(0));
    let counters =
        Counters { sent: sent.clone(), generated: generated.clone(), effect_failures: effect_failures.clone() };
    let mount = sensor.mount();
    let task = tokio::spawn(run(sensor, sink, stop_rx, silenced.clone(), counters));
    SensorStream { stop: stop_tx, silenced, sent, generated, effect_failures, mount, task: Some(task) }
}

/// What the stream's task counts for its handle.
struct Counters {
    sent: Arc<AtomicU64>,
    generated: Arc<AtomicU64>,
    effect_failures: Arc<AtomicU64>,
}

async fn run<S: FrameSink>(
    mut sensor: RigSensor,
    mut sink: S,
    mut stop: watch::Receiver<bool>,
    silenced: Arc<AtomicBool>,
    counters: Counters,
) -> StreamEnd {
    let Counters { sent, generated, effect_failures } = counters;
    let rate = sensor.config().frame_rate_hz;
    let rate = if rate.is_finite() && rate > 0.0 { rate } else { 30.0 };
    let clock = sensor.rig().clock();
    // Tokio timers tick at 1 ms at best; a faster rig-time rate just runs at
    // that pace (frames are stamped with rig time, so nothing is skewed).
    let period = clock.wall_for(1.0 / rate).max(Duration::from_micros(500));
    let mut ticks = tokio::time::interval(period);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            changed = stop.changed() => {
                // A dropped handle (Err) means stop as well.
                if changed.is_err() || *stop.borrow() {
                    return StreamEnd::Stopped { frames_sent: sent.load(Ordering::SeqCst) };
                }
            }
            _ = ticks.tick() => {
                let frame = sensor.frame();
                generated.fetch_add(1, Ordering::SeqCst);
                effect_failures.store(sensor.effect_failures(), Ordering::SeqCst);
                if silenced.load(Ordering::SeqCst) {
                    continue;
                }
                if let Err(error) = sink.send(&frame).await {
                    return StreamEnd::SinkFailed { frames_sent: sent.load(Ordering::SeqCst), error };
                }
                sent.fetch_add(1, Ordering::SeqCst);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::VirtualClock;
    use crate::emulator::axis::AxisConfig;
    use crate::sensor::field::NoiseConfig;
    use crate::setup::SimSetupInput;

    fn axis() -> AxisConfig {
        AxisConfig {
            max_velocity: 1e6,
            acceleration: 1e9,
            min_position: -10.0,
            max_position: 10.0,
            resolution: 0.0,
            backlash: 0.0,
            home_velocity: 1.0,
            power_on_position: 0.0,
        }
    }

    #[tokio::test]
    async fn stream_follows_the_stage_silences_and_stops() {
        let rig = Rig::new(VirtualClock::new(100.0), axis(), axis());
        let (sink, mut rx) = channel_sink(64);
        let setup = SimSetupInput { noise: NoiseConfig::NONE, ..SimSetupInput::default() }.resolve().unwrap();
        let cfg = SensorSimConfig { setup, ..SensorSimConfig::default() };
        let stream = spawn_sensor_stream(rig.clone(), cfg, sink).unwrap();
        let f0 = rx.recv().await.unwrap();
        assert_eq!(f0.index, 1000);
        assert!(f0.displacements.iter().all(|d| *d == [0.0; 3]));
        rig.with_stage(|ax, t| ax.command_move_to(t, 0.4));
        // Frames until the press shows up.
        let mut pressed = None;
        for _ in 0..500 {
            let f = rx.recv().await.unwrap();
            if f.displacements.iter().any(|d| d[2] < -0.1) {
                pressed = Some(f);
                break;
            }
        }
        let pressed = pressed.expect("stage move never reached the sensor");
        // Rig time stamps at 30 frames/s of rig time.
        let next = rx.recv().await.unwrap();
        assert_eq!(next.index, pressed.index + 1);
        assert!(next.t_s > pressed.t_s);
        // Silence: the counter keeps going, so the next frame after resuming jumps.
        stream.set_silenced(true);
        while rx.try_recv().is_ok() {}
        let generated = stream.frames_generated();
        while stream.frames_generated() < generated + 3 {
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        while let Ok(f) = rx.try_recv() {
            // At most a frame already in flight when silencing.
            assert!(f.index <= next.index + 2);
        }
        let last_before = stream.frames_generated();
        stream.set_silenced(false);
        let after = rx.recv().await.unwrap();
        assert!(after.index >= 1000 + last_before, "{} vs {}", after.index, last_before);
        match stream.stop().await {
            StreamEnd::Stopped { frames_sent } => assert!(frames_sent >= 3),
            other => panic!("{other:?}"),
        }
    }

    #[tokio::test]
    async fn a_closed_sink_ends_the_stream() {
        let rig = Rig::new(VirtualClock::new(100.0), axis(), axis());
        let (sink, rx) = channel_sink(1);
        drop(rx);
        let stream = spawn_sensor_stream(rig, SensorSimConfig::default(), sink).unwrap();
        while !stream.is_finished() {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        assert!(matches!(stream.stop().await, StreamEnd::SinkFailed { frames_sent: 0, error: SinkError::Closed }));
    }
}
