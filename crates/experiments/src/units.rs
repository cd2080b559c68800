//! Experiments split into shards: the independent units of work (each method or ablation
//! variant with each seed, and each fly-through), a shard's file of measured units, and the
//! merge that hands them to the same assembly a one-process run uses.
//!
//! A unit is a pure function of the experiment file (its images are bit-identical for a seed,
//! whatever the machine or thread count), so `experiment FILE --shard I/N` on N machines
//! followed by `experiment merge FILE SHARDS...` writes the tables and report one process would
//! write: the spp-budget metrics, the seed spreads and biases and the fly-through errors bit for
//! bit. Times, and so the time budgets' snapshots, are measured wherever a unit ran.
//!
//! Unit `k` belongs to shard `i/n` when `k mod n = i`. A shard file holds the experiment's key
//! (a hash of the experiment and scene files), so a merge refuses shards of another version of
//! the experiment, a unit given twice and a missing one.

use super::config::{Experiment, MethodSpec};
use super::denoised::Denoisers;
use super::flythrough::{FlightSetup, FrameRecord, fly};
use super::measure::run_method;
use super::records::{Budget, CacheRecord, Snapshot};
use crate::error::{Error, Result, refuse};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use volume_pt::{RenderKey, Scene, Shard};

/// One unit of an experiment's work.
#[derive(Debug, Clone, Copy)]
pub enum UnitSpec<'a> {
    /// `method` with `seed` at `budgets` (a main method or an ablation variant).
    Method {
        method: &'a MethodSpec,
        seed: u64,
        budgets: &'a [Budget],
        /// The denoised twins to measure beside it (main methods of a `denoise = true` file).
        denoise: Option<&'a super::config::DenoiseSpec>,
    },
    /// Fly-through number `index` of the file.
    Fly { index: usize },
}

/// What a unit measured.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub enum UnitResult {
    Method {
        snapshots: Vec<Snapshot>,
        record: Option<CacheRecord>,
    },
    Fly(Vec<FrameRecord>),
}

/// Every unit of `exp` in the order the assembly reads them: the methods' seeds, then the
/// fly-throughs, then the ablation variants' seeds. `budgets` holds the main budgets and each
/// ablation's, as `run` computes them.
pub fn all<'a>(
    exp: &'a Experiment,
    main_budgets: &'a [Budget],
    ablation_budgets: &'a [Vec<Budget>],
) -> Vec<UnitSpec<'a>> {
    let mut out = Vec::new();
    for m in &exp.methods {
        for &seed in &exp.seeds {
            out.push(UnitSpec::Method {
                method: m,
                seed,
                budgets: main_budgets,
                denoise: exp.denoise.as_ref(),
            });
        }
    }
    out.extend((0..exp.flythroughs.len()).map(|index| UnitSpec::Fly { index }));
    for (a, budgets) in exp.ablations.iter().zip(ablation_budgets) {
        for (_, m) in &a.variants {
            for &seed in &exp.seeds {
                out.push(UnitSpec::Method {
                    method: m,
                    seed,
                    budgets,
                    denoise: None,
                });
            }
        }
    }
    out
}

/// Measures one unit.
pub fn measure_unit(
    exp: &Experiment,
    scene: &Scene,
    spec: UnitSpec<'_>,
    denoisers: &mut Denoisers,
    progress: &dyn Fn(&str),
) -> Result<UnitResult> {
    Ok(match spec {
        UnitSpec::Method {
            method,
            seed,
            budgets,
            denoise,
        } => {
            let (snapshots, record) = run_method(scene, method, seed, budgets, denoise, denoisers)?;
            UnitResult::Method { snapshots, record }
        }
        UnitSpec::Fly { index } => {
            let fl = &exp.flythroughs[index];
            let methods: Vec<&MethodSpec> = exp
                .methods
                .iter()
                .filter(|m| fl.methods.is_empty() || fl.methods.contains(&m.name))
                .collect();
            let setup = FlightSetup {
                scene,
                scene_file: &exp.scene,
                seed: exp.seeds[0],
                reference_dir: &exp.reference.dir,
                denoise: exp.denoise.as_ref(),
            };
            UnitResult::Fly(fly(&setup, fl, &methods, denoisers, progress)?)
        }
    })
}

/// The key of an experiment: its file's text, its scene file's text and its unit count.
pub fn experiment_key(path: &Path, exp: &Experiment, unit_count: usize) -> Result<String> {
    let read = |p: &Path| std::fs::read(p).map_err(|e| Error::io(p, "cannot read", e));
    Ok(RenderKey::new()
        .part(&read(path)?)
        .part(&read(&exp.scene)?)
        .part(&(unit_count as u64).to_le_bytes())
        .hex())
}

