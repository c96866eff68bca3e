//! render-preview library.
