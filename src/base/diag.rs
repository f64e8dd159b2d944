//! Diagnostics: lobe's one error type, a message with hints, located or not, rendered once with carets at
//! the user's own source.
//!
//! Every stage that can reject user input (the front end, parameter overrides, scene files, numerical checks,
//! the JIT) produces [`Diagnostic`]s; [`Diagnostics::render`] turns them into `file:line:col` text with the
//! offending source underlined (codespan-reporting), which the CLI prints and the snapshot tests compare whole.
//!
//! Nothing below the CLI knows how the user spelled a setting, so what a message is about ([`Setting`]) and
//! what to change ([`Hint`]) are structured; the front end that shows the error words them through a
//! [`Wording`] (the CLI names its flags, the web page its controls). [`Plain`] words them without either.

use super::span::{is_line_break, line_col, lone_cr_as_lf, Span};
use codespan_reporting::diagnostic::{Diagnostic as CsDiag, Label};
use codespan_reporting::files::SimpleFile;
use codespan_reporting::term::{self, termcolor::Buffer};
use std::any::Any;
use std::fmt;
use std::sync::Arc;

/// Longest source line a diagnostic quotes; longer ones are referred to by line and column.
pub(crate) const MAX_ECHOED_LINE: usize = 1000;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Severity {
    Error,
    Warning,
}

/// What to change to get past an error. Advice that every front end words alike is [`Hint::Text`]; advice
/// that names a setting or an action of some front end is [`Hint::Advice`], a value of the layer the advice is
/// about (`lobe::CompileAdvice`, `lobe::numerics::NumericsAdvice`, …), which each front end words its own way
/// ([`Wording::hint`]).
#[derive(Clone, Debug)]
pub enum Hint {
    Text(String),
    /// The JIT failed; the interpreter computes the same values. (The backend's own advice: it moves to the
    /// backend layer as an [`Advice`] with the backend's error style.)
    UseInterpreter,
    /// Structured advice a layer above defines.
    Advice(Arc<dyn Advice>),
}

/// Structured advice: what to change, as a value of the layer it is about. [`Advice::plain`] words it
/// naming no front end's controls; a front end with controls for it finds it with [`Hint::advice`] and
/// names them.
pub trait Advice: Any + fmt::Debug + Send + Sync {
    /// The advice in words that name no front end's flags, commands or controls.
    fn plain(&self) -> String;
}

impl Hint {
    /// The advice of type `T` this hint holds, if it holds one.
    pub fn advice<T: Advice>(&self) -> Option<&T> {
        match self {
            Hint::Advice(a) => (a.as_ref() as &dyn Any).downcast_ref(),
            _ => None,
        }
    }
}

/// Same kind and same words: advice of the same type that words itself alike.
impl PartialEq for Hint {
    fn eq(&self, other: &Hint) -> bool {
        match (self, other) {
            (Hint::Text(a), Hint::Text(b)) => a == b,
            (Hint::UseInterpreter, Hint::UseInterpreter) => true,
            (Hint::Advice(a), Hint::Advice(b)) => (a.as_ref() as &dyn Any).type_id() == (b.as_ref() as &dyn Any).type_id() && a.plain() == b.plain(),
            _ => false,
        }
    }
}

impl<T: Advice> From<T> for Hint {
    fn from(a: T) -> Hint {
        Hint::Advice(Arc::new(a))
    }
}

impl From<String> for Hint {
    fn from(s: String) -> Hint {
        Hint::Text(s)
    }
}

impl From<&str> for Hint {
    fn from(s: &str) -> Hint {
        Hint::Text(s.to_string())
    }
}

/// A setting of this run that a message is about (its prefix), spelled by the front end that took it.
#[derive(Clone, Debug, PartialEq)]
pub enum Setting {
    /// A parameter value given for this run: the name, and the value when the message is about it.
    Param { name: String, value: Option<f64> },
}

/// How a front end words structured hints and settings.
pub trait Wording {
    fn hint(&self, h: &Hint) -> String;
    fn setting(&self, s: &Setting) -> String;
}

/// Words hints and settings by what they are, naming no front end's controls (library callers, tests, the
/// web page).
pub(crate) struct Plain;