/// A shard's measured units.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardFile {
    pub format: u32,
    pub experiment: String,
    pub key: String,
    /// `I/N`.
    pub shard: String,
    pub unit_count: usize,
    pub units: Vec<(usize, UnitResult)>,
    /// FNV-1a of the key, the unit count and the units as written: a file edited or damaged
    /// after it was written is refused.
    #[serde(default)]
    pub checksum: String,
}

/// The shard file format this program writes and reads.
pub const FORMAT: u32 = 2;

/// The longest a unit's time may be (seconds): 115 days. A larger one is not a measurement.
const MAX_SECONDS: f64 = 1e7;

/// Measures the units of `shard`.
pub fn run_shard(
    path: &Path,
    exp: &Experiment,
    scene: &Scene,
    units: &[UnitSpec<'_>],
    shard: Shard,
    progress: &dyn Fn(&str),
) -> Result<ShardFile> {
    let mut measured = Vec::new();
    let mut denoisers = Denoisers::new();
    for (k, spec) in units.iter().enumerate().filter(|(k, _)| shard.owns(*k)) {
        measured.push((
            k,
            measure_unit(exp, scene, *spec, &mut denoisers, progress)?,
        ));
        progress(&format!(
            "shard {shard}: unit {k} of {} measured",
            units.len()
        ));
    }
    Ok(ShardFile {
        format: FORMAT,
        experiment: exp.name.clone(),
        key: experiment_key(path, exp, units.len())?,
        shard: shard.to_string(),
        unit_count: units.len(),
        units: measured,
        checksum: String::new(),
    })
}

impl ShardFile {
    /// Writes the file atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let signed = ShardFile {
            checksum: self.payload_checksum()?,
            ..self.clone()
        };
        crate::write_text(path, &serde_json::to_string(&signed)?)
    }

    /// The checksum of what the file says (key, unit count, units).
    fn payload_checksum(&self) -> Result<String> {
        Ok(RenderKey::new()
            .part(self.key.as_bytes())
            .part(&(self.unit_count as u64).to_le_bytes())
            .part(serde_json::to_string(&self.units)?.as_bytes())
            .hex())
    }

    pub fn read(path: &Path) -> Result<Self> {
        // Images make shard files large (a 320x180 snapshot is 0.9 MB of base64); a quarter of
        // the memory available bounds what is read.
        let limit = volume_pt::io::available_memory() / 4;
        let bytes = volume_pt::io::read_regular(path, limit, "an experiment shard file")?;
        let f: ShardFile = serde_json::from_slice(&bytes).map_err(|e| {
            Error::file(
                path,
                format!(
                    "not an experiment shard file (written by `gscache experiment --shard`): {e}"
                ),
            )
        })?;
        if f.format != FORMAT {
            refuse!(
                "{}: shard file format {}: expected {FORMAT} (run the shard again with this gscache)",
                path.display(),
                f.format
            );
        }
        if f.checksum.is_empty() {
            refuse!(
                "{}: the checksum is missing: the file was edited after it was written (every shard file gscache writes has one)",
                path.display()
            );
        }
        if f.payload_checksum()? != f.checksum {
            refuse!(
                "{}: the checksum does not match: the file was changed or damaged after it was written",
                path.display()
            );
        }
        Ok(f)
    }
}

