//! Thorlabs APT protocol: pure codec, unit scaling, and drivers for the
//! KDC101 + Z8 actuator (linear stage) and the K10CR1 rotation mount.

pub mod codec;
pub mod driver;
pub mod scaling;

pub use codec::{AptDecoder, AptMessage, CodecError, Frame, decode_frame, encode};
pub use driver::{AptConfig, AptError, AptLink, AptRotation, AptStage, probe, probe_on};
pub use scaling::{ControllerFamily, Scale};
