//! Datagrams to frames: packets of several frames in any order, bounded in
//! memory and time.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use super::codec::{decode_frame, parse_packet_header};
use super::{HEADER_LEN, Tac3dError, Tac3dFrame};

#[derive(Debug)]
struct Partial {
    last: u16,
    parts: Vec<Option<Vec<u8>>>,
    got: usize,
    /// Payload bytes held.
    bytes: usize,
    /// When the latest packet of this frame arrived (the client's rule).
    touched: Instant,
}

/// Reassembles frames from datagrams that may arrive in any order and
/// interleaved across frames. Frames not complete `timeout` after their latest
/// packet are dropped; [`Tac3dReassembler::expire`] reports how many.
#[derive(Debug)]
pub struct Tac3dReassembler {
    partial: HashMap<u32, Partial>,
    timeout: Duration,
    max_packets: u16,
    max_pending: usize,
    /// Payload bytes held across all partial frames, and the budget for them.
    bytes: usize,
    max_bytes: usize,
    /// Partials pushed out to make room, not yet reported by `expire`.
    evicted: usize,
}

/// Largest frame accepted, bytes (a 20x20 frame of four matrices is ~39 kB).
pub const MAX_FRAME_BYTES: usize = 1 << 20;
/// Payload bytes held for incomplete frames at once (docs/hardening.md).
pub const MAX_BYTES_IN_FLIGHT: usize = 4 << 20;

impl Tac3dReassembler {
    /// `timeout` ~1 s as in the vendor's client.
    pub fn new(timeout: Duration) -> Self {
        Self {
            partial: HashMap::new(),
            timeout,
            // A 4-matrix frame is ~39 kB: even 64-byte datagrams stay far below this.
            max_packets: 4096,
            // Frames in flight at once; bounds memory against a flood of serials.
            max_pending: 32,
            bytes: 0,
            max_bytes: MAX_BYTES_IN_FLIGHT,
            evicted: 0,
        }
    }

    /// Frames waiting for packets.
    pub fn pending(&self) -> usize {
        self.partial.len()
    }

    /// Payload bytes held for frames waiting for packets.
    pub fn bytes_in_flight(&self) -> usize {
        self.bytes
    }

    fn drop_partial(&mut self, serial: u32) -> Option<Partial> {
        let p = self.partial.remove(&serial)?;
        self.bytes -= p.bytes;
        Some(p)
    }

    /// Push out the stalest partial (not `keep`); false when there is none.
    fn evict_stalest(&mut self, keep: u32) -> bool {
        let oldest = self.partial.iter().filter(|(k, _)| **k != keep).min_by_key(|(_, p)| p.touched).map(|(k, _)| *k);
        match oldest {
            Some(k) => {
                self.drop_partial(k);
                self.evicted += 1;
                true
            }
            None => false,
        }
    }

    /// Take one datagram. `Ok(Some(frame))` when it completed a frame.
    /// Errors name the bad datagram or frame; the frame they belong to (if any)
    /// is dropped. Call [`Self::expire`] regularly to drop stale partials.
    pub fn push(&mut self, datagram: &[u8], now: Instant) -> Result<Option<Tac3dFrame>, Tac3dError> {
        let h = parse_packet_header(datagram)?;
        if h.last >= self.max_packets {
            return Err(Tac3dError::TooManyPackets { serial: h.serial, last: h.last, limit: self.max_packets });
        }
        if h.this > h.last {
            return Err(Tac3dError::PacketIndex { serial: h.serial, index: h.this, last: h.last });
        }
        if !self.partial.contains_key(&h.serial) && self.partial.len() >= self.max_pending {
            // Make room by dropping the stalest partial; expire() would drop it soon anyway.
            self.evict_stalest(h.serial);
        }
        let payload = datagram.len() - HEADER_LEN;
        let held = self.partial.get(&h.serial).map_or(0, |p| p.bytes);
        if held + payload > MAX_FRAME_BYTES {
            self.drop_partial(h.serial);
            return Err(Tac3dError::FrameTooLarge { serial: h.serial, bytes: held + payload, limit: MAX_FRAME_BYTES });
        }
        // Memory in flight stays within the budget: the stalest other frames go first.
        while self.bytes + payload > self.max_bytes && self.evict_stalest(h.serial) {}
        let p = self.partial.entry(h.serial).or_insert_with(|| Partial {
            last: h.last,
            parts: vec![None; usize::from(h.last) + 1],
            got: 0,
            bytes: 0,
            touched: now,
        });
        if p.last != h.last {
            let expected = p.last;
            self.drop_partial(h.serial);
            return Err(Tac3dError::PacketCount { serial: h.serial, expected, got: h.last });
        }
        let slot = &mut p.parts[usize::from(h.this)];
        if slot.is_some() {
            return Err(Tac3dError::DuplicatePacket { serial: h.serial, index: h.this });
        }
        *slot = Some(datagram[HEADER_LEN..].to_vec());
        p.got += 1;
        p.bytes += payload;
        p.touched = now;
        self.bytes += payload;
        if p.got < p.parts.len() {
            return Ok(None);
        }
        let Some(p) = self.drop_partial(h.serial) else {
            return Ok(None);
        };
        let mut parts = p.parts.into_iter().flatten();
        let head = parts.next().unwrap_or_default();
        let rest: Vec<Vec<u8>> = parts.collect();
        let blob = rest.concat();
        decode_frame(&head, &blob).map(Some)
    }

    /// Drop partial frames whose latest packet is older than the timeout;
    /// returns how many incomplete frames were dropped since the last call
    /// (including those pushed out because too many were in flight).
    pub fn expire(&mut self, now: Instant) -> usize {
        let before = self.partial.len();
        let timeout = self.timeout;
        self.partial.retain(|_, p| now.saturating_duration_since(p.touched) <= timeout);
        self.bytes = self.partial.values().map(|p| p.bytes).sum();
        before - self.partial.len() + std::mem::take(&mut self.evicted)
    }
}
