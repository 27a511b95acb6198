//! Pseudo-terminals for the emulators. The emulator owns the master side; a
//! driver (ours, or a user's own client) opens the slave path exactly as it
//! would open `/dev/ttyUSB0`. The slave is put in raw mode so the line
//! discipline neither echoes nor rewrites bytes, and the emulator keeps its own
//! slave handle open: otherwise the master's reads fail with EIO whenever no
//! client happens to have the port open.

use std::ffi::CStr;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::task::{Context, Poll, ready};

use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// The master side of a pseudo-terminal, usable as an async byte stream.
#[derive(Debug)]
pub struct PtyMaster {
    fd: AsyncFd<OwnedFd>,
    slave_path: PathBuf,
    _slave_keepalive: OwnedFd,
}

fn cvt(ret: libc::c_int) -> io::Result<libc::c_int> {
    if ret < 0 { Err(io::Error::last_os_error()) } else { Ok(ret) }
}

fn set_raw(fd: RawFd) -> io::Result<()> {
    // SAFETY: termios is plain old data; tcgetattr fills it for a valid fd.
    unsafe {
        let mut t: libc::termios = std::mem::zeroed();
        cvt(libc::tcgetattr(fd, &mut t))?;
        libc::cfmakeraw(&mut t);
        cvt(libc::tcsetattr(fd, libc::TCSANOW, &t))?;
    }
    Ok(())
}

impl PtyMaster {
    /// Open a new pseudo-terminal pair. Must be called inside a tokio runtime.
    pub fn open() -> io::Result<Self> {
        // SAFETY: plain libc calls on a freshly opened descriptor we own.
        unsafe {
            let master = cvt(libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC))?;
            let master = OwnedFd::from_raw_fd(master);
            cvt(libc::grantpt(master.as_raw_fd()))?;
            cvt(libc::unlockpt(master.as_raw_fd()))?;
            let mut buf = [0 as libc::c_char; 128];
            let rc = libc::ptsname_r(master.as_raw_fd(), buf.as_mut_ptr(), buf.len());
            if rc != 0 {
                return Err(io::Error::from_raw_os_error(rc));
            }
            let slave_path = PathBuf::from(CStr::from_ptr(buf.as_ptr()).to_string_lossy().into_owned());
            let slave = cvt(libc::open(buf.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC))?;
            let slave = OwnedFd::from_raw_fd(slave);
            set_raw(slave.as_raw_fd())?;
            let flags = cvt(libc::fcntl(master.as_raw_fd(), libc::F_GETFL))?;
            cvt(libc::fcntl(master.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK))?;
            Ok(Self {
                // SAFETY: we own `master` and nothing else registers or closes this fd.
                fd: AsyncFd::register(master)?,
                slave_path,
                _slave_keepalive: slave,
            })
        }
    }

    /// Path a client opens, e.g. `/dev/pts/7`.
    pub fn slave_path(&self) -> &Path {
        &self.slave_path
    }
}

/// Bytes written to a pty that its reader has not taken yet: FIONREAD on a
/// descriptor of the slave side, opened only for this and never read from.
///
/// Why: time acceleration multiplies the link's wall-clock latency into rig
/// time. A producer that outpaces the reader fills the pty buffer (several
/// 10 kB frames), and every frame the host then reads is that many frames
/// old: at 50x a few milliseconds of backlog are a whole stage step, and a
/// run of stale frames agrees with itself well enough to pass as settled. A
/// real sensor on a slow link drops frames rather than queueing them; so
/// does the emulated one (see `super::sensor_sink`), and the host sees the
/// gaps as dropped frames.
#[derive(Debug)]
pub struct SlaveBacklog(std::fs::File);

impl SlaveBacklog {
    /// Open `path` (a pty slave) without making it the controlling terminal.
    pub fn open(path: &Path) -> io::Result<Self> {
        use std::os::unix::fs::OpenOptionsExt;
        let f = std::fs::OpenOptions::new().read(true).write(true).custom_flags(libc::O_NOCTTY).open(path)?;
        Ok(Self(f))
    }

    /// Unread bytes now (0 if the query fails).
    pub fn bytes(&self) -> usize {
        let mut n: libc::c_int = 0;
        // SAFETY: FIONREAD writes one c_int through the pointer; the fd is ours and open.
        let rc = unsafe { libc::ioctl(self.0.as_raw_fd(), libc::FIONREAD, &mut n) };
        if rc < 0 { 0 } else { n.max(0) as usize }
    }
}

impl AsyncRead for PtyMaster {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.fd.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            // SAFETY: reading into an initialized buffer of the given length.
            let res = guard.try_io(|inner| {
                let n = unsafe { libc::read(inner.as_raw_fd(), unfilled.as_mut_ptr().cast(), unfilled.len()) };
                if n < 0 { Err(io::Error::last_os_error()) } else { Ok(n as usize) }
            });
            match res {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                // EIO on a master means no slave is open: report it as end of stream.
                Ok(Err(e)) if e.raw_os_error() == Some(libc::EIO) => return Poll::Ready(Ok(())),
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for PtyMaster {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.fd.poll_write_ready(cx))?;
            // SAFETY: writing from a valid slice.
            let res = guard.try_io(|inner| {
                let n = unsafe { libc::write(inner.as_raw_fd(), data.as_ptr().cast(), data.len()) };
                if n < 0 { Err(io::Error::last_os_error()) } else { Ok(n as usize) }
            });
            match res {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[tokio::test]
    async fn bytes_pass_unchanged_both_ways() {
        let mut master = PtyMaster::open().unwrap();
        let std_slave = std::fs::OpenOptions::new().read(true).write(true).open(master.slave_path()).unwrap();
        let mut slave = tokio::fs::File::from_std(std_slave);
        // Bytes a line discipline would mangle: CR, LF, ^C, ^S, DEL, 0x00, 0xff.
        let payload: Vec<u8> = vec![0x0d, 0x0a, 0x03, 0x13, 0x7f, 0x00, 0xff, 0x23, 0x00];
        slave.write_all(&payload).await.unwrap();
        slave.flush().await.unwrap();
        let mut got = vec![0u8; payload.len()];
        master.read_exact(&mut got).await.unwrap();
        assert_eq!(got, payload);
        master.write_all(&payload).await.unwrap();
        let mut back = vec![0u8; payload.len()];
        slave.read_exact(&mut back).await.unwrap();
        assert_eq!(back, payload);
    }

    #[tokio::test]
    async fn the_backlog_counts_what_the_reader_has_not_taken() {
        let mut master = PtyMaster::open().unwrap();
        let backlog = SlaveBacklog::open(master.slave_path()).unwrap();
        let std_slave = std::fs::OpenOptions::new().read(true).write(true).open(master.slave_path()).unwrap();
        let mut slave = tokio::fs::File::from_std(std_slave);
        assert_eq!(backlog.bytes(), 0);
        master.write_all(&[0x5a; 100]).await.unwrap();
        let mut got = [0u8; 40];
        slave.read_exact(&mut got).await.unwrap();
        // The line discipline hands bytes over in its own time: wait for the rest.
        let mut waiting = 0;
        while backlog.bytes() < 60 && waiting < 100_000 {
            tokio::task::yield_now().await;
            waiting += 1;
        }
        assert_eq!(backlog.bytes(), 60);
        let mut rest = [0u8; 60];
        slave.read_exact(&mut rest).await.unwrap();
        assert_eq!(backlog.bytes(), 0);
    }
}
