//! Writing an experiment's results: `summary.csv`, `flythrough.csv`, `ablations.csv`,
//! `results.json` (everything) and `report.md` (tables, the figures, and what they show).
//! `runs.csv` is written while the experiment runs (see `run`).

use super::csv::{budget_fields, csv_text};
use super::figures::Figure;
use super::records::Budget;
use super::run::{Results, SummaryRow};
use crate::error::Result;
use std::fmt::Write as _;
use std::path::Path;

use crate::write_text as write;

const SUMMARY_HEADER: &str = "method,budget_kind,budget,seeds,spp,seconds,rel_mse,rel_mse_sd,psnr_hdr,psnr_tonemapped,smape,flip,ssim,efficiency,efficiency_vs_baseline,gain_vs_baseline,rel_bias_sq,brightness_bias,brightness_bias_se";

fn summary_csv(prefix: &str, s: &SummaryRow) -> String {
    let (kind, value) = budget_fields(s.budget);
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    format!(
        "{prefix}{},{kind},{value},{},{:.3},{:.6},{:.6e},{:.6e},{:.4},{:.4},{:.6},{},{},{:.6e},{},{},{},{},{}",
        csv_text(&s.method),
        s.seeds,
        s.spp,
        s.seconds,
        s.rel_mse,
        s.rel_mse_sd,
        s.psnr_hdr,
        s.psnr_tonemapped,
        s.smape,
        opt(s.flip),
        opt(s.ssim),
        s.efficiency,
        opt(s.efficiency_vs_baseline),
        opt(s.gain_vs_baseline),
        opt(s.bias.map(|b| b.rel_bias_sq)),
        opt(s.bias.map(|b| b.brightness)),
        opt(s.bias.map(|b| b.brightness_se)),
    )
}

/// Writes every file but `runs.csv`; `figures` are already written.
pub fn write_reports(out: &Path, r: &Results, figures: &[Figure]) -> Result<()> {
    let mut csv = format!("{SUMMARY_HEADER}\n");
    for s in &r.summary {
        csv.push_str(&summary_csv("", s));
        csv.push('\n');
    }
    write(&out.join("summary.csv"), &csv)?;
    if !r.flythroughs.is_empty() {
        let mut csv = String::from(
            "flythrough,method,frame,warmup,passes,trace_ms,splat_ms,train_ms,total_ms,rel_mse,level_mse,denoise_ms,flip,flicker,jod\n",
        );
        for f in &r.flythroughs {
            let levels: Vec<String> = f
                .level_mse
                .iter()
                .map(|m| m.map_or(String::new(), |v| format!("{v:.6e}")))
                .collect();
            let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6e}"));
            writeln!(
                csv,
                "{},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{},{},{:.3},{},{},{}",
                csv_text(&f.flythrough),
                csv_text(&f.method),
                f.frame,
                f.warmup,
                f.passes,
                f.trace_ms,
                f.splat_ms,
                f.train_ms,
                f.total_ms,
                opt(f.rel_mse),
                levels.join(";"),
                f.denoise_ms,
                opt(f.flip),
                opt(f.flicker),
                f.jod.map_or(String::new(), |v| format!("{v:.4}")),
            )?;
        }
        write(&out.join("flythrough.csv"), &csv)?;
    }
    if !r.ablations.is_empty() {
        let mut csv = format!("ablation,parameter,value,{SUMMARY_HEADER}\n");
        for a in &r.ablations {
            for (value, rows) in &a.rows {
                for s in rows {
                    let prefix = format!(
                        "{},{},{},",
                        csv_text(&a.name),
                        csv_text(&a.parameter),
                        csv_text(value)
                    );
                    csv.push_str(&summary_csv(&prefix, s));
                    csv.push('\n');
                }
            }
        }
        write(&out.join("ablations.csv"), &csv)?;
    }
    write(&out.join("results.json"), &serde_json::to_string_pretty(r)?)?;
    write(&out.join("report.md"), &markdown(r, figures))
}

fn sci(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if (1e-3..1e3).contains(&v.abs()) {
        format!("{v:.4}")
    } else {
        format!("{v:.2e}")
    }
}

fn budget_label(b: Budget) -> String {
    match b {
        Budget::Spp(s) => format!("{s} spp"),
        Budget::Seconds(s) => format!("{:.0} ms", s * 1e3),
    }
}

