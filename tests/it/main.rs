//! lobe's integration tests: one binary, one module per area.
mod benched;
mod browser;
mod catalogue;
mod cli;
mod differential;
mod export;
mod front;
mod fuzz;
mod hostile;
mod jit;
mod parse_errors;
mod simplify;
mod accuracy;
mod energy;
mod render;
mod serve;
