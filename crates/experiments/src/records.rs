//! What a measured run leaves, as every part of the runner shares it: the budget, the image at
//! a budget ([`Snapshot`]), a cached run's record ([`CacheRecord`]), and how images travel in
//! shard and resume files ([`image_bits`]). Measuring (`measure`), denoising (`denoised`) and
//! sharding (`shard`) all read these; none of them reads another for them.

use glam::Vec3;

/// A budget: samples per pixel, or wall-clock seconds per image.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", content = "value", rename_all = "lowercase")]
pub enum Budget {
    Spp(u32),
    Seconds(f64),
}

impl std::fmt::Display for Budget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Budget::Spp(s) => write!(f, "{s} spp"),
            Budget::Seconds(s) => write!(f, "{s} s"),
        }
    }
}

/// The image a progressive run had when it reached a budget.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Snapshot {
    pub budget: Budget,
    /// Passes (samples per pixel) in the image.
    pub spp: u32,
    /// Wall-clock seconds of those passes (for a cache: tracing, lookup and training).
    pub seconds: f64,
    #[serde(with = "image_bits")]
    pub image: Vec<Vec3>,
    /// For a denoised twin's image: the guides its denoiser took (`None`: the method's own).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoised: Option<denoise::Guides>,
    /// The feature buffers at this image, kept only until the twins are denoised.
    #[serde(skip)]
    pub features: Option<hdr_image::FeatureImages>,
}

/// What a cached run leaves besides its snapshots.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct CacheRecord {
    pub init_seconds: f64,
    pub warmup_seconds: f64,
    /// Per frame (warm-up, then measured): per level, the MSE before the step (the neural
    /// cache: one entry, the mean relative L2 loss of the step taken during the frame, which
    /// trains on the previous frame's records).
    pub level_mse: Vec<Vec<Option<f64>>>,
    /// Per measured frame that used the cache: seconds of path tracing, lookup (splatting, or
    /// the neural cache's inference and composition) and training (the neural cache's: what its
    /// step, run beside the path tracing, adds after it, `FrameReport::train_seconds`). Frames
    /// after the handoff (plain path tracing) are counted in `handed_off` instead, so the
    /// cache's per-frame cost is that of the frames that pay it.
    pub frame_seconds: Vec<[f64; 3]>,
    /// Measured frames traced without the cache after its handoff.
    pub handed_off: u32,
    /// The levels as last drawn, at the scene camera.
    #[serde(with = "image_bits::many")]
    pub level_images: Vec<Vec<Vec3>>,
    pub parameter_bytes: usize,
    pub nonfinite_samples: u64,
}

/// Images in shard files: f32 bits in base64 (exact, and a third the size of decimal text).
pub mod image_bits {
    use base64::Engine as _;
    use base64::engine::general_purpose::STANDARD as BASE64;
    use glam::Vec3;
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn encode(image: &[Vec3]) -> String {
        let bytes: Vec<u8> = image
            .iter()
            .flat_map(|p| p.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        BASE64.encode(bytes)
    }

    pub fn decode(text: &str) -> Result<Vec<Vec3>, String> {
        let bytes = BASE64.decode(text).map_err(|e| e.to_string())?;
        if bytes.len() % 12 != 0 {
            return Err(format!(
                "{} bytes is not a whole number of RGB pixels",
                bytes.len()
            ));
        }
        Ok(bytes
            .chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes(c[i..i + 4].try_into().expect("4 bytes"));
                Vec3::new(f(0), f(4), f(8))
            })
            .collect())
    }

    pub fn serialize<S: Serializer>(image: &[Vec3], s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&encode(image))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec3>, D::Error> {
        decode(&String::deserialize(d)?).map_err(serde::de::Error::custom)
    }

    /// A list of images.
    pub mod many {
        use super::Vec3;
        use serde::{Deserialize, Deserializer, Serializer};

        pub fn serialize<S: Serializer>(images: &[Vec<Vec3>], s: S) -> Result<S::Ok, S::Error> {
            s.collect_seq(images.iter().map(|i| super::encode(i)))
        }

        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<Vec3>>, D::Error> {
            Vec::<String>::deserialize(d)?
                .iter()
                .map(|t| super::decode(t).map_err(serde::de::Error::custom))
                .collect()
        }
    }
}