impl Wording for Plain {
    fn hint(&self, h: &Hint) -> String {
        match h {
            Hint::Text(t) => t.clone(),
            Hint::UseInterpreter => "the interpreter computes the same values: use the interpreter backend".into(),
            Hint::Advice(a) => a.plain(),
        }
    }
    fn setting(&self, s: &Setting) -> String {
        match s {
            Setting::Param { name, value: None } => format!("set {name}"),
            Setting::Param { name, value: Some(v) } => format!("set {name}={v}"),
        }
    }
}

/// One message, with hints, a primary span, and optional secondary spans: lobe's error type.
#[derive(Clone, Debug, PartialEq)]
pub struct Diagnostic {
    pub severity: Severity,
    /// The setting the message is about, shown before it (`SETTING: message`); boxed, as it is rare and the
    /// type travels in every `Result` of the front end.
    pub subject: Option<Box<Setting>>,
    pub message: String,
    /// The main location and its label (what is wrong *here*).
    pub primary: Option<(Span, String)>,
    /// Related locations ("parenthesis opened here").
    pub secondary: Vec<(Span, String)>,
    /// "help: …" lines.
    pub hints: Vec<Hint>,
}

impl Diagnostic {
    pub fn error(message: impl Into<String>) -> Diagnostic {
        Diagnostic {
            severity: Severity::Error,
            subject: None,
            message: message.into(),
            primary: None,
            secondary: vec![],
            hints: vec![],
        }
    }
    pub(crate) fn warning(message: impl Into<String>) -> Diagnostic {
        Diagnostic { severity: Severity::Warning, ..Diagnostic::error(message) }
    }
    pub(crate) fn at(mut self, span: Span, label: impl Into<String>) -> Diagnostic {
        self.primary = Some((span, label.into()));
        self
    }
    pub(crate) fn also(mut self, span: Span, label: impl Into<String>) -> Diagnostic {
        self.secondary.push((span, label.into()));
        self
    }
    pub fn hint(mut self, h: impl Into<Hint>) -> Diagnostic {
        self.hints.push(h.into());
        self
    }
    /// The message is about `s`, a setting of this run.
    pub(crate) fn about(mut self, s: Setting) -> Diagnostic {
        self.subject = Some(Box::new(s));
        self
    }
    /// The message as the user reads it: the subject, if any, then the message.
    pub fn text(&self, w: &dyn Wording) -> String {
        match &self.subject {
            Some(s) => format!("{}: {}", w.setting(s), self.message),
            None => self.message.clone(),
        }
    }
    /// The hints as the user reads them.
    pub fn hint_texts(&self, w: &dyn Wording) -> Vec<String> {
        self.hints.iter().map(|h| w.hint(h)).collect()
    }
}

/// The message, then each hint as ` (help: …)`, in [`Plain`] words.
impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text(&Plain))?;
        for h in self.hint_texts(&Plain) {
            write!(f, " (help: {h})")?;
        }
        Ok(())
    }
}

impl std::error::Error for Diagnostic {}

