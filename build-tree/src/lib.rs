//! build-tree library.
