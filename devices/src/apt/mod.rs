//! Thorlabs APT protocol: pure codec, unit scaling, the protocol engine, and
//! one driver for the KDC101 + Z8 actuator (linear stage) and the K10CR1
//! rotation mount.

pub mod codec;
pub mod driver;
pub mod link;
pub mod scaling;

pub use codec::{AptDecoder, AptMessage, CodecError, Frame, decode_frame, encode};
pub use driver::{AptAxis, AptConfig, AptError, AptRotation, AptStage, probe, probe_on};
pub use link::AptLink;
pub use scaling::{ControllerFamily, Scale};
