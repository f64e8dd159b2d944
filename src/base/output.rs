//! Writing output files without losing anything the user has.
//!
//! Policy, the same for every command and every output (images, plots, shaders, tables):
//! - only **regular files** are written or replaced: a directory, device node, FIFO or socket at the output
//!   path is refused, even when the user allows replacing files (`/dev/null` must never be replaced);
//! - an existing file is replaced only if lobe wrote it (recognised from a bounded **prefix** — a PNG's
//!   `Software: lobe` chunk or a text header — so a 2 GB foreign file costs one 64 KiB read) or when the user
//!   allows replacing it (`force`);
//! - the write is **atomic**: a temporary file `.NAME.lobe-tmp-PID` in the target's directory, synced, then
//!   renamed over the target, so a failure or a kill never leaves a truncated file at the user's path;
//! - a **symlink** is followed: the file it points to is replaced and the link stays a link (a dangling link
//!   is refused); the **permissions** of a replaced file are kept;
//! - temporary files are removed on failure, on SIGINT/SIGTERM/SIGHUP ([`remove_temporaries`], called by the
//!   CLI's signal handler), and — for ones a killed process left behind, whatever file they were for — on the
//!   next write to the same directory (a writer's death is told from `/proc`; without it, only temporaries
//!   older than an hour are taken as left behind).
//!
//! [`check`] answers "may I write here?"; commands call it early (before a long render) and again right before
//! [`write_atomic`], so a file another program put there in between (e.g. during `lobe watch`) is not
//! clobbered.

use super::diag::{Advice, Diagnostic};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// An existing file lobe did not write is kept unless the user explicitly allows replacing it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AllowOverwrite;

impl Advice for AllowOverwrite {
    fn plain(&self) -> String {
        "choose another output path, or allow replacing the file".into()
    }
}

/// How much of an existing file is read to decide whether lobe wrote it.
pub(crate) const PREFIX_BYTES: u64 = 64 * 1024;

/// Temporary files being written right now, so a signal handler can remove them.
static IN_FLIGHT: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Checks that `path` may be (over)written: its directory exists; if something is there it is a regular file
/// (after following symlinks), and, unless `force`, one that `is_ours` recognises from its first
/// [`PREFIX_BYTES`]. A foreign file is refused with [`AllowOverwrite`].
pub fn check(path: &Path, force: bool, is_ours: fn(&[u8]) -> bool) -> Result<(), Diagnostic> {
    let target = resolve(path)?;
    let dir = parent_dir(&target);
    if !dir.is_dir() {
        return Err(format!("the directory `{}` does not exist", dir.display()).into());
    }
    let meta = match std::fs::metadata(&target) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(format!("cannot inspect `{}`: {e}", path.display()).into()),
    };
    regular(path, &meta)?;
    if !force {
        let mut prefix = Vec::new();
        std::fs::File::open(&target)
            .and_then(|f| f.take(PREFIX_BYTES).read_to_end(&mut prefix))
            .map_err(|e| format!("cannot read existing `{}`: {e}", path.display()))?;
        if !is_ours(&prefix) {
            return Err(Diagnostic::error(format!("`{}` exists and nothing in it shows lobe wrote it; not overwriting it (refusing to overwrite unless allowed)", path.display()))
                .hint(AllowOverwrite));
        }
    }
    Ok(())
}

/// Writes `bytes` to `path` (following a symlink to its target) atomically: a temporary file in the same
/// directory, fsync, rename; the replaced file's permissions are kept. On failure the temporary file is
/// removed and `path` is untouched. Refuses non-regular targets. Does not check authorship: callers run
/// [`check`] right before it.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), String> {
    let target = resolve(path)?;
    let existing = std::fs::metadata(&target).ok();
    if let Some(m) = &existing {
        regular(path, m)?;
    }
    let dir = parent_dir(&target);
    let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    remove_stale_temporaries(&dir);
    let tmp = dir.join(temporary_name(&name, std::process::id()));
    lock_in_flight().push(tmp.clone());
    let result = (|| -> std::io::Result<()> {
        let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        f.write_all(bytes)?;
        if let Some(m) = &existing {
            f.set_permissions(m.permissions())?;
        }
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, &target)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    lock_in_flight().retain(|p| p != &tmp);
    result.map_err(|e| format!("cannot write `{}`: {e}", path.display()))
}

