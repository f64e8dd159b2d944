//! Colour transfer: how the renderer's linear radiance becomes 8-bit values. The image type and its PNG
//! encoding are [`crate::base::image`] (report and serve write PNGs too); re-exported here for the renderer.
//!
//! The renderer accumulates linear RGB in f64. The papers' program clamps each channel to 0..1 and scales to
//! 0..255 with no gamma curve, so that is the default ([`Transfer::Linear`]) and what the comparison metrics
//! are computed on; [`Transfer::Srgb`] applies the sRGB transfer curve instead, which is what a physically based
//! pipeline would display. NaN channels become 0.

pub use crate::base::image::{is_lobe_png, Image};

/// How linear radiance becomes an 8-bit value.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Transfer {
    /// clamp(c, 0, 1)·255, rounded — the papers' convention.
    #[default]
    Linear,
    /// The sRGB curve (IEC 61966-2-1) after clamping.
    Srgb,
}

impl Transfer {
    pub fn encode(self, c: f64) -> u8 {
        let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
        let c = match self {
            Transfer::Linear => c,
            Transfer::Srgb if c <= 0.003_130_8 => 12.92 * c,
            Transfer::Srgb => 1.055 * c.powf(1.0 / 2.4) - 0.055,
        };
        // c·255 + 0.5 truncated is round-half-up for c ≥ 0, and, unlike `round`, needs no libm call on the
        // baseline x86-64 target (no SSE4.1): this runs three times per pixel.
        (c * 255.0 + 0.5) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transfer_matches_definitions() {
        // c·255 + 0.5 truncated rounds half up, like `round` on these values.
        for k in 0..=2550 {
            let c = k as f64 / 2550.0;
            assert_eq!(Transfer::Linear.encode(c), (c * 255.0).round() as u8, "{c}");
        }
        assert_eq!(Transfer::Linear.encode(0.5), 128);
        assert_eq!(Transfer::Linear.encode(2.0), 255);
        assert_eq!(Transfer::Linear.encode(f64::NAN), 0);
        assert_eq!(Transfer::Linear.encode(-1.0), 0);
        // sRGB of linear 0.5 is 0.7354 → 188.
        assert_eq!(Transfer::Srgb.encode(0.5), 188);
        assert_eq!(Transfer::Srgb.encode(1.0), 255);
    }
}
