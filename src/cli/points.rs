//! `lobe eval FILE --points PATH|-`: reading the CSV (a file or standard input, bounded); parsing and the
//! batched evaluation are [`lobe::numerics::points`].

use super::common::CliError;
use std::io::Read;

/// The largest CSV read (about ten million points).
pub const MAX_POINTS_BYTES: u64 = 256 << 20;

/// Reads `path` (`-`: standard input) as text, bounded by [`MAX_POINTS_BYTES`].
pub fn read(path: &str) -> Result<String, CliError> {
    let bytes = if path == "-" {
        let mut b = Vec::new();
        std::io::stdin().take(MAX_POINTS_BYTES + 1).read_to_end(&mut b).map_err(|e| CliError::msg(format!("stdin: {e}")))?;
        b
    } else {
        use lobe::base::source::ReadError;
        lobe::base::source::read_regular_file(std::path::Path::new(path), MAX_POINTS_BYTES).map_err(|e| {
            let why = match e {
                ReadError::Io(e) => e.to_string(),
                ReadError::NotRegular => "not a regular file".into(),
                ReadError::TooLarge => format!("more than {} MiB of points", MAX_POINTS_BYTES >> 20),
                ReadError::Refused(why) => why,
            };
            CliError::hint(format!("{path}: {why}"), "--points takes a CSV file, or `-` for standard input")
        })?
    };
    if bytes.len() as u64 > MAX_POINTS_BYTES {
        return Err(CliError::hint(
            format!("{path}: more than {} MiB of points", MAX_POINTS_BYTES >> 20),
            "split the file and evaluate the parts",
        ));
    }
    String::from_utf8(bytes).map_err(|e| CliError::hint(format!("{path}: not UTF-8 text ({e})"), "--points takes CSV text"))
}
