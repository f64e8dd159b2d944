//! The shading plan: what shading one material computes, decided once per material and frame, before any
//! pixel.
//!
//! Shading evaluates I = ka·Ia·C + Σ_lights Il·(kd·NL·C + ks·coef·F·Cs). The plan is the uniform/varying split
//! of that sum for one material (what OSL's batched shading derives per shader network): the uniforms
//! (ka·Ia·C, kd·C, ks·coef·Cs, the cut-off) and which varying quantities the formula's inputs need. Every
//! cosine comes from raw dot products and three inverse lengths, never from normalised vectors:
//!
//! | step | computes, per pixel | when |
//! |---|---|---|
//! | surface | p, n interpolated; n turned to the viewer on two-sided surfaces | always |
//! | view | v = eye − p, 1/\|n\|, 1/\|v\|, NV = n·v/(\|n\|\|v\|) | always (NV: the two-sided flip, NH, VH, VR) |
//! | light (per light) | l, 1/\|l\|, NL = n·l/(\|n\|\|l\|) | always (NL > 0 decides "lit") |
//! | view·light | VL = v·l/(\|v\|\|l\|) | NH, VH or VR read |
//! | half | NH = (NL + NV)/√(2 + 2VL), VH = (1 + VL)/√(2 + 2VL) (0 where L = −V) | NH or VH read |
//! | reflect | VR = 2·NL·NV − VL (V̂·R̂ with R = 2(N̂·L̂)N̂ − L̂) | VR read |
//! | frame | tangent t interpolated with n; T̂ = norm(t − N̂(N̂·t)), B̂ = N̂ × T̂, turned by the material's tangent angle; Vx = V̂·T̂, Vy = V̂·B̂ (Vz = NV) | a direction component read |
//! | light frame (per light) | Lx = L̂·T̂, Ly = L̂·B̂ (Lz = NL), inside the light loop | a direction component read |
//! | kernel | F on the lit pixels (NL > 0, and the lobe cosine above the cut-off), one batch per channel | ks ≠ 0 |
//! | colour | I_c += Il_c·(kd·C_c·max(NL, 0) + ks·coef_c·Cs_c·F_c), F non-finite → 0 and counted; F·NL with `times_nl` | always |
//!
//! The cosines reach the kernel unclamped: clamping them to [0, 1] is the formula's domain policy, which
//! the front end writes into its IR, so every backend applies it identically.
//!
//! A formula that reads directions in the local frame (L, V, N, X, Y, as BRDF Explorer's `BRDF(L, V, N, X, Y)`)
//! gets the two frame steps; a cosine formula never runs them, so it pays nothing for tangent frames. A
//! colour formula (`Formula.rgb`) has one F per channel, its three channels sharing their common nodes; a
//! scalar formula's F serves all three channels. Energy normalisation (`coef`) is per channel too.
//!
//! The steps are written once, as the material's shading program ([`super::program`], built from this plan
//! by [`super::program::spec`]): one lobe IR with the formula inlined and the steps after interpolation as IR
//! nodes, run by the interpreter or compiled by the JIT. Inverse lengths are exact `1/sqrt`; the kernel row
//! is a guarded region per light (F only where some lane is lit; no compaction), F non-finite → 0 and
//! counted.
//!
//! Cost model: per visible pixel ~25 flops (surface) + ~20 and two square roots (view); per lit pixel and
//! light ~15 flops and one square root (light), 5 (view·light), 6 and one root (half), 3 (reflect), the
//! kernel, 9 (colour). Directions add ~9 flops per pixel (tangent
//! interpolation), ~40 and one root (frame) and ~12 per light; colour adds F's two other channels.
//! Measured split: BENCHMARKS.md.

use super::Material;
use crate::backend::Evaluator;
use crate::ir::{Input, InputSet, N_INPUTS};

/// The papers' cut-off for one material: F is not evaluated where the lobe cosine (`input`) is below `cos`,
/// because beyond that angle the lobe stays below 2^−q (the papers' lobe-size metric uses the same level).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cutoff {
    pub q: f64,
    /// The lobe cosine: NH or VR.
    pub input: Input,
    /// Cosine of the cut-off angle: the kernel is skipped where `input < cos`.
    pub cos: f64,
}

/// Angular resolution of the cut-off search, degrees.
const CUTOFF_STEP_DEG: f64 = 0.01;

impl Cutoff {
    /// Finds the cut-off angle of a formula of one lobe cosine (NH or VR): the smallest angle θ from the lobe's
    /// axis such that F(cos θ') < 2^−q at every sampled θ' ≥ θ (0.01° steps up to 90°; a NaN counts as "not
    /// below", so a defect is never cut away). Costs 9 001 scalar evaluations, once per material.
    pub(crate) fn find(ev: &dyn Evaluator, used: InputSet, params: &[f64], q: f64) -> Result<Cutoff, String> {
        if !(q > 0.0 && q <= 1000.0) {
            return Err(format!("cutoff = {q} is not a usable exponent q (the lobe is cut where F < 2^-q); use q in (0, 1000], e.g. 8"));
        }
        let lobe: Vec<Input> = used.iter().collect();
        let input = match lobe.as_slice() {
            [i @ (Input::NH | Input::VR)] => *i,
            _ => {
                let names: Vec<&str> = lobe.iter().map(|i| i.name()).collect();
                return Err(format!(
                    "cutoff needs a formula of one lobe cosine (NH or VR, as the papers' models are); this one reads {}",
                    if names.is_empty() { "no input".to_string() } else { names.join(", ") }
                ));
            }
        };
        let level = (-q).exp2();
        let steps = (90.0 / CUTOFF_STEP_DEG).round() as usize;
        let mut x = [0.0; N_INPUTS];
        // Scan from the axis outwards; remember the last sample at or above the level.
        let mut last_above: Option<usize> = None;
        for s in 0..=steps {
            x[input.index()] = (s as f64 * CUTOFF_STEP_DEG).to_radians().cos();
            let f = ev.eval(&x, params);
            if f.is_nan() || f >= level {
                last_above = Some(s);
            }
        }
        let cos = match last_above {
            None => f64::INFINITY,
            Some(s) if s == steps => f64::NEG_INFINITY,
            Some(s) => ((s + 1) as f64 * CUTOFF_STEP_DEG).to_radians().cos(),
        };
        Ok(Cutoff { q, input, cos })
    }

