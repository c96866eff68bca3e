//! Speed–accuracy sweep (placeholder, filled in below).
