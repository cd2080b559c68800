//! Colour-map presets for transfer functions made without a scene file (`--colormap NAME`).
//!
//! Each is a list of evenly spaced sRGB control colours, linearised and interpolated in linear
//! RGB (the renderer's albedo space). Sources and licences:
//! - `viridis`, `inferno`: Nathaniel Smith and Stéfan van der Walt's maps for matplotlib,
//!   released to the public domain (CC0); the ten-step colours published with them.
//! - `cool-to-warm`: Kenneth Moreland's diverging map ("Diverging Color Maps for Scientific
//!   Visualization", 2009), ParaView's default, free to use; its five published control points.
//! - `bone`: a warm off-white ramp made for this project (CT and MRI), public domain.
//! - `grayscale`: black to white.
//!
//! Albedo is colour times single-scattering albedo, so a map's dark end absorbs light: `bone`,
//! the default, stays light enough that dense tissue scatters rather than swallows.

use glam::Vec3;

/// A named colour map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Colormap {
    #[default]
    Bone,
    Viridis,
    Inferno,
    CoolToWarm,
    Grayscale,
}

impl std::fmt::Display for Colormap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Colormap::Bone => "bone",
            Colormap::Viridis => "viridis",
            Colormap::Inferno => "inferno",
            Colormap::CoolToWarm => "cool-to-warm",
            Colormap::Grayscale => "grayscale",
        })
    }
}

impl std::str::FromStr for Colormap {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Colormap::ALL
            .into_iter()
            .find(|c| c.to_string().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| {
                let names: Vec<String> = Colormap::ALL.iter().map(|c| c.to_string()).collect();
                format!("colour map `{s}`: expected one of {}", names.join(", "))
            })
    }
}

/// sRGB control colours, 0-255, evenly spaced over [0, 1].
const VIRIDIS: [[u8; 3]; 10] = [
    [0x44, 0x01, 0x54],
    [0x48, 0x28, 0x78],
    [0x3e, 0x4a, 0x89],
    [0x31, 0x68, 0x8e],
    [0x26, 0x82, 0x8e],
    [0x1f, 0x9e, 0x89],
    [0x35, 0xb7, 0x79],
    [0x6d, 0xcd, 0x59],
    [0xb4, 0xde, 0x2c],
    [0xfd, 0xe7, 0x25],
];
const INFERNO: [[u8; 3]; 10] = [
    [0x00, 0x00, 0x04],
    [0x1b, 0x0c, 0x41],
    [0x4a, 0x0c, 0x6b],
    [0x78, 0x1c, 0x6d],
    [0xa5, 0x2c, 0x60],
    [0xcf, 0x44, 0x46],
    [0xed, 0x69, 0x25],
    [0xfb, 0x9b, 0x06],
    [0xf7, 0xd1, 0x3d],
    [0xfc, 0xff, 0xa4],
];
const COOL_TO_WARM: [[u8; 3]; 5] = [
    [59, 76, 192],
    [141, 176, 254],
    [221, 221, 221],
    [244, 154, 123],
    [180, 4, 38],
];
const BONE: [[u8; 3]; 4] = [
    [190, 160, 140],
    [220, 195, 170],
    [240, 225, 205],
    [252, 248, 240],
];
const GRAYSCALE: [[u8; 3]; 2] = [[0, 0, 0], [255, 255, 255]];

/// An sRGB-encoded channel (0-255) as linear radiance-space reflectance.
fn linear(c: u8) -> f32 {
    let s = c as f32 / 255.0;
    if s <= 0.04045 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

impl Colormap {
    pub const ALL: [Colormap; 5] = [
        Colormap::Bone,
        Colormap::Viridis,
        Colormap::Inferno,
        Colormap::CoolToWarm,
        Colormap::Grayscale,
    ];

    fn controls(self) -> &'static [[u8; 3]] {
        match self {
            Colormap::Bone => &BONE,
            Colormap::Viridis => &VIRIDIS,
            Colormap::Inferno => &INFERNO,
            Colormap::CoolToWarm => &COOL_TO_WARM,
            Colormap::Grayscale => &GRAYSCALE,
        }
    }

    /// The map's linear colour at `t` in [0, 1] (clamped; NaN reads as 0).
    pub fn at(self, t: f32) -> Vec3 {
        let c = self.controls();
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        let x = t * (c.len() - 1) as f32;
        let i = (x as usize).min(c.len() - 2);
        let f = x - i as f32;
        let col = |k: usize| Vec3::new(linear(c[k][0]), linear(c[k][1]), linear(c[k][2]));
        col(i).lerp(col(i + 1), f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_hit_their_control_colours_and_read_their_names() {
        // The ends are the first and last control colours, linearised.
        assert!((Colormap::Grayscale.at(0.0) - Vec3::ZERO).length() < 1e-6);
        assert!((Colormap::Grayscale.at(1.0) - Vec3::ONE).length() < 1e-6);
        // Control colours are linearised (sRGB 0x80 is linear 0.2158), then interpolated
        // linearly: half way between black and white is 0.5.
        assert!((linear(0x80) - 0.2158).abs() < 1e-3);
        let mid = Colormap::Grayscale.at(0.5);
        assert!((mid.x - 0.5).abs() < 1e-6, "{mid}");
        let v = Colormap::Viridis.at(1.0);
        assert!((v - Vec3::new(linear(0xfd), linear(0xe7), linear(0x25))).length() < 1e-6);
        for c in Colormap::ALL {
            assert_eq!(c.to_string().parse::<Colormap>(), Ok(c));
            for k in 0..=10 {
                let x = c.at(k as f32 / 10.0);
                assert!(x.min_element() >= 0.0 && x.max_element() <= 1.0);
            }
        }
        assert!("jet".parse::<Colormap>().unwrap_err().contains("viridis"));
    }
}
