//! The experiment's figures: relMSE against time (log-log), images and error maps side by side,
//! the cache's levels, loss over frames, and the fly-through curves. Each returns the files it
//! wrote (relative to the output folder) with a caption, for the report.

use super::method::MethodCache;
use super::records::Budget;
use super::run::{Results, SummaryRow};
use crate::error::{Error, Result};
use crate::plot::{Chart, Rgb8, Series, false_colour, tone_mapped, write_chart, write_image_grid};
use image_metrics::rel_mse_map;
use std::path::Path;
use volume_pt::Scene;

/// A figure in the report: caption and file (relative to the report).
pub type Figure = (String, String);

/// Error maps span relative squared errors from 1e-4 (dark) to 10 (yellow).
const ERROR_MAP_LOG_RANGE: (f64, f64) = (-4.0, 1.0);

pub fn write_all(out: &Path, results: &Results, scene: &Scene) -> Result<Vec<Figure>> {
    let dir = out.join("plots");
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, "cannot create", e))?;
    let mut figs = vec![error_against_time(&dir, results)?];
    figs.extend(image_grids(&dir, results, scene)?);
    figs.extend(cache_levels(&dir, results, scene)?);
    figs.extend(loss_over_frames(&dir, results)?);
    figs.extend(flythrough_curves(&dir, results)?);
    figs.extend(ablation_charts(&dir, results)?);
    Ok(figs)
}

fn file(name: &str) -> String {
    format!("plots/{name}.png")
}

fn error_against_time(dir: &Path, r: &Results) -> Result<Figure> {
    let mut series = Vec::new();
    for m in &r.methods {
        let rows: Vec<_> = r.summary.iter().filter(|s| s.method == m.name).collect();
        series.push(time_series(&m.name, &rows));
    }
    let title = format!(
        "{}: relMSE against time ({} seeds, bars: 1 sd)",
        r.name,
        r.seeds.len()
    );
    save(
        dir,
        "error_vs_time",
        "relMSE against wall-clock time, every budget, mean over seeds".into(),
        &time_chart(title, series),
    )
}

/// relMSE against seconds per image on log-log axes.
fn time_chart(title: String, series: Vec<Series>) -> Chart {
    Chart {
        title,
        x_label: "seconds per image".into(),
        y_label: "relMSE".into(),
        log_x: true,
        log_y: true,
        series,
        marks: vec![],
    }
}

/// Writes `chart` as `plots/<name>.{png,svg}` and returns it as a report figure.
fn save(dir: &Path, name: &str, caption: String, chart: &Chart) -> Result<Figure> {
    write_chart(&dir.join(name), chart)?;
    Ok((caption, file(name)))
}

