//! The streaming decoder: bytes as they arrive in any chunking, messages out,
//! resynchronising on the sync pattern after any error.

use super::codec::{parse_header, parse_payload, u32_at};
use super::{CRC_LEN, HEADER_LEN, LinkError, LinkMessage, MAX_PAYLOAD, SYNC, VERSION, crc32};

/// Longest run of garbage reported as one [`LinkError::Garbage`]: a sender on
/// the wrong baud rate shows up in the stats without waiting for a sync.
pub const GARBAGE_REPORT: u64 = 1024;

/// Streaming decoder: feed bytes as they arrive with [`push`](Self::push),
/// take messages and errors with [`next_message`](Self::next_message) until it
/// says `None`. Resynchronises on the sync pattern after any error.
///
/// What it reports does not depend on how the bytes were chunked: a run of
/// garbage is one error (split every [`GARBAGE_REPORT`] bytes), reported when
/// the next message starts, and the bytes of a message already reported as
/// bad are not counted again as garbage.
#[derive(Debug, Default)]
pub struct LinkDecoder {
    buf: Vec<u8>,
    /// Start of undecoded bytes in `buf`.
    start: usize,
    /// Stream offset of `buf[0]`.
    base: u64,
    /// Stream offset before which skipped bytes are not reported as garbage:
    /// the rest of a message whose payload checksum failed.
    quiet_until: u64,
    /// After a bad header the message's end is unknown: skipped bytes stay
    /// quiet until the next sound header.
    quiet_run: bool,
    /// Garbage skipped and not reported yet: (stream offset, bytes).
    run: Option<(u64, u64)>,
}

impl LinkDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, bytes: &[u8]) {
        // Compact lazily so decoding a large frame is not quadratic.
        if self.start > 0 && self.start >= self.buf.len() / 2 {
            self.buf.drain(..self.start);
            self.base += self.start as u64;
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held but not yet decoded.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.start
    }

    /// Step over `n` bytes, adding the loud ones to the garbage run.
    fn skip(&mut self, n: usize) {
        let at = self.base + self.start as u64;
        self.start += n;
        let end = self.base + self.start as u64;
        let from = self.quiet_until.max(at);
        if self.quiet_run || end <= from {
            return;
        }
        match &mut self.run {
            Some((_, len)) => *len += end - from,
            None => self.run = Some((from, end - from)),
        }
    }

    fn take_run(&mut self) -> Option<LinkError> {
        self.run.take().map(|(at, len)| LinkError::Garbage { at, skipped: len as usize })
    }

    pub fn next_message(&mut self) -> Option<Result<LinkMessage, LinkError>> {
        loop {
            let avail = &self.buf[self.start..];
            match avail.windows(2).position(|w| w == SYNC) {
                Some(0) => {}
                Some(k) => {
                    self.skip(k);
                    continue;
                }
                None => {
                    // Keep a trailing first sync byte: its partner may come next.
                    let keep = usize::from(avail.last() == Some(&SYNC[0]));
                    let mut n = avail.len() - keep;
                    if n == 0 {
                        return None;
                    }
                    // Cut the run at exactly GARBAGE_REPORT bytes, however the
                    // bytes were chunked.
                    if let Some((_, len)) = self.run {
                        n = n.min((GARBAGE_REPORT - len.min(GARBAGE_REPORT)).max(1) as usize);
                    } else if !self.quiet_run {
                        n = n.min(GARBAGE_REPORT as usize);
                    }
                    self.skip(n);
                    if matches!(self.run, Some((_, len)) if len >= GARBAGE_REPORT) {
                        return self.take_run().map(Err);
                    }
                    continue;
                }
            }
            // A message starts here: report the garbage before it first.
            if let Some(e) = self.take_run() {
                return Some(Err(e));
            }
            let avail = &self.buf[self.start..];
            if avail.len() < HEADER_LEN {
                return None;
            }
            let at = self.base + self.start as u64;
            let h = match parse_header(at, &avail[..HEADER_LEN]) {
                Ok(h) => h,
                Err(e) => {
                    // Not a real header (sync bytes inside data, or corruption):
                    // step past this sync and look again.
                    self.start += 1;
                    if at < self.quiet_until || self.quiet_run {
                        continue;
                    }
                    self.quiet_run = true;
                    return Some(Err(e));
                }
            };
            self.quiet_run = false;
            if h.len > MAX_PAYLOAD {
                self.start += SYNC.len();
                self.quiet_run = true;
                return Some(Err(LinkError::TooLong { at, len: h.len }));
            }
            let total = HEADER_LEN + h.len + CRC_LEN;
            if avail.len() < total {
                return None;
            }
            let payload = &avail[HEADER_LEN..HEADER_LEN + h.len];
            let computed = crc32(payload);
            let received = u32_at(avail, HEADER_LEN + h.len);
            if computed != received {
                // The header is sound, so the message really was this long, but
                // bytes may have been lost inside it and a next message may start
                // there: skip only the header and rescan the rest quietly.
                self.quiet_until = at + total as u64;
                self.start += HEADER_LEN;
                return Some(Err(LinkError::Checksum { at, computed, received }));
            }
            let result = if h.version != VERSION {
                Err(LinkError::Version { at, version: h.version })
            } else {
                parse_payload(at, h.kind, payload)
            };
            self.start += total;
            return Some(result);
        }
    }
}
