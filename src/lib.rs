//! The command-line programs' shared code.
//!
//! - [`metrics`]: image error against a reference (relMSE, SMAPE, PSNR, FLIP, SSIM, bias across
//!   seeds, efficiency).
//! - [`camera_path`]: the camera paths of fly-throughs (an orbit, or key frames).
//! - [`plot`]: charts and image grids (SVG, PNG) for reports.
//! - [`experiment`]: the experiment runner: methods at budgets against a cached reference,
//!   fly-throughs with scene edits, ablation sweeps, and their report.

#![forbid(unsafe_code)]

pub mod camera_path;
pub mod experiment;
pub mod metrics;
pub mod plot;

/// Writes a text file for the user atomically ([`render_base::write_atomically`]): reports,
/// tables, charts and shard files alike.
pub fn write_text(path: &std::path::Path, text: &str) -> anyhow::Result<()> {
    render_base::write_atomically(path, |file| {
        std::io::Write::write_all(file, text.as_bytes()).map_err(|e| e.to_string())
    })?;
    Ok(())
}
