//! voxelize library.
