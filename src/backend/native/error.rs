//! The one error type of both native tiers.

use crate::base::diag::{Diagnostic, Hint};
use std::fmt;

/// Why native code generation failed, whichever tier compiled. None of these is caused by the formula's text
/// (the front end rejects bad input); they mean an unsupported host or an internal error, and are reported
/// as a [`Diagnostic`] with a hint to fall back to the interpreter.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NativeError {
    /// The host CPU is not supported by the tier's compiler, a flag was rejected, or this build lacks the tier.
    Host(String),
    /// The compiler rejected the generated code or could not allocate executable memory.
    Module(String),
    /// A broken invariant in lobe itself (a bug): reported instead of panicking.
    Internal(String),
}

impl fmt::Display for NativeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NativeError::Host(m) => write!(f, "the JIT cannot target this machine: {m}"),
            NativeError::Module(m) => write!(f, "the JIT failed to compile the formula: {m}"),
            NativeError::Internal(m) => write!(f, "internal JIT error: {m}"),
        }
    }
}

impl std::error::Error for NativeError {}

impl NativeError {
    /// An internal error (a broken invariant of lobe's code generation).
    pub(crate) fn internal(m: impl fmt::Display) -> NativeError {
        NativeError::Internal(m.to_string())
    }

    /// The error as a diagnostic, with a hint to fall back to the interpreter.
    pub(crate) fn to_diagnostic(&self) -> Diagnostic {
        Diagnostic::error(self.to_string()).hint(Hint::UseInterpreter)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_become_diagnostics_with_a_fallback_hint() {
        let d = NativeError::Module("out of memory".into()).to_diagnostic();
        assert!(d.message.contains("out of memory"));
        assert!(d.hints.contains(&Hint::UseInterpreter));
        assert_eq!(NativeError::internal("root outside the arena").to_string(), "internal JIT error: root outside the arena");
    }
}
