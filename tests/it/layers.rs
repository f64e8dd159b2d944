//! Layering kept true by a scan of the source: nothing below the CLI names a CLI flag or a subcommand. The
//! library words what to change as a structured hint (`lobe::Hint`) and the CLI spells it with its flags and
//! commands, so a flag in a message, a hint or a doc comment below `src/cli`, or a subcommand in a message, is a
//! layering bug: the web page and the Python module would show it, and renaming the flag would leave it stale.
//! Also here: every BENCHMARKS.md section a comment cites exists.

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

/// Lines of the library (src/ outside the CLI: src/cli and main.rs) that `hit` matches, as `src/FILE:LINE: text`.
fn library_lines(hit: impl Fn(&str) -> bool) -> Vec<String> {
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
            if hit(line) {
                found.push(format!("src/{}:{}: {}", rel.display(), i + 1, line.trim()));
            }
        }
    }
    found
}

#[test]
fn nothing_below_the_cli_names_a_flag() {
    let found = library_lines(names_a_flag);
    assert!(found.is_empty(), "CLI flags named below src/cli (word them as a lobe::Hint the CLI spells):\n{}", found.join("\n"));
}

/// The `lobe` subcommands.
const SUBCOMMANDS: [&str; 15] =
    ["eval", "watch", "bench", "plot", "check", "export", "import", "energy", "accuracy", "fit", "tabulate", "sweep", "render", "compare", "serve"];

/// `lobe SUBCOMMAND` inside a string literal of a line of code (comments may name commands; messages may not).
fn names_a_subcommand(line: &str) -> bool {
    let code = line.trim_start();
    if code.starts_with("//") {
        return false;
    }
    code.split('"').skip(1).step_by(2).any(|lit| {
        lit.match_indices("lobe ").any(|(at, _)| {
            let rest = lit[at + 5..].trim_start_matches('`');
            SUBCOMMANDS.iter().any(|c| rest.strip_prefix(c).is_some_and(|r| !r.starts_with(|ch: char| ch.is_alphanumeric() || ch == '_')))
        })
    })
}

#[test]
fn nothing_below_the_cli_names_a_subcommand() {
    let found = library_lines(names_a_subcommand);
    assert!(found.is_empty(), "subcommands named in messages below src/cli (word them as a lobe::Hint the CLI spells):\n{}", found.join("\n"));
}

