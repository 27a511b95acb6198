//! Opening a serial port with the Thorlabs APT line settings (docs/hardware.md
//! A.1): 115200 baud, 8N1, hardware RTS/CTS flow control, then the
//! recommended purge / RTS sequence. Works on a real FTDI tty and on an
//! emulator's pseudo-terminal, where the modem-line ioctls fail with ENOTTY.

use std::io;
use std::path::Path;
use std::time::Duration;

use tokio_serial::{
    ClearBuffer, DataBits, FlowControl, Parity, SerialPort, SerialPortBuilderExt, SerialStream, StopBits,
};

/// APT baud rate.
pub const APT_BAUD: u32 = 115_200;

fn to_io(e: tokio_serial::Error) -> io::Error {
    let kind = match e.kind() {
        tokio_serial::ErrorKind::NoDevice => io::ErrorKind::NotFound,
        tokio_serial::ErrorKind::InvalidInput => io::ErrorKind::InvalidInput,
        tokio_serial::ErrorKind::Io(k) => k,
        tokio_serial::ErrorKind::Unknown => io::ErrorKind::Other,
    };
    io::Error::new(kind, e.description)
}

/// Pseudo-terminals have no modem lines: RTS/DTR ioctls fail with ENOTTY,
/// which serialport reports as an unknown error with the errno text.
fn is_enotty(e: &tokio_serial::Error) -> bool {
    e.kind() == tokio_serial::ErrorKind::Unknown
        && ["Inappropriate ioctl", "ENOTTY", "Not a typewriter"].iter().any(|t| e.description.contains(t))
}

fn tolerate_enotty(r: tokio_serial::Result<()>) -> io::Result<()> {
    match r {
        Ok(()) => Ok(()),
        Err(e) if is_enotty(&e) => Ok(()),
        Err(e) => Err(to_io(e)),
    }
}

/// Open `path` for an APT unit: 115200 8N1, RTS/CTS, exclusive; purge both
/// buffers with the 50 ms pauses Thorlabs recommends, then assert RTS.
/// The FTDI "reset device" step has no tty equivalent and is skipped, as
/// every tty-based client does.
pub async fn open_serial(path: impl AsRef<Path>) -> io::Result<SerialStream> {
    open_serial_settle(path, Duration::from_millis(50)).await
}

/// [`open_serial`] with a chosen pause around the purge. An emulator's
/// pseudo-terminal has no FTDI chip to settle, so tests pass zero.
pub async fn open_serial_settle(path: impl AsRef<Path>, settle: Duration) -> io::Result<SerialStream> {
    let path = path.as_ref().to_string_lossy().into_owned();
    let mut port = tokio_serial::new(&path, APT_BAUD)
        .data_bits(DataBits::Eight)
        .parity(Parity::None)
        .stop_bits(StopBits::One)
        .flow_control(FlowControl::Hardware)
        .timeout(Duration::from_millis(100))
        .open_native_async()
        .map_err(to_io)?;
    if !settle.is_zero() {
        tokio::time::sleep(settle).await;
    }
    port.clear(ClearBuffer::All).map_err(to_io)?;
    if !settle.is_zero() {
        tokio::time::sleep(settle).await;
    }
    tolerate_enotty(port.write_request_to_send(true))?;
    Ok(port)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enotty_is_tolerated_and_other_errors_are_not() {
        let enotty =
            tokio_serial::Error::new(tokio_serial::ErrorKind::Unknown, "ENOTTY: Inappropriate ioctl for device");
        assert!(tolerate_enotty(Err(enotty)).is_ok());
        let other = tokio_serial::Error::new(
            tokio_serial::ErrorKind::Io(io::ErrorKind::PermissionDenied),
            "EACCES: Permission denied",
        );
        let e = tolerate_enotty(Err(other)).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
    }

    #[tokio::test]
    async fn missing_port_is_not_found() {
        let e = open_serial("/dev/easycalib-no-such-port").await.unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
    }
}
