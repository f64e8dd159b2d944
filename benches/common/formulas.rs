//! The benched formulas: which catalogue files the benches time, under which criterion id, and a fasteval
//! spelling of each (bench-only: fasteval cannot read .brdf files), with the few lines that compile and
//! evaluate both. Included by `benches/common/mod.rs` and by `tests/it/benched.rs`, which asserts that every
//! stem is a file `examples/brdfs/<stem>.brdf` and that every spelling evaluates to the compiled file.
#![allow(dead_code)]

use lobe::{Backend, Kernel, Options, N_INPUTS};
use std::path::PathBuf;

/// One benched formula.
pub struct Benched {
    /// The catalogue file `examples/brdfs/<stem>.brdf`.
    pub stem: &'static str,
    /// Criterion's group suffix (`eval/<id>`, `compile/<id>`): the names saved baselines are filed under.
    pub id: &'static str,
    /// The same function for fasteval: variables are the inputs (`NL` … `VH`) and the file's parameters. No
    /// input clamps or outer `max(…, 0)` (the benched inputs are cosines in [0, 1], where they change nothing),
    /// but every `max(…, 0)` the file writes.
    pub fasteval: &'static str,
}

const fn row(stem: &'static str, id: &'static str, fasteval: &'static str) -> Benched {
    Benched { stem, id, fasteval }
}

pub const BENCHED: &[Benched] = &[
    row("phong", "phong", "VR^n"),
    row("blinn", "blinn", "NH^n"),
    row("schlick", "schlick", "NH / (n - n*NH + NH)"),
    row("modified_schlick", "modified_schlick", "2*NH / (1.25*(n - n*NH + 1.25*NH)^2)"),
    row("scos2", "scos2", "max((-1.1/(-n + n*NH - 2*NH))*n*(NH - 1) + 1, 0)^2"),
    row("fst", "f_st", "max(n/a*(NH - 1) + 1, 0)^a"),
    row("gaussian", "gaussian", "e()^(-n*acos(NH)^2/2)"),
];

impl Benched {
    pub fn path(&self) -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/brdfs").join(format!("{}.brdf", self.stem))
    }

    /// The catalogue file's text.
    pub fn source(&self) -> String {
        let path = self.path();
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    }

    /// The catalogue file compiled by `lobe::compile_source`, as shipped.
    pub fn kernel(&self, backend: Backend) -> Kernel {
        self.kernel_in(backend, lobe::Mode::Precise)
    }

    /// [`Self::kernel`] in math mode `math`.
    pub fn kernel_in(&self, backend: Backend, math: lobe::Mode) -> Kernel {
        let opts = Options { backend, math, ..Options::default() };
        lobe::compile_source(&self.path().display().to_string(), &self.source(), &opts)
            .unwrap_or_else(|d| panic!("{}", d.render(false)))
    }

    /// The fasteval spelling, compiled.
    pub fn fasteval(&self) -> Result<(fasteval::Slab, fasteval::Instruction), fasteval::Error> {
        use fasteval::Compiler;
        let mut slab = fasteval::Slab::new();
        let parsed = fasteval::Parser::new().parse(self.fasteval, &mut slab.ps)?;
        let compiled = parsed.from(&slab.ps).compile(&slab.ps, &mut slab.cs);
        Ok((slab, compiled))
    }
}

/// A fasteval variable's value at `x` with `params` of `kernel`: an input by name, or a parameter.
pub fn fasteval_var(name: &str, x: &[f64; N_INPUTS], kernel: &Kernel, params: &[f64]) -> Option<f64> {
    match lobe::Input::from_name(name) {
        Some(i) => Some(x[i.index()]),
        None => kernel.formula.params.iter().position(|p| p.name == name).and_then(|k| params.get(k).copied()),
    }
}
