//! The front end: .brdf text → [`Formula`](crate::ir::Formula), or diagnostics. Knows nothing of backends.

pub mod diag;
pub mod span;

use crate::ir::Formula;
use diag::{Diagnostic, Diagnostics};

/// Parses and lowers one .brdf source file.
pub fn parse(file: &str, _src: &str) -> Result<Formula, Diagnostics> {
    Err(Diagnostics::single(file, Diagnostic::error("the parser is not built yet")))
}

/// The closest candidate by edit distance, if close enough to be a plausible typo.
pub fn suggest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let lname = name.to_lowercase();
    candidates
        .into_iter()
        .map(|c| (levenshtein(&lname, &c.to_lowercase()), c))
        .filter(|(d, c)| *d <= (c.len().max(name.len()) / 3).max(1))
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

fn levenshtein(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1];
        for (j, cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != *cb);
            cur.push(sub.min(prev[j + 1] + 1).min(cur[j] + 1));
        }
        prev = cur;
    }
    prev[b.len()]
}

#[cfg(test)]
mod tests {
    #[test]
    fn suggests_close_names() {
        assert_eq!(super::suggest("NX", ["NL", "NV", "NH", "VR"]), Some("NL"));
        assert_eq!(super::suggest("acoss", ["acos", "cos"]), Some("acos"));
        assert_eq!(super::suggest("zzzzzz", ["acos", "cos"]), None);
    }
}
