//! Caps on what a file may make a reader allocate or do.

/// Limits a reader enforces before any allocation driven by a count in the file.
///
/// Every count is first checked against what the file could possibly hold (a count of
/// fixed-size records can never exceed the remaining bytes); these caps bound what
/// *compressed* data could claim. Exceeding one is [`crate::Error::LimitExceeded`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest decompressed size of any one section or block, in bytes.
    pub max_decompressed_bytes: u64,
    /// Most sections in one file.
    pub max_sections: u32,
    /// Most nodes in one scene tree.
    pub max_tree_nodes: u64,
    /// Most levels (depth + 1) in one scene tree.
    pub max_tree_levels: u32,
    /// Most scene-graph nodes in one file.
    pub max_graph_nodes: u64,
    /// Most samples in one samples file.
    pub max_samples: u64,
    /// Longest UTF-8 string (paths, names, generator JSON), in bytes.
    pub max_string_bytes: u32,
    /// Deepest chain of inline files followed by a traversal.
    pub max_inline_depth: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_decompressed_bytes: 4 << 30,
            max_sections: 4096,
            max_tree_nodes: 1 << 32,
            max_tree_levels: 256,
            max_graph_nodes: 1 << 26,
            max_samples: 1 << 31,
            max_string_bytes: 1 << 20,
            max_inline_depth: 64,
        }
    }
}

impl Limits {
    /// No practical limits (for trusted files only).
    pub fn unlimited() -> Self {
        Limits {
            max_decompressed_bytes: u64::MAX,
            max_sections: u32::MAX,
            max_tree_nodes: u64::MAX,
            max_tree_levels: u32::MAX,
            max_graph_nodes: u64::MAX,
            max_samples: u64::MAX,
            max_string_bytes: u32::MAX,
            max_inline_depth: u32::MAX,
        }
    }

    /// Checks `value <= limit`, naming the quantity in the error.
    pub fn check(what: &'static str, value: u64, limit: u64) -> crate::Result<()> {
        if value > limit {
            Err(crate::Error::LimitExceeded { what, value, limit })
        } else {
            Ok(())
        }
    }
}
