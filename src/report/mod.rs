//! Reports for people and other tools: timing a kernel's evaluation paths ([`measure`]), the speed-against-
//! error table of `lobe bench` ([`bench`]), and lobe plots ([`plot`]).

pub mod bench;
pub mod measure;
pub mod plot;
