//! Layering kept true by a scan of the source: nothing below the CLI names a CLI flag. The library words what
//! to change as a structured hint (`lobe::Hint`) and the CLI spells it with its flags, so a flag in a message,
//! a hint or a doc comment below `src/cli` is a layering bug: the web page would show it, and renaming the
//! flag would leave it stale.

use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`, recursively.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// `--` followed by at least two lowercase letters: a long flag (`--set`, `--at`, `--backend`). One letter is
/// left alone, since `--x` is a double negation in the formula language the tests parse.
fn names_a_flag(line: &str) -> bool {
    let b = line.as_bytes();
    b.windows(4).any(|w| w[0] == b'-' && w[1] == b'-' && w[2].is_ascii_lowercase() && w[3].is_ascii_lowercase())
}

#[test]
fn nothing_below_the_cli_names_a_flag() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = vec![];
    rust_files(&src, &mut files);
    assert!(files.len() > 20, "found only {} source files under {}", files.len(), src.display());
    let mut found = vec![];
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        if rel.starts_with("cli") || rel == Path::new("main.rs") {
            continue;
        }
        for (i, line) in std::fs::read_to_string(f).unwrap().lines().enumerate() {
            if names_a_flag(line) {
                found.push(format!("src/{}:{}: {}", rel.display(), i + 1, line.trim()));
            }
        }
    }
    assert!(found.is_empty(), "CLI flags named below src/cli (word them as a lobe::Hint the CLI spells):\n{}", found.join("\n"));
}

#[test]
fn the_scan_sees_flags() {
    assert!(names_a_flag(r#"hint("rerun with `--backend interp`")"#));
    assert!(names_a_flag("/// `--at` gives inputs"));
    assert!(!names_a_flag(r#"("--x", "(-(-x))")"#));
    assert!(!names_a_flag("a - -b and x--y"));
}
