//! "Is this port a GRBL?" without moving anything: used by `easycalib devices
//! --probe`. Sends only the status query `?` (real-time, never queued) and the
//! build-info line `$I`; never a reset, never G-code. A board that reboots on
//! port open (Arduino DTR) prints its banner late, so `$I` is repeated once
//! the banner arrives.

use std::path::Path;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

use super::codec::{LineSplitter, Response, parse_line_bytes};
use super::driver::{GrblError, open_serial};
use crate::motion::DeviceInfo;

const PROBE_BYTES: &[u8] = b"?$I\n";
/// `$I` is sent again after a banner or a spoiled answer, at most this often.
const MAX_RESENDS: u32 = 2;

/// What a probe learned before it decided.
#[derive(Debug, Default)]
struct Evidence {
    banner: Option<String>,
    ver: Option<(String, String)>,
    status: bool,
    /// `ok`/`error:N` lines seen: only GRBL-like firmware prints them.
    acks: u32,
    /// A line that is not GRBL (or bytes with no line end) arrived.
    foreign: bool,
    /// First bytes received, to show in the error.
    sample: Vec<u8>,
}

impl Evidence {
    fn is_grbl(&self) -> bool {
        self.banner.is_some() || self.ver.is_some() || self.status
    }

    fn info(&self) -> DeviceInfo {
        let (firmware, serial) = match &self.ver {
            Some((v, info)) => (v.clone(), info.clone()),
            None => (self.banner.clone().unwrap_or_default(), String::new()),
        };
        let short = self.banner.clone().unwrap_or_else(|| firmware.split('.').take(2).collect::<Vec<_>>().join("."));
        DeviceInfo { model: if short.is_empty() { "GRBL".into() } else { format!("GRBL {short}") }, serial, firmware }
    }
}

/// Probe an open byte stream. `Ok` once `$I` has been answered with
/// `[VER:...]` (or, at the deadline, if a banner or a status report showed
/// it is GRBL); `Unexpected` if only non-GRBL bytes came back; `Timeout` if
/// nothing came back.
pub async fn probe_stream<T>(io: &mut T, timeout: Duration) -> Result<DeviceInfo, GrblError>
where
    T: AsyncRead + AsyncWrite + Unpin + Send,
{
    const DURING: &str = "probing for GRBL";
    let io_err = |e: std::io::Error| GrblError::Io { during: DURING, source: e };
    let deadline = Instant::now() + timeout;
    let write = async {
        io.write_all(PROBE_BYTES).await?;
        io.flush().await
    };
    match tokio::time::timeout_at(deadline, write).await {
        Ok(r) => r.map_err(io_err)?,
        Err(_) => {
            return Err(GrblError::Timeout { during: DURING, after: timeout });
        }
    }
    let mut ev = Evidence::default();
    let mut resends = 0;
    let mut splitter = LineSplitter::new();
    let mut buf = [0u8; 256];
    loop {
        let n = match tokio::time::timeout_at(deadline, io.read(&mut buf)).await {
            Err(_) => break,
            Ok(Ok(0)) => return Err(GrblError::Closed { during: DURING }),
            Ok(Ok(n)) => n,
            Ok(Err(e)) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Ok(Err(e)) => return Err(io_err(e)),
        };
        let take = (32 - ev.sample.len().min(32)).min(n);
        ev.sample.extend_from_slice(&buf[..take]);
        let mut lines = Vec::new();
        splitter.push(&buf[..n], &mut lines);
        for line in lines {
            let parsed = line.as_deref().map_err(Clone::clone).and_then(parse_line_bytes);
            match parsed {
                Ok(Response::Welcome { version }) => {
                    // The board just (re)booted: whatever was sent before is gone.
                    ev.banner = Some(version);
                    if resends < MAX_RESENDS {
                        resends += 1;
                        io.write_all(b"$I\n").await.map_err(io_err)?;
                    }
                }
                Ok(Response::Version { version, info }) => ev.ver = Some((version, info)),
                Ok(Response::Status(_)) => ev.status = true,
                Ok(Response::Ok | Response::Error(_)) => {
                    ev.acks += 1;
                    if ev.ver.is_some() {
                        return Ok(ev.info());
                    }
                    // Leftover bytes in GRBL's line buffer (e.g. from another
                    // protocol's probe) spoiled the request; the buffer is empty now.
                    if resends < MAX_RESENDS {
                        resends += 1;
                        io.write_all(b"$I\n").await.map_err(io_err)?;
                    }
                }
                Ok(_) => {}
                Err(_) => ev.foreign = true,
            }
        }
    }
    // Binary protocols (APT) rarely send a line feed: a dangling partial line is foreign too.
    ev.foreign |= splitter.pending() > 0;
    if ev.is_grbl() || (ev.acks > 0 && !ev.foreign) {
        return Ok(ev.info());
    }
    if !ev.sample.is_empty() {
        return Err(GrblError::Unexpected {
            expected: "a GRBL reply to `?` / `$I`",
            got: ev.sample.iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" "),
        });
    }
    Err(GrblError::Timeout { during: DURING, after: timeout })
}

