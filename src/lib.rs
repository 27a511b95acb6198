//! easycalib: the rig controller.
