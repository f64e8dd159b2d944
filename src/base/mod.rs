//! The bottom layer: what every stage above uses to talk about the user's files. Byte [`span`]s,
//! [`diag`]nostics (lobe's one error type: a message with structured hints) rendered once with carets,
//! reading a formula [`source`] (bounded, UTF-8) into a string or a diagnostic, writing [`output`] files without losing the user's, polling a file for changes ([`watch`]), 8-bit RGB [`image`]s and their PNG encoding, and
//! the one rule for numbers in JSON output ([`json`]), a deterministic [`rng`] for reproducible samples, and the token that stops a long computation early ([`cancel`]). Nothing here knows about formulas, kernels or the CLI.

pub mod cancel;
pub mod diag;
pub mod image;
pub mod json;
pub mod output;
pub mod rng;
pub mod source;
pub mod span;
pub mod stack;
pub mod watch;
