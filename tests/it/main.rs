//! lobe's integration tests: one binary, one module per area.

mod front;
mod parse_errors;
