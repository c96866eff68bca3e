//! # sct-format
//!
//! The SCT ("scene tree") file format of the Canopy point-based renderer, as specified in
//! `spec/SCT.md`: a hierarchy of bounding spheres whose nodes carry a normal cone, surface
//! area and colour, compressed relative to their parents, embedded in a scene graph of
//! groups, instances and inlines.
//!
//! A short tour:
//! - [`Node`] is a decoded scene node; [`geometry`] computes a parent from two children
//!   (thesis EQ 9–14), shared by the tree builder and the validator.
//! - [`SceneTree`] is a tree in breadth-first order: one "has children" bit per node is its
//!   whole topology.
//! - [`codec`] holds the node profiles (raw, canopy, default).
//! - [`samples`] reads and writes the samples file that `sct-voxelize` produces.
//! - [`write`] and [`read`] write and read SCT files; [`raw`] mirrors the on-disk tables.
//! - [`view`] defines the default view (presets, up axis, framing) shared by the tools.
//! - [`Limits`] caps what a hostile file can make a reader allocate; every failure is an
//!   [`Error`].
//!
//! ```
//! use sct_format::{geometry, Generator, Limits, Node, Profile, Scene, SceneTree, SctReader, WriteOptions};
//!
//! // Two leaf samples and their parent (thesis EQ 9-14), stored breadth first.
//! let a = Node { center: [0.0, 0.0, 0.0], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [255, 0, 0, 255] };
//! let b = Node { center: [1.0, 0.0, 0.0], ..a };
//! let root = geometry::parent_of(&a, &b);
//! let tree = SceneTree::from_bfs(vec![root, a, b], vec![true, false, false])?;
//!
//! let mut bytes = Vec::new();
//! let scene = Scene::single_tree(Generator { tool: "doc".into(), ..Default::default() }, tree);
//! sct_format::write_scene(&scene, &WriteOptions { profile: Profile::Canopy, ..Default::default() }, &mut bytes)?;
//!
//! let reader = SctReader::from_bytes(bytes, &Limits::default())?;
//! let decoded = reader.read_tree(0)?;
//! assert_eq!(decoded.leaf_count(), 2);
//! // Lossy profiles guarantee the decoded sphere contains the original.
//! assert!(geometry::sphere_contains(&decoded.nodes()[1], &a, 1e-4));
//! # Ok::<(), sct_format::Error>(())
//! ```
#![deny(unsafe_code)]
#![warn(missing_docs)]

pub mod affine;
pub mod atomic;
pub mod codec;
pub mod container;
pub mod error;
pub mod export;
pub mod fsio;
pub mod graph;
pub mod geometry;
pub mod limits;
pub mod memory;
pub mod node;
pub mod raw;
pub mod read;
pub mod rng;
pub mod samples;
pub mod traverse;
pub mod tree;
pub mod validate;
pub mod view;
pub mod write;

pub use affine::{Affine, AffineMap, Transform};
pub use codec::Profile;
pub use error::{Error, Result};
pub use graph::{Generator, GraphNode, InstanceAttrs, Propagation, SceneGraph, Similarity, SourceRef};
pub use limits::Limits;
pub use node::Node;
pub use read::SctReader;
pub use tree::SceneTree;
pub use write::{write_scene, write_scene_file, LeafRefinement, Scene, WriteOptions};
