//! Errors of the build-tree library, split by who must act: the input's author or the caller/environment.

/// Everything `build-tree` can fail with.
/// Non-exhaustive so that a new failure kind is not a breaking change for callers.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BuildError {
    /// The samples, scene description or referenced files are unusable (exit code 1).
    #[error("bad input: {0}")]
    Input(String),
    /// Reading or writing a file failed (exit code 2).
    #[error("{0}")]
    Io(String),
    /// The SCT library rejected something; carries its message.
    #[error(transparent)]
    Format(#[from] sct_format::Error),
    /// A bug: an invariant of the builder itself does not hold.
    #[error("internal error: {0}")]
    Internal(String),
}

impl BuildError {
    /// Process exit code for this error: 1 for bad input, 2 for I/O and everything else.
    pub fn exit_code(&self) -> i32 {
        match self {
            BuildError::Input(_) => 1,
            BuildError::Format(e) if e.is_invalid_input() => 1,
            _ => 2,
        }
    }
}