    /// The cut-off angle in degrees (0 when everything is cut, 90+ when nothing is).
    pub fn angle_deg(&self) -> f64 {
        if self.cos == f64::NEG_INFINITY {
            f64::INFINITY
        } else {
            self.cos.clamp(-1.0, 1.0).acos().to_degrees()
        }
    }
}

/// What shading one material computes (see the module doc for the step table).
#[derive(Clone, Debug, PartialEq)]
pub struct ShadingPlan {
    /// The reflect step (VR read); the program decides the view·light and half-vector steps from the inputs
    /// its formulas read.
    pub reflect: bool,
    /// The frame steps (a direction component read).
    pub directions: bool,
    /// (cos, sin) of the material's tangent angle: T and B are turned by it about N.
    pub tangent_rotation: [f64; 2],
    /// F is multiplied by NL (the material's `times_nl`), applied when F is scattered back.
    pub times_nl: bool,
    /// The kernel runs at all (ks ≠ 0).
    pub specular: bool,
    /// The cut-off, if the material has one and the render applies it.
    pub cutoff: Option<Cutoff>,
    /// ka·Ia·C: every visible pixel starts here.
    pub ambient: [f64; 3],
    /// kd·C, multiplied by NL.
    pub diffuse: [f64; 3],
    /// ks·coef·Cs, multiplied by F (per channel).
    pub spec: [f64; 3],
}

impl ShadingPlan {
    /// The plan for `m` under a scene's ambient light; `cutoff` = false ignores the material's cut-off.
    pub fn new(m: &Material, ambient: glam::DVec3, cutoff: bool) -> ShadingPlan {
        let r = m.used;
        let spec = m.specular * m.coef * m.ks;
        let (s, c) = m.tangent_angle_deg.to_radians().sin_cos();
        ShadingPlan {
            reflect: r.contains(Input::VR),
            directions: r.reads_directions(),
            tangent_rotation: [c, s],
            times_nl: m.times_nl,
            specular: m.ks != 0.0,
            cutoff: if cutoff { m.cutoff } else { None },
            ambient: (ambient * m.color * m.ka).to_array(),
            diffuse: (m.color * m.kd).to_array(),
            spec: spec.to_array(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::FnEvaluator;

    fn set(inputs: &[Input]) -> InputSet {
        let mut s = InputSet::default();
        for i in inputs {
            s.insert(*i);
        }
        s
    }

    #[test]
    fn cutoff_of_a_cosine_power_is_the_papers_angle() {
        // cos^n < 2^-q beyond acos(2^(-q/n)) (the papers' lobe size of Blinn/Phong).
        let f = FnEvaluator(|x: &[f64; N_INPUTS], p: &[f64]| x[2].clamp(0.0, 1.0).powf(p[0]));
        let c = Cutoff::find(&f, set(&[Input::NH]), &[50.0], 8.0).unwrap();
        let exact = (-8.0f64 / 50.0).exp2().acos().to_degrees();
        assert!(c.angle_deg() > exact && c.angle_deg() <= exact + 2.0 * CUTOFF_STEP_DEG, "{} vs {exact}", c.angle_deg());
        assert_eq!(c.input, Input::NH);
        // Never below the level: nothing is cut. Always below: everything is.
        let one = FnEvaluator(|_: &[f64; N_INPUTS], _: &[f64]| 1.0);
        assert_eq!(Cutoff::find(&one, set(&[Input::VR]), &[], 8.0).unwrap().cos, f64::NEG_INFINITY);
        let zero = FnEvaluator(|_: &[f64; N_INPUTS], _: &[f64]| 0.0);
        assert_eq!(Cutoff::find(&zero, set(&[Input::VR]), &[], 8.0).unwrap().cos, f64::INFINITY);
        // A NaN far from the axis is not cut away.
        let nan = FnEvaluator(|x: &[f64; N_INPUTS], _: &[f64]| if x[3] < 0.1 { f64::NAN } else { x[3].powi(50) });
        assert_eq!(Cutoff::find(&nan, set(&[Input::VR]), &[], 8.0).unwrap().cos, f64::NEG_INFINITY);
    }

    #[test]
    fn cutoff_refuses_formulas_of_several_cosines_and_bad_q() {
        let f = FnEvaluator(|_: &[f64; N_INPUTS], _: &[f64]| 1.0);
        let e = Cutoff::find(&f, set(&[Input::NH, Input::NL]), &[], 8.0).unwrap_err();
        assert!(e.contains("reads NL, NH"), "{e}");
        assert!(Cutoff::find(&f, set(&[Input::NH]), &[], 0.0).is_err());
        assert!(Cutoff::find(&f, set(&[Input::NH]), &[], f64::NAN).is_err());
    }
}
