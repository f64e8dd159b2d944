//! Axes and ticks: linear axes with 1-2-5 steps, log axes with 1-2-5 ticks and minor grid lines, and the
//! tick labels (short exact decimals, powers of ten with superscripts).

/// An axis in plotted units: log10 of the value on a log axis.
#[derive(Clone, Debug)]
pub(super) struct Axis<'a> {
    pub(super) lo: f64,
    pub(super) hi: f64,
    pub(super) log: bool,
    pub(super) desc: &'a str,
}

/// One tick: position in plotted units, and its label if it has one (an unlabelled tick is a minor grid line).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct AxisTick {
    pub(super) at: f64,
    pub(super) label: Option<String>,
}

impl Axis<'_> {
    /// Ticks whose labels lie at least `min_px` apart on an axis `len_px` long: 1-2-5 steps on a linear axis
    /// (labels written from integers, so no 0.30000000000000004), [`log_ticks`] on a log axis.
    pub(super) fn ticks(&self, len_px: f64, min_px: f64) -> Vec<AxisTick> {
        if self.log {
            let ticks = log_ticks(self.lo, self.hi, len_px, min_px);
            // One style per axis: when some label needs a power of ten, every label is written as one.
            let powers = ticks.iter().any(|t| t.labelled && !(-4..=4).contains(&t.exp));
            let label = |t: &Tick| if powers { power_label(t) } else { tick_label(t) };
            return ticks.iter().map(|t| AxisTick { at: t.value().log10(), label: t.labelled.then(|| label(t)) }).collect();
        }
        linear_ticks(self.lo, self.hi, len_px, min_px)
    }
}

/// Labelled ticks at multiples of the smallest 1-2-5 step that keeps them `min_px` apart.
pub(super) fn linear_ticks(lo: f64, hi: f64, len_px: f64, min_px: f64) -> Vec<AxisTick> {
    let span = hi - lo;
    if !(span > 0.0 && span.is_finite() && len_px > 0.0) {
        return vec![];
    }
    let mut e = (span * min_px.max(1.0) / len_px).log10().floor() as i32 - 1;
    loop {
        for m in [1i64, 2, 5] {
            let step = m as f64 * 10f64.powi(e);
            if step * len_px / span >= min_px || e > 300 {
                let (i0, i1) = ((lo / step - 1e-9).ceil() as i64, (hi / step + 1e-9).floor() as i64);
                // One style per axis: when some label needs d.dd×10ⁿ, every label is written so.
                let sci = (i0..=i1).any(|i| decimal(i * m, e, false).contains('×'));
                return (i0..=i1).map(|i| AxisTick { at: i as f64 * step, label: Some(decimal(i * m, e, sci)) }).collect();
            }
        }
        e += 1;
    }
}

/// q·10^e written exactly: plain decimals while they stay short (at most 6 digits), d.dd×10ⁿ otherwise or
/// when `sci`; minus as U+2212.
pub(super) fn decimal(q: i64, e: i32, sci: bool) -> String {
    if q == 0 {
        return "0".into();
    }
    let (mut q, mut e) = (q, e);
    while q % 10 == 0 {
        q /= 10;
        e += 1;
    }
    let sign = if q < 0 { "−" } else { "" };
    let digits = q.unsigned_abs().to_string();
    let n = digits.len() as i32;
    let plain = if sci {
        None
    } else if e >= 0 {
        (n + e <= 6).then(|| format!("{digits}{}", "0".repeat(e as usize)))
    } else if n > -e {
        let (a, b) = digits.split_at((n + e) as usize);
        Some(format!("{a}.{b}"))
    } else {
        (-e <= 6).then(|| format!("0.{}{digits}", "0".repeat((-e - n) as usize)))
    };
    plain.map(|p| format!("{sign}{p}")).unwrap_or_else(|| {
        let mantissa = if n > 1 { format!("{}.{}", &digits[..1], &digits[1..]) } else { digits.clone() };
        format!("{sign}{mantissa}×10{}", superscript(e + n - 1))
    })
}

pub(super) fn superscript(e: i32) -> String {
    const SUP: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
    e.to_string().chars().map(|c| c.to_digit(10).map_or('⁻', |d| SUP[d as usize])).collect()
}

/// A tick of a log axis: mantissa·10^exp, labelled or a minor (unlabelled) grid line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Tick {
    pub(super) mantissa: u32,
    pub(super) exp: i32,
    pub(super) labelled: bool,
}

impl Tick {
    pub(super) fn value(&self) -> f64 {
        self.mantissa as f64 * 10f64.powi(self.exp)
    }
}

/// Ticks at 1-2-5 steps inside [lo, hi] (10^lo..10^hi in log10 units), labelled while neighbouring labels are
/// at least `min_px` apart on an axis of `len_px`; otherwise only powers of ten are labelled (2 and 5 stay as
/// minor grid lines), and for very long ranges only every k-th power.
pub(super) fn log_ticks(lo: f64, hi: f64, len_px: f64, min_px: f64) -> Vec<Tick> {
    let px_per_decade = len_px / (hi - lo).max(1e-9);
    // The closest 1-2-5 neighbours are 5→10 (log10 2 = 0.301 decades).
    let all125 = px_per_decade * 2f64.log10() >= min_px;
    let every = if all125 { 1 } else { (min_px / px_per_decade).ceil().max(1.0) as i32 };
    let mut out = Vec::new();
    for exp in (lo.floor() as i32 - 1)..=(hi.ceil() as i32) {
        for mantissa in [1u32, 2, 5] {
            let v = (mantissa as f64).log10() + exp as f64;
            if v < lo - 1e-9 || v > hi + 1e-9 {
                continue;
            }
            let labelled = if all125 { true } else { mantissa == 1 && exp.rem_euclid(every) == 0 };
            if labelled || every == 1 {
                out.push(Tick { mantissa, exp, labelled });
            }
        }
    }
    out
}

/// Plain decimals for ordinary magnitudes (0.0001 … 50000), m×10ⁿ outside.
pub(super) fn tick_label(t: &Tick) -> String {
    if (-4..=4).contains(&t.exp) {
        if t.exp >= 0 {
            (t.mantissa as u64 * 10u64.pow(t.exp as u32)).to_string()
        } else {
            format!("0.{}{}", "0".repeat((-t.exp - 1) as usize), t.mantissa)
        }
    } else {
        const SUP: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
        let e: String = t.exp.to_string().chars().map(|c| c.to_digit(10).map_or('⁻', |d| SUP[d as usize])).collect();
        if t.mantissa == 1 {
            format!("10{e}")
        } else {
            format!("{}×10{e}", t.mantissa)
        }
    }
}

/// m×10ⁿ, or 10ⁿ for m = 1, at any exponent.
pub(super) fn power_label(t: &Tick) -> String {
    if t.mantissa == 1 {
        format!("10{}", superscript(t.exp))
    } else {
        format!("{}×10{}", t.mantissa, superscript(t.exp))
    }
}

/// Three significant digits, for footnotes.
pub(super) fn short(v: f64) -> String {
    if !v.is_finite() || v == 0.0 {
        return format!("{v}");
    }
    if (1e-3..1e5).contains(&v.abs()) {
        let decimals = (2 - v.abs().log10().floor() as i32).max(0) as usize;
        format!("{v:.decimals$}")
    } else {
        format!("{v:.2e}")
    }
}
