//! Library errors, split by who is at fault so the binary can pick an exit code.

use std::path::PathBuf;

/// Everything that can fail while rendering a preview.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Reading an SCT file failed (malformed content or I/O).
    #[error("{}: {source}", path.display())]
    Sct {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        #[source]
        source: sct_format::Error,
    },
    /// Loading the reference mesh failed.
    #[error(transparent)]
    Mesh(#[from] voxelize::LoadError),
    /// The camera or render settings cannot produce an image.
    #[error("invalid camera: {0}")]
    Camera(String),
    /// An inline of `file`'s graph node `graph_node` cannot be followed (target missing or
    /// unreadable, hash mismatch, cycle, nesting too deep).
    #[error("{}: inline (graph node {graph_node}): {kind}", file.display())]
    Inline {
        /// The file holding the inline.
        file: PathBuf,
        /// The inline's graph node.
        graph_node: u32,
        /// What went wrong (boxed: it is large and rare).
        #[source]
        kind: Box<sct_format::traverse::TraverseErrorKind>,
    },
    /// Nothing was drawn (the reason says why); the binary accepts it with `--allow-empty`.
    #[error("nothing was drawn: {0}")]
    Empty(String),
    /// A `--min-psnr` / `--min-iou` gate failed, or the comparison could not be scored.
    #[error("check failed: {0}")]
    Check(String),
    /// The texture an SCT file was sampled with (its provenance) cannot be found for the
    /// reference.
    #[error("the SCT file was sampled with texture {recorded:?}, which is not found (tried {}); pass --reference-texture IMAGE", tried.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "))]
    ReferenceTexture {
        /// The path as recorded.
        recorded: String,
        /// Where it was looked for.
        tried: Vec<PathBuf>,
    },
    /// Some other invalid setting or input (bad inline path, scene too deep …).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// Writing an output failed.
    #[error("{}", if message.contains(&path.display().to_string()) { format!("cannot write: {message}") } else { format!("cannot write {}: {message}", path.display()) })]
    Output {
        /// The output file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// Shorthand.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// True when the input (file content, camera, settings) is at fault rather than the
    /// environment: the binary exits 1 for these, 2 for I/O.
    pub fn is_invalid_input(&self) -> bool {
        match self {
            Error::Sct { source, .. } => source.is_invalid_input(),
            Error::Mesh(e) => !matches!(e, voxelize::LoadError::Io { .. }),
            // A missing or unreadable inline target is the referring file's fault.
            Error::Inline { .. } | Error::Camera(_) | Error::Invalid(_) | Error::Empty(_) | Error::Check(_) => true,
            Error::Output { .. } | Error::ReferenceTexture { .. } => false,
        }
    }

    pub(crate) fn sct(path: &std::path::Path, source: sct_format::Error) -> Self {
        Error::Sct { path: path.to_path_buf(), source }
    }
}