/// Open `path` with GRBL's line settings and [`probe_stream`] it.
pub async fn probe(path: impl AsRef<Path>, timeout: Duration) -> Result<DeviceInfo, GrblError> {
    let mut io = open_serial(path)?;
    probe_stream(&mut io, timeout).await
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DeviceFault;
    use crate::FaultKind;
    use tokio::io::DuplexStream;

    async fn expect(dev: &mut DuplexStream, want: &[u8]) {
        let mut got = vec![0u8; want.len()];
        dev.read_exact(&mut got).await.unwrap();
        assert_eq!(got, want);
    }

    #[tokio::test]
    async fn answers_with_version_and_sends_nothing_but_query_and_build_info() {
        let (mut host, mut dev) = tokio::io::duplex(1024);
        let script = async move {
            expect(&mut dev, b"?$I\n").await;
            dev.write_all(
                b"<Idle|MPos:0.000,0.000,0.000|FS:0,0>\r\n[VER:1.1h.20190830:rig-z]\r\n[OPT:V,15,128]\r\nok\r\n",
            )
            .await
            .unwrap();
            dev
        };
        let (r, mut dev) = tokio::join!(probe_stream(&mut host, Duration::from_secs(1)), script);
        let info = r.unwrap();
        assert_eq!(info.model, "GRBL 1.1h");
        assert_eq!(info.firmware, "1.1h.20190830");
        assert_eq!(info.serial, "rig-z");
        drop(host);
        let mut rest = Vec::new();
        dev.read_to_end(&mut rest).await.unwrap();
        assert!(rest.is_empty(), "{rest:?}");
    }

    #[tokio::test]
    async fn late_banner_triggers_a_second_build_info_request() {
        let (mut host, mut dev) = tokio::io::duplex(1024);
        let script = async move {
            // The bootloader swallowed the first request.
            expect(&mut dev, b"?$I\n").await;
            dev.write_all(b"\r\nGrbl 1.1f ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n").await.unwrap();
            expect(&mut dev, b"$I\n").await;
            dev.write_all(b"[VER:1.1f.20170801:]\r\n[OPT:V,15,128]\r\nok\r\n").await.unwrap();
            dev
        };
        let (r, _dev) = tokio::join!(probe_stream(&mut host, Duration::from_secs(1)), script);
        let info = r.unwrap();
        assert_eq!(info.model, "GRBL 1.1f");
        assert_eq!(info.firmware, "1.1f.20170801");
    }

    #[tokio::test]
    async fn spoiled_first_request_is_repeated() {
        let (mut host, mut dev) = tokio::io::duplex(1024);
        let script = async move {
            expect(&mut dev, b"?$I\n").await;
            // "P" left in the line buffer by an APT frame made the line "P$I".
            dev.write_all(b"<Idle|MPos:0.000,0.000,0.000|FS:0,0>\r\nerror:2\r\n").await.unwrap();
            expect(&mut dev, b"$I\n").await;
            dev.write_all(b"[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n").await.unwrap();
            dev
        };
        let (r, _dev) = tokio::join!(probe_stream(&mut host, Duration::from_secs(1)), script);
        assert_eq!(r.unwrap().firmware, "1.1h.20190830");
    }

    #[tokio::test]
    async fn binary_device_is_protocol_error_silent_one_is_timeout() {
        let (mut host, mut dev) = tokio::io::duplex(1024);
        // An APT unit answering with a binary frame, no line feed.
        dev.write_all(&[0x06, 0x00, 0x54, 0x00, 0x81, 0x50, 0x01]).await.unwrap();
        let e = probe_stream(&mut host, Duration::from_millis(50)).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Protocol, "{e}");
        assert!(e.to_string().contains("06 00 54 00 81 50"), "{e}");

        let (mut host, _dev) = tokio::io::duplex(1024);
        let e = probe_stream(&mut host, Duration::from_millis(50)).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Timeout, "{e}");
    }

    #[tokio::test]
    async fn alarm_locked_grbl_still_identified_by_its_status() {
        let (mut host, mut dev) = tokio::io::duplex(1024);
        dev.write_all(b"<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n").await.unwrap();
        let info = probe_stream(&mut host, Duration::from_millis(50)).await.unwrap();
        assert_eq!(info.model, "GRBL");
    }
}