const TABLE_HEAD: &str = "| method | budget | spp | ms | relMSE (sd) | PSNR HDR | PSNR tone-mapped | SMAPE | FLIP | SSIM | efficiency | vs baseline: gain / efficiency | rel. bias² | brightness bias (se) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";

fn table_row(s: &SummaryRow, label: &str) -> String {
    let vs = match (s.gain_vs_baseline, s.efficiency_vs_baseline) {
        (Some(g), Some(e)) => format!("{g:.2}x / {e:.2}x"),
        _ => "-".into(),
    };
    let (bias, bright) = match s.bias {
        Some(b) => (
            sci(b.rel_bias_sq),
            format!(
                "{:+.2}% ({:.2}%)",
                b.brightness * 100.0,
                b.brightness_se * 100.0
            ),
        ),
        None => ("-".into(), "-".into()),
    };
    format!(
        "| {label} | {} | {:.1} | {:.1} | {} ({}) | {:.2} | {:.2} | {:.4} | {} | {} | {} | {vs} | {bias} | {bright} |\n",
        budget_label(s.budget),
        s.spp,
        s.seconds * 1e3,
        sci(s.rel_mse),
        sci(s.rel_mse_sd),
        s.psnr_hdr,
        s.psnr_tonemapped,
        s.smape,
        s.flip.map_or("-".into(), |f| format!("{f:.4}")),
        s.ssim.map_or("-".into(), |f| format!("{f:.4}")),
        sci(s.efficiency),
    )
}

