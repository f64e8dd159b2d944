//! Reports for people and other tools: shader export (and, later, bench tables and plots).

pub mod bench;
pub mod glsl;
pub mod plot;
