//! Running an experiment: the reference, every method at every budget for every seed, the
//! fly-throughs and the ablation sweeps. Each run's row is appended to `runs.csv` as soon as it
//! is measured, so an interrupted experiment keeps what it measured.

use super::config::{Budgets, DenoiseSpec, Experiment, MethodSpec};
use super::csv::{budget_fields, csv_text};
use super::flythrough::FrameRecord;
use super::records::{Budget, CacheRecord, Snapshot};
use super::reference::reference;
use super::units::{UnitResult, measure_unit};
use crate::error::{Error, Result, refuse};
use glam::Vec3;
use hdr_image::tone_map;
use image_metrics::{
    BiasEstimate, SeedSpread, efficiency, flip, hdr_peak, psnr, psnr_8bit, rel_mse, smape, ssim,
};
use serde::Serialize;
use std::path::PathBuf;
use volume_pt::Scene;

/// One method at one budget with one seed.
#[derive(Debug, Clone, Serialize)]
pub struct RunRow {
    pub method: String,
    pub budget: Budget,
    pub seed: u64,
    pub spp: u32,
    /// Wall-clock seconds of the image (a cache's warm-up excluded; see `warmup_seconds`).
    pub seconds: f64,
    pub warmup_seconds: f64,
    pub rel_mse: f64,
    pub psnr_hdr: f64,
    pub psnr_tonemapped: f64,
    pub smape: f64,
    pub flip: Option<f64>,
    pub ssim: Option<f64>,
    pub efficiency: f64,
    pub nonfinite_samples: u64,
}

impl RunRow {
    pub const CSV_HEADER: &'static str = "method,budget_kind,budget,seed,spp,seconds,warmup_seconds,rel_mse,psnr_hdr,psnr_tonemapped,smape,flip,ssim,efficiency,nonfinite_samples";

    pub fn csv(&self) -> String {
        let (kind, value) = budget_fields(self.budget);
        format!(
            "{},{kind},{value},{},{},{:.6},{:.6},{:.6e},{:.4},{:.4},{:.6},{},{},{:.6e},{}",
            csv_text(&self.method),
            self.seed,
            self.spp,
            self.seconds,
            self.warmup_seconds,
            self.rel_mse,
            self.psnr_hdr,
            self.psnr_tonemapped,
            self.smape,
            self.flip.map_or(String::new(), |f| format!("{f:.6}")),
            self.ssim.map_or(String::new(), |f| format!("{f:.6}")),
            self.efficiency,
            self.nonfinite_samples
        )
    }
}

/// One method at one budget, over the seeds.
#[derive(Debug, Clone, Serialize)]
pub struct SummaryRow {
    pub method: String,
    pub budget: Budget,
    pub seeds: usize,
    pub spp: f64,
    pub seconds: f64,
    pub rel_mse: f64,
    /// Standard deviation over seeds.
    pub rel_mse_sd: f64,
    pub psnr_hdr: f64,
    pub psnr_tonemapped: f64,
    pub smape: f64,
    pub flip: Option<f64>,
    pub ssim: Option<f64>,
    /// `1 / (mean relMSE x mean seconds)`.
    pub efficiency: f64,
    /// This method's efficiency over the baseline's at the same budget.
    pub efficiency_vs_baseline: Option<f64>,
    /// The baseline's relMSE over this method's at the same budget (at a time budget: the gain
    /// at equal time).
    pub gain_vs_baseline: Option<f64>,
    pub bias: Option<BiasEstimate>,
}

/// What a cached method's first seed left: its cost and its levels.
#[derive(Debug, Clone, Serialize)]
pub struct CacheSummary {
    pub method: String,
    pub init_seconds: f64,
    pub warmup_seconds: f64,
    pub warmup_frames: u32,
    pub parameter_bytes: usize,
    /// Mean per measured frame: path tracing, splatting (lookup), training, in ms.
    pub trace_ms: f64,
    pub splat_ms: f64,
    pub train_ms: f64,
    #[serde(skip)]
    pub record: CacheRecord,
}

