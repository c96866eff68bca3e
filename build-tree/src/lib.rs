//! `build-tree`: turns samples into an SCT scene tree (thesis §5.3) and composes scenes
//! of groups, instances and inlines (§5.10).
//!
//! [`build_tree`] is the core: a top-down partition at the centre of the largest extent
//! with duplicate welding, laid out breadth first, with hierarchical attributes from
//! [`sct_format::geometry`]. [`scene`] builds a whole scene graph.
#![forbid(unsafe_code)]

pub mod error;
pub mod tree;

pub use error::BuildError;
pub use tree::{build_tree, build_tree_owned, build_tree_with_map, BuildOptions, BuildStats, Weld};
pub mod batch;
pub mod convert;
pub mod pipeline;
pub mod progress;
pub mod scene;
pub mod sidecar;