fn markdown(r: &Results, figures: &[Figure]) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# Experiment `{}`\n", r.name);
    let _ = writeln!(
        md,
        "Scene `{}`, {}x{}, {} threads, seeds {:?}. Reference: {} spp NEE (`{}`, {}).\n",
        r.scene.display(),
        r.width,
        r.height,
        r.threads,
        r.seeds,
        r.reference.spp,
        r.reference
            .file
            .file_name()
            .map(|f| f.to_string_lossy())
            .unwrap_or_default(),
        if r.reference.reused {
            "reused from disk".to_string()
        } else {
            format!("rendered in {:.1} s", r.reference.seconds)
        }
    );
    let _ = writeln!(
        md,
        "Metrics: relMSE with epsilon 0.01 and the top 0.1% of pixels trimmed; PSNR on HDR with peak {:.4} (the reference's 99.9th percentile) and on the tone-mapped 8-bit images with peak 255; SMAPE with epsilon 0.01; FLIP (LDR, lower is better) and SSIM (luma, Gaussian window, higher is better) on the tone-mapped images; efficiency 1 / (relMSE x seconds). Times are wall-clock per image; a cache's warm-up frames are not counted (see the cache table). The bias columns are estimated across the seeds: relative squared bias (mean minus reference, squared, less the variance of the mean, over reference² + 0.01) and the mean brightness against the reference's, with its standard error. Gains are the baseline's relMSE over the method's at the same budget{}; a denoised twin (`+ OIDN`) is compared with the baseline's twin with the same guides, and its time includes the denoiser's, once per image.\n",
        r.reference.hdr_peak,
        r.baseline
            .as_ref()
            .map_or(String::new(), |b| format!(" (baseline `{b}`)"))
    );
    let _ = writeln!(md, "## Methods\n");
    for m in &r.methods {
        let cache = m.cache.report_text();
        let _ = writeln!(md, "- `{}`: {}{cache}", m.name, m.integrator);
        let _ = writeln!(
            md,
            "  - its image at 1 spp (seed {}): `{}`; with N in place of the 1 after `{}`, its \
             image at N spp, whatever the budget that reached it (a run's spp is in runs.csv)",
            r.seeds[0],
            super::command::render_command(
                &r.scene,
                r.width,
                r.height,
                m,
                r.denoise.as_ref(),
                r.seeds[0],
                1
            ),
            if m.has_cache() { "--frames" } else { "--spp" }
        );
    }
    let _ = writeln!(md, "\n## Results\n");
    md.push_str(TABLE_HEAD);
    for s in &r.summary {
        md.push_str(&table_row(s, &s.method));
    }
    md.push('\n');
    md.push_str(&findings(r));
    if !r.caches.is_empty() {
        let _ = writeln!(md, "\n## Caches (first seed)\n");
        md.push_str("Per-frame costs are over the measured frames that used the cache; the frames after its handoff to plain path tracing (`handoff_frames`) are counted apart.\n\n");
        md.push_str("`read ms` is splatting (or ray tracing) the levels for the Gaussian cache, and inference with composition for the neural cache (the GSCache paper's ST and IT); `train ms` is OT.\n\n");
        md.push_str("| method | init ms | warm-up frames | warm-up s | trace ms per frame | read ms | train ms | (read + train) / trace | frames with the cache / handed off | MB |\n|---|---|---|---|---|---|---|---|---|---|\n");
        for c in &r.caches {
            let _ = writeln!(
                md,
                "| {} | {:.0} | {} | {:.2} | {:.1} | {:.1} | {:.1} | {:.2}x | {} / {} | {:.1} |",
                c.method,
                c.init_seconds * 1e3,
                c.warmup_frames,
                c.warmup_seconds,
                c.trace_ms,
                c.splat_ms,
                c.train_ms,
                (c.splat_ms + c.train_ms) / c.trace_ms.max(1e-9),
                c.record.frame_seconds.len(),
                c.record.handed_off,
                c.parameter_bytes as f64 / 1e6
            );
        }
    }
    for a in &r.ablations {
        let _ = writeln!(md, "\n## Ablation `{}`: `{}`\n", a.name, a.parameter);
        md.push_str(&TABLE_HEAD.replacen("| method |", &format!("| {} |", a.parameter), 1));
        for (value, rows) in &a.rows {
            for s in rows {
                md.push_str(&table_row(s, value));
            }
        }
        md.push_str(&ablation_findings(a));
    }
    if !r.flythroughs.is_empty() {
        let _ = writeln!(md, "\n## Fly-throughs (seed {})\n", r.seeds[0]);
        md.push_str(
            "Means over the measured frames (after the warm-up); the errors over the scored ones. \
             Flicker: each scored frame's change from the frame before against the references' \
             change (relMSE-weighted); JOD: ColorVideoVDP over the closing clip (10: no visible \
             difference).\n\n",
        );
        md.push_str("| flythrough | method | frames | passes | ms per frame | trace | splat | train | denoise | relMSE | FLIP | flicker | JOD |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
        let mut keys: Vec<(&str, &str)> = r
            .flythroughs
            .iter()
            .map(|f| (f.flythrough.as_str(), f.method.as_str()))
            .collect();
        keys.dedup();
        for (fly, m) in keys {
            let fr: Vec<_> = r
                .flythroughs
                .iter()
                .filter(|f| f.flythrough == fly && f.method == m && !f.warmup)
                .collect();
            let n = fr.len().max(1) as f64;
            let mean = |v: &dyn Fn(&&super::flythrough::FrameRecord) -> f64| {
                fr.iter().map(v).sum::<f64>() / n
            };
            let scored_mean = |v: &dyn Fn(&&super::flythrough::FrameRecord) -> Option<f64>,
                               show: &dyn Fn(f64) -> String| {
                let vals: Vec<f64> = fr.iter().filter_map(v).collect();
                if vals.is_empty() {
                    "-".to_string()
                } else {
                    show(vals.iter().sum::<f64>() / vals.len() as f64)
                }
            };
            let _ = writeln!(
                md,
                "| {fly} | {m} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {} | {} | {} |",
                fr.len(),
                mean(&|f| f64::from(f.passes)),
                mean(&|f| f.total_ms),
                mean(&|f| f.trace_ms),
                mean(&|f| f.splat_ms),
                mean(&|f| f.train_ms),
                mean(&|f| f.denoise_ms),
                scored_mean(&|f| f.rel_mse, &sci),
                scored_mean(&|f| f.flip, &|v| format!("{v:.4}")),
                scored_mean(&|f| f.flicker, &sci),
                scored_mean(&|f| f.jod, &|v| format!("{v:.3}")),
            );
        }
        for (fly, frame, what) in &r.flythrough_events {
            let _ = writeln!(md, "\nFly-through `{fly}`: at frame {frame}, {what}.");
        }
    }
    let _ = writeln!(md, "\n## Figures\n");
    for (caption, file) in figures {
        let _ = writeln!(md, "{caption}:\n\n![{caption}]({file})\n");
    }
    let _ = writeln!(
        md,
        "Files: `runs.csv` (every run), `summary.csv`, `ablations.csv`, `flythrough.csv`, `results.json` (everything), `plots/` (PNG and SVG)."
    );
    md
}

