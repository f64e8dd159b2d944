//! Reports for people and other tools: `lobe eval`'s values ([`eval`]), timing a kernel's evaluation paths ([`measure`]), the speed-against-
//! error table of `lobe bench` ([`mod@bench`]), lobe plots ([`plot`]), and a render's stage split ([`render`]).

pub mod bench;
pub mod eval;
pub mod measure;
#[cfg(feature = "plot")]
pub mod plot;
pub mod render;
