//! One error type for the whole crate, split by who caused the failure
//! (the file, the environment, the caller, or a configured limit).

use std::path::PathBuf;

/// Everything that can go wrong while reading or writing SCT and samples files.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The operating system failed an I/O request.
    #[error("I/O error{}: {source}", path.as_ref().map(|p| format!(" on {}", p.display())).unwrap_or_default())]
    Io {
        /// File involved, when known.
        path: Option<PathBuf>,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The bytes do not follow the specification.
    #[error("malformed file at byte {offset}: {what}")]
    Malformed {
        /// Absolute byte offset in the file (or in the decompressed block when `what` says so).
        offset: u64,
        /// What was wrong.
        what: String,
    },
    /// A stored checksum does not match the bytes it covers.
    #[error("checksum mismatch in {what} at byte {offset}: stored {stored:#010x}, computed {computed:#010x}")]
    Checksum {
        /// Section tag or block description.
        what: String,
        /// Absolute byte offset of the checksummed range.
        offset: u64,
        /// Checksum stored in the file.
        stored: u32,
        /// Checksum of the bytes as read.
        computed: u32,
    },
    /// The file is not an SCT file (or not the kind of SCT file expected).
    #[error("not an {expected} file (magic bytes {found:02x?})")]
    BadMagic {
        /// The kind of file expected.
        expected: &'static str,
        /// The first bytes found.
        found: Vec<u8>,
    },
    /// The file's major version is newer (or older) than this reader understands.
    #[error("unsupported format version {major}.{minor}: this reader understands {supported}.x; upgrade the SCT tools")]
    UnsupportedVersion {
        /// Major version in the file.
        major: u16,
        /// Minor version in the file.
        minor: u16,
        /// Major version this reader supports.
        supported: u16,
    },
    /// A section marked required is unknown to this reader.
    #[error("unknown required section {tag:?} at byte {offset}: the file needs a newer reader")]
    UnknownRequiredSection {
        /// Four-character tag.
        tag: String,
        /// Offset of its section-table entry.
        offset: u64,
    },
    /// A count or size in the file exceeds a configured [`crate::Limits`] cap.
    #[error("limit exceeded: {what} is {value}, limit is {limit}")]
    LimitExceeded {
        /// Which quantity.
        what: &'static str,
        /// Value found (or requested).
        value: u64,
        /// The configured limit.
        limit: u64,
    },
    /// The caller passed something the API cannot represent (not a file problem).
    #[error("invalid argument: {0}")]
    Misuse(String),
}

/// Shorthand for results of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// A [`Error::Malformed`] at `offset`.
    pub fn malformed(offset: u64, what: impl Into<String>) -> Self {
        Error::Malformed { offset, what: what.into() }
    }

    /// An I/O error tied to a path.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: Some(path.into()), source }
    }

    /// True when the file content (not the environment or the caller) is at fault.
    pub fn is_invalid_input(&self) -> bool {
        !matches!(self, Error::Io { .. } | Error::Misuse(_))
    }
}

impl From<std::io::Error> for Error {
    fn from(source: std::io::Error) -> Self {
        Error::Io { path: None, source }
    }
}

/// True when `e` or one of its causes is a closed pipe: whoever read the tool's stdout went
/// away (`sct-inspect x.sct | head`). Tools end quietly then, as other Unix tools do.
pub fn is_broken_pipe(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cause = Some(e);
    while let Some(c) = cause {
        if c.downcast_ref::<std::io::Error>().is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe) {
            return true;
        }
        cause = c.source();
    }
    false
}

/// Writes `text` and a newline to stdout (the data of a tool: a report, a table, JSON).
/// A closed pipe is not an error: the reader has what it wanted (see [`is_broken_pipe`]).
/// `println!` panics there instead.
pub fn print_stdout(text: &str) -> std::io::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.write_all(b"\n")).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => r,
    }
}

/// An error and its causes on one line, each cause once, as the tools print it: most errors
/// already name their source in their own message (an I/O error's holds its source's), and
/// some parsers' messages span lines.
pub fn one_line(e: &(dyn std::error::Error + 'static)) -> String {
    let mut msg = String::new();
    let mut cause = Some(e);
    while let Some(c) = cause {
        let s = c.to_string();
        if !msg.contains(&s) {
            if !msg.is_empty() {
                msg.push_str(": ");
            }
            msg.push_str(&s);
        }
        cause = c.source();
    }
    msg.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Causes follow on one line; a cause whose text the message already holds is not
    /// repeated, and line breaks inside a message fold to spaces.
    #[test]
    fn one_line_names_each_cause_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "gone");
        let e = Error::io("a/b.sct", io);
        let line = one_line(&e);
        assert_eq!(line.matches("gone").count(), 1, "{line}");
        assert!(line.contains("a/b.sct") && !line.contains('\n'), "{line}");
    }
}