/// Per budget, the sweep's best value and how far ahead of the next it is, in standard errors
/// of the difference of the means over seeds.
fn ablation_findings(a: &super::run::AblationResult) -> String {
    let budgets: Vec<Budget> = a
        .rows
        .first()
        .map(|(_, rows)| rows.iter().map(|s| s.budget).collect())
        .unwrap_or_default();
    let mut out = String::new();
    for b in budgets {
        let mut ranked: Vec<(&str, &SummaryRow)> = a
            .rows
            .iter()
            .filter_map(|(v, rows)| Some((v.as_str(), rows.iter().find(|s| s.budget == b)?)))
            .collect();
        ranked.sort_by(|x, y| x.1.rel_mse.total_cmp(&y.1.rel_mse));
        let Some((best, first)) = ranked.first() else {
            continue;
        };
        let _ = write!(
            out,
            "\n- At {}: lowest relMSE with `{}={best}` ({:.4})",
            budget_label(b),
            a.parameter,
            first.rel_mse
        );
        if let Some((next, second)) = ranked.get(1) {
            let se = |s: &SummaryRow| s.rel_mse_sd / (s.seeds.max(1) as f64).sqrt();
            let z = (second.rel_mse - first.rel_mse) / se(first).hypot(se(second));
            let apart = if z.is_finite() {
                format!("{z:.1} standard errors apart")
            } else {
                "no spread across seeds".into()
            };
            let _ = write!(
                out,
                ", then `{}={next}` ({:.4}; {apart})",
                a.parameter, second.rel_mse
            );
        }
        out.push('.');
    }
    if !out.is_empty() {
        out.push('\n');
    }
    out
}

/// An unbiased estimator's relMSE falls with samples. When it rises by half or more from one
/// spp budget to a larger one, rare bright samples (fireflies) are at work: at low spp they
/// land in the trimmed top 0.1% of pixels, at high spp they are too many to trim, so the
/// low-spp relMSE understates the error. Says so, or `None`.
fn rising_error(rows: &[&SummaryRow]) -> Option<String> {
    let mut by_spp: Vec<&&SummaryRow> = rows
        .iter()
        .filter(|s| matches!(s.budget, Budget::Spp(_)))
        .collect();
    by_spp.sort_by(|a, b| a.spp.total_cmp(&b.spp));
    by_spp.windows(2).find_map(|w| {
        (w[1].rel_mse > 1.5 * w[0].rel_mse).then(|| {
            format!(
                "its relMSE rises from {:.4} at {} to {:.4} at {}: rare bright samples (fireflies) \
                 fall in the trimmed top 0.1% at low spp and not at high spp, so its low-spp \
                 relMSE understates its error",
                w[0].rel_mse,
                budget_label(w[0].budget),
                w[1].rel_mse,
                budget_label(w[1].budget)
            )
        })
    })
}

/// Where a method stops paying as samples grow: the spp budgets at which its efficiency (1 /
/// (relMSE x time)) against the baseline's is at least 1, and the first larger one at which it
/// falls below, or `None` when it never changes side (or has fewer than two spp budgets).
fn stops_paying(rows: &[&SummaryRow]) -> Option<String> {
    let mut by_spp: Vec<(f64, f64)> = rows
        .iter()
        .filter(|s| matches!(s.budget, Budget::Spp(_)))
        .filter_map(|s| Some((s.spp, s.efficiency_vs_baseline?)))
        .collect();
    by_spp.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (&(first_spp, first), rest) = by_spp.split_first()?;
    if first < 1.0 {
        return None;
    }
    let lost = rest.iter().position(|&(_, e)| e < 1.0)?;
    let (last_win, last_eff) = if lost == 0 {
        (first_spp, first)
    } else {
        rest[lost - 1]
    };
    let (spp, eff) = rest[lost];
    Some(format!(
        "it stops paying between {last_win} spp (efficiency {last_eff:.2}x the baseline's) and {spp} spp ({eff:.2}x)"
    ))
}

