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

/// The elastomer's E1 and nu1, the pair a calibration recovers: a fit's or an
/// inversion's answer, a simulated rig's truth, a profile's material.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    #[error("{what}: Young's modulus must be finite and > 0 MPa, got {value}")]
    Modulus { what: &'static str, value: f64 },
    #[error("{what}: Poisson's ratio must lie in (0, 0.5), got {value}")]
    Poisson { what: &'static str, value: f64 },
    #[error("{what}: radius must be > 0 mm (inf for flat), got {value}")]
    Radius { what: &'static str, value: f64 },
    #[error("elastomer layer: thickness must be finite and > 0 mm, got {value}")]
    Thickness { value: f64 },
    #[error("elastomer layer: thickness tolerance must be >= 0 and below the thickness {thickness_mm} mm, got {value}")]
    ThicknessTolerance { value: f64, thickness_mm: f64 },
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

/// How the elastomer layer sits on the sensor's rigid window (docs/physics.md, layer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LayerBase {
    /// Glued to the window: no displacement at the base (the usual gel).
    Bonded,
    /// Resting on the window: no normal displacement, no shear traction at the base.
    Sliding,
}

impl LayerBase {
    pub fn as_str(self) -> &'static str {
        match self {
            LayerBase::Bonded => "bonded",
            LayerBase::Sliding => "sliding",
        }
    }

    pub fn parse(s: &str) -> Option<LayerBase> {
        match s.trim() {
            "bonded" => Some(LayerBase::Bonded),
            "sliding" => Some(LayerBase::Sliding),
            _ => None,
        }
    }
}

/// The elastomer as a layer of finite thickness on a rigid base, as the
/// sensor's datasheet declares it. Absent, the elastomer is a half-space.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Layer {
    /// Thickness h of the gel, mm.
    pub thickness_mm: f64,
    pub base: LayerBase,
    /// One standard deviation of the declared thickness, mm, when the datasheet gives one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thickness_tol_mm: Option<f64>,
}

impl Layer {
    pub fn bonded(thickness_mm: f64) -> Self {
        Self { thickness_mm, base: LayerBase::Bonded, thickness_tol_mm: None }
    }

    /// Reject a thickness or tolerance no real gel has.
    pub fn validate(&self) -> Result<(), ParamError> {
        if !(self.thickness_mm.is_finite() && self.thickness_mm > 0.0) {
            return Err(ParamError::Thickness { value: self.thickness_mm });
        }
        if let Some(t) = self.thickness_tol_mm
            && !(t.is_finite() && t >= 0.0 && t < self.thickness_mm)
        {
            return Err(ParamError::ThicknessTolerance { value: t, thickness_mm: self.thickness_mm });
        }
        Ok(())
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
