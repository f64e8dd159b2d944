//! The accuracy pass's decisions on disk, so the second command on the same formula pays nothing.
//!
//! # Design
//! The search measures candidates against the truth (tens of milliseconds to seconds); its result is a short
//! [`Decision`] — the kept steps — that rebuilds the chosen formula without measuring ([`super::robust::replay`]).
//! One file per key, in the platform cache directory: the key is the formula (its program text and parameter
//! declarations), the baked values (bits), the pass options that change the choice, the registry's rule names
//! in its order (a rule added, removed or moved is a miss), lobe's version and [`PASS_VERSION`]; the file name
//! is a 128-bit FNV-1a hash of the key and the file holds the key itself, so a collision or a file from another
//! version reads as a miss. A file that does not parse is a miss; writes go to a temporary file renamed into
//! place, so concurrent commands never read half a file. Any I/O error is a miss or a skipped store: the cache
//! never makes a command fail.

use super::robust::{Decision, DecisionStore, PassOptions, Step};
use crate::ir::Formula;
use crate::simplify::accuracy::{rule, RULES};
use std::path::PathBuf;

/// Bumped whenever the pass's choices may change for the same inputs and the same registry (the key holds the
/// rules' names): the search, or the bits of the math library it measures with (3, exp's 16-row table; 4, sin
/// of a bounded argument without reduction; 5, the baked pass always keeps the live choice; 7, no second round
/// of rules applied everywhere).
pub(crate) const PASS_VERSION: u32 = 7;

/// A cache directory.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cache {
    dir: PathBuf,
}

impl Cache {
    /// The cache in `dir` (created on the first store).
    pub fn at(dir: impl Into<PathBuf>) -> Cache {
        Cache { dir: dir.into() }
    }

    /// `$LOBE_CACHE_DIR`, else the platform's cache directory: `$XDG_CACHE_HOME/lobe` or `~/.cache/lobe` on
    /// Linux and other Unix, `~/Library/Caches/lobe` on macOS, `%LOCALAPPDATA%\lobe` on Windows. `None` when
    /// none is known.
    pub fn platform() -> Option<Cache> {
        let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from);
        if let Some(d) = var("LOBE_CACHE_DIR") {
            return Some(Cache::at(d));
        }
        let base = if cfg!(windows) {
            var("LOCALAPPDATA")
        } else if cfg!(target_os = "macos") {
            var("HOME").map(|h| h.join("Library/Caches"))
        } else {
            var("XDG_CACHE_HOME").or_else(|| var("HOME").map(|h| h.join(".cache")))
        };
        base.map(|b| Cache::at(b.join("lobe")))
    }

    fn key(f: &Formula, bake: &[(usize, f64)], o: &PassOptions) -> String {
        let mut k = format!(
            "lobe {} pass {PASS_VERSION}\nprefer {:?} max-cost {:x} points {} seed {:x} math {}\n",
            env!("CARGO_PKG_VERSION"),
            o.prefer,
            o.max_cost.to_bits(),
            o.points,
            o.seed,
            o.math.name()
        );
        k += "rules";
        for r in RULES {
            k += &format!(" {}", r.name());
        }
        k += "\n";
        for d in &f.params {
            k += &format!("param {} {:?} {:x} {:x} {:x}\n", d.name, d.kind, d.default.to_bits(), d.lo.to_bits(), d.hi.to_bits());
        }
        let mut bake = bake.to_vec();
        bake.sort_by_key(|(i, _)| *i);
        for (i, v) in bake {
            k += &format!("bake {i} {:x}\n", v.to_bits());
        }
        k + &f.to_program_text()
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{:032x}.pass", fnv1a128(key.as_bytes())))
    }

}

/// Compile options with the accuracy pass as the commands run it: its search bounded by
/// [`super::robust::COMMAND_BUDGET`], its decisions read from and stored in the platform cache when `cached`
/// and there is a cache directory.
pub fn command_pass(opts: crate::Options, pass: PassOptions, cached: bool) -> crate::Options {
    command_pass_until(opts, pass, cached, crate::base::cancel::Cancel::never())
}

/// [`command_pass`] whose searches also stop when `cancel` trips (the server's request deadline).
pub(crate) fn command_pass_until(opts: crate::Options, pass: PassOptions, cached: bool, cancel: crate::base::cancel::Cancel) -> crate::Options {
    let pass = PassOptions { budget: super::robust::COMMAND_BUDGET, ..pass };
    super::robust::with_pass_until(opts, pass, platform_store(cached), cancel)
}

/// The platform cache ([`Cache::platform`]) as a decision store, when `cached` and there is a cache directory.
pub fn platform_store(cached: bool) -> Option<std::sync::Arc<dyn DecisionStore>> {
    cached.then(Cache::platform).flatten().map(|c| std::sync::Arc::new(c) as std::sync::Arc<dyn DecisionStore>)
}

/// A formula's kernels as the commands compile them (`eval`, and the Python binding, which must give the same
/// bits): one per channel (red, green, blue for a colour formula), `bake` baked, through the accuracy pass of
/// [`command_pass`] at `pass` (its math taken from `math`).
pub fn command_channels(
    f: &Formula,
    bake: &[(String, f64)],
    backend: crate::Backend,
    math: crate::Mode,
    pass: PassOptions,
    cached: bool,
) -> Result<Vec<crate::Kernel>, crate::Diagnostics> {
    let opts = crate::Options { backend, bake: bake.to_vec(), math, ..crate::Options::default() };
    let opts = command_pass(opts, pass, cached);
    f.channels().into_iter().map(|c| crate::compile_formula(c, &opts)).collect()
}

