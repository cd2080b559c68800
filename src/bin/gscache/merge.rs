//! `gscache merge PARTS...`: joins the partial films of a sharded render (`render --shard`)
//! into its image, bit for bit the one a single process would have made.

use crate::common::{finite_f32, prepare_output};
use crate::denoising::{DenoiseArgs, write_denoised, write_image};
use anyhow::{Result, bail};
use hdr_image::ToneMap;
use std::path::PathBuf;
use volume_pt::PartialRender;

/// Merge partial films (`gscache render --shard I/N --partial FILE`) into an image.
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct MergeArgs {
    /// Partial films of one render, in any order.
    #[arg(required = true)]
    parts: Vec<PathBuf>,
    /// Linear EXR output.
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// Tone-mapped PNG output (default: next to the EXR).
    #[arg(long)]
    png: Option<PathBuf>,
    /// PNG exposure in stops (default: the scene's, which the parts carry; else 0).
    #[arg(long, value_parser = finite_f32)]
    exposure: Option<f32>,
    /// PNG tone map (default: the scene's, which the parts carry; else clip).
    #[arg(long, value_enum)]
    tonemap: Option<ToneMap>,
    /// Write the merged partial film instead of (or beside) the image: merges can form a tree.
    #[arg(long)]
    partial: Option<PathBuf>,
    /// Write an image even when the parts do not hold every sample of the render.
    #[arg(long)]
    allow_incomplete: bool,
    /// The image's denoised twin (the shards' feature buffers guide it where they carry them:
    /// `render --shard ... --features`).
    #[command(flatten)]
    denoise: DenoiseArgs,
}

pub fn run(a: MergeArgs) -> Result<i32> {
    if a.output.is_none() && a.partial.is_none() {
        bail!("nothing to write: give -o OUT.exr, --partial OUT, or both");
    }
    let png = a
        .output
        .as_ref()
        .map(|o| a.png.clone().unwrap_or_else(|| o.with_extension("png")));
    for p in [&a.output, &png, &a.partial].into_iter().flatten() {
        prepare_output(p)?;
    }
    if a.denoise.denoise && a.output.is_none() {
        bail!("--denoise needs an image to denoise: give -o OUT.exr");
    }
    let mut denoiser = a.denoise.load()?;
    let mut merged: Option<PartialRender> = None;
    for path in &a.parts {
        let part = PartialRender::read(path)?;
        match &mut merged {
            None => merged = Some(part),
            Some(m) => m
                .merge(&part)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?,
        }
    }
    let merged = merged.expect("clap requires at least one part");
    let ranges: Vec<String> = merged
        .ranges()
        .iter()
        .map(|r| format!("{}..{}", r.start, r.end))
        .collect();
    if let Some(p) = &a.partial {
        merged.write(p)?;
    }
    if let (Some(exr), Some(png)) = (&a.output, &png) {
        if !merged.is_complete() && !a.allow_incomplete {
            bail!(
                "the parts hold samples {} of 0..{}: some shards are missing (add them, or pass --allow-incomplete for an image of what is here)",
                ranges.join(", "),
                merged.spp()
            );
        }
        let image = merged.image();
        let features = merged.feature_images();
        // As the scene asks, like a one-process render: it once tone-mapped with clip where the
        // scene said aces.
        let (exposure, tonemap) = merged.output().unwrap_or((0.0, ToneMap::Clip));
        let (exposure, tonemap) = (a.exposure.unwrap_or(exposure), a.tonemap.unwrap_or(tonemap));
        write_image(&image, features.as_ref(), exr, png, exposure, tonemap)?;
        if let Some(denoiser) = &mut denoiser {
            if features.is_none() && a.denoise.needs_features() {
                eprintln!(
                    "note: the parts carry no feature buffers (render the shards with --features): denoising the colour alone"
                );
            }
            let (path, seconds) = write_denoised(
                denoiser,
                &a.denoise,
                &image,
                features.as_ref(),
                exr,
                exposure,
                tonemap,
            )?;
            eprintln!(
                "denoised in {:.0} ms: wrote {} and its PNG",
                seconds * 1e3,
                path.display()
            );
        }
    }
    if merged.nonfinite_samples() > 0 {
        eprintln!(
            "warning: {} samples were NaN or infinite and were counted as black",
            merged.nonfinite_samples()
        );
    }
    let wrote: Vec<String> = [&a.output, &png, &a.partial]
        .into_iter()
        .flatten()
        .map(|p| p.display().to_string())
        .collect();
    println!(
        "merged {} parts of render {} ({}x{}, samples {} of {}); wrote {}",
        a.parts.len(),
        merged.key(),
        merged.width(),
        merged.height(),
        ranges.join(", "),
        merged.spp(),
        wrote.join(" and ")
    );
    Ok(0)
}