/// Removes the temporary files of writes in progress (for a signal handler: the process is about to exit).
pub(crate) fn remove_temporaries() {
    for p in lock_in_flight().drain(..) {
        let _ = std::fs::remove_file(p);
    }
}

/// Installs a handler for SIGINT, SIGTERM and SIGHUP that removes in-flight temporaries and exits with the
/// conventional 128 + signal status. A no-op where signals cannot be caught.
pub fn clean_up_on_signals() {
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
        if let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) {
            std::thread::spawn(move || {
                if let Some(sig) = signals.forever().next() {
                    remove_temporaries();
                    std::process::exit(128 + sig);
                }
            });
        }
    }
}

fn lock_in_flight() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    IN_FLIGHT.lock().unwrap_or_else(|e| e.into_inner())
}

/// How old a temporary must be before a system without `/proc` (where a writer's liveness cannot be told)
/// takes it for one a killed process left: writes last seconds, so an hour is far beyond any live one.
const STALE_AGE: std::time::Duration = std::time::Duration::from_secs(3600);

/// Removes the temporaries (`.NAME.lobe-tmp-PID`, any target name) in `dir` that killed writes left behind: on
/// systems with `/proc`, those of processes that no longer run, and this process's own ones that no write of
/// it has in flight (a PID reused after a reboot or in a new container); elsewhere those older than
/// [`STALE_AGE`]. Only regular files of exactly that name shape are touched.
fn remove_stale_temporaries(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let proc_fs = Path::new("/proc/self").exists();
    for e in entries.flatten() {
        let file = e.file_name();
        let Some(pid) = file.to_str().and_then(temporary_pid) else { continue };
        let Ok(meta) = e.metadata() else { continue };
        if !meta.is_file() {
            continue;
        }
        let path = e.path();
        let stale = if proc_fs {
            if pid == std::process::id() {
                // Held under the lock, so a write of this process cannot register it in between.
                let in_flight = lock_in_flight();
                let mine = !in_flight.contains(&path);
                if mine {
                    let _ = std::fs::remove_file(&path);
                }
                continue;
            }
            !Path::new(&format!("/proc/{pid}")).exists()
        } else {
            meta.modified().ok().and_then(|t| t.elapsed().ok()).is_some_and(|age| age > STALE_AGE)
        };
        if stale {
            let _ = std::fs::remove_file(&path);
        }
    }
}

/// The longest file name the common file systems take (ext4, XFS, btrfs, APFS, NTFS: 255 bytes or UTF-16 units).
const MAX_NAME_BYTES: usize = 255;

/// The temporary file's name for a write to `name` by process `pid`: `.NAME.lobe-tmp-PID`, NAME shortened (at a
/// character boundary) so the whole stays within [`MAX_NAME_BYTES`] — a legal 254-byte output name must not fail
/// because its temporary's name is too long.
fn temporary_name(name: &str, pid: u32) -> String {
    let suffix = format!(".lobe-tmp-{pid}");
    let room = MAX_NAME_BYTES - 1 - suffix.len();
    let mut end = name.len().min(room);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    format!(".{}{suffix}", &name[..end])
}

/// The writer's PID of a temporary file name `.NAME.lobe-tmp-PID` (NAME not empty), or `None` for any other
/// name.
fn temporary_pid(file: &str) -> Option<u32> {
    let (head, pid) = file.rsplit_once(".lobe-tmp-")?;
    if head.len() < 2 || !head.starts_with('.') || pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// The path to write: `path` itself, or the file a symlink at `path` points to.
fn resolve(path: &Path) -> Result<PathBuf, String> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => std::fs::canonicalize(path)
            .map_err(|e| format!("`{}` is a symbolic link whose target cannot be resolved: {e}", path.display())),
        _ => Ok(path.to_path_buf()),
    }
}

fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Refuses anything but a regular file at `path` (described by `m`), naming what it is.
fn regular(path: &Path, m: &std::fs::Metadata) -> Result<(), String> {
    if m.is_file() {
        return Ok(());
    }
    Err(format!("`{}` is {}, not a regular file; lobe writes only regular files", path.display(), kind_of(m)))
}

