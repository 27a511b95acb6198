//! The EasyCalib contact model (paper Section II), as plain functions of typed
//! parameters. Units: mm, N, MPa (= N/mm²), N·mm; angles in rad unless a name
//! says `_deg`. Index 1 is the sensor's elastomer, index 2 the indenter.

pub mod inversion;
pub mod layer;
pub mod normal;
pub mod params;
pub mod quadrature;
pub mod torsion;

pub use inversion::{h1_from_materials, h3_from_materials, invert_exact, invert_paper_rounded, reduced_coefficients};
pub use layer::{LayeredContact, LayeredNormal, LayeredTorsion, Profile};
pub use normal::{NormalError, NormalModel, NormalState};
pub use params::{Body, ContactPair, Layer, LayerBase, Material, ParamError};
pub use torsion::{TorsionState, rod_correction_factor, torsion_at};

/// Yoffe's factor on the indenter's Hertz term, 32/(9π) (Eq. 20).
pub const YOFFE: f64 = 32.0 / (9.0 * std::f64::consts::PI);
