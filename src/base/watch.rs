//! File watching for `lobe watch`: poll a file, and on every change of its content call back.
//!
//! Design: polling (modification time, length, and a hash of the content) rather than inotify — no extra
//! dependency, works on every file system including network mounts and editors that replace files by rename,
//! and costs one `stat` plus one read and hash of the (small) file per interval (`lobe watch` polls every
//! 100 ms by default). A change is only reported once the content is stable across two polls, so a half-saved
//! file is not compiled.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::io::Read;
use std::path::Path;
use std::time::{Duration, SystemTime};

/// What one poll saw.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Stamp {
    modified: Option<SystemTime>,
    len: u64,
    hash: u64,
}

/// The file's stamp and content: regular files only (a FIFO would block the poll), at most one byte more than
/// a formula source may have (so an oversized file is reported as such, not read whole).
fn stamp(path: &Path) -> Option<(Stamp, Vec<u8>)> {
    let meta = std::fs::metadata(path).ok().filter(|m| m.is_file())?;
    let mut bytes = Vec::new();
    std::fs::File::open(path).ok()?.take(super::source::MAX_SOURCE_BYTES as u64 + 1).read_to_end(&mut bytes).ok()?;
    let mut h = DefaultHasher::new();
    bytes.hash(&mut h);
    Some((Stamp { modified: meta.modified().ok(), len: meta.len(), hash: h.finish() }, bytes))
}

/// Whether `path` no longer holds `seen` (changed, or gone): `lobe watch` polls it during a long render to stop
/// refining a stale image. One `stat`, read and comparison, as a poll of [`watch`] costs.
pub fn differs(path: &Path, seen: &[u8]) -> bool {
    stamp(path).is_none_or(|(_, bytes)| bytes != seen)
}

/// What the callback wants next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Next {
    Continue,
    Stop,
}

/// Calls `on_change(bytes)` once at start and then whenever the file's content changes, until the callback
/// returns [`Next::Stop`]. A missing file is waited for (an editor may delete and recreate it).
pub fn watch(path: &Path, interval: Duration, mut on_change: impl FnMut(Option<Vec<u8>>) -> Next) {
    let mut last: Option<u64> = None;
    let mut pending: Option<Stamp> = None;
    let mut first = true;
    loop {
        match stamp(path) {
            Some((s, bytes)) => {
                let changed = last != Some(s.hash);
                // Report when the content is stable across two polls (or on the very first poll).
                if changed && (first || pending.as_ref() == Some(&s)) {
                    last = Some(s.hash);
                    pending = None;
                    first = false;
                    if on_change(Some(bytes)) == Next::Stop {
                        return;
                    }
                } else if changed {
                    pending = Some(s);
                }
            }
            None => {
                if first || last.is_some() {
                    last = None;
                    first = false;
                    if on_change(None) == Next::Stop {
                        return;
                    }
                }
            }
        }
        std::thread::sleep(interval);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_initial_content_and_each_change() {
        let dir = std::env::temp_dir().join(format!("lobe-watch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("f.brdf");
        std::fs::write(&p, "NH^n").unwrap();
        let p2 = p.clone();
        let writer = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(100));
            std::fs::write(&p2, "VR^n").unwrap();
        });
        let mut seen = vec![];
        watch(&p, Duration::from_millis(10), |b| {
            seen.push(String::from_utf8(b.unwrap_or_default()).unwrap());
            if seen.len() == 2 {
                Next::Stop
            } else {
                Next::Continue
            }
        });
        writer.join().unwrap();
        assert_eq!(seen, vec!["NH^n", "VR^n"]);
        assert!(!differs(&p, b"VR^n") && differs(&p, b"NH^n") && differs(&dir.join("gone.brdf"), b""));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
