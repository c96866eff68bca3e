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
    /// Largest in-memory size of one parsed scene graph, in bytes: every graph node counts
    /// `max(size_of::<GraphNode>(), 77)` bytes (at least its largest fixed-size record), each
    /// group child 4 and each inline path its length. Graph records can be 5 bytes on disk
    /// and zstd packs thousands of them in a few bytes, so this, not the node cap, bounds the
    /// graph's memory; since no record takes less memory than its stored bytes, it also caps
    /// the decompressed `GRPH` section (at this plus its 12-byte head).
    pub max_graph_bytes: u64,
    /// Most graph nodes one traversal visits, counting a node once per path that reaches it
    /// (a group child, an instance's child, an inline's root). Shared subgraphs make the paths
    /// of a small graph exponential in number (a chain of groups that each use the previous
    /// one twice), so every consumer that expands paths stops here.
    pub max_traversal_visits: u64,
    /// Largest memory for the decoded samples of one samples file, in bytes
    /// (`size_of::<Node>()` = 40 per sample). Checked from the chunk headers (or the legacy
    /// `SMPL` section's length) before anything is decoded.
    pub max_sample_bytes: u64,
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
            max_graph_bytes: 1 << 30,
            max_traversal_visits: 10_000_000,
            max_sample_bytes: 4 << 30,
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
            max_graph_bytes: u64::MAX,
            max_traversal_visits: u64::MAX,
            max_sample_bytes: u64::MAX,
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
