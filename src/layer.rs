//! The declared gel layer's finite-element model (docs/fem.md): one
//! constructor for a layer on its base under an indenter, shared by what
//! reads the layer — the sensing's field and tie (`sensing::layer`), the
//! fit's forward model (`fit::layer_model`) and the laws the emulated rig and
//! the diagnosis run on (`fit::fe_law`). `fem` knows nothing of the
//! recording's `Layer`, and `sim` nothing of `fem`; the two meet here.

use std::sync::Arc;

use sim::physics::{Layer, LayerBase};

/// The FE layer model of `layer` (on its base) under an indenter of
/// modulus `e_mpa`, Poisson's ratio `nu` and radius `r_mm` (built once per
/// process and key).
pub fn forward(layer: &Layer, e_mpa: f64, nu: f64, r_mm: f64) -> Result<Arc<fem::forward::Forward>, fem::FemError> {
    fem::forward::Forward::cached_on(fem_base(layer.base), layer.thickness_mm, e_mpa, nu, r_mm)
}

/// The FE model's boundary at the gel's base for a declared `base`.
pub fn fem_base(base: LayerBase) -> fem::Base {
    match base {
        LayerBase::Bonded => fem::Base::Bonded,
        LayerBase::Sliding => fem::Base::Sliding,
    }
}
