//! Diagnostics: span-carrying errors rendered once, with carets, at the user's own source.
//!
//! Every stage that can reject user input (the front end, `--set` overrides, scene files) produces
//! [`Diagnostic`]s; [`Diagnostics::render`] turns them into `file:line:col` text with the offending source
//! underlined (codespan-reporting), which the CLI prints and the snapshot tests compare whole.

use super::span::{line_col, Span};
use codespan_reporting::diagnostic::{Diagnostic as CsDiag, Label};
use codespan_reporting::files::SimpleFile;
use codespan_reporting::term::{self, termcolor::Buffer};
use std::fmt;

/// Longest source line a diagnostic quotes; longer ones are referred to by line and column.
pub const MAX_ECHOED_LINE: usize = 1000;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Severity {
    Error,
    Warning,
}

/// One message about the source, with a primary span, optional secondary spans, and hints.
#[derive(Clone, Debug, PartialEq)]
pub struct Diagnostic {
    pub severity: Severity,
    pub message: String,
    /// The main location and its label (what is wrong *here*).
    pub primary: Option<(Span, String)>,
    /// Related locations ("parenthesis opened here").
    pub secondary: Vec<(Span, String)>,
    /// "help: …" lines.
    pub hints: Vec<String>,
}

impl Diagnostic {
    pub fn error(message: impl Into<String>) -> Diagnostic {
        Diagnostic { severity: Severity::Error, message: message.into(), primary: None, secondary: vec![], hints: vec![] }
    }
    pub fn warning(message: impl Into<String>) -> Diagnostic {
        Diagnostic { severity: Severity::Warning, ..Diagnostic::error(message) }
    }
    pub fn at(mut self, span: Span, label: impl Into<String>) -> Diagnostic {
        self.primary = Some((span, label.into()));
        self
    }
    pub fn also(mut self, span: Span, label: impl Into<String>) -> Diagnostic {
        self.secondary.push((span, label.into()));
        self
    }
    pub fn hint(mut self, h: impl Into<String>) -> Diagnostic {
        self.hints.push(h.into());
        self
    }
}

/// All diagnostics for one source file.
#[derive(Clone, Debug)]
pub struct Diagnostics {
    pub file: String,
    pub source: String,
    pub items: Vec<Diagnostic>,
}

impl Diagnostics {
    pub fn new(file: impl Into<String>, source: impl Into<String>) -> Diagnostics {
        Diagnostics { file: file.into(), source: source.into(), items: vec![] }
    }
    /// A single error that has no useful location (an unreadable file, say).
    pub fn single(file: impl Into<String>, d: Diagnostic) -> Diagnostics {
        let mut ds = Diagnostics::new(file, "");
        ds.push(d);
        ds
    }
    /// A single error located in `source`.
    pub fn single_in(file: impl Into<String>, source: impl Into<String>, d: Diagnostic) -> Diagnostics {
        let mut ds = Diagnostics::new(file, source);
        ds.push(d);
        ds
    }
    pub fn push(&mut self, d: Diagnostic) {
        self.items.push(d);
    }
    pub fn has_errors(&self) -> bool {
        self.items.iter().any(|d| d.severity == Severity::Error)
    }
    pub fn errors(&self) -> impl Iterator<Item = &Diagnostic> {
        self.items.iter().filter(|d| d.severity == Severity::Error)
    }

    /// Renders every diagnostic as `error: …` followed by `┌─ file:line:col` and the underlined source.
    pub fn render(&self, color: bool) -> String {
        let file = SimpleFile::new(self.file.as_str(), self.source.as_str());
        let mut buf = if color { Buffer::ansi() } else { Buffer::no_color() };
        let config = term::Config::default();
        let len = self.source.len();
        for d in &self.items {
            let mut cs = match d.severity {
                Severity::Error => CsDiag::error(),
                Severity::Warning => CsDiag::warning(),
            }
            .with_message(&d.message);
            let clip = |s: Span| {
                let a = (s.start as usize).min(len);
                let b = (s.end as usize).clamp(a, len);
                a..b
            };
            // A label on a very long line (a minified or binary-ish file) would echo the whole line: name its
            // place instead.
            let too_long = |s: Span| {
                let (r, bytes) = (clip(s), self.source.as_bytes());
                let start = bytes[..r.start].iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
                let end = bytes[r.end..].iter().position(|&b| b == b'\n').map_or(len, |i| r.end + i);
                end - start > MAX_ECHOED_LINE
            };
            let mut labels = vec![];
            let mut placed = vec![];
            let spans = d.primary.iter().map(|p| (p, true)).chain(d.secondary.iter().map(|p| (p, false)));
            for ((s, l), primary) in spans {
                if too_long(*s) {
                    let (line, col) = line_col(&self.source, clip(*s).start);
                    placed.push(format!("at {}:{line}:{col}: {l} (the line is too long to show)", self.file));
                } else if primary {
                    labels.push(Label::primary((), clip(*s)).with_message(l));
                } else {
                    labels.push(Label::secondary((), clip(*s)).with_message(l));
                }
            }
            cs = cs.with_labels(labels);
            let mut notes: Vec<String> = placed;
            notes.extend(d.hints.iter().map(|h| format!("help: {h}")));
            if d.primary.is_none() && !self.file.is_empty() {
                notes.insert(0, format!("in {}", self.file));
            }
            cs = cs.with_notes(notes);
            // Writing to an in-memory buffer cannot fail except on a span bug; fall back to plain text.
            if term::emit(&mut buf, &config, &file, &cs).is_err() {
                use std::io::Write;
                let _ = writeln!(buf, "error: {}", d.message);
            }
        }
        String::from_utf8_lossy(buf.as_slice()).into_owned()
    }

    /// The diagnostics as JSON for tools and the `lobe serve` page: one object per item with `severity`,
    /// `message`, `file`, the primary span's 1-based `line`/`col` and `end_line`/`end_col` (absent when the
    /// item has no place), its `label`, `hints`, and `rendered`, the caret text [`Diagnostics::render`] prints.
    pub fn to_json(&self) -> serde_json::Value {
        let items = self.items.iter().map(|d| {
            let mut o = serde_json::json!({
                "severity": match d.severity { Severity::Error => "error", Severity::Warning => "warning" },
                "message": d.message,
                "file": self.file,
                "hints": d.hints,
            });
            if let Some((s, label)) = &d.primary {
                let (line, col) = line_col(&self.source, s.start as usize);
                let (end_line, end_col) = line_col(&self.source, s.end as usize);
                o["line"] = line.into();
                o["col"] = col.into();
                o["end_line"] = end_line.into();
                o["end_col"] = end_col.into();
                o["label"] = label.as_str().into();
            }
            let one = Diagnostics { file: self.file.clone(), source: self.source.clone(), items: vec![d.clone()] };
            o["rendered"] = one.render(false).into();
            o
        });
        serde_json::Value::Array(items.collect())
    }
}

impl fmt::Display for Diagnostics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.render(false))
    }
}

impl std::error::Error for Diagnostics {}