/// Largest cache entry read: a key (the formula's text and options) and a decision are far smaller.
const MAX_ENTRY_BYTES: u64 = 16 << 20;

impl DecisionStore for Cache {
    /// The stored decision for this formula, baked values and options, if any.
    fn load(&self, f: &Formula, bake: &[(usize, f64)], o: &PassOptions) -> Option<Decision> {
        let key = Cache::key(f, bake, o);
        // Only a regular file of bounded size, opened without blocking: a FIFO, a device or a huge file at an
        // entry's path is a miss, not a hang or a read of gigabytes.
        let bytes = crate::base::source::read_regular_file(&self.path(&key), MAX_ENTRY_BYTES).ok()?;
        let text = String::from_utf8(bytes).ok()?;
        let (head, body) = text.split_once("\n--\n")?;
        (head == key).then(|| parse(body)).flatten()
    }

    /// Stores a decision (errors ignored: a later command searches again).
    fn store(&self, f: &Formula, bake: &[(usize, f64)], o: &PassOptions, d: &Decision) {
        let key = Cache::key(f, bake, o);
        let path = self.path(&key);
        let tmp = path.with_extension(format!("tmp{}", std::process::id()));
        let text = format!("{key}\n--\n{}", render(d));
        if std::fs::create_dir_all(&self.dir).is_ok() && std::fs::write(&tmp, text).is_ok() && std::fs::rename(&tmp, &path).is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
    }
}

fn fnv1a128(bytes: &[u8]) -> u128 {
    let mut h: u128 = 0x6c62272e07bb014262b821756295c58d;
    for &b in bytes {
        h ^= u128::from(b);
        h = h.wrapping_mul(0x0000000001000000000000000000013B);
    }
    h
}


fn render(d: &Decision) -> String {
    let mut s = String::new();
    for st in &d.live {
        s += &format!("live {} {}\n", st.rule.name(), st.site.map_or("-".to_string(), |k| k.to_string()));
    }
    s += &format!("baked-live-choice {}\n", u8::from(d.baked_live_choice));
    s += &format!("baked-power {}\n", d.baked_power.map_or("-", |r| r.name()));
    s
}

fn parse(body: &str) -> Option<Decision> {
    let mut d = Decision::default();
    let (mut choice, mut power) = (false, false);
    for line in body.lines() {
        let w: Vec<&str> = line.split(' ').collect();
        match w.as_slice() {
            ["live", c, site] => {
                let site = if *site == "-" { None } else { Some(site.parse().ok()?) };
                d.live.push(Step { rule: rule(c)?, site });
            }
            ["baked-live-choice", v] => {
                d.baked_live_choice = *v == "1";
                choice = true;
            }
            ["baked-power", c] => {
                d.baked_power = if *c == "-" { None } else { Some(rule(c)?) };
                power = true;
            }
            _ => return None,
        }
    }
    (choice && power).then_some(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decisions_round_trip_and_bad_files_are_misses() {
        let d = Decision {
            live: vec![Step { rule: rule("compensated-params").unwrap(), site: None }, Step { rule: rule("quotient-chain").unwrap(), site: Some(2) }],
            baked_live_choice: true,
            baked_power: rule("compensated-power"),
        };
        assert_eq!(parse(&render(&d)), Some(d));
        assert_eq!(parse("live no-such-rule -\nbaked-live-choice 0\nbaked-power -\n"), None);
        assert_eq!(parse("live quotient-chain x\nbaked-live-choice 0\nbaked-power -\n"), None);
        assert_eq!(parse("baked-live-choice 0\n"), None);
    }

    #[test]
    fn a_stored_decision_is_found_only_under_its_key() {
        let dir = std::env::temp_dir().join(format!("lobe-cache-test-{}", std::process::id()));
        let c = Cache::at(&dir);
        let f = crate::front::parse("t.brdf", "param a = 2 in 1..10\nNH^a").unwrap();
        let o = PassOptions::default();
        let d = Decision { live: vec![Step { rule: rule("pow-call").unwrap(), site: None }], ..Decision::default() };
        assert_eq!(c.load(&f, &[], &o), None);
        c.store(&f, &[], &o, &d);
        assert_eq!(c.load(&f, &[], &o), Some(d.clone()));
        assert_eq!(c.load(&f, &[(0, 3.0)], &o), None, "other baked values");
        assert_eq!(c.load(&f, &[], &PassOptions { max_cost: 2.0, ..o }), None, "other options");
        // The registry is part of the key: a rule added, removed or moved is a miss.
        let key = Cache::key(&f, &[], &o);
        assert!(RULES.iter().all(|r| key.contains(&format!(" {}", r.name()))), "{key}");
        // A damaged file is a miss, not an error.
        let path = c.path(&Cache::key(&f, &[], &o));
        std::fs::write(&path, "garbage").unwrap();
        assert_eq!(c.load(&f, &[], &o), None);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
