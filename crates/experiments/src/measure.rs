//! Running one method progressively: 1-spp passes (or cached frames) accumulated into a film,
//! with a snapshot each time a budget is reached. Budgets in spp and in seconds share one run,
//! so a method's images at 1, 4 and 16 spp are the prefixes of one progressive render, as a
//! user watching it would see them. Times are wall-clock around each pass.

use super::config::{DenoiseSpec, MethodSpec};
use super::denoised::Denoisers;
use super::records::{Budget, CacheRecord, Snapshot};
use crate::error::Result;
use glam::Vec3;
use render_session::{Control, FrameReport, Session};
use std::time::Instant;
use volume_pt::Scene;

/// Renders frames of `session` (1 spp each, by the sampling rule) until every budget is
/// reached, snapshotting its image at each; `on_frame` sees every frame's report. A time budget
/// is reached by the first frame that ends at or past it (its image includes that frame).
pub fn progressive(
    budgets: &[Budget],
    session: &mut Session,
    mut on_frame: impl FnMut(&FrameReport),
) -> Result<Vec<Snapshot>> {
    progressive_with(
        budgets,
        session,
        |s| {
            let r = s.next_frame(&Control::none())?;
            on_frame(&r);
            Ok(r.seconds)
        },
        |s| (s.mean(), s.feature_images()),
    )
}

/// [`progressive`] over any state: `frame(state)` adds one frame (1 spp) to the image and
/// returns its seconds, `image(state)` is the image so far and its feature buffers, if kept.
fn progressive_with<S>(
    budgets: &[Budget],
    state: &mut S,
    mut frame: impl FnMut(&mut S) -> Result<f64>,
    image: impl Fn(&S) -> (Vec<Vec3>, Option<hdr_image::FeatureImages>),
) -> Result<Vec<Snapshot>> {
    let mut pending: Vec<Budget> = budgets.to_vec();
    let mut out = Vec::new();
    let (mut k, mut seconds) = (0u32, 0.0);
    while !pending.is_empty() {
        seconds += frame(state)?;
        k += 1;
        let mut reached_now = Vec::new();
        pending.retain(|b| {
            let reached = match *b {
                Budget::Spp(s) => k >= s,
                Budget::Seconds(t) => seconds >= t,
            };
            if reached {
                reached_now.push(*b);
            }
            !reached
        });
        if !reached_now.is_empty() {
            let (pixels, features) = image(state);
            for budget in reached_now {
                out.push(Snapshot {
                    budget,
                    spp: k,
                    seconds,
                    image: pixels.clone(),
                    denoised: None,
                    features: features.clone(),
                });
            }
        }
    }
    Ok(out)
}

/// The render session of `method` on `scene` with `seed`: one sample per pixel a frame.
pub fn method_session(scene: &Scene, method: &MethodSpec, seed: u64) -> Result<Session> {
    let mut scene = scene.clone();
    scene.settings.spp = 1;
    scene.settings.path.integrator = method.integrator;
    scene.settings.seed = seed;
    Ok(Session::new(scene, method.cache_choice()?)?)
}

/// `method` at the scene camera with `seed`: its warm-up (a cache's), then frames of 1 spp
/// snapshotted at every budget; with `denoise`, also its denoised twins' snapshots (see
/// [`super::denoised`]).
pub fn run_method(
    scene: &Scene,
    method: &MethodSpec,
    seed: u64,
    budgets: &[Budget],
    denoise: Option<&DenoiseSpec>,
    denoisers: &mut Denoisers,
) -> Result<(Vec<Snapshot>, Option<CacheRecord>)> {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let plan = match denoise {
        Some(spec) => super::denoised::plan(denoisers, budgets, spec, w, h)?,
        None => Vec::new(),
    };
    // The images the twins denoise are snapshots too; the features ride along with them.
    let mut all_budgets = budgets.to_vec();
    for &(_, _, render) in &plan {
        if !all_budgets.contains(&render) {
            all_budgets.push(render);
        }
    }
    let session = method_session(scene, method, seed)?;
    let wants_features = plan.iter().any(|p| p.0 != denoise::Guides::None);
    let mut session = session.with_features(wants_features);
    let mut finish = |raw: Vec<Snapshot>| -> Result<Vec<Snapshot>> {
        let mut twins = match denoise {
            Some(spec) => super::denoised::twins(denoisers, &plan, &raw, spec, w, h)?,
            None => Vec::new(),
        };
        let mut out: Vec<Snapshot> = raw
            .into_iter()
            .filter(|s| budgets.contains(&s.budget))
            .map(|s| Snapshot {
                features: None,
                ..s
            })
            .collect();
        out.append(&mut twins);
        Ok(out)
    };
    if !method.has_cache() {
        let raw = progressive(&all_budgets, &mut session, |_| {})?;
        return Ok((finish(raw)?, None));
    }
    let mut record = CacheRecord {
        init_seconds: session.cache_seconds(),
        parameter_bytes: session.cache().parameter_bytes(),
        ..Default::default()
    };
    let start = Instant::now();
    let warm = session.warm_up(
        method.cache.warmup(),
        method.cache.warmup_orbit_degrees(),
        &Control::none(),
    )?;
    record.warmup_seconds = start.elapsed().as_secs_f64();
    for r in warm {
        record.nonfinite_samples += r.nonfinite_samples;
        record.level_mse.push(r.loss);
    }
    let snaps = progressive(&all_budgets, &mut session, |r| {
        record.nonfinite_samples += r.nonfinite_samples;
        record.level_mse.push(r.loss.clone());
        if r.handed_off {
            record.handed_off += 1;
        } else {
            record
                .frame_seconds
                .push([r.trace_seconds, r.lookup_seconds, r.train_seconds]);
        }
    })?;
    if let Some(frame) = session.cache().drawn_levels() {
        record.level_images = (0..frame.levels())
            .map(|l| {
                frame
                    .image(l)
                    .iter()
                    .map(|&c| Vec3::from_array(c))
                    .collect()
            })
            .collect();
    }
    Ok((finish(snaps)?, Some(record)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progressive_snapshots_every_budget_once_in_order_reached() {
        let budgets = [Budget::Spp(3), Budget::Seconds(0.25), Budget::Spp(1)];
        let snaps = progressive_with(&budgets, &mut (), |_| Ok(0.1), |_| (vec![], None)).unwrap();
        let got: Vec<(Budget, u32)> = snaps.iter().map(|s| (s.budget, s.spp)).collect();
        // 0.25 s is first reached by the third pass (0.3 s).
        assert_eq!(
            got,
            vec![
                (Budget::Spp(1), 1),
                (Budget::Spp(3), 3),
                (Budget::Seconds(0.25), 3)
            ]
        );
        assert!((snaps[2].seconds - 0.3).abs() < 1e-12);
    }
}
