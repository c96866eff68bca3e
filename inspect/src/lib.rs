//! inspect library.
