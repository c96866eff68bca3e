//! Typed errors of the library. Every variant names the file and, where it applies, the
//! element and its index/offset, so that one line of output tells the user what to fix.

use std::path::PathBuf;

/// A failure to load a mesh file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LoadError {
    /// The file (or a file it references that is required, such as a glTF buffer) could not
    /// be read.
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The extension is not one of .obj, .gltf, .glb, .ply (and the content did not tell).
    #[error("{}: unknown mesh format (expected .obj, .gltf, .glb or .ply)", path.display())]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// The content is not a mesh this tool reads (STL, FBX, an SCT file, …), named by
    /// what it is.
    #[error("{}: this is {found}; {hint}", path.display())]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
        /// What the content is ("an STL file").
        found: &'static str,
        /// What to do about it.
        hint: &'static str,
    },
    /// The file is not valid in its format.
    #[error("{}: {format} parse error at {location}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// "OBJ", "glTF", "PLY", …
        format: &'static str,
        /// Where (line, element, accessor, byte offset), as precise as the parser allows.
        location: String,
        /// What is wrong.
        message: String,
    },
    /// The text encoding cannot be decoded.
    #[error("{}: text encoding: {message}", path.display())]
    Encoding {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The file requires an extension this tool does not implement.
    #[error("{}: requires unsupported glTF extension {extension}: {hint}", path.display())]
    UnsupportedExtension {
        /// The file.
        path: PathBuf,
        /// The extension name as written in `extensionsRequired`.
        extension: String,
        /// What to do about it.
        hint: &'static str,
    },
    /// A coordinate or attribute is NaN or infinite.
    #[error("{}: non-finite value in {element} {index}", path.display())]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// e.g. "POSITION of mesh 0 primitive 0", "vertex".
        element: String,
        /// Index of the offending item in that element.
        index: u64,
    },
    /// An index refers past the end of the vertex array.
    #[error("{}: {element} index {index} = {value} is out of range (vertex count {count})", path.display())]
    IndexOutOfRange {
        /// The file.
        path: PathBuf,
        /// e.g. "indices of mesh 0 primitive 0", "face".
        element: String,
        /// Position in the index stream.
        index: u64,
        /// The value found.
        value: u64,
        /// The number of vertices.
        count: u64,
    },
    /// A value is outside what the tool can represent (too many elements, too large).
    #[error("{}: {what}", path.display())]
    Limit {
        /// The file.
        path: PathBuf,
        /// What exceeded which limit.
        what: String,
    },
    /// The file (the input or a resource it names) is not a regular file after following
    /// symlinks: a FIFO would block forever and a device never ends, so neither is read.
    #[error("{}: is {kind}, not a regular file; only regular files are read", path.display())]
    NotRegularFile {
        /// The file.
        path: PathBuf,
        /// "a FIFO", "a character device", "a directory", …
        kind: &'static str,
    },
    /// A glTF buffer or image URI resolves to a file outside the model's directory, which is
    /// refused unless [`crate::LoadOptions::allow_outside_uris`] is set.
    #[error("{}: {what} URI {uri:?} resolves to {}, outside the model's directory {} (pass --allow-outside-uris to read it)", path.display(), resolved.display(), dir.display())]
    UriOutsideDirectory {
        /// The model file.
        path: PathBuf,
        /// "buffer 0", "image 3".
        what: String,
        /// The URI as written.
        uri: String,
        /// Where it leads (symlinks followed where the file exists).
        resolved: PathBuf,
        /// The model's directory.
        dir: PathBuf,
    },
    /// A panic inside a third-party parser, caught so that hostile input never aborts the
    /// process.
    #[error("{}: {format} parser failed internally on this input: {message}", path.display())]
    ParserPanic {
        /// The file.
        path: PathBuf,
        /// "OBJ", "glTF", "PLY".
        format: &'static str,
        /// The panic message.
        message: String,
    },
}

impl LoadError {
    pub(crate) fn parse(
        path: &std::path::Path,
        format: &'static str,
        location: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        LoadError::Parse {
            path: path.to_path_buf(),
            format,
            location: location.into(),
            message: message.into(),
        }
    }
}

/// A failure of the whole voxelize job.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An input could not be loaded (bad input: exit status 1).
    #[error(transparent)]
    Load(#[from] LoadError),
    /// Options are inconsistent or out of range (usage: exit status 2).
    #[error("invalid option: {0}")]
    Usage(String),
    /// The input is valid but cannot be sampled as asked (bad input: exit status 1).
    #[error("{0}")]
    Sampling(String),
    /// Writing the output failed (I/O: exit status 2).
    #[error("{}", write_message(path, source))]
    Write {
        /// Output path.
        path: PathBuf,
        /// Cause.
        #[source]
        source: sct_format::Error,
    },
}

impl Error {
    /// The process exit status the binary uses for this error: 1 bad input, 2 usage or I/O.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Load(LoadError::Io { .. } | LoadError::NotRegularFile { .. }) => 2,
            Error::Load(_) | Error::Sampling(_) => 1,
            Error::Usage(_) | Error::Write { .. } => 2,
        }
    }
}

/// `PATH: cannot write: CAUSE`, the path once: the writer's own messages often name it.
fn write_message(path: &std::path::Path, source: &sct_format::Error) -> String {
    let cause = match source {
        sct_format::Error::Misuse(m) => m.clone(),
        other => other.to_string(),
    };
    if cause.contains(&path.display().to_string()) {
        format!("cannot write: {cause}")
    } else {
        format!("{}: cannot write: {cause}", path.display())
    }
}
