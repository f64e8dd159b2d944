//! The eval command's JSON report: the value at one point, or the values at every point of a CSV, with what produced
//! them (keys listed in docs/commands.md; numbers follow [`crate::base::json`]).

use crate::base::json;
use crate::Kernel;
use serde::Serialize;

/// One point's value: a number for a scalar formula, `[r, g, b]` for a colour one.
#[derive(Clone, Debug, PartialEq)]
pub struct PointValue(pub Vec<f64>);

impl Serialize for PointValue {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeSeq;
        match self.0.as_slice() {
            [one] => json::num(one, s),
            all => {
                let mut seq = s.serialize_seq(Some(all.len()))?;
                for v in all {
                    seq.serialize_element(&Num(*v))?;
                }
                seq.end()
            }
        }
    }
}

/// An `f64` serialised under [`crate::base::json`]'s rule.
struct Num(f64);

impl Serialize for Num {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        json::num(&self.0, s)
    }
}

/// The kernels' compile time, summed over channels, in µs.
fn compile_us(ks: &[Kernel]) -> f64 {
    ks.iter().map(|k| k.compile_time.as_secs_f64()).sum::<f64>() * 1e6
}

/// The LLVM tier's lanes when `ks` ran on LLVM.
fn lanes(ks: &[Kernel]) -> Option<u32> {
    if ks[0].backend_used() == crate::Backend::Llvm {
        crate::Tier::llvm_lanes()
    } else {
        None
    }
}

/// `lobe eval` at one point.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    pub value: PointValue,
    pub backend: &'static str,
    /// The LLVM tier's lanes (absent for the other backends).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lanes: Option<u32>,
    #[serde(serialize_with = "json::num")]
    pub compile_us: f64,
    /// Set when a direction was normalised.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

impl EvalReport {
    /// `value` from the channel kernels `ks`.
    pub fn new(ks: &[Kernel], value: Vec<f64>, note: Option<String>) -> EvalReport {
        EvalReport { value: PointValue(value), backend: ks[0].backend_used().name(), lanes: lanes(ks), compile_us: compile_us(ks), note }
    }

    /// The report of a value that is the ground truth: backend `truth`, nothing compiled.
    pub fn truth(self) -> EvalReport {
        EvalReport { backend: TRUTH, lanes: None, compile_us: 0.0, ..self }
    }
}

/// The backend name of values that are the ground truth ([`crate::numerics::truth`]).
const TRUTH: &str = "truth";

/// How the values at many points were timed.
#[derive(Clone, Copy, Debug)]
pub enum PointsTiming {
    /// The steady state of the batched kernels (wall and thread CPU time, [`crate::report::measure::steady_state`]).
    Steady(crate::report::measure::Steady),
    /// The one pass that computed the values, ns per point of wall time (NaN: not timed).
    OnePass(f64),
}

/// The eval command's JSON report for many points.
#[derive(Clone, Debug, Serialize)]
pub struct PointsReport {
    pub values: Vec<PointValue>,
    pub points: usize,
    pub backend: &'static str,
    /// The LLVM tier's lanes (absent for the other backends).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lanes: Option<u32>,
    pub math: &'static str,
    #[serde(serialize_with = "json::num")]
    pub compile_us: f64,
    /// ns per point of evaluating every channel over the points in the steady state (kernels compiled and
    /// warm, output written before): the median of repeated passes, wall time; for the truth, its one pass.
    #[serde(serialize_with = "json::num")]
    pub eval_ns_per_point: f64,
    /// The same passes in this thread's CPU time (the batched kernels run on it), which a shared machine does
    /// not inflate (absent for the truth, which runs on every thread).
    #[serde(skip_serializing_if = "Option::is_none", serialize_with = "json::opt_num")]
    pub eval_cpu_ns_per_point: Option<f64>,
    /// Set when rows had a non-unit L or V.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

impl PointsReport {
    /// `values` per point from the channel kernels `ks`, timed as `timing` says.
    pub fn new(ks: &[Kernel], values: Vec<PointValue>, timing: PointsTiming, note: Option<String>) -> PointsReport {
        let points = values.len();
        let (eval_ns_per_point, eval_cpu_ns_per_point) = match timing {
            PointsTiming::Steady(s) => (s.wall.median_ns, Some(s.cpu.median_ns)),
            PointsTiming::OnePass(ns) => (ns, None),
        };
        PointsReport {
            values,
            points,
            backend: ks[0].backend_used().name(),
            lanes: lanes(ks),
            math: ks[0].math.name(),
            compile_us: compile_us(ks),
            eval_ns_per_point,
            eval_cpu_ns_per_point,
            note,
        }
    }

    /// The report of values that are the ground truth: backend and math `truth`, nothing compiled.
    pub fn truth(self) -> PointsReport {
        PointsReport { backend: TRUTH, math: TRUTH, lanes: None, compile_us: 0.0, ..self }
    }
}

/// Entries in order, serialised as a JSON object (name → value).
#[derive(Clone, Debug, PartialEq)]
pub struct Named<T>(pub Vec<(String, T)>);

impl<T: Serialize> Serialize for Named<T> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, v)?;
        }
        m.end()
    }
}

/// The eval command's gradient at one point: the value and each partial derivative (name → value; `[r, g, b]` for a
/// colour formula).
#[derive(Clone, Debug, Serialize)]
pub struct GradReport {
    pub value: PointValue,
    pub grad: Named<PointValue>,
    pub backend: &'static str,
    pub math: &'static str,
    /// Compiling the value-and-gradient programs (accuracy pass included), µs.
    #[serde(serialize_with = "json::num")]
    pub compile_us: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The eval command's gradient at many points: the values and, per partial, the list of its values (name → list).
#[derive(Clone, Debug, Serialize)]
pub struct GradPointsReport {
    pub values: Vec<PointValue>,
    pub grad: Named<Vec<PointValue>>,
    pub points: usize,
    pub backend: &'static str,
    pub math: &'static str,
    #[serde(serialize_with = "json::num")]
    pub compile_us: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_is_a_number_or_a_triple_under_the_json_rule() {
        assert_eq!(serde_json::to_string(&PointValue(vec![0.25])).unwrap(), "0.25");
        assert_eq!(serde_json::to_string(&PointValue(vec![f64::INFINITY])).unwrap(), r#""inf""#);
        assert_eq!(serde_json::to_string(&PointValue(vec![0.5, 1.0, f64::NAN])).unwrap(), r#"[0.5,1.0,"NaN"]"#);
        let g = Named(vec![("n".to_string(), PointValue(vec![1.0])), ("NH".to_string(), PointValue(vec![-0.5]))]);
        assert_eq!(serde_json::to_string(&g).unwrap(), r#"{"n":1.0,"NH":-0.5}"#);
    }
}
