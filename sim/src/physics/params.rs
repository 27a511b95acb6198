//! Material and geometry of the two bodies in contact.

use serde::{Deserialize, Serialize};

/// An elastic body: Young's modulus, Poisson's ratio and radius of curvature
/// at the contact (`f64::INFINITY` for a flat surface).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Body {
    pub e_mpa: f64,
    pub nu: f64,
    pub r_mm: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    #[error("{what}: Young's modulus must be finite and > 0 MPa, got {value}")]
    Modulus { what: &'static str, value: f64 },
    #[error("{what}: Poisson's ratio must lie in (0, 0.5), got {value}")]
    Poisson { what: &'static str, value: f64 },
    #[error("{what}: radius must be > 0 mm (inf for flat), got {value}")]
    Radius { what: &'static str, value: f64 },
}

impl Body {
    pub fn new(e_mpa: f64, nu: f64, r_mm: f64) -> Self {
        Self { e_mpa, nu, r_mm }
    }

    /// Reject parameters no real material has, naming the body.
    pub fn validate(&self, what: &'static str) -> Result<(), ParamError> {
        if !(self.e_mpa.is_finite() && self.e_mpa > 0.0) {
            return Err(ParamError::Modulus { what, value: self.e_mpa });
        }
        if !(self.nu > 0.0 && self.nu < 0.5) {
            return Err(ParamError::Poisson { what, value: self.nu });
        }
        if self.r_mm.is_nan() || self.r_mm <= 0.0 {
            return Err(ParamError::Radius { what, value: self.r_mm });
        }
        Ok(())
    }

    /// Plane-strain modulus E* = E / (1 - nu²) (Eq. 3).
    pub fn plane_strain_mpa(&self) -> f64 {
        self.e_mpa / (1.0 - self.nu * self.nu)
    }

    /// Shear modulus G = E / (2 (1 + nu)) (Eq. 33).
    pub fn shear_mpa(&self) -> f64 {
        self.e_mpa / (2.0 * (1.0 + self.nu))
    }

    /// Tatara's finite-size compliance b = (1+nu)(3-2nu)/(4 pi E R), 0 for a flat body (Eq. 5).
    pub fn tatara_mm_per_n(&self) -> f64 {
        if self.r_mm.is_infinite() {
            0.0
        } else {
            (1.0 + self.nu) * (3.0 - 2.0 * self.nu) / (4.0 * std::f64::consts::PI * self.e_mpa * self.r_mm)
        }
    }
}

/// The sensor's elastomer (1) against the calibration indenter (2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactPair {
    pub elastomer: Body,
    pub indenter: Body,
}

impl ContactPair {
    pub fn validate(&self) -> Result<(), ParamError> {
        self.elastomer.validate("elastomer")?;
        self.indenter.validate("indenter")
    }

    /// Composite modulus 1/E* = 1/E1* + 1/E2* (Eq. 3).
    pub fn composite_modulus_mpa(&self) -> f64 {
        1.0 / (1.0 / self.elastomer.plane_strain_mpa() + 1.0 / self.indenter.plane_strain_mpa())
    }

    /// Composite radius 1/R* = 1/R1 + 1/R2 (Eq. 3).
    pub fn composite_radius_mm(&self) -> f64 {
        1.0 / (1.0 / self.elastomer.r_mm + 1.0 / self.indenter.r_mm)
    }
}