/// Which of relMSE, FLIP and PSNR-HDR rate `row` ahead of `base` (the baseline at the same
/// budget), with the figures, e.g. "ahead by relMSE (2.10x lower) and PSNR-HDR (+1.3 dB),
/// behind by FLIP (0.0312 against 0.0287)". A difference under 2% (0.1 dB) is a tie: the three
/// seeds cannot tell it apart.
fn metric_verdict(row: &SummaryRow, base: &SummaryRow) -> String {
    let (mut ahead, mut behind, mut tied) = (Vec::new(), Vec::new(), Vec::new());
    let mut judge = |name: &str, better: Option<bool>, text: String| match better {
        Some(true) => ahead.push(format!("{name} ({text})")),
        Some(false) => behind.push(format!("{name} ({text})")),
        None => tied.push(name.to_string()),
    };
    let ratio = base.rel_mse / row.rel_mse;
    judge(
        "relMSE",
        ((ratio - 1.0).abs() > 0.02).then_some(ratio > 1.0),
        if ratio >= 1.0 {
            format!("{ratio:.2}x lower")
        } else {
            format!("{:.2}x higher", 1.0 / ratio)
        },
    );
    if let (Some(f), Some(bf)) = (row.flip, base.flip) {
        judge(
            "FLIP",
            ((f - bf).abs() > 0.02 * bf).then_some(f < bf),
            format!("{f:.4} against {bf:.4}"),
        );
    }
    let d = row.psnr_hdr - base.psnr_hdr;
    judge(
        "PSNR-HDR",
        (d.abs() > 0.1).then_some(d > 0.0),
        format!("{d:+.1} dB"),
    );
    let mut out = Vec::new();
    if !ahead.is_empty() {
        out.push(format!("ahead by {}", ahead.join(" and ")));
    }
    if !behind.is_empty() {
        out.push(format!("behind by {}", behind.join(" and ")));
    }
    if !tied.is_empty() {
        out.push(format!("tied by {}", tied.join(" and ")));
    }
    out.join(", ")
}

