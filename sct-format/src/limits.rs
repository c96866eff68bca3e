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
    /// Most bytes a file may stand for once decoded, per byte of the file: with `F` the
    /// file's size, a file whose decoded size exceeds `max(decoded_floor, max_decoded_ratio ×
    /// F)` is refused before anything is inflated. The decoded size counts every node of every
    /// scene tree and every sample at 40 bytes (a raw node record; about what each takes in
    /// memory) plus the raw lengths of the compressed tables (`GRPH`, `INST`, `AFFI`, …).
    ///
    /// Why: zstd regenerates up to 32,768 bytes per stored byte, so the absolute caps above
    /// still let a file of a few hundred kilobytes stand for gigabytes of samples, nodes or
    /// graph records (a zip bomb). Real files are far below the default ratio (written
    /// scene files decode to 8–30 times their size, samples of curved surfaces to 1–6, see
    /// `scripts/decoded-ratios.sh`), so only crafted files and freak inputs hit it; a caller
    /// that trusts its input raises it.
    pub max_decoded_ratio: u64,
    /// Decoded size any file may have whatever its size (see [`Limits::max_decoded_ratio`]).
    /// Samples on flat, axis-aligned surfaces compress far beyond the ratio (the glTF Box's
    /// 634,000 samples: 597 times their 42 KB), so the floor admits every samples file the
    /// voxelizer writes under its default budget of 4 M samples (160 MB), and costs nothing
    /// in the bound for small files: 256 MiB is what the ratio allows a 1 MiB file anyway.
    pub decoded_floor: u64,
}

/// What [`Limits::check_decoded`] names in its error (the limit it reports is the larger of
/// the floor and the ratio times the file's size).
pub const DECODED_SIZE: &str = "decoded size (40 bytes a node or sample, plus tables) for the file's size";

/// Default [`Limits::max_decoded_ratio`].
pub const DEFAULT_DECODED_RATIO: u64 = 256;
/// Default [`Limits::decoded_floor`].
pub const DEFAULT_DECODED_FLOOR: u64 = 256 << 20;

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
            max_decoded_ratio: DEFAULT_DECODED_RATIO,
            decoded_floor: DEFAULT_DECODED_FLOOR,
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
            max_decoded_ratio: u64::MAX,
            decoded_floor: u64::MAX,
        }
    }

    /// Checks that a file of `file_len` bytes standing for `decoded` bytes once decoded stays
    /// within [`Limits::max_decoded_ratio`] and [`Limits::decoded_floor`].
    pub fn check_decoded(&self, decoded: u64, file_len: u64) -> crate::Result<()> {
        let allowed = self.max_decoded_ratio.saturating_mul(file_len).max(self.decoded_floor);
        Limits::check(DECODED_SIZE, decoded, allowed)
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