/// One ablation's results.
#[derive(Debug, Clone, Serialize)]
pub struct AblationResult {
    pub name: String,
    pub parameter: String,
    /// (value, the variant's summary at each budget).
    pub rows: Vec<(String, Vec<SummaryRow>)>,
}

/// The reference's facts, for the report.
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceInfo {
    pub file: PathBuf,
    pub spp: u32,
    pub reused: bool,
    pub seconds: f64,
    /// The PSNR peak on HDR images: the reference's 99.9th percentile channel value.
    pub hdr_peak: f64,
}

/// Everything an experiment measured.
#[derive(Debug, Clone, Serialize)]
pub struct Results {
    pub name: String,
    pub scene: PathBuf,
    pub width: u32,
    pub height: u32,
    pub threads: usize,
    pub seeds: Vec<u64>,
    pub baseline: Option<String>,
    pub methods: Vec<MethodSpec>,
    pub reference: ReferenceInfo,
    pub runs: Vec<RunRow>,
    pub summary: Vec<SummaryRow>,
    pub caches: Vec<CacheSummary>,
    pub flythroughs: Vec<FrameRecord>,
    /// (flythrough, frame, what changed).
    pub flythrough_events: Vec<(String, u32, String)>,
    pub ablations: Vec<AblationResult>,
    /// How the denoised twins were made (the report's command lines repeat it).
    #[serde(skip)]
    pub denoise: Option<DenoiseSpec>,
    #[serde(skip)]
    pub images: Images,
}

/// Images kept for the figures (first seed only).
#[derive(Debug, Clone, Default)]
pub struct Images {
    pub reference: Vec<Vec3>,
    /// (method, budget, image).
    pub snapshots: Vec<(String, Budget, Vec<Vec3>)>,
}

/// What rendering a method at budgets gives.
struct Evaluation {
    runs: Vec<RunRow>,
    summary: Vec<SummaryRow>,
    cache: Option<CacheSummary>,
    snapshots: Vec<Snapshot>,
}

/// The tone-mapped image of the report's figures and the tone-mapped metrics.
fn ldr(img: &[Vec3], scene: &Scene) -> Vec<u8> {
    tone_map(img, scene.output.exposure, scene.output.tonemap)
}

fn budgets_of(b: &Budgets) -> Vec<Budget> {
    b.spp
        .iter()
        .map(|&s| Budget::Spp(s))
        .chain(b.seconds.iter().map(|&s| Budget::Seconds(s)))
        .collect()
}

/// Where the assembly gets unit `k`'s measurements: measured on the spot (one process), or
/// from shard files (a merge).
pub type UnitSource<'a> = dyn FnMut(usize) -> Result<UnitResult> + 'a;

/// The rows of `runs.csv`, written out after each.
struct RunsCsv {
    path: std::path::PathBuf,
    text: String,
}

impl RunsCsv {
    fn create(path: std::path::PathBuf) -> Result<Self> {
        let csv = Self {
            path,
            text: format!("{}\n", RunRow::CSV_HEADER),
        };
        csv.save()?;
        Ok(csv)
    }

    fn push(&mut self, row: &str) -> Result<()> {
        self.text.push_str(row);
        self.text.push('\n');
        self.save()
    }

    fn save(&self) -> Result<()> {
        crate::write_text(&self.path, &self.text)
    }
}

struct Setup<'a, 's> {
    scene: &'a Scene,
    reference: &'a [Vec3],
    reference_ldr: Vec<u8>,
    peak: f64,
    seeds: &'a [u64],
    /// `runs.csv` so far: rewritten whole (atomically) after each run, so a stopped experiment
    /// keeps the rows it has and the file is never written through a planted link.
    csv: RunsCsv,
    source: &'a mut UnitSource<'s>,
    /// The next unit the assembly reads (the order of `units::all`).
    next_unit: usize,
}

impl Setup<'_, '_> {
    fn next(&mut self) -> Result<UnitResult> {
        let k = self.next_unit;
        self.next_unit += 1;
        (self.source)(k)
    }
}

