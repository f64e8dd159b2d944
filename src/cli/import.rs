//! `lobe import FILE [-o out.brdf]`: a formula file (a BRDF Explorer `.brdf`, typically) written back as lobe's
//! own language, for people to read and edit. The text is [`lobe::ir::print::source`] of the lowered,
//! unsimplified formula, so reading it back gives the same IR and the same values.

use super::args::{self, FormulaSource, Json, Output};
use super::common::CliError;

#[derive(clap::Args, Debug)]
#[command(mut_arg("output", args::help("Write the lobe source to this file instead of standard output")))]
pub struct ImportArgs {
    #[command(flatten)]
    pub formula: FormulaSource,
    #[command(flatten)]
    pub out: Output,
    /// Print `{"file", "output", "text"}` (the text also with -o, which still writes it).
    #[command(flatten)]
    pub json: Json,
}

/// The first line of every imported file: how `--force`-less overwriting recognises lobe's own output.
const MARK: &str = "imported by `lobe import`";

fn is_ours(bytes: &[u8]) -> bool {
    String::from_utf8_lossy(&bytes[..bytes.len().min(400)]).contains(MARK)
}

pub fn run(a: &ImportArgs) -> Result<(), CliError> {
    if let Some(p) = &a.out.path {
        a.out.force.check(p, is_ours)?;
    }
    let f = a.formula.load()?;
    let from = a.formula.file.as_deref().unwrap_or("<expr>");
    let text = lobe::ir::print::source(&f, &format!("{from}, {MARK}: the same function in lobe's language"));
    a.out.emit_text(&text, is_ours, a.json.on.then(|| serde_json::json!({"file": from})))
}
