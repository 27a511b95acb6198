//! The one home of the simulated set-up's defaults: the Tac3D-like sensor and
//! the paper's PDMS indenter (paper Sec. IV), the noise a Tac3D-class sensor
//! shows, the noise seed and the emulated rig's time acceleration. Everything
//! that needs "the default rig" takes it from here (the resolved set-up is
//! [`crate::setup::SimSetup`]).

use crate::physics::{Body, ContactPair};

/// Young's modulus of the default simulated elastomer, MPa (the paper's result).
pub const ELASTOMER_E_MPA: f64 = 0.33;
/// Poisson's ratio of the default simulated elastomer.
pub const ELASTOMER_NU: f64 = 0.39;
/// Effective dome radius R1 of the default sensor, mm.
pub const ELASTOMER_R_MM: f64 = 33.0;
/// Thickness of the emulated rig's default gel, mm: the EasyCalib reference
/// sensor's flat 5 mm layer bonded to its window (30 mm across, the geometry
/// of the project's finite-element test data). `easycalib run` simulates it
/// and declares it unless told otherwise (docs/run.md, "The simulated gel");
/// the generator's default stays the paper's half-space.
pub const ELASTOMER_THICKNESS_MM: f64 = 5.0;
/// The paper's calibration indenter: E2 (MPa), nu2, R2 (mm).
pub const INDENTER_E_MPA: f64 = 1.1;
pub const INDENTER_NU: f64 = 0.39;
pub const INDENTER_R_MM: f64 = 5.0;
/// Per-component noise of a simulated marker displacement, mm (4 um measured
/// on a Tac3D, docs/hardware.md C.1).
pub const MARKER_SIGMA_MM: f64 = 0.004;
/// Per-sample noise of the depth reading gamma1, mm.
pub const GAMMA1_SIGMA_MM: f64 = 0.002;
/// Per-sample noise of the twist reading theta1, degrees.
pub const THETA1_SIGMA_DEG: f64 = 0.02;
/// Resolution of the micrometer stage, mm, and of the rotation mount, degrees.
pub const STAGE_RESOLUTION_MM: f64 = 0.001;
pub const ROTATION_RESOLUTION_DEG: f64 = 0.01;
/// Coulomb friction between the indenter and a simulated gel layer (pressing
/// and twisting), as in the finite-element recordings of the project's test data.
pub const GEL_FRICTION: f64 = 0.4;
/// Seed of the simulated noise.
pub const SEED: u64 = 1;
/// Time acceleration of the emulated rig for a calibration run: rig time runs
/// this many times faster than wall time.
pub const SPEEDUP: f64 = 40.0;

/// The default sensor elastomer.
pub fn elastomer() -> Body {
    Body::new(ELASTOMER_E_MPA, ELASTOMER_NU, ELASTOMER_R_MM)
}

/// The default calibration indenter.
pub fn indenter() -> Body {
    Body::new(INDENTER_E_MPA, INDENTER_NU, INDENTER_R_MM)
}

/// The default contact pair: the sensor against the paper's indenter.
pub fn pair() -> ContactPair {
    ContactPair { elastomer: elastomer(), indenter: indenter() }
}
