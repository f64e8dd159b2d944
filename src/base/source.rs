//! Reading formula sources: a path, or `-` for standard input. Bounded (a .brdf file is a few lines, so a
//! large or binary file is refused before it costs time or memory), UTF-8 only, no NUL bytes. Failures are a
//! [`Diagnostic`] with a hint, made once here; callers attach it to their own location (a scene key, say).

use super::diag::Diagnostic;
use super::span::line_col;
use std::io::Read;

/// Largest formula source accepted.
pub(crate) const MAX_SOURCE_BYTES: usize = 1 << 20;

/// Why [`read_regular_file`] read nothing.
#[derive(Debug)]
pub enum ReadError {
    Io(std::io::Error),
    /// A directory, device node, FIFO or socket: reading it could block or never end.
    NotRegular,
    /// More than the caller's limit.
    TooLarge,
    /// The [`FileAccess`] policy does not allow this path (the policy's reason).
    Refused(String),
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReadError::Io(e) => write!(f, "{e}"),
            ReadError::NotRegular => f.write_str("not a regular file"),
            ReadError::TooLarge => f.write_str("too large"),
            ReadError::Refused(why) => f.write_str(why),
        }
    }
}

/// The bytes of the regular file at `path`, if it holds at most `max` bytes; never reads more than `max + 1`.
/// For inputs that only make sense as files (scenes, meshes); formula sources also accept pipes (`-`,
/// `<(…)`) and use [`read_source`]. A FIFO, device or socket is refused before it is opened, and the open
/// itself does not block (`O_NONBLOCK`, then the type checked again on the open file), so one swapped in
/// meanwhile is refused too.
pub fn read_regular_file(path: &std::path::Path, max: u64) -> Result<Vec<u8>, ReadError> {
    if !std::fs::metadata(path).map_err(ReadError::Io)?.is_file() {
        return Err(ReadError::NotRegular);
    }
    let mut open = std::fs::OpenOptions::new();
    open.read(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::custom_flags(&mut open, libc::O_NONBLOCK);
    let file = open.open(path).map_err(ReadError::Io)?;
    if !file.metadata().map_err(ReadError::Io)?.is_file() {
        return Err(ReadError::NotRegular);
    }
    let mut bytes = Vec::new();
    file.take(max + 1).read_to_end(&mut bytes).map_err(ReadError::Io)?;
    if bytes.len() as u64 > max {
        return Err(ReadError::TooLarge);
    }
    Ok(bytes)
}

/// Which files a load may read: everything a scene names (the scene itself, meshes, formula files, measured
/// tables) is read through one. The commands read anything ([`Files::any`]); `lobe serve` reads only regular
/// files under the directories it serves. A policy answers [`ReadError::Refused`] without opening the file,
/// so nothing of a refused file reaches an error message.
pub trait FileAccess: Send + Sync {
    /// The bytes of the file at `path` (at most `max`), or why not.
    fn read(&self, path: &std::path::Path, max: u64) -> Result<Vec<u8>, ReadError>;
}

impl<T: FileAccess> FileAccess for std::sync::Arc<T> {
    fn read(&self, path: &std::path::Path, max: u64) -> Result<Vec<u8>, ReadError> {
        T::read(self, path, max)
    }
}

/// Any regular file the process can read ([`read_regular_file`]).
struct AnyFile;

impl FileAccess for AnyFile {
    fn read(&self, path: &std::path::Path, max: u64) -> Result<Vec<u8>, ReadError> {
        read_regular_file(path, max)
    }
}

/// A shared [`FileAccess`] policy; the default reads any regular file.
#[derive(Clone)]
pub struct Files(std::sync::Arc<dyn FileAccess>);

impl Files {
    /// Any regular file (the commands).
    pub fn any() -> Files {
        Files(std::sync::Arc::new(AnyFile))
    }
    pub fn new(policy: impl FileAccess + 'static) -> Files {
        Files(std::sync::Arc::new(policy))
    }
    pub fn read(&self, path: &std::path::Path, max: u64) -> Result<Vec<u8>, ReadError> {
        self.0.read(path, max)
    }
    /// A formula file: read through the policy, then checked as [`read_source`] checks one.
    pub fn read_formula(&self, path: &str) -> Result<String, Diagnostic> {
        let bytes = self.read(std::path::Path::new(path), MAX_SOURCE_BYTES as u64).map_err(|e| match e {
            ReadError::TooLarge => Diagnostic::error(format!("`{path}` is larger than {} KiB; a formula file is a few lines", MAX_SOURCE_BYTES / 1024))
                .hint("is this the right file?"),
            ReadError::NotRegular => Diagnostic::error(format!("`{path}` is not a regular file")).hint("give a .brdf file"),
            e => Diagnostic::error(format!("cannot open `{path}`: {e}")).hint("check the path"),
        })?;
        source_from_bytes(path, bytes)
    }
}

impl Default for Files {
    fn default() -> Files {
        Files::any()
    }
}

impl std::fmt::Debug for Files {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Files")
    }
}

