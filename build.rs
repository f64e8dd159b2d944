//! Runs lalrpop over grammar/ (the only grammar); the parser lands in OUT_DIR.
fn main() {
    println!("cargo:rerun-if-changed=grammar");
    if let Err(e) = lalrpop::Configuration::new().set_in_dir("grammar").process() {
        eprintln!("lalrpop failed on grammar/: {e}");
        std::process::exit(1);
    }
}
