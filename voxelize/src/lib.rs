//! # voxelize
//!
//! Turns textured meshes (OBJ/MTL, glTF/GLB, PLY) into the surface samples of the SCT
//! toolchain (thesis §5.2): a scan-line voxelization in one uniform grid, or the QSplat
//! vertex-patch sampler.
//!
//! - [`load()`] reads a file into a [`mesh::LoadedScene`] (reused by the preview renderer and
//!   `inspect --against`);
//! - [`sample`] holds the samplers and the density choice (EQ 15–17);
//! - [`run`] does the whole job of the `sct-voxelize` binary.
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// `!(x > 0.0)` is the deliberate NaN-rejecting test throughout (NaN fails every comparison).
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod alpha;
pub mod args;
pub mod error;
pub mod interrupt;
pub mod load;
pub mod mesh;
pub mod polygon;
mod par;
pub mod sides;

pub use error::{Error, LoadError};
pub use load::{load, LoadOptions};
pub mod run;
pub mod sample;

pub use run::{run, sample_in_memory, Options, Summary};
pub use sample::{AreaMode, Density, Method, SampleOptions};