/// Plain sentences: where each method beats the baseline at equal time and where it loses,
/// by relMSE and, per budget, by each metric.
fn findings(r: &Results) -> String {
    let Some(base) = &r.baseline else {
        return String::new();
    };
    let base_method = r.methods.iter().find(|m| &m.name == base);
    let mut out = String::from("What this shows:\n\n");
    for m in r.methods.iter().filter(|m| &m.name != base) {
        let rows: Vec<&SummaryRow> = r.summary.iter().filter(|s| s.method == m.name).collect();
        // A twin is judged against the baseline's twin with the same guides.
        let base_name = match (m.denoised, base_method) {
            (Some(g), Some(b)) => b.denoised_twin(g).name,
            _ => base.clone(),
        };
        if base_name == m.name {
            continue;
        }
        let base_rows: Vec<&SummaryRow> =
            r.summary.iter().filter(|s| s.method == base_name).collect();
        let timed: Vec<&&SummaryRow> = rows
            .iter()
            .filter(|s| matches!(s.budget, Budget::Seconds(_)))
            .collect();
        let mut parts = Vec::new();
        // Per time budget, in words that cannot be misread: lower or higher, and by how much.
        let at_equal_time: Vec<String> = timed
            .iter()
            .filter_map(|s| {
                let g = s.gain_vs_baseline?;
                let at = budget_label(s.budget);
                Some(if g >= 1.0 {
                    format!("{g:.2}x lower at {at}")
                } else {
                    format!("{:.2}x higher at {at}", 1.0 / g)
                })
            })
            .collect();
        if !at_equal_time.is_empty() {
            parts.push(format!("relMSE at equal time {}", at_equal_time.join(", ")));
        }
        let verdicts: Vec<String> = rows
            .iter()
            .filter(|s| matches!(s.budget, Budget::Seconds(_)) || s.budget == Budget::Spp(1))
            .filter_map(|s| {
                let b = base_rows.iter().find(|b| b.budget == s.budget)?;
                // A denoised twin whose filter alone outlasts the budget denoises one frame
                // and overruns: said, so that its figures are not read as fitting.
                let over = match s.budget {
                    Budget::Seconds(t) if s.seconds > 1.25 * t => {
                        format!(" (over budget: {:.0} ms)", s.seconds * 1e3)
                    }
                    _ => String::new(),
                };
                Some(format!(
                    "at {}{over}: {}",
                    budget_label(s.budget),
                    metric_verdict(s, b)
                ))
            })
            .collect();
        if !verdicts.is_empty() {
            parts.push(format!("by metric, {}", verdicts.join("; ")));
        }
        let effs: Vec<f64> = rows
            .iter()
            .filter_map(|s| s.efficiency_vs_baseline)
            .collect();
        if !effs.is_empty() {
            let lo = effs.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = effs.iter().cloned().fold(0.0, f64::max);
            let range = if hi - lo < 0.005 {
                format!("{lo:.2}x")
            } else {
                format!("{lo:.2}x to {hi:.2}x")
            };
            parts.push(format!(
                "efficiency (1 / (relMSE x time)) {range} the baseline's over all budgets"
            ));
        }
        let bias: Vec<String> = rows
            .iter()
            .filter_map(|s| {
                s.bias
                    .filter(|b| {
                        (b.brightness.abs() > 3.0 * b.brightness_se) && b.brightness.abs() > 0.01
                    })
                    .map(|b| {
                        format!(
                            "{:+.1}% at {}",
                            b.brightness * 100.0,
                            budget_label(s.budget)
                        )
                    })
            })
            .collect();
        if !bias.is_empty() {
            parts.push(format!(
                "brightness bias beyond 3 standard errors: {}",
                bias.join(", ")
            ));
        }
        if let Some(warning) = rising_error(&rows) {
            parts.push(warning);
        }
        if let Some(crossing) = stops_paying(&rows) {
            parts.push(crossing);
        }
        let _ = writeln!(
            out,
            "- `{}` against `{base_name}`: {}.",
            m.name,
            parts.join("; ")
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(spp: u32, rel_mse: f64) -> SummaryRow {
        SummaryRow {
            method: "m".into(),
            budget: Budget::Spp(spp),
            seeds: 3,
            spp: spp as f64,
            seconds: 0.01 * spp as f64,
            rel_mse,
            rel_mse_sd: 0.0,
            psnr_hdr: 0.0,
            psnr_tonemapped: 0.0,
            smape: 0.0,
            flip: None,
            ssim: None,
            efficiency: 1.0,
            efficiency_vs_baseline: None,
            gain_vs_baseline: None,
            bias: None,
        }
    }

    #[test]
    fn a_relmse_rising_with_samples_is_flagged() {
        // Listed out of order on purpose: the check sorts by spp.
        let (a, b, c) = (row(16, 2.1), row(1, 0.09), row(4, 0.08));
        let w = rising_error(&[&a, &b, &c]).expect("0.08 at 4 spp to 2.1 at 16 spp is flagged");
        assert!(
            w.contains("0.0800 at 4 spp") && w.contains("2.1000 at 16 spp"),
            "{w}"
        );
        // Falling, or a rise under half, is not.
        let (a, b, c) = (row(1, 0.18), row(4, 0.05), row(16, 0.07));
        assert_eq!(rising_error(&[&a, &b, &c]), None);
    }

    #[test]
    fn where_a_method_stops_paying_is_named() {
        let with = |spp, e| SummaryRow {
            efficiency_vs_baseline: Some(e),
            ..row(spp, 0.1)
        };
        // Out of order on purpose; wins at 1 and 4, loses from 16.
        let (a, b, c, d) = (with(16, 0.8), with(1, 3.0), with(64, 0.5), with(4, 1.4));
        let s = stops_paying(&[&a, &b, &c, &d]).expect("1.4x at 4 spp, 0.8x at 16 spp");
        assert!(
            s.contains("between 4 spp (efficiency 1.40x") && s.contains("and 16 spp (0.80x)"),
            "{s}"
        );
        // Always winning, or losing from the start, says nothing.
        let (a, b) = (with(1, 2.0), with(16, 1.1));
        assert_eq!(stops_paying(&[&a, &b]), None);
        let (a, b) = (with(1, 0.9), with(16, 1.1));
        assert_eq!(stops_paying(&[&a, &b]), None);
    }
}