/// Measures `method` at `budgets` over the seeds: one evaluation for the method's own images
/// and one for each of its denoised `twins` (the twin methods, in the order the units carry
/// their snapshots).
fn evaluate(
    cx: &mut Setup,
    method: &MethodSpec,
    budgets: &[Budget],
    twins: &[MethodSpec],
) -> Result<Vec<Evaluation>> {
    let (w, h) = (cx.scene.camera.width, cx.scene.camera.height);
    let variants: Vec<&MethodSpec> = std::iter::once(method).chain(twins).collect();
    let mut runs: Vec<Vec<RunRow>> = variants.iter().map(|_| Vec::new()).collect();
    let mut spreads: Vec<Vec<SeedSpread>> = variants
        .iter()
        .map(|_| {
            budgets
                .iter()
                .map(|_| SeedSpread::new(cx.reference.len()))
                .collect()
        })
        .collect();
    let mut cache = None;
    let mut first_snapshots: Vec<Vec<Snapshot>> = variants.iter().map(|_| Vec::new()).collect();
    for (si, &seed) in cx.seeds.iter().enumerate() {
        let UnitResult::Method {
            snapshots: mut snaps,
            record,
        } = cx.next()?
        else {
            refuse!(
                "unit {} is not a run of `{}`: the shards do not match the experiment",
                cx.next_unit - 1,
                method.name
            );
        };
        // Snapshots arrive in the order their budgets were reached, which depends on the
        // machine's speed (8 spp may come before or after 0.02 s): rows follow the experiment's
        // budget order instead, so that every run, shard and merge lists them alike.
        snaps.sort_by_key(|s| budgets.iter().position(|b| *b == s.budget));
        let warmup_seconds = record.as_ref().map_or(0.0, |r| r.warmup_seconds);
        let nonfinite = record.as_ref().map_or(0, |r| r.nonfinite_samples);
        for (vi, variant) in variants.iter().enumerate() {
            let mine: Vec<Snapshot> = snaps
                .iter()
                .filter(|s| s.denoised == variant.denoised)
                .cloned()
                .collect();
            if mine.len() != budgets.len() {
                refuse!(
                    "unit {} holds {} images of `{}` for {} budgets: the shards do not match the \
                     experiment",
                    cx.next_unit - 1,
                    mine.len(),
                    variant.name,
                    budgets.len()
                );
            }
            for snap in &mine {
                let img = &snap.image;
                let e = rel_mse(img, cx.reference);
                let tm = ldr(img, cx.scene);
                let row = RunRow {
                    method: variant.name.clone(),
                    budget: snap.budget,
                    seed,
                    spp: snap.spp,
                    seconds: snap.seconds,
                    warmup_seconds,
                    rel_mse: e,
                    psnr_hdr: psnr(img, cx.reference, cx.peak),
                    psnr_tonemapped: psnr_8bit(&tm, &cx.reference_ldr),
                    smape: smape(img, cx.reference),
                    flip: flip(&tm, &cx.reference_ldr, w, h),
                    ssim: ssim(&tm, &cx.reference_ldr, w, h),
                    efficiency: efficiency(e, snap.seconds),
                    nonfinite_samples: nonfinite,
                };
                cx.csv.push(&row.csv())?;
                let i = budgets.iter().position(|b| *b == snap.budget).unwrap_or(0);
                spreads[vi][i].add(img);
                runs[vi].push(row);
            }
            if si == 0 {
                first_snapshots[vi] = mine;
            }
        }
        if si == 0
            && let (true, Some(r)) = (method.has_cache(), record)
        {
            let n = r.frame_seconds.len().max(1) as f64;
            let mean = |k: usize| r.frame_seconds.iter().map(|s| s[k]).sum::<f64>() / n * 1e3;
            cache = Some(CacheSummary {
                method: method.name.clone(),
                init_seconds: r.init_seconds,
                warmup_seconds: r.warmup_seconds,
                warmup_frames: method.cache.warmup(),
                parameter_bytes: r.parameter_bytes,
                trace_ms: mean(0),
                splat_ms: mean(1),
                train_ms: mean(2),
                record: r,
            });
        }
    }
    let mut out = Vec::new();
    for (vi, variant) in variants.iter().enumerate() {
        let summary = budgets
            .iter()
            .zip(&spreads[vi])
            .map(|(b, spread)| summarise(&variant.name, *b, &runs[vi], spread, cx.reference))
            .collect();
        out.push(Evaluation {
            runs: std::mem::take(&mut runs[vi]),
            summary,
            cache: if vi == 0 { cache.take() } else { None },
            snapshots: std::mem::take(&mut first_snapshots[vi]),
        });
    }
    Ok(out)
}