fn kind_of(m: &std::fs::Metadata) -> &'static str {
    let t = m.file_type();
    if t.is_dir() {
        return "a directory";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    "not a regular file"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("lobe-out-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }
    fn ours(b: &[u8]) -> bool {
        b.starts_with(b"LOBE")
    }
    #[test]
    fn the_longest_legal_names_can_be_written_and_replaced() {
        let d = scratch("long");
        // 254 and 255 bytes, and a name of 2-byte characters cut by the shortening inside a character.
        for name in ["a".repeat(250) + ".png", "b".repeat(251) + ".png", "é".repeat(125) + "x.png"] {
            assert!(name.len() <= MAX_NAME_BYTES);
            let p = d.join(&name);
            write_atomic(&p, b"LOBE one").unwrap_or_else(|e| panic!("{} bytes: {e}", name.len()));
            write_atomic(&p, b"LOBE two").unwrap();
            assert_eq!(std::fs::read(&p).unwrap(), b"LOBE two");
        }
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 3, "no temporaries left");
        for pid in [1, u32::MAX] {
            let t = temporary_name(&"é".repeat(200), pid);
            assert!(t.len() <= MAX_NAME_BYTES && temporary_pid(&t) == Some(pid), "{t}");
        }
        let _ = std::fs::remove_dir_all(&d);
    }

    /// What a command does: check, then write.
    fn write(path: &Path, bytes: &[u8], force: bool, is_ours: fn(&[u8]) -> bool) -> Result<(), String> {
        check(path, force, is_ours).map_err(|d| d.message)?;
        write_atomic(path, bytes)
    }

    #[test]
    fn temporary_names_are_recognised_exactly() {
        assert_eq!(temporary_pid(".o.png.lobe-tmp-123"), Some(123));
        assert_eq!(temporary_pid(".a.lobe-tmp-x.lobe-tmp-9"), Some(9));
        for name in ["o.png.lobe-tmp-1", ".lobe-tmp-1", ".o.lobe-tmp-", ".o.lobe-tmp-1x", ".o.lobe-tmp--1", ".o.png"] {
            assert_eq!(temporary_pid(name), None, "{name}");
        }
    }

    #[test]
    fn refuses_foreign_and_non_regular_files() {
        let d = scratch("foreign");
        let p = d.join("notes.txt");
        std::fs::write(&p, "precious").unwrap();
        assert!(write(&p, b"LOBE x", false, ours).is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"precious");
        assert!(write(&p, b"LOBE x", true, ours).is_ok());
        assert!(write(&p, b"LOBE y", false, ours).is_ok());
        assert!(check(&d, true, ours).unwrap_err().message.contains("directory"));
        assert!(check(&d.join("missing/x"), false, ours).is_err());
        #[cfg(unix)]
        {
            let e = check(Path::new("/dev/null"), true, ours).unwrap_err();
            assert!(e.message.contains("character device"), "{e}");
            assert!(write_atomic(Path::new("/dev/null"), b"LOBE").is_err());
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn keeps_links_and_modes_and_cleans_stale_temporaries() {
        use std::os::unix::fs::PermissionsExt;
        let d = scratch("link");
        let real = d.join("real.png");
        std::fs::write(&real, b"LOBE old").unwrap();
        std::fs::set_permissions(&real, std::fs::Permissions::from_mode(0o600)).unwrap();
        let link = d.join("link.png");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        // Temporaries left by processes that no longer exist (pids beyond any real one), for this file and
        // for another; one with this process's pid that no write has in flight (a reused pid); and files
        // that are not such temporaries, or belong to a live process (pid 1), which stay.
        let stale = d.join(".real.png.lobe-tmp-4294967295");
        let other = d.join(".other.svg.lobe-tmp-4294967294");
        let reused = d.join(format!(".real.png.lobe-tmp-{}", std::process::id()));
        let kept = ["notes.lobe-tmp-7", ".x.lobe-tmp-12a", ".lobe-tmp-5", ".live.png.lobe-tmp-1"].map(|n| d.join(n));
        for p in [&stale, &other, &reused].into_iter().chain(&kept) {
            std::fs::write(p, b"").unwrap();
        }
        write(&link, b"LOBE new", false, ours).unwrap();
        assert!(!other.exists() && !reused.exists());
        for p in &kept {
            assert!(p.exists(), "{} was removed", p.display());
        }
        assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read(&real).unwrap(), b"LOBE new");
        assert_eq!(std::fs::metadata(&real).unwrap().permissions().mode() & 0o777, 0o600);
        assert!(!stale.exists());
        std::os::unix::fs::symlink(d.join("nowhere"), d.join("dangling")).unwrap();
        assert!(write(&d.join("dangling"), b"LOBE", true, ours).is_err());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
