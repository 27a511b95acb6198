//! Link statistics shared by every sensor transport: frames delivered, the
//! sensor-side frame rate, frames lost (gaps in the sensor's own counter) and
//! malformed input counted by reason. Malformed input never stops a link; it is
//! counted here so the operator can see a bad cable or a wrong sender.

use std::collections::{BTreeMap, VecDeque};
use std::fmt;

use serde::Serialize;

/// Why a piece of input was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BadReason {
    /// Bytes before a sync pattern that belong to no message (link protocol).
    Garbage,
    /// Header checksum mismatch (link protocol).
    HeaderChecksum,
    /// Payload checksum mismatch (link protocol).
    Checksum,
    /// Protocol version this decoder does not speak.
    Version,
    /// Message kind this decoder does not know.
    UnknownKind,
    /// A length field disagrees with the bytes present or with the content.
    Length,
    /// A value that must be finite is NaN or infinite.
    NotFinite,
    /// Datagram too short to hold the 8-byte Tac3D header.
    ShortDatagram,
    /// Tac3D packet index outside the frame's packet count, or a frame whose
    /// packets disagree on the packet count.
    PacketIndex,
    /// Tac3D packet received twice for the same frame.
    DuplicatePacket,
    /// Tac3D frame whose packets did not all arrive before the timeout.
    Incomplete,
    /// Tac3D header that is not ASCII or not the YAML subset the sender writes.
    Yaml,
    /// A required header key or data item is missing or has the wrong type.
    MissingField,
    /// Tac3D frame sent while the sensor is still initialising (`InitializeProgress` != 100).
    Initializing,
    /// Frame counter went backwards by a little: a late, out-of-order frame.
    Stale,
    /// Decoded frames arrived faster than the consumer read them; the oldest was discarded.
    Overrun,
    /// A datagram from an address other than the configured sensor's.
    Foreign,
    /// Queued before the rig last moved and discarded unread by the
    /// consumer ([`crate::sensor::SensorLink::discard_queued`]): it shows the
    /// rig before or during the move.
    Superseded,
}

impl fmt::Display for BadReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self {
            BadReason::Garbage => "garbage",
            BadReason::HeaderChecksum => "header checksum",
            BadReason::Checksum => "checksum",
            BadReason::Version => "version",
            BadReason::UnknownKind => "unknown kind",
            BadReason::Length => "length",
            BadReason::NotFinite => "not finite",
            BadReason::ShortDatagram => "short datagram",
            BadReason::PacketIndex => "packet index",
            BadReason::DuplicatePacket => "duplicate packet",
            BadReason::Incomplete => "incomplete",
            BadReason::Yaml => "yaml",
            BadReason::MissingField => "missing field",
            BadReason::Initializing => "initializing",
            BadReason::Stale => "stale",
            BadReason::Overrun => "overrun",
            BadReason::Foreign => "foreign sender",
            BadReason::Superseded => "superseded",
        };
        f.write_str(s)
    }
}

/// A snapshot of a link's counters.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct LinkStats {
    /// Good frames received since the link was opened, whether or not it was
    /// started (the counter and rate stay meaningful across start/stop).
    pub frames: u64,
    /// Frame rate from the sensor's own timestamps over the last frames, Hz
    /// (0 until two frames arrived). Sensor time, so it is the sensor's rate
    /// and not disturbed by how fast the consumer reads.
    pub rate_hz: f64,
    /// Frames lost, counted from gaps in the sensor's frame counter.
    pub dropped: u64,
    /// Rejected input by reason.
    pub bad: BTreeMap<BadReason, u64>,
}

impl LinkStats {
    /// Total of all bad counters.
    pub fn bad_total(&self) -> u64 {
        self.bad.values().sum()
    }

    /// Count for one reason (0 if never seen).
    pub fn bad_count(&self, reason: BadReason) -> u64 {
        self.bad.get(&reason).copied().unwrap_or(0)
    }
}

/// A backwards jump of the counter larger than this is taken as a restart of
/// the sensor (its counter starts again), not as a late frame.
const RESTART_JUMP: u64 = 1000;
/// Frames in the rate window.
const RATE_WINDOW: usize = 32;

/// What the tracker decided about one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    Accept,
    /// Late or repeated frame; counted as [`BadReason::Stale`] and to be discarded.
    Stale,
}

/// Keeps [`LinkStats`] up to date as frames and rejects come in.
#[derive(Debug, Clone, Default)]
pub struct FrameTracker {
    stats: LinkStats,
    last_index: Option<u64>,
    times: VecDeque<f64>,
}

impl FrameTracker {
    pub fn new() -> Self {
        Self::default()
    }

    /// Count one rejected piece of input.
    pub fn bad(&mut self, reason: BadReason) {
        *self.stats.bad.entry(reason).or_insert(0) += 1;
    }

    /// Account for a decoded frame with the sensor's counter `index` and
    /// timestamp `t_s`; says whether to deliver it.
    pub fn frame(&mut self, index: u64, t_s: f64) -> Verdict {
        if let Some(last) = self.last_index {
            if index <= last && last - index <= RESTART_JUMP {
                self.bad(BadReason::Stale);
                return Verdict::Stale;
            }
            if index > last {
                self.stats.dropped += index - last - 1;
            } else {
                // The sensor restarted: its counter and clock begin again.
                self.times.clear();
            }
        }
        self.last_index = Some(index);
        self.stats.frames += 1;
        if self.times.len() == RATE_WINDOW {
            self.times.pop_front();
        }
        self.times.push_back(t_s);
        self.stats.rate_hz = match (self.times.front(), self.times.back()) {
            (Some(first), Some(last)) if self.times.len() >= 2 && last > first => {
                (self.times.len() - 1) as f64 / (last - first)
            }
            _ => 0.0,
        };
        Verdict::Accept
    }

    pub fn stats(&self) -> LinkStats {
        self.stats.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_count_as_dropped_and_rate_comes_from_sensor_time() {
        let mut t = FrameTracker::new();
        for (i, idx) in [100u64, 101, 102, 105, 106].iter().enumerate() {
            assert_eq!(t.frame(*idx, *idx as f64 / 30.0), Verdict::Accept, "frame {i}");
        }
        let s = t.stats();
        assert_eq!(s.frames, 5);
        assert_eq!(s.dropped, 2);
        // 5 frames spanning indices 100..106 at 30 Hz sensor time: 4 intervals over 6/30 s.
        assert!((s.rate_hz - 4.0 / (6.0 / 30.0)).abs() < 1e-9, "{}", s.rate_hz);
    }

    #[test]
    fn late_frame_is_stale_and_restart_is_accepted() {
        let mut t = FrameTracker::new();
        assert_eq!(t.frame(5000, 0.0), Verdict::Accept);
        assert_eq!(t.frame(5002, 0.1), Verdict::Accept);
        assert_eq!(t.frame(5001, 0.05), Verdict::Stale);
        assert_eq!(t.frame(5002, 0.1), Verdict::Stale);
        assert_eq!(t.frame(3, 0.0), Verdict::Accept, "counter restart");
        let s = t.stats();
        assert_eq!(s.frames, 3);
        assert_eq!(s.dropped, 1);
        assert_eq!(s.bad_count(BadReason::Stale), 2);
        assert_eq!(s.bad_total(), 2);
    }
}