#[test]
fn the_scan_sees_subcommands() {
    assert!(names_a_subcommand(r#"    .hint("run `lobe sweep` on the file")"#));
    assert!(names_a_subcommand(r#"const H: &str = "or write one with `lobe tabulate`";"#));
    assert!(!names_a_subcommand(r#"    // `lobe check` shows it"#));
    assert!(!names_a_subcommand(r#"    "lobe evaluates in f64; lobe reads files""#));
    assert!(!names_a_subcommand(r#"    format!("lobe {} pass {v}", x)"#));
}

#[test]
fn the_scan_sees_flags() {
    assert!(names_a_flag(r#"hint("rerun with `--backend interp`")"#));
    assert!(names_a_flag("/// `--at` gives inputs"));
    assert!(!names_a_flag(r#"("--x", "(-(-x))")"#));
    assert!(!names_a_flag("a - -b and x--y"));
}

/// Every file whose comments and docs may cite BENCHMARKS.md: the sources, tests, benches, docs and the Python
/// module.
fn citing_files() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = vec![root.join("README.md")];
    for dir in ["src", "tests", "benches", "docs", "python"] {
        let mut stack = vec![root.join(dir)];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    // Built or installed copies are not the source.
                    if !p.file_name().is_some_and(|n| n == "target" || n.to_string_lossy().starts_with('.')) {
                        stack.push(p);
                    }
                } else if p.extension().is_some_and(|x| x == "rs" || x == "md" || x == "py" || x == "pyi") {
                    out.push(p);
                }
            }
        }
    }
    out
}

/// How a citation names a place in BENCHMARKS.md.
#[derive(Debug, PartialEq)]
enum Cites {
    /// `BENCHMARKS.md §N`: the section numbered N.
    Section(u32),
    /// `BENCHMARKS.md#id`: an anchor (`<a id="id">`).
    Anchor(String),
    /// `BENCHMARKS.md, 2026-12-01` or `BENCHMARKS.md, robust4`: a dated or labelled entry of a journal, which
    /// the file does not keep (one current table per topic; history is git's).
    Entry(String),
    /// The file as a whole.
    File,
}

/// What the citation starting right after `BENCHMARKS.md` in `rest` names.
fn cites(rest: &str) -> Cites {
    // A markdown link's target ends the link: `[BENCHMARKS.md](../BENCHMARKS.md) §15`.
    let rest = rest.strip_prefix("](../BENCHMARKS.md)").or_else(|| rest.strip_prefix("](BENCHMARKS.md)")).unwrap_or(rest);
    if let Some(id) = rest.strip_prefix('#') {
        return Cites::Anchor(id.chars().take_while(|c| c.is_alphanumeric() || *c == '-' || *c == '_').collect());
    }
    let t = rest.trim_start_matches([')', ']']).trim_start();
    if let Some(n) = t.strip_prefix('§') {
        let digits: String = n.trim_start().chars().take_while(char::is_ascii_digit).collect();
        if let Ok(n) = digits.parse() {
            return Cites::Section(n);
        }
    }
    let word: String = t.trim_start_matches(',').trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '-').collect();
    let dated = word.len() >= 10 && word.as_bytes()[4] == b'-' && word[..4].chars().all(|c| c.is_ascii_digit());
    let labelled = word.chars().any(|c| c.is_ascii_digit()) && word.chars().next().is_some_and(|c| c.is_ascii_lowercase());
    if dated || t.starts_with(',') && labelled {
        return Cites::Entry(word);
    }
    Cites::File
}

#[test]
fn every_benchmarks_section_a_comment_names_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let bench = std::fs::read_to_string(root.join("BENCHMARKS.md")).unwrap();
    let sections: Vec<u32> = bench.lines().filter_map(|l| l.strip_prefix("## ")?.split_once(". ")?.0.parse().ok()).collect();
    assert!(sections.len() > 10, "BENCHMARKS.md has only sections {sections:?}");
    let mut bad = vec![];
    let mut cited = 0;
    for f in citing_files() {
        let rel = f.strip_prefix(root).unwrap().to_string_lossy().into_owned();
        if rel == "tests/it/layers.rs" {
            continue;
        }
        let Ok(text) = std::fs::read_to_string(&f) else { continue };
        for (i, line) in text.lines().enumerate() {
            for (at, _) in line.match_indices("BENCHMARKS.md") {
                cited += 1;
                let wrong = match cites(&line[at + "BENCHMARKS.md".len()..]) {
                    Cites::Section(n) if !sections.contains(&n) => Some(format!("§{n} is not a section")),
                    Cites::Anchor(id) if !bench.contains(&format!("id=\"{id}\"")) => Some(format!("#{id} is not an anchor")),
                    Cites::Entry(e) => Some(format!("`{e}` names a journal entry; cite a section as `BENCHMARKS.md §N`")),
                    _ => None,
                };
                let Some(wrong) = wrong else { continue };
                bad.push(format!("{rel}:{}: {wrong}: {}", i + 1, line.trim()));
            }
        }
    }
    assert!(cited > 20, "found only {cited} citations of BENCHMARKS.md");
    assert!(bad.is_empty(), "citations of BENCHMARKS.md that name no section it has:\n{}", bad.join("\n"));
}

#[test]
fn citations_are_read_as_written() {
    assert_eq!(cites(" §15)."), Cites::Section(15));
    assert_eq!(cites("](../BENCHMARKS.md) §15."), Cites::Section(15));
    assert_eq!(cites("#building)."), Cites::Anchor("building".into()));
    assert_eq!(cites(", 2026-12-01, robust4)."), Cites::Entry("2026-12-01".into()));
    assert_eq!(cites(", robust7). `x`"), Cites::Entry("robust7".into()));
    assert_eq!(cites(" 2026-12-01,"), Cites::Entry("2026-12-01".into()));
    assert_eq!(cites(") has the method;"), Cites::File);
    assert_eq!(cites(", the `pass` bench)."), Cites::File);
    assert_eq!(cites("](../BENCHMARKS.md))."), Cites::File);
}