fn summarise(
    method: &str,
    budget: Budget,
    runs: &[RunRow],
    spread: &SeedSpread,
    reference: &[Vec3],
) -> SummaryRow {
    let rows: Vec<&RunRow> = runs.iter().filter(|r| r.budget == budget).collect();
    let n = rows.len().max(1) as f64;
    let mean = |f: &dyn Fn(&RunRow) -> f64| rows.iter().map(|r| f(r)).sum::<f64>() / n;
    let e = mean(&|r| r.rel_mse);
    let sd =
        (rows.iter().map(|r| (r.rel_mse - e).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
    let seconds = mean(&|r| r.seconds);
    let mean_of = |f: &dyn Fn(&RunRow) -> Option<f64>| {
        let v: Vec<f64> = rows.iter().filter_map(|r| f(r)).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    SummaryRow {
        method: method.to_string(),
        budget,
        seeds: rows.len(),
        spp: mean(&|r| r.spp as f64),
        seconds,
        rel_mse: e,
        rel_mse_sd: sd,
        psnr_hdr: mean(&|r| r.psnr_hdr),
        psnr_tonemapped: mean(&|r| r.psnr_tonemapped),
        smape: mean(&|r| r.smape),
        flip: mean_of(&|r| r.flip),
        ssim: mean_of(&|r| r.ssim),
        efficiency: efficiency(e, seconds),
        efficiency_vs_baseline: None,
        gain_vs_baseline: None,
        bias: spread.estimate(reference),
    }
}

/// Fills the comparisons with the baseline's rows at the same budgets.
fn compare_with(rows: &mut [SummaryRow], baseline: &[SummaryRow]) {
    for r in rows {
        if let Some(b) = baseline.iter().find(|b| b.budget == r.budget) {
            r.efficiency_vs_baseline = Some(r.efficiency / b.efficiency);
            r.gain_vs_baseline = Some(b.rel_mse / r.rel_mse);
        }
    }
}

/// The experiment's scene at the experiment's image size.
pub fn experiment_scene(exp: &Experiment) -> Result<Scene> {
    let mut scene = volume_pt::load_scene(&exp.scene)?;
    if let Some((w, h)) = exp.size {
        scene.camera = scene
            .camera
            .with_size(w, h)
            .map_err(|e| Error::file(&exp.file, format!("width and height: {e}")))?;
    }
    Ok(scene)
}

/// The main budgets and each ablation's.
pub fn all_budgets(exp: &Experiment) -> (Vec<Budget>, Vec<Vec<Budget>>) {
    (
        budgets_of(&exp.budgets),
        exp.ablations
            .iter()
            .map(|a| budgets_of(&a.budgets))
            .collect(),
    )
}

/// Runs the experiment in one process; `progress` receives one line per step.
pub fn run(exp: &Experiment, progress: &dyn Fn(&str)) -> Result<Results> {
    run_resumable(
        exp,
        progress,
        &render_session::Control::none(),
        Default::default(),
        &mut |_, _| {},
    )
}

/// Stops an experiment between units: [`run_resumable`]'s error when its control is cancelled.
#[derive(Debug, thiserror::Error)]
#[error("the experiment was interrupted between units")]
pub struct Cancelled;

/// [`run`] that takes the units in `done` as measured (a resumed run), hands each unit it
/// measures to `measured`, and stops with [`Cancelled`] before the next unit once `control` is
/// cancelled, so the caller can keep what was measured.
pub fn run_resumable(
    exp: &Experiment,
    progress: &dyn Fn(&str),
    control: &render_session::Control,
    mut done: std::collections::BTreeMap<usize, UnitResult>,
    measured: &mut dyn FnMut(usize, &UnitResult),
) -> Result<Results> {
    let scene = experiment_scene(exp)?;
    let (main, ablation) = all_budgets(exp);
    let units = super::units::all(exp, &main, &ablation);
    // The run's own denoisers and costs: the twins' timings do not depend on earlier runs.
    let mut denoisers = super::denoised::Denoisers::new();
    assemble(exp, &scene, progress, &mut |k| {
        if let Some(r) = done.remove(&k) {
            return Ok(r);
        }
        if control.cancelled() {
            return Err(Error::Cancelled);
        }
        let r = measure_unit(exp, &scene, units[k], &mut denoisers, progress)?;
        measured(k, &r);
        Ok(r)
    })
}

/// Runs the experiment from units measured by shards (`units::gather_units`).
pub fn merge(
    exp: &Experiment,
    mut measured: std::collections::BTreeMap<usize, UnitResult>,
    progress: &dyn Fn(&str),
) -> Result<Results> {
    let scene = experiment_scene(exp)?;
    assemble(exp, &scene, progress, &mut |k| {
        measured
            .remove(&k)
            .ok_or_else(|| Error::Invalid(format!("unit {k} is missing from the shards")))
    })
}

/// Everything but the measuring: the reference, the metrics of every unit read from `source`
/// in the order of `units::all`, summaries and comparisons, `runs.csv`.
fn assemble(
    exp: &Experiment,
    scene: &Scene,
    progress: &dyn Fn(&str),
    source: &mut UnitSource<'_>,
) -> Result<Results> {
    let (w, h) = (scene.camera.width, scene.camera.height);
    std::fs::create_dir_all(&exp.output)
        .map_err(|e| Error::io(&exp.output, "cannot create the output folder", e))?;
    let r = experiment_reference(exp, scene, progress)?;
    let peak = hdr_peak(&r.image);
    let csv_path = exp.output.join("runs.csv");
    let csv = RunsCsv::create(csv_path)?;
    let mut cx = Setup {
        scene,
        reference: &r.image,
        reference_ldr: ldr(&r.image, scene),
        peak,
        seeds: &exp.seeds,
        csv,
        source,
        next_unit: 0,
    };
    let mut results = Results {
        name: exp.name.clone(),
        scene: exp.scene.clone(),
        width: w,
        height: h,
        threads: rayon::current_num_threads(),
        seeds: exp.seeds.clone(),
        baseline: exp.baseline.clone(),
        methods: exp.methods.clone(),
        reference: ReferenceInfo {
            file: r.file.clone(),
            spp: r.spp,
            reused: r.reused,
            seconds: r.seconds,
            hdr_peak: peak,
        },
        runs: Vec::new(),
        summary: Vec::new(),
        caches: Vec::new(),
        flythroughs: Vec::new(),
        flythrough_events: Vec::new(),
        ablations: Vec::new(),
        denoise: exp.denoise.clone(),
        images: Images {
            reference: r.image.clone(),
            snapshots: Vec::new(),
        },
    };
    evaluate_methods(&mut cx, exp, &mut results, progress)?;
    let base_rows = compare_with_baseline(exp, &mut results);
    gather_flythroughs(&mut cx, exp, &mut results)?;
    evaluate_ablations(&mut cx, exp, &base_rows, &mut results, progress)?;
    Ok(results)
}

/// The experiment's reference image, rendered or reused (and said which).
fn experiment_reference(
    exp: &Experiment,
    scene: &Scene,
    progress: &dyn Fn(&str),
) -> Result<super::reference::Reference> {
    let r = reference(
        &exp.reference.dir,
        &exp.scene,
        "",
        scene,
        &scene.camera,
        exp.reference.spp,
        Some(progress),
    )?;
    progress(&if r.reused {
        format!("reference: reused {}", r.file.display())
    } else {
        format!(
            "reference: rendered {} ({} spp, {:.1} s)",
            r.file.display(),
            r.spp,
            r.seconds
        )
    });
    Ok(r)
}

/// Every method and its denoised twins at the experiment's budgets: their runs, summaries,
/// cache records and snapshots (the methods list gains the twins, each after its method).
fn evaluate_methods(
    cx: &mut Setup<'_, '_>,
    exp: &Experiment,
    results: &mut Results,
    progress: &dyn Fn(&str),
) -> Result<()> {
    let budgets = budgets_of(&exp.budgets);
    let mut methods = Vec::new();
    for m in &exp.methods {
        let twins: Vec<MethodSpec> = exp
            .denoise
            .iter()
            .flat_map(|d| d.guides.iter().map(|&g| m.denoised_twin(g)))
            .collect();
        let evs = evaluate(cx, m, &budgets, &twins)?;
        for (variant, ev) in std::iter::once(m).chain(&twins).zip(evs) {
            progress(&format!("{}: {} runs", variant.name, ev.runs.len()));
            results.runs.extend(ev.runs);
            results.summary.extend(ev.summary);
            results.caches.extend(ev.cache);
            results.images.snapshots.extend(
                ev.snapshots
                    .into_iter()
                    .map(|s| (variant.name.clone(), s.budget, s.image)),
            );
            methods.push(variant.clone());
        }
    }
    results.methods = methods;
    Ok(())
}

/// Each summary row's gains over the baseline's at its budget: a twin against the baseline's
/// twin of the same guides (denoised against denoised), every other method against the
/// baseline. Returns the baseline's rows (the ablations compare with them too).
fn compare_with_baseline(exp: &Experiment, results: &mut Results) -> Vec<SummaryRow> {
    let rows_of = |summary: &[SummaryRow], name: &str| -> Vec<SummaryRow> {
        summary
            .iter()
            .filter(|r| r.method == name)
            .cloned()
            .collect()
    };
    let base_rows: Vec<SummaryRow> = exp
        .baseline
        .as_deref()
        .map(|b| rows_of(&results.summary, b))
        .unwrap_or_default();
    let mut comparisons = Vec::new();
    if let Some(b) = exp
        .methods
        .iter()
        .find(|m| Some(&m.name) == exp.baseline.as_ref())
    {
        for m in &results.methods {
            let base = match m.denoised {
                Some(g) => b.denoised_twin(g).name,
                None => b.name.clone(),
            };
            comparisons.push((m.name.clone(), rows_of(&results.summary, &base)));
        }
    }
    for (name, base) in comparisons {
        for r in results.summary.iter_mut().filter(|r| r.method == name) {
            compare_with(std::slice::from_mut(r), &base);
        }
    }
    base_rows
}

/// Each fly-through's frames (from its unit) and the scene edits on its way.
fn gather_flythroughs(
    cx: &mut Setup<'_, '_>,
    exp: &Experiment,
    results: &mut Results,
) -> Result<()> {
    for fl in &exp.flythroughs {
        for e in &fl.events {
            let (_, what) = super::flythrough::event_edit(cx.scene, e)?;
            results
                .flythrough_events
                .push((fl.name.clone(), e.frame, what));
        }
        let UnitResult::Fly(frames) = cx.next()? else {
            refuse!(
                "unit {} is not fly-through `{}`: the shards do not match the experiment",
                cx.next_unit - 1,
                fl.name
            );
        };
        results.flythroughs.extend(frames);
    }
    Ok(())
}

/// Every ablation's variants at its budgets, compared with the baseline's rows.
fn evaluate_ablations(
    cx: &mut Setup<'_, '_>,
    exp: &Experiment,
    base_rows: &[SummaryRow],
    results: &mut Results,
    progress: &dyn Fn(&str),
) -> Result<()> {
    for a in &exp.ablations {
        let budgets = budgets_of(&a.budgets);
        let mut rows = Vec::new();
        for (value, m) in &a.variants {
            let ev = evaluate(cx, m, &budgets, &[])?
                .pop()
                .expect("one evaluation: the method's own");
            progress(&format!("ablation `{}`: {}", a.name, m.name));
            let mut summary = ev.summary;
            compare_with(&mut summary, base_rows);
            results.runs.extend(ev.runs);
            rows.push((value.clone(), summary));
        }
        results.ablations.push(AblationResult {
            name: a.name.clone(),
            parameter: a.parameter.clone(),
            rows,
        });
    }
    Ok(())
}
