//! A render's denoised twin (`--denoise`, `--denoise-quality`, `--denoise-guides`) and the EXR
//! that carries its feature buffers: shared by `render` and `merge`.

use anyhow::{Result, bail};
use denoise::{Denoiser, Guides, Options, Quality};
use hdr_image::{FeatureImages, RgbImage, ToneMap};
use std::path::{Path, PathBuf};

/// Denoising of a render.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct DenoiseArgs {
    /// Also write NAME.denoised.exr and NAME.denoised.png, denoised by Intel Open Image Denoise
    /// (found at run time: `pip install pyoidn`, or GSCACHE_OIDN=/path/to/the/library).
    #[arg(long)]
    pub denoise: bool,
    /// Open Image Denoise's quality: `high` for final frames, `balanced` or `fast` for previews.
    #[arg(long, value_enum, default_value_t = Options::default().quality, requires = "denoise")]
    pub denoise_quality: Quality,
    /// Feature buffers that guide the denoiser. Colour alone by default: guided by the albedo,
    /// the filter leaves a few background pixels near a light many times too bright, though
    /// its error elsewhere is lower from 16 spp on (BENCHMARKS.md).
    #[arg(
        long,
        value_enum,
        default_value_t = Guides::None,
        requires = "denoise",
        alias = "denoise-aovs"
    )]
    pub denoise_guides: Guides,
    /// Give the guides to the colour filter as they are, instead of denoising them first as
    /// `denoise::Options::default()` does (faster: one filter pass instead of three; noisier at
    /// low sample counts).
    #[arg(long, requires = "denoise")]
    pub denoise_raw_guides: bool,
}

impl DenoiseArgs {
    /// The denoiser's options.
    pub fn options(&self) -> Options {
        Options {
            quality: self.denoise_quality,
            prefilter: Options::default().prefilter && !self.denoise_raw_guides,
        }
    }

    /// Whether the denoiser needs the film's feature buffers.
    pub fn needs_features(&self) -> bool {
        self.denoise && self.denoise_guides != Guides::None
    }

    /// The denoiser, loaded before any rendering so that a missing library is said at once;
    /// `None` without `--denoise`.
    pub fn load(&self) -> Result<Option<Denoiser>> {
        if !self.denoise {
            return Ok(None);
        }
        let threads = rayon::current_num_threads();
        match Denoiser::load(threads) {
            Ok(d) => Ok(Some(d)),
            Err(e) => bail!("--denoise: {e}"),
        }
    }
}

/// `NAME.denoised.exr` beside `NAME.exr`.
pub fn denoised_path(exr: &Path) -> PathBuf {
    let stem = exr
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "render".into());
    exr.with_file_name(format!("{stem}.denoised.exr"))
}

/// Writes the image's EXR (with its feature layers where kept) and PNG.
pub fn write_image(
    image: &RgbImage,
    features: Option<&FeatureImages>,
    exr: &Path,
    png: &Path,
    exposure: f32,
    tonemap: ToneMap,
) -> Result<()> {
    match features {
        Some(f) => image.write_exr_with_features(exr, f)?,
        None => image.write_exr(exr)?,
    }
    image.write_png(png, exposure, tonemap)?;
    Ok(())
}

/// Denoises `image` as `args` say and writes NAME.denoised.exr and .png beside `exr`; returns
/// the EXR's path and the seconds the filter took.
pub fn write_denoised(
    denoiser: &mut Denoiser,
    args: &DenoiseArgs,
    image: &RgbImage,
    features: Option<&FeatureImages>,
    exr: &Path,
    exposure: f32,
    tonemap: ToneMap,
) -> Result<(PathBuf, f64)> {
    let start = std::time::Instant::now();
    let out = denoiser.denoise_guided(image, features, args.denoise_guides, args.options())?;
    let seconds = start.elapsed().as_secs_f64();
    let path = denoised_path(exr);
    out.write_exr(&path)?;
    out.write_png(&path.with_extension("png"), exposure, tonemap)?;
    Ok((path, seconds))
}
