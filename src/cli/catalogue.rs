//! The papers' catalogue (`examples/brdfs`), compiled into the binary, so that `lobe bench` and the default
//! `--reference` work from any directory. A file of the same path under the working directory is read instead
//! (a checkout's edits show).

use lobe::base::diag::Diagnostic;

/// Every catalogue file: its path in the checkout and its text.
pub use lobe::report::bench::CATALOGUE as BUILT_IN;

/// A formula file's name and text: the file if it exists, else the built-in copy of a catalogue path.
pub fn read(path: &str) -> Result<(String, String), Diagnostic> {
    match lobe::base::source::read_source(path) {
        Err(e) if !std::path::Path::new(path).exists() => match BUILT_IN.iter().find(|(p, _)| *p == path) {
            Some((p, text)) => Ok((p.to_string(), text.to_string())),
            None => Err(e),
        },
        r => r,
    }
}

/// The catalogue's paths, in order.
pub fn paths() -> Vec<String> {
    BUILT_IN.iter().map(|(p, _)| p.to_string()).collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_catalogue_file_is_built_in_and_sorted() {
        let mut on_disk: Vec<String> = std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/brdfs"))
            .unwrap()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "brdf"))
            .map(|p| format!("examples/brdfs/{}", p.file_name().unwrap().to_string_lossy()))
            .collect();
        on_disk.sort();
        assert_eq!(super::paths(), on_disk);
    }
}
