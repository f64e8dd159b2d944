//! lobe's integration tests: one binary, one module per area.
mod catalogue;
mod cli;
mod differential;
mod export;
mod jit;
mod simplify;
