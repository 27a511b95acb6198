//! The sensor family's typed error, shared by every [`super::SensorLink`]
//! transport so a link can be chosen at run time (`Box<dyn SensorLink>`).

use std::io;
use std::sync::Arc;
use std::time::Duration;

use super::link::LinkEncodeError;
use super::tac3d::Tac3dEncodeError;
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
    /// The receive task's transport failed and the link ended; every later
    /// call returns the same I/O error (shared, hence the `Arc`).
    #[error("sensor link {what} failed: {source}")]
    Lost {
        what: &'static str,
        #[source]
        source: Arc<io::Error>,
    },
    /// A frame or command could not be put on the wire (the data, not the link).
    #[error("cannot encode {what}: {source}")]
    Encode {
        what: &'static str,
        #[source]
        source: EncodeError,
    },
}

/// Why a message could not be encoded, per protocol.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EncodeError {
    #[error(transparent)]
    Link(#[from] LinkEncodeError),
    #[error(transparent)]
    Tac3d(#[from] Tac3dEncodeError),
}

impl DeviceFault for SensorError {
    fn kind(&self) -> FaultKind {
        match self {
            SensorError::Timeout { .. } | SensorError::NoAck { .. } => FaultKind::Timeout,
            SensorError::NotStreaming | SensorError::Encode { .. } => FaultKind::Protocol,
            SensorError::Io { .. }
            | SensorError::NoPeer { .. }
            | SensorError::Closed { .. }
            | SensorError::Lost { .. } => FaultKind::Disconnected,
        }
    }
}

/// `map_err(encode_err("link frame"))`: a message that cannot be encoded.
pub fn encode_err<E: Into<EncodeError>>(what: &'static str) -> impl FnOnce(E) -> SensorError {
    move |e| SensorError::Encode { what, source: e.into() }
}

/// `map_err(io_err("bind UDP socket"))`: an I/O failure on the transport.
pub fn io_err(what: &'static str) -> impl FnOnce(io::Error) -> SensorError {
    move |source| SensorError::Io { what, source }
}
