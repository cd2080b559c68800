//! Denoised twins: a method's images put through Intel Open Image Denoise, measured as a method
//! of their own (`nee + OIDN`, `nee + OIDN (albedo)`).
//!
//! Time counts the denoiser once per image: at a budget of `T` seconds the twin denoises the
//! progressive render's image at `T - c` seconds, where `c` is the denoiser's cost at this image
//! size measured before the run (the median of five calls after three that build and warm
//! the filter), and its time is the render's plus the denoiser's actual time on that image. Where
//! `c >= T` the image is one frame and the twin is over its budget (its time says by how much):
//! the denoiser does not fit. Spp budgets denoise the image at that spp.

use super::config::DenoiseSpec;
use super::records::{Budget, Snapshot};
use crate::error::{Error, Result, Within};
use denoise::{Denoiser, Guides};
use glam::Vec3;
use hdr_image::RgbImage;
use std::collections::HashMap;
use std::time::Instant;

/// What a denoising cost is measured for: image width and height, guides, quality.
type CostKey = (u32, u32, Guides, denoise::Quality);

/// The denoisers of one run and the costs measured with them: a value the run owns, so that a
/// twin's timing does not depend on what ran before it in the process (they were statics).
/// One denoiser per set of guides: a filter is built once per image size and guides, and
/// switching guides on one device would rebuild it every call (and put the build in the
/// timings).
#[derive(Debug, Default)]
pub struct Denoisers {
    by_guides: HashMap<Guides, Denoiser>,
    /// Costs measured so far, in seconds.
    costs: HashMap<CostKey, f64>,
}

impl Denoisers {
    /// None loaded yet, no cost measured.
    pub fn new() -> Self {
        Self::default()
    }

    /// The denoiser for `guides`, loaded on first use.
    fn for_guides(&mut self, guides: Guides) -> Result<&mut Denoiser> {
        Ok(match self.by_guides.entry(guides) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                e.insert(Denoiser::load(rayon::current_num_threads()).within(|| {
                    "the experiment asks for denoised twins (denoise = true)".to_string()
                })?)
            }
        })
    }

    /// Denoises `image` with `guides` from `features`; returns the image and the seconds taken.
    pub(crate) fn run(
        &mut self,
        image: &RgbImage,
        features: Option<&hdr_image::FeatureImages>,
        guides: Guides,
        spec: &DenoiseSpec,
    ) -> Result<(RgbImage, f64)> {
        let d = self.for_guides(guides)?;
        let start = Instant::now();
        let out = d.denoise_guided(image, features, guides, spec.options())?;
        Ok((out, start.elapsed().as_secs_f64()))
    }

    /// The denoiser's cost per image at `width x height` with `guides`, measured once per run.
    pub fn cost(
        &mut self,
        width: u32,
        height: u32,
        guides: Guides,
        spec: &DenoiseSpec,
    ) -> Result<f64> {
        let key = (width, height, guides, spec.quality);
        if let Some(c) = self.costs.get(&key) {
            return Ok(*c);
        }
        // A noisy image (the cost of the network does not depend on the pixels) and flat guides.
        let n = width as usize * height as usize;
        let pixels = (0..n)
            .map(|i| {
                let h = render_base::hash::hash32(&[i as u32, 0x5eed]);
                Vec3::splat(render_base::hash::unit_f32(h))
            })
            .collect();
        let image = RgbImage::from_pixels(width, height, pixels)?;
        let features = hdr_image::FeatureImages::new(
            width,
            height,
            vec![Vec3::splat(0.5); n],
            vec![Vec3::Z; n],
            vec![1.0; n],
            vec![1.0; n],
        )?;
        // The first calls build the filter and warm its memory (the first few after the build
        // ran up to twice the steady time at high quality); the median of the next five is
        // the cost.
        for _ in 0..3 {
            self.run(&image, Some(&features), guides, spec)?;
        }
        let mut times: Vec<f64> = (0..5)
            .map(|_| self.run(&image, Some(&features), guides, spec).map(|r| r.1))
            .collect::<Result<_>>()?;
        times.sort_by(f64::total_cmp);
        let c = times[2];
        self.costs.insert(key, c);
        Ok(c)
    }
}

/// Which render budget each (guides, budget) twin denoises: the budget itself in spp, `T - c`
/// in seconds (one frame where the denoiser alone takes the budget).
pub fn plan(
    denoisers: &mut Denoisers,
    budgets: &[Budget],
    spec: &DenoiseSpec,
    width: u32,
    height: u32,
) -> Result<Vec<(Guides, Budget, Budget)>> {
    let mut out = Vec::new();
    for &guides in &spec.guides {
        let c = denoisers.cost(width, height, guides, spec)?;
        for &b in budgets {
            let render = match b {
                Budget::Spp(_) => b,
                Budget::Seconds(t) if t > c => Budget::Seconds(t - c),
                Budget::Seconds(_) => Budget::Spp(1),
            };
            out.push((guides, b, render));
        }
    }
    Ok(out)
}

/// The twins' snapshots: each planned image denoised, at its budget, with the render's time
/// plus the denoiser's.
pub fn twins(
    denoisers: &mut Denoisers,
    plan: &[(Guides, Budget, Budget)],
    raw: &[Snapshot],
    spec: &DenoiseSpec,
    width: u32,
    height: u32,
) -> Result<Vec<Snapshot>> {
    let mut out = Vec::new();
    for &(guides, budget, render) in plan {
        let src = raw
            .iter()
            .find(|s| s.budget == render)
            .ok_or_else(|| Error::Invalid(format!("no image at {render} to denoise")))?;
        let image = RgbImage::from_pixels(width, height, src.image.clone())?;
        let (denoised, seconds) = denoisers.run(&image, src.features.as_ref(), guides, spec)?;
        out.push(Snapshot {
            budget,
            spp: src.spp,
            seconds: src.seconds + seconds,
            image: denoised.into_pixels(),
            denoised: Some(guides),
            features: None,
        });
    }
    Ok(out)
}