/// A plain message without hints.
impl From<String> for Diagnostic {
    fn from(m: String) -> Diagnostic {
        Diagnostic::error(m)
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
    pub(crate) fn new(file: impl Into<String>, source: impl Into<String>) -> Diagnostics {
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
    pub(crate) fn push(&mut self, d: Diagnostic) {
        self.items.push(d);
    }
    pub fn has_errors(&self) -> bool {
        self.items.iter().any(|d| d.severity == Severity::Error)
    }
    pub fn errors(&self) -> impl Iterator<Item = &Diagnostic> {
        self.items.iter().filter(|d| d.severity == Severity::Error)
    }

    /// Renders every diagnostic as `error: …` followed by `┌─ file:line:col` and the underlined source, in
    /// [`Plain`] words.
    pub fn render(&self, color: bool) -> String {
        self.render_with(color, &Plain)
    }

    /// [`Diagnostics::render`] with hints and settings in a front end's words.
    pub fn render_with(&self, color: bool, w: &dyn Wording) -> String {
        // The caret renderer knows `\n` and `\r\n` line ends only: a lone `\r` (a line break to the lexer) is
        // shown as one, not echoed raw (the terminal would draw the next line over this one).
        let shown = lone_cr_as_lf(&self.source);
        let file = SimpleFile::new(self.file.as_str(), shown.as_ref());
        let mut buf = if color { Buffer::ansi() } else { Buffer::no_color() };
        let config = term::Config::default();
        let len = self.source.len();
        for d in &self.items {
            let mut cs = match d.severity {
                Severity::Error => CsDiag::error(),
                Severity::Warning => CsDiag::warning(),
            }
            .with_message(d.text(w));
            let clip = |s: Span| {
                let a = (s.start as usize).min(len);
                let b = (s.end as usize).clamp(a, len);
                a..b
            };
            // A label on a very long line (a minified or binary-ish file) would echo the whole line: name its
            // place instead.
            let too_long = |s: Span| {
                let (r, bytes) = (clip(s), self.source.as_bytes());
                let start = (0..r.start).rev().find(|&i| is_line_break(bytes, i)).map_or(0, |i| i + 1);
                let end = (r.end..len).find(|&i| bytes[i] == b'\n' || bytes[i] == b'\r').unwrap_or(len);
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
            notes.extend(d.hint_texts(w).iter().map(|h| format!("help: {h}")));
            if d.primary.is_none() && !self.file.is_empty() {
                notes.insert(0, format!("in {}", self.file));
            }
            cs = cs.with_notes(notes);
            // Writing to an in-memory buffer cannot fail except on a span bug; fall back to plain text.
            if term::emit(&mut buf, &config, &file, &cs).is_err() {
                use std::io::Write;
                let _ = writeln!(buf, "error: {}", d.text(w));
            }
        }
        String::from_utf8_lossy(buf.as_slice()).into_owned()
    }

    /// The diagnostics as JSON for tools and the `lobe serve` page: one object per item with `severity`,
    /// `message`, `file`, the primary span's 1-based `line`/`col` and `end_line`/`end_col` (absent when the
    /// item has no place), its `label`, `hints`, and `rendered`, the caret text [`Diagnostics::render`] prints;
    /// all in [`Plain`] words.
    pub fn to_json(&self) -> serde_json::Value {
        self.to_json_with(&Plain)
    }

    /// [`Diagnostics::to_json`] with messages and hints in `w`'s words (the command line names its flags).
    pub fn to_json_with(&self, w: &dyn Wording) -> serde_json::Value {
        let items = self.items.iter().map(|d| {
            let mut o = serde_json::json!({
                "severity": match d.severity { Severity::Error => "error", Severity::Warning => "warning" },
                "message": d.text(w),
                "file": self.file,
                "hints": d.hint_texts(w),
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
            o["rendered"] = one.render_with(false, w).into();
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

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq)]
    enum Pick {
        This,
        That(u8),
    }

    impl Advice for Pick {
        fn plain(&self) -> String {
            match self {
                Pick::This => "pick this".into(),
                Pick::That(n) => format!("pick that {n}"),
            }
        }
    }

    /// A front end finds the advice it has words for by its type; any other words itself plainly.
    struct Front;

    impl Wording for Front {
        fn hint(&self, h: &Hint) -> String {
            match h.advice::<Pick>() {
                Some(Pick::This) => "press T".into(),
                _ => Plain.hint(h),
            }
        }
        fn setting(&self, s: &Setting) -> String {
            Plain.setting(s)
        }
    }

    #[test]
    fn advice_is_worded_by_the_front_end_that_knows_it() {
        let d = Diagnostic::error("no").hint(Pick::This).hint(Pick::That(2)).hint("as text");
        assert_eq!(d.hint_texts(&Front), ["press T", "pick that 2", "as text"]);
        assert_eq!(d.hint_texts(&Plain), ["pick this", "pick that 2", "as text"]);
        assert_eq!(d.to_string(), "no (help: pick this) (help: pick that 2) (help: as text)");
        assert_eq!(d.hints[1].advice::<Pick>(), Some(&Pick::That(2)));
        assert_eq!(d.hints[2].advice::<Pick>(), None);
    }

    #[test]
    fn hints_compare_by_kind_and_words() {
        assert_eq!(Hint::from(Pick::That(1)), Hint::from(Pick::That(1)));
        assert_ne!(Hint::from(Pick::That(1)), Hint::from(Pick::That(2)));
        // The same words as text are not the advice.
        assert_ne!(Hint::from(Pick::This), Hint::from("pick this"));
    }
}