/// Every unit from `files`, checked against the experiment's key and units (`specs`, whose
/// images have `pixels` pixels): none missing, none twice, and each one checked as a fresh
/// measurement would be ([`check_unit`]).
pub fn gather_units(
    files: &[(std::path::PathBuf, ShardFile)],
    key: &str,
    specs: &[UnitSpec<'_>],
    pixels: usize,
) -> Result<BTreeMap<usize, UnitResult>> {
    let unit_count = specs.len();
    let out = checked_units(files, key, specs, pixels)?;
    let missing: Vec<String> = (0..unit_count)
        .filter(|k| !out.contains_key(k))
        .map(|k| k.to_string())
        .collect();
    if !missing.is_empty() {
        refuse!(
            "units {} of {unit_count} are missing: merge every shard's file",
            missing.join(", ")
        );
    }
    Ok(out)
}

/// The units of `files` (some or all of the experiment's), each checked: the experiment's key
/// and unit count, no unit twice, and every unit as [`check_unit`] checks it. What a merge and
/// a resumed run share.
pub fn checked_units(
    files: &[(std::path::PathBuf, ShardFile)],
    key: &str,
    specs: &[UnitSpec<'_>],
    pixels: usize,
) -> Result<BTreeMap<usize, UnitResult>> {
    let unit_count = specs.len();
    let mut out = BTreeMap::new();
    for (path, f) in files {
        if f.key != key || f.unit_count != unit_count {
            refuse!(
                "{}: a shard of another version of the experiment (key {}, {} units; this file gives key {key}, {unit_count} units): run the shards again",
                path.display(),
                f.key,
                f.unit_count
            );
        }
        for (k, r) in &f.units {
            if *k >= unit_count || out.insert(*k, r.clone()).is_some() {
                refuse!(
                    "{}: unit {k} is given twice or does not exist: each shard may be merged once",
                    path.display()
                );
            }
            check_unit(&specs[*k], r, pixels)
                .map_err(|e| Error::file(path, format!("unit {k}: {e}")))?;
        }
    }
    Ok(out)
}

/// Checks a unit read from a shard file as a fresh measurement would be: the kind of unit its
/// spec says; every budget of the spec snapshotted exactly once; images of `pixels` pixels,
/// each finite and >= 0; times finite, >= 0 and at most `MAX_SECONDS`; at least 1 spp.
pub fn check_unit(spec: &UnitSpec<'_>, r: &UnitResult, pixels: usize) -> Result<(), String> {
    let seconds = |what: &str, s: f64| {
        if (0.0..=MAX_SECONDS).contains(&s) {
            Ok(())
        } else {
            Err(format!(
                "{what} {s}: expected a time in seconds from 0 to {MAX_SECONDS:e}"
            ))
        }
    };
    let image = |what: &str, px: &[Vec3]| {
        if px.len() != pixels {
            return Err(format!(
                "{what} has {} pixels: expected the experiment's {pixels}",
                px.len()
            ));
        }
        match px
            .iter()
            .position(|p| !(p.is_finite() && p.min_element() >= 0.0))
        {
            Some(i) => Err(format!(
                "{what}: pixel {i} is {}: expected finite radiance >= 0",
                px[i]
            )),
            None => Ok(()),
        }
    };
    let loss = |l: &Option<f64>| match l {
        Some(v) if !(*v >= 0.0 && v.is_finite()) => Err(format!("a training loss of {v}")),
        _ => Ok(()),
    };
    match (spec, r) {
        (UnitSpec::Method { budgets, .. }, UnitResult::Method { snapshots, record }) => {
            for b in budgets.iter() {
                let n = snapshots.iter().filter(|s| s.budget == *b).count();
                if n != 1 {
                    return Err(format!(
                        "{n} snapshots at budget {b}: expected exactly one per budget"
                    ));
                }
            }
            if snapshots.len() != budgets.len() {
                return Err(format!(
                    "{} snapshots for {} budgets",
                    snapshots.len(),
                    budgets.len()
                ));
            }
            for s in snapshots {
                if s.spp == 0 {
                    return Err(format!("the snapshot at {} has 0 spp", s.budget));
                }
                seconds(&format!("the snapshot at {} took", s.budget), s.seconds)?;
                image(&format!("the snapshot at {}", s.budget), &s.image)?;
            }
            if let Some(c) = record {
                seconds("the cache's initialisation took", c.init_seconds)?;
                seconds("the cache's warm-up took", c.warmup_seconds)?;
                for f in &c.frame_seconds {
                    for &x in f {
                        seconds("a cached frame's part took", x)?;
                    }
                }
                for l in c.level_mse.iter().flatten() {
                    loss(l)?;
                }
                for (i, level) in c.level_images.iter().enumerate() {
                    image(&format!("the cache's level image {i}"), level)?;
                }
            }
            Ok(())
        }
        (UnitSpec::Fly { .. }, UnitResult::Fly(frames)) => {
            for f in frames {
                let at = format!("fly-through `{}` frame {}", f.flythrough, f.frame);
                for ms in [f.trace_ms, f.splat_ms, f.train_ms, f.total_ms] {
                    seconds(&format!("{at} took"), ms / 1e3)?;
                }
                seconds(&format!("{at}'s denoiser took"), f.denoise_ms / 1e3)?;
                let measures = [
                    ("relMSE", f.rel_mse),
                    ("FLIP", f.flip),
                    ("flicker", f.flicker),
                ];
                for (what, v) in measures {
                    if let Some(e) = v
                        && !(e >= 0.0 && e.is_finite())
                    {
                        return Err(format!("{at}: {what} {e}: expected a finite value >= 0"));
                    }
                }
                if let Some(j) = f.jod
                    && !j.is_finite()
                {
                    return Err(format!("{at}: JOD {j}: expected a finite value"));
                }
                for l in &f.level_mse {
                    loss(l)?;
                }
            }
            Ok(())
        }
        _ => Err("a unit of another kind than the experiment has here".into()),
    }
}