/// Reads a formula source from `path`, or standard input for `-`. Returns the display name and the text.
pub fn read_source(path: &str) -> Result<(String, String), Diagnostic> {
    let mut bytes = Vec::new();
    let name = if path == "-" {
        std::io::stdin()
            .take(MAX_SOURCE_BYTES as u64 + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| Diagnostic::error(format!("cannot read standard input: {e}")))?;
        "<stdin>".to_string()
    } else {
        let file = std::fs::File::open(path).map_err(|e| {
            Diagnostic::error(format!("cannot open `{path}`: {e}"))
                .hint("check the path; `-` reads the formula from standard input")
        })?;
        if file.metadata().map(|m| m.is_dir()).unwrap_or(false) {
            return Err(Diagnostic::error(format!("`{path}` is a directory")).hint("give a .brdf file"));
        }
        file.take(MAX_SOURCE_BYTES as u64 + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| Diagnostic::error(format!("cannot read `{path}`: {e}")))?;
        path.to_string()
    };
    source_from_bytes(&name, bytes).map(|s| (name, s))
}

/// Validates raw bytes as a formula source (size, UTF-8, no NUL bytes).
pub fn source_from_bytes(name: &str, bytes: Vec<u8>) -> Result<String, Diagnostic> {
    if bytes.len() > MAX_SOURCE_BYTES {
        return Err(Diagnostic::error(format!(
            "`{name}` is larger than {} KiB; a formula file is a few lines",
            MAX_SOURCE_BYTES / 1024
        ))
        .hint("is this the right file?"));
    }
    match String::from_utf8(bytes) {
        // A UTF-8 byte-order mark (some Windows editors write one) is not part of the formula.
        Ok(s) if s.starts_with('\u{feff}') => source_from_bytes(name, s.into_bytes().split_off(3)),
        Ok(s) if s.contains('\0') => Err(Diagnostic::error(format!(
            "`{name}` contains NUL bytes; it looks like a binary file, not a formula"
        ))
        .hint("a .brdf file is UTF-8 text")),
        Ok(s) => Ok(s),
        Err(e) => {
            let at = e.utf8_error().valid_up_to();
            let (line, col) = line_col(&String::from_utf8_lossy(&e.into_bytes()[..at]), at);
            Err(Diagnostic::error(format!("{name}:{line}:{col}: the file is not valid UTF-8 text (byte offset {at})"))
                .hint("a .brdf file is UTF-8 text; is this a binary file?"))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_input_is_refused() {
        assert!(source_from_bytes("x", vec![0xff, 0xfe, 0x00]).is_err());
        assert!(source_from_bytes("x", b"NH\0".to_vec()).is_err());
        assert!(source_from_bytes("x", vec![b'1'; MAX_SOURCE_BYTES + 1]).is_err());
        assert_eq!(source_from_bytes("x", "\u{feff}NH^n".as_bytes().to_vec()).unwrap(), "NH^n");
    }
}
