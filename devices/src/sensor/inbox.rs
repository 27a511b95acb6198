//! Hand-over between a transport's background receive task and the consumer.
//! The task decodes continuously (so the OS socket buffer never overflows while
//! the rig is busy moving) and queues good frames; the consumer takes them with
//! a real wall-clock timeout. A full queue drops its oldest frame: the rig
//! wants recent deformation, not a backlog.

use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::Notify;

use super::error::SensorError;
use super::frame::SensorFrame;
use super::stats::{BadReason, FrameTracker, LinkStats, Verdict};

#[derive(Debug)]
struct State {
    tracker: FrameTracker,
    queue: VecDeque<SensorFrame>,
    capacity: usize,
    streaming: bool,
    closed: Option<Ended>,
}

/// Why the receive task ended.
#[derive(Debug, Clone)]
enum Ended {
    /// Orderly: end of stream.
    Closed(String),
    /// The transport failed with this error.
    Failed(&'static str, Arc<io::Error>),
}

#[derive(Debug)]
pub(crate) struct Inbox {
    state: Mutex<State>,
    notify: Notify,
}

impl Inbox {
    pub fn new(capacity: usize) -> Self {
        Self {
            state: Mutex::new(State {
                tracker: FrameTracker::new(),
                queue: VecDeque::new(),
                capacity: capacity.max(1),
                streaming: false,
                closed: None,
            }),
            notify: Notify::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panicking consumer must not wedge the receive task.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Account for a decoded frame and queue it if the link is streaming.
    pub fn frame(&self, frame: SensorFrame) {
        let mut s = self.lock();
        if s.tracker.frame(frame.index, frame.t_s) == Verdict::Stale || !s.streaming {
            return;
        }
        if s.queue.len() == s.capacity {
            s.queue.pop_front();
            s.tracker.bad(BadReason::Overrun);
        }
        s.queue.push_back(frame);
        drop(s);
        self.notify.notify_one();
    }

    pub fn bad(&self, reason: BadReason) {
        self.lock().tracker.bad(reason);
    }

    /// The transport ended in order (end of stream).
    pub fn close(&self, reason: String) {
        self.end(Ended::Closed(reason));
    }

    /// The transport failed: `what` the task was doing, and the error.
    pub fn fail(&self, what: &'static str, e: io::Error) {
        self.end(Ended::Failed(what, Arc::new(e)));
    }

    fn end(&self, why: Ended) {
        self.lock().closed.get_or_insert(why);
        self.notify.notify_one();
    }

    pub fn set_streaming(&self, on: bool) {
        let mut s = self.lock();
        s.streaming = on;
        // Frames queued before a start/stop belong to another phase of the run.
        s.queue.clear();
    }

    /// Drop every frame queued so far, unread (counted as
    /// [`BadReason::Superseded`]); how many.
    pub fn discard_queued(&self) -> usize {
        let mut s = self.lock();
        let n = s.queue.len();
        s.queue.clear();
        for _ in 0..n {
            s.tracker.bad(BadReason::Superseded);
        }
        n
    }

    pub fn stats(&self) -> LinkStats {
        self.lock().tracker.stats()
    }

    pub async fn next(&self, timeout: Duration) -> Result<SensorFrame, SensorError> {
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            {
                let mut s = self.lock();
                if !s.streaming {
                    return Err(SensorError::NotStreaming);
                }
                if let Some(f) = s.queue.pop_front() {
                    return Ok(f);
                }
                match &s.closed {
                    Some(Ended::Closed(reason)) => return Err(SensorError::Closed { reason: reason.clone() }),
                    Some(Ended::Failed(what, e)) => return Err(SensorError::Lost { what, source: e.clone() }),
                    None => {}
                }
            }
            // notify_one stores a permit, so a frame queued between the check
            // above and this wait is not missed.
            if tokio::time::timeout_at(deadline, self.notify.notified()).await.is_err() {
                return Err(SensorError::Timeout { waited: timeout });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(index: u64) -> SensorFrame {
        SensorFrame { index, t_s: index as f64 / 30.0, positions: vec![], displacements: vec![] }
    }

    /// A consumer that fell behind finds a full queue of frames older than
    /// the move it just finished: discarding them hands it the next frame
    /// the sensor sends, and the link counts them as skipped by the
    /// consumer, not lost on the wire.
    #[tokio::test]
    async fn frames_queued_before_a_move_are_discarded_and_counted_as_superseded() {
        let inbox = Inbox::new(8);
        inbox.set_streaming(true);
        for i in 0..12 {
            inbox.frame(frame(i));
        }
        // Frames 4..=11 wait (the four oldest overran).
        assert_eq!(inbox.discard_queued(), 8);
        assert_eq!(inbox.discard_queued(), 0);
        let short = Duration::from_millis(5);
        assert!(matches!(inbox.next(short).await, Err(SensorError::Timeout { .. })));
        inbox.frame(frame(12));
        assert_eq!(inbox.next(short).await.unwrap().index, 12);
        let st = inbox.stats();
        assert_eq!((st.bad_count(BadReason::Overrun), st.bad_count(BadReason::Superseded)), (4, 8));
        assert_eq!(st.frames, 13);
    }
}
