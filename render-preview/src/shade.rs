//! Headlight shading shared by the splat renderer and the mesh reference: Lambert plus
//! ambient, computed in linear light, two-sided (|n·l|) so that meshes and point sets with
//! inconsistently oriented normals still look right.

use std::sync::OnceLock;

/// How colours are lit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Shading {
    /// Ambient + Lambert from a light at the eye.
    #[default]
    Lambert,
    /// The stored colour, unlit.
    Flat,
}

/// Fraction of light that is ambient.
pub const AMBIENT: f32 = 0.25;

/// sRGB 8-bit → linear.
pub fn srgb_to_linear_lut() -> &'static [f32; 256] {
    static LUT: OnceLock<[f32; 256]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = [0.0; 256];
        for (i, v) in t.iter_mut().enumerate() {
            let c = i as f32 / 255.0;
            *v = if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) };
        }
        t
    })
}

const ENC: usize = 4096;

/// Linear [0, 1] → sRGB 8-bit (table lookup).
#[inline]
pub fn linear_to_srgb8(c: f32) -> u8 {
    static LUT: OnceLock<Vec<u8>> = OnceLock::new();
    let lut = LUT.get_or_init(|| {
        (0..=ENC)
            .map(|i| {
                let c = i as f32 / ENC as f32;
                let s = if c <= 0.0031308 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
                (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
            })
            .collect()
    });
    let i = (c.clamp(0.0, 1.0) * ENC as f32 + 0.5) as usize;
    lut[i.min(ENC)]
}

/// Light factor for a unit normal and unit direction to the light.
#[inline]
pub fn lambert(n: [f32; 3], l: [f32; 3]) -> f32 {
    let d = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).abs().min(1.0);
    AMBIENT + (1.0 - AMBIENT) * d
}

/// Lights an sRGB colour by `k` (linear factor); alpha is kept.
#[inline]
pub fn apply(color: [u8; 4], k: f32) -> [u8; 4] {
    let lut = srgb_to_linear_lut();
    [
        linear_to_srgb8(lut[color[0] as usize] * k),
        linear_to_srgb8(lut[color[1] as usize] * k),
        linear_to_srgb8(lut[color[2] as usize] * k),
        color[3],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip() {
        let lut = srgb_to_linear_lut();
        for i in 0..=255u8 {
            assert!((linear_to_srgb8(lut[i as usize]) as i32 - i as i32).abs() <= 1, "{i}");
        }
    }

    #[test]
    fn lambert_is_two_sided_with_ambient_floor() {
        assert!((lambert([0.0, 0.0, 1.0], [0.0, 0.0, 1.0]) - 1.0).abs() < 1e-6);
        assert!((lambert([0.0, 0.0, -1.0], [0.0, 0.0, 1.0]) - 1.0).abs() < 1e-6);
        assert!((lambert([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]) - AMBIENT).abs() < 1e-6);
    }
}