/// A method's relMSE against seconds over its budgets, with 1-sd bars.
fn time_series(name: &str, rows: &[&SummaryRow]) -> Series {
    let mut points: Vec<(f64, f64)> = rows.iter().map(|s| (s.seconds, s.rel_mse)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    Series {
        name: name.to_string(),
        points,
        bars: rows
            .iter()
            .map(|s| {
                (
                    s.seconds,
                    s.rel_mse - s.rel_mse_sd,
                    s.rel_mse + s.rel_mse_sd,
                )
            })
            .collect(),
        markers: true,
    }
}

/// One grid per chosen budget: the reference, then each method's image and relMSE map.
/// The widest panel of an image grid: larger images are shrunk by an integer factor (a
/// 1280x720 run's grid of ten methods was 14 MB as PNG).
const GRID_PANEL_WIDTH: u32 = 480;

fn image_grids(dir: &Path, r: &Results, scene: &Scene) -> Result<Vec<Figure>> {
    let (w, h) = (r.width, r.height);
    let shrink = w.div_ceil(GRID_PANEL_WIDTH);
    let tm = |img: &[glam::Vec3]| {
        tone_mapped(img, w, h, scene.output.exposure, scene.output.tonemap).downscaled(shrink)
    };
    let mut chosen: Vec<Budget> = Vec::new();
    let budgets: Vec<Budget> = r.summary.iter().map(|s| s.budget).collect();
    if let Some(b) = budgets.iter().find(|b| matches!(b, Budget::Spp(_))) {
        chosen.push(*b);
    }
    if let Some(b) = budgets.iter().find(|b| matches!(b, Budget::Seconds(_))) {
        chosen.push(*b);
    }
    let mut figs = Vec::new();
    for (i, budget) in chosen.iter().enumerate() {
        let mut rows = vec![(
            format!("reference\n{} spp nee", r.reference.spp),
            vec![tm(&r.images.reference)],
        )];
        for (method, b, img) in &r.images.snapshots {
            if b != budget {
                continue;
            }
            let map = rel_mse_map(img, &r.images.reference);
            let s = r
                .summary
                .iter()
                .find(|s| &s.method == method && s.budget == *budget);
            let label = match s {
                Some(s) => format!(
                    "{method}\n{:.1} spp, {:.0} ms\nrelMSE {:.4}",
                    s.spp,
                    s.seconds * 1e3,
                    s.rel_mse
                ),
                None => method.clone(),
            };
            let (lo, hi) = ERROR_MAP_LOG_RANGE;
            rows.push((
                label,
                vec![tm(img), false_colour(&map, w, h, lo, hi).downscaled(shrink)],
            ));
        }
        let name = format!("images_{i}");
        write_image_grid(
            &dir.join(format!("{name}.jpg")),
            &format!("{} at {budget} (first seed)", r.name),
            &["image".into(), "relMSE per pixel, log 1e-4..10".into()],
            &rows,
        )?;
        figs.push((
            format!("Images and relMSE maps at {budget}"),
            format!("plots/{name}.jpg"),
        ));
    }
    Ok(figs)
}

fn cache_levels(dir: &Path, r: &Results, scene: &Scene) -> Result<Vec<Figure>> {
    let rows: Vec<(String, Vec<Rgb8>)> = r
        .caches
        .iter()
        .filter(|c| !c.record.level_images.is_empty())
        .map(|c| {
            let imgs = c
                .record
                .level_images
                .iter()
                .map(|l| {
                    tone_mapped(
                        l,
                        r.width,
                        r.height,
                        scene.output.exposure,
                        scene.output.tonemap,
                    )
                })
                .collect();
            (c.method.clone(), imgs)
        })
        .collect();
    if rows.is_empty() {
        return Ok(vec![]);
    }
    let levels = rows.iter().map(|r| r.1.len()).max().unwrap_or(0);
    let cols: Vec<String> = (1..=levels)
        .map(|l| format!("paths of length {l}"))
        .collect();
    write_image_grid(
        &dir.join("cache_levels.png"),
        &format!("{}: the cache's levels at the scene camera", r.name),
        &cols,
        &rows,
    )?;
    Ok(vec![(
        "The cache's levels as drawn at the last frame (first seed)".into(),
        file("cache_levels"),
    )])
}

fn loss_over_frames(dir: &Path, r: &Results) -> Result<Vec<Figure>> {
    let mut figs = Vec::new();
    for (i, c) in r.caches.iter().enumerate() {
        // The neural cache files one "level": its training steps' mean relative L2 loss.
        let neural = r
            .methods
            .iter()
            .any(|m| m.name == c.method && matches!(m.cache, MethodCache::Neural(_)));
        let levels = c
            .record
            .level_mse
            .iter()
            .map(|l| l.len())
            .max()
            .unwrap_or(0);
        let series = (0..levels)
            .map(|l| Series {
                name: if neural {
                    "relative L2 loss".into()
                } else {
                    format!("length {}", l + 1)
                },
                points: c
                    .record
                    .level_mse
                    .iter()
                    .enumerate()
                    .filter_map(|(f, m)| Some((f as f64, m.get(l).copied().flatten()?)))
                    .collect(),
                ..Default::default()
            })
            .collect();
        let (what, y_label) = if neural {
            (
                "relative L2 loss of the frame's training steps",
                "mean loss of the steps",
            )
        } else {
            ("MSE to the frame's samples", "MSE before the step")
        };
        let chart = Chart {
            title: format!("{}: loss over frames ({what})", c.method),
            x_label: "frame".into(),
            y_label: y_label.into(),
            log_y: true,
            series,
            marks: vec![(c.warmup_frames as f64, "measured from here".into())],
            ..Default::default()
        };
        figs.push(save(
            dir,
            &format!("loss_{i}"),
            format!(
                "{}: {} over the warm-up and measured frames",
                c.method,
                if neural {
                    "training loss"
                } else {
                    "per-level loss"
                }
            ),
            &chart,
        )?);
    }
    Ok(figs)
}

fn flythrough_curves(dir: &Path, r: &Results) -> Result<Vec<Figure>> {
    let mut names: Vec<&str> = r
        .flythroughs
        .iter()
        .map(|f| f.flythrough.as_str())
        .collect();
    names.dedup();
    let mut figs = Vec::new();
    for (i, fly) in names.iter().enumerate() {
        let frames: Vec<_> = r
            .flythroughs
            .iter()
            .filter(|f| f.flythrough == *fly)
            .collect();
        let mut methods: Vec<&str> = frames.iter().map(|f| f.method.as_str()).collect();
        methods.dedup();
        let per = |m: &str,
                   v: &dyn Fn(&super::flythrough::FrameRecord) -> Option<f64>|
         -> Vec<(f64, f64)> {
            frames
                .iter()
                .filter(|f| f.method == m)
                .filter_map(|f| Some((f.frame as f64, v(f)?)))
                .collect()
        };
        let mut timing = Vec::new();
        for m in &methods {
            timing.push(Series {
                name: format!("{m} total"),
                points: per(m, &|f| Some(f.total_ms)),
                ..Default::default()
            });
            if frames.iter().any(|f| f.method == *m && f.splat_ms > 0.0) {
                timing.push(Series {
                    name: format!("{m} trace"),
                    points: per(m, &|f| Some(f.trace_ms)),
                    ..Default::default()
                });
                timing.push(Series {
                    name: format!("{m} splat"),
                    points: per(m, &|f| Some(f.splat_ms)),
                    ..Default::default()
                });
                timing.push(Series {
                    name: format!("{m} train"),
                    points: per(m, &|f| Some(f.train_ms)),
                    ..Default::default()
                });
            }
        }
        let marks: Vec<(f64, String)> = r
            .flythrough_events
            .iter()
            .filter(|e| e.0 == *fly)
            .map(|e| (e.1 as f64, e.2.clone()))
            .collect();
        let t = Chart {
            title: format!("flythrough `{fly}`: time per frame"),
            x_label: "frame".into(),
            y_label: "ms".into(),
            series: timing,
            marks: marks.clone(),
            ..Default::default()
        };
        figs.push(save(
            dir,
            &format!("flythrough_{i}_time"),
            format!("Fly-through `{fly}`: per-frame times (trace, splat, train)"),
            &t,
        )?);
        let err = Chart {
            title: format!("flythrough `{fly}`: relMSE of each frame (1 spp)"),
            x_label: "frame".into(),
            y_label: "relMSE".into(),
            log_y: true,
            series: methods
                .iter()
                .map(|m| Series {
                    name: m.to_string(),
                    points: per(m, &|f| f.rel_mse),
                    markers: true,
                    ..Default::default()
                })
                .collect(),
            marks,
            ..Default::default()
        };
        figs.push(save(
            dir,
            &format!("flythrough_{i}_error"),
            format!("Fly-through `{fly}`: error of each frame against its reference"),
            &err,
        )?);
    }
    Ok(figs)
}

fn ablation_charts(dir: &Path, r: &Results) -> Result<Vec<Figure>> {
    let mut figs = Vec::new();
    for (i, a) in r.ablations.iter().enumerate() {
        // Speed against error for every value, beside the baseline measured in the same run.
        let mut series: Vec<Series> = a
            .rows
            .iter()
            .map(|(v, rows)| {
                let rows: Vec<&SummaryRow> = rows.iter().collect();
                time_series(&format!("{}={v}", a.parameter), &rows)
            })
            .collect();
        if let Some(base) = &r.baseline {
            let rows: Vec<&SummaryRow> = r.summary.iter().filter(|s| &s.method == base).collect();
            series.push(time_series(&format!("{base} (baseline)"), &rows));
        }
        figs.push(save(
            dir,
            &format!("ablation_{i}_time"),
            format!("Ablation `{}`: relMSE against time per value", a.name),
            &time_chart(
                format!("ablation `{}`: relMSE against time", a.name),
                series,
            ),
        )?);
        let numeric: Option<Vec<f64>> = a.rows.iter().map(|(v, _)| v.parse::<f64>().ok()).collect();
        let Some(xs) = numeric else { continue };
        let budgets: Vec<Budget> = a
            .rows
            .first()
            .map(|r| r.1.iter().map(|s| s.budget).collect())
            .unwrap_or_default();
        let log_x = xs.iter().all(|&x| x > 0.0)
            && xs.iter().cloned().fold(0.0, f64::max)
                / xs.iter().cloned().fold(f64::INFINITY, f64::min)
                > 20.0;
        let series = budgets
            .iter()
            .map(|b| Series {
                name: b.to_string(),
                points: xs
                    .iter()
                    .zip(&a.rows)
                    .filter_map(|(&x, (_, rows))| {
                        Some((x, rows.iter().find(|s| s.budget == *b)?.rel_mse))
                    })
                    .collect(),
                markers: true,
                ..Default::default()
            })
            .collect();
        let chart = Chart {
            title: format!("ablation `{}`: relMSE against {}", a.name, a.parameter),
            x_label: a.parameter.clone(),
            y_label: "relMSE".into(),
            log_x,
            log_y: true,
            series,
            marks: vec![],
        };
        figs.push(save(
            dir,
            &format!("ablation_{i}"),
            format!("Ablation `{}`: relMSE against {}", a.name, a.parameter),
            &chart,
        )?);
    }
    Ok(figs)
}
