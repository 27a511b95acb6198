//! The sensor family's typed error, shared by every [`super::SensorLink`]
//! transport so a link can be chosen at run time (`Box<dyn SensorLink>`).

use std::io;
use std::time::Duration;

use crate::motion::{DeviceFault, FaultKind};

#[derive(Debug, thiserror::Error)]
pub enum SensorError {
    /// No good frame arrived in time (malformed ones are counted in the stats).
    #[error("no sensor frame within {waited:?}")]
    Timeout { waited: Duration },
    /// `next_frame` was called on a link that was not started.
    #[error("sensor link is not streaming: call start() first")]
    NotStreaming,
    /// An I/O call on the transport failed.
    #[error("sensor link {what}: {source}")]
    Io {
        what: &'static str,
        #[source]
        source: io::Error,
    },
    /// A command needs the sensor's address, but no frame has arrived yet.
    #[error("cannot send {command}: no sensor has sent a frame yet, so its address is unknown")]
    NoPeer { command: &'static str },
    /// The device did not confirm a command.
    #[error("sensor did not acknowledge {command} within {waited:?}")]
    NoAck { command: &'static str, waited: Duration },
    /// The transport ended (end of stream, socket closed, receiver task gone).
    #[error("sensor link closed: {reason}")]
    Closed { reason: String },
}

impl DeviceFault for SensorError {
    fn kind(&self) -> FaultKind {
        match self {
            SensorError::Timeout { .. } | SensorError::NoAck { .. } => FaultKind::Timeout,
            SensorError::NotStreaming => FaultKind::Protocol,
            SensorError::Io { .. } | SensorError::NoPeer { .. } | SensorError::Closed { .. } => FaultKind::Disconnected,
        }
    }
}

pub(crate) fn io_err(what: &'static str) -> impl FnOnce(io::Error) -> SensorError {
    move |source| SensorError::Io { what, source }
}
