//! A mutation fuzzer over every reader, on stable Rust: volumes (raw, NRRD, NIfTI, VTK legacy and
//! XML), scene and experiment TOML, Gaussian clouds (PLY, `.splat`), saved caches, partial films,
//! experiment shard files and EXR images (references are kept as EXR).
//!
//! Each bundled file is a seed. Case `i` of a seed applies mutations drawn from a counter-based
//! hash of `(seed file, i)`: bit flips, "interesting" integers written over header bytes, numbers
//! in text replaced by huge, negative or non-finite ones, truncation, repeated or deleted
//! chunks; gzip files are mutated inside the stream and recompressed, so the header behind the
//! compression is reached. A reader passes a case when it returns (a value or an error) without
//! panicking, within [`CASE_TIME_LIMIT`]; an allocation failure would abort the whole test
//! binary, which fails the test too. Partial films and shard files carry checksums, so for them
//! a mutant read as a value other than the seed's is a failure too ("silent wrong"): it would
//! merge into wrong pixels or tables.
//!
//! First every file in `tests/fuzz-corpus/` is replayed (the hostile inputs found so far, kept
//! as a regression corpus), then fuzz cases run until `GSCACHE_FUZZ_SECONDS` (default 20) is
//! spent, shared among the seeds. A failing case is written to `target/fuzz-failures/` with its
//! seed file and case number in the name; copy it into `tests/fuzz-corpus/` once it is fixed.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// One case may take this long; a reader that is still busy is taken to hang.
const CASE_TIME_LIMIT: Duration = Duration::from_secs(10);

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// SplitMix64 over a counter: the numbers of case `i` are the same on every run and thread.
struct Numbers(u64);

impl Numbers {
    fn new(seed: &str, case: u64) -> Self {
        use render_base::hash::{FNV_OFFSET, GOLDEN_GAMMA, fnv1a64};
        Numbers(fnv1a64(seed.as_bytes(), FNV_OFFSET) ^ case.wrapping_mul(GOLDEN_GAMMA))
    }
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(render_base::hash::GOLDEN_GAMMA);
        render_base::hash::splitmix64_finalize(self.0)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const INTERESTING_INTEGERS: [u64; 10] = [
    0,
    1,
    0x7f,
    0xff,
    0x7fff,
    0xffff,
    0x7fff_ffff,
    0xffff_ffff,
    0x8000_0000_0000_0000,
    u64::MAX,
];

const INTERESTING_NUMBERS: [&str; 12] = [
    "0",
    "-1",
    "18446744073709551615",
    "4294967296",
    "2147483648",
    "100000",
    "nan",
    "inf",
    "-inf",
    "1e30",
    "1e-45",
    "",
];

/// One mutation of `bytes`, in place. Most land in the first 1 KiB: headers live there.
fn mutate(bytes: &mut Vec<u8>, n: &mut Numbers) {
    let hot = bytes.len().clamp(1, 1024);
    match n.below(6) {
        0 => {
            for _ in 0..1 + n.below(8) {
                if !bytes.is_empty() {
                    let i = n.below(hot.min(bytes.len()));
                    bytes[i] ^= 1 << n.below(8);
                }
            }
        }
        1 => {
            let v = INTERESTING_INTEGERS[n.below(INTERESTING_INTEGERS.len())];
            let width = [1, 2, 4, 8][n.below(4)];
            let at = n.below(hot.min(bytes.len()).saturating_sub(width).max(1));
            let le = v.to_le_bytes();
            for k in 0..width {
                if let Some(b) = bytes.get_mut(at + k) {
                    *b = le[k];
                }
            }
        }
        2 => {
            // A number in the text replaced.
            let digits: Vec<usize> = (0..bytes.len().min(4096))
                .filter(|&i| {
                    bytes[i].is_ascii_digit() && (i == 0 || !bytes[i - 1].is_ascii_digit())
                })
                .collect();
            if !digits.is_empty() {
                let start = digits[n.below(digits.len())];
                let end = (start..bytes.len())
                    .find(|&i| !(bytes[i].is_ascii_digit() || bytes[i] == b'.'))
                    .unwrap_or(bytes.len());
                let with = INTERESTING_NUMBERS[n.below(INTERESTING_NUMBERS.len())];
                bytes.splice(start..end, with.bytes());
            }
        }
        3 => {
            let len = n.below(bytes.len() + 1);
            bytes.truncate(len);
        }
        4 => {
            // A chunk repeated.
            if !bytes.is_empty() {
                let at = n.below(bytes.len());
                let len = 1 + n.below(64.min(bytes.len() - at));
                let chunk = bytes[at..at + len].to_vec();
                let to = n.below(hot.min(bytes.len()));
                bytes.splice(to..to, chunk);
            }
        }
        _ => {
            // A chunk deleted.
            if !bytes.is_empty() {
                let at = n.below(hot.min(bytes.len()));
                let len = 1 + n.below(64.min(bytes.len() - at));
                bytes.drain(at..at + len);
            }
        }
    }
}

fn is_gzip(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b])
}

/// A mutated copy of `seed`: mutated inside the gzip stream when it is one (most of the time).
fn mutant(seed: &[u8], n: &mut Numbers) -> Vec<u8> {
    use std::io::{Read, Write};
    let mutations = 1 + n.below(4);
    if is_gzip(seed) && n.below(4) != 0 {
        let mut inner = Vec::new();
        flate2::read::GzDecoder::new(seed)
            .read_to_end(&mut inner)
            .expect("seed gzip decodes");
        for _ in 0..mutations {
            mutate(&mut inner, n);
        }
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(&inner).unwrap();
        return e.finish().unwrap();
    }
    let mut out = seed.to_vec();
    for _ in 0..mutations {
        mutate(&mut out, n);
    }
    out
}

/// The readers, by what a seed file is.
#[derive(Clone, Copy, Debug)]
enum Reader {
    Volume,
    Scene,
    Experiment,
    Cloud,
    SavedCache,
    PartialFilm,
    ExperimentShard,
    Exr,
    /// An OME-Zarr store (a folder) with one of its files mutated: the case's name says which
    /// (`group.zarr.json`, `array.zarr.json`, `chunk.zst`); read whole and streamed.
    Store,
}

/// How a reader took a case.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Outcome {
    /// An error naming the fault.
    Refused,
    /// A value (for the checksummed formats: the seed's own value).
    Read,
    /// A checksummed format read as a value other than the seed's.
    SilentWrong,
}

/// The seed values the checksummed readers compare against, made once.
fn seed_partial() -> (Vec<u8>, volume_pt::PartialRender) {
    let mut scene = volume_pt::load_scene(&repo().join("data/scenes/default.toml")).unwrap();
    scene.camera = scene.camera.with_size(6, 4).unwrap();
    let mut film = volume_pt::Film::new(6, 4);
    volume_pt::render_samples(
        &scene.media,
        &scene.camera,
        &scene.settings,
        2..5,
        &mut film,
        &volume_pt::Control::none(),
    );
    let p = volume_pt::PartialRender::from_film(&film, "fuzz", 8, 2..5);
    let bytes = p.to_bytes();
    let read = volume_pt::PartialRender::from_bytes(&bytes, Path::new("seed")).unwrap();
    (bytes, read)
}

fn seed_shard(dir: &Path) -> Vec<u8> {
    use experiments::records::{Budget, Snapshot};
    use experiments::units::{FORMAT, ShardFile, UnitResult};
    let image = |k: f32| {
        (0..24)
            .map(|i| glam::Vec3::splat(0.01 * i as f32 + k))
            .collect()
    };
    let file = ShardFile {
        format: FORMAT,
        experiment: "fuzz".into(),
        key: "0123456789abcdef".into(),
        shard: "0/1".into(),
        unit_count: 1,
        units: vec![(
            0,
            UnitResult::Method {
                snapshots: vec![
                    Snapshot {
                        budget: Budget::Spp(1),
                        spp: 1,
                        seconds: 0.0125,
                        image: image(0.1),
                        denoised: None,
                        features: None,
                    },
                    Snapshot {
                        budget: Budget::Seconds(0.05),
                        spp: 4,
                        seconds: 0.0501,
                        image: image(0.2),
                        denoised: Some(denoise::Guides::Albedo),
                        features: None,
                    },
                ],
                record: None,
            },
        )],
        checksum: String::new(),
    };
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join("seed.json");
    file.write(&path).unwrap();
    std::fs::read(&path).unwrap()
}

/// A small EXR as the program writes references: 12x8, linear, with a bright pixel.
fn exr_seed(dir: &Path) -> Vec<u8> {
    let mut img = hdr_image::RgbImage::new(12, 8);
    for (i, p) in img.pixels_mut().iter_mut().enumerate() {
        *p = glam::Vec3::new(i as f32 * 0.01, 0.5, 2.0);
    }
    img.pixels_mut()[5] = glam::Vec3::splat(3e4);
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join("seed.exr");
    img.write_exr(&path).unwrap();
    std::fs::read(&path).unwrap()
}

/// The seed file's bytes: read from disk, or made here for the formats no bundled file has.
fn seed_bytes(path: &Path, name: &str, scratch: &Path) -> Vec<u8> {
    match name {
        "generated.splat" => splat_seed(),
        "part.gspartial" => seed_partial().0,
        "shard.json" => seed_shard(scratch),
        "image.exr" => exr_seed(scratch),
        "group.zarr.json" | "array.zarr.json" | "chunk.zst" => {
            std::fs::read(template_store().join(store_part(name))).unwrap()
        }
        _ => std::fs::read(path).unwrap(),
    }
}

fn expected(scratch: &Path) -> Expected {
    let shard = seed_shard(scratch);
    let path = scratch.join("expected-shard.json");
    std::fs::write(&path, shard).unwrap();
    let f = experiments::units::ShardFile::read(&path).unwrap();
    Expected {
        partial: seed_partial().1,
        shard: shard_text(&f),
    }
}

/// What a shard's units say, for comparing a mutant's with the seed's.
fn shard_text(f: &experiments::units::ShardFile) -> String {
    serde_json::to_string(&(&f.key, f.unit_count, &f.units)).unwrap()
}

/// The values a checksummed mutant must equal to count as read correctly.
#[derive(Clone)]
struct Expected {
    partial: volume_pt::PartialRender,
    shard: String,
}

/// Runs `reader` on `path` on its own thread: how it took the case, or Err(why) on a panic or
/// a hang.
fn run_reader(reader: Reader, path: &Path, expected: &Expected) -> Result<Outcome, String> {
    let path = path.to_path_buf();
    let expected = expected.clone();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let read = |ok: bool| if ok { Outcome::Read } else { Outcome::Refused };
        let outcome = catch_unwind(AssertUnwindSafe(|| match reader {
            Reader::Volume => read(volume_pt::io::read_volume(&path, &Default::default()).is_ok()),
            Reader::Scene => read(volume_pt::load_scene(&path).is_ok()),
            Reader::Experiment => read(experiments::config::load_experiment(&path).is_ok()),
            Reader::Cloud => match splat_raster::io::read_cloud(&path) {
                Ok(cloud) => {
                    let _ = cloud.count_unusable();
                    Outcome::Read
                }
                Err(_) => Outcome::Refused,
            },
            Reader::SavedCache => {
                let dir = path.parent().unwrap();
                read(gs_cache::GsCache::load(dir, gs_cache::CacheConfig::default()).is_ok())
            }
            Reader::PartialFilm => match volume_pt::PartialRender::read(&path) {
                Ok(p) if p == expected.partial => Outcome::Read,
                Ok(_) => Outcome::SilentWrong,
                Err(_) => Outcome::Refused,
            },
            Reader::ExperimentShard => match experiments::units::ShardFile::read(&path) {
                Ok(f) if shard_text(&f) == expected.shard => Outcome::Read,
                Ok(_) => Outcome::SilentWrong,
                Err(_) => Outcome::Refused,
            },
            Reader::Store => {
                let whole = volume_pt::io::read_volume(&path, &Default::default()).is_ok();
                // Streamed within a budget of a few bricks: the survey reads every chunk, and
                // a lookup of every voxel reads them all again (a failure is recorded).
                let hints = volume_pt::io::ReadHints {
                    memory_budget: Some(96 * 1024),
                    ..Default::default()
                };
                let streamed = match volume_pt::io::read_volume(&path, &hints) {
                    Ok(v) => {
                        let _ = v.grid.to_f32();
                        v.grid.check_streaming().is_ok()
                    }
                    Err(_) => false,
                };
                read(whole || streamed)
            }
            Reader::Exr => match hdr_image::RgbImage::read_exr(&path) {
                Ok(img) => {
                    // What a kept reference is checked for before it is reused.
                    let _ = img.pixels().iter().all(|p| p.is_finite());
                    Outcome::Read
                }
                Err(_) => Outcome::Refused,
            },
        }));
        let _ = tx.send(outcome.map_err(|p| {
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default()
        }));
    });
    match rx.recv_timeout(CASE_TIME_LIMIT) {
        Ok(Ok(Outcome::SilentWrong)) => Err("read as a value other than the seed's".into()),
        Ok(Ok(outcome)) => Ok(outcome),
        Ok(Err(panic)) => Err(format!("panicked: {panic}")),
        Err(_) => Err(format!("still running after {CASE_TIME_LIMIT:?}")),
    }
}

/// A `.splat` file (antimatter15: 32-byte records) of the bundled asset's first 300 Gaussians,
/// written here by the format's definition: there is no `.splat` file among the bundled data.
fn splat_seed() -> Vec<u8> {
    let cloud =
        splat_raster::io::read_ply(&repo().join("data/splats/fruit_drops_minimal_inria.ply"))
            .unwrap();
    let stride = cloud.color_stride();
    let mut out = Vec::new();
    for g in 0..cloud.len().min(300) {
        for v in &cloud.means[3 * g..3 * g + 3] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in &cloud.log_scales[3 * g..3 * g + 3] {
            out.extend_from_slice(&v.exp().to_le_bytes());
        }
        for c in &cloud.colors[g * stride..g * stride + 3] {
            out.push(((0.5 + 0.282_094_8 * c).clamp(0.0, 1.0) * 255.0) as u8);
        }
        out.push((255.0 / (1.0 + (-cloud.opacity_logits[g]).exp())) as u8);
        let q = &cloud.rotations[4 * g..4 * g + 4];
        let n = q.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
        for v in q {
            out.push((v / n * 127.0 + 128.0) as u8);
        }
    }
    out
}

/// The seeds: (file, reader, the name the mutant is written under, files it needs beside it).
fn seeds() -> Vec<(PathBuf, Reader, String)> {
    let data = repo().join("data");
    let mut out = Vec::new();
    for dir in ["fixtures", "volumes/original"] {
        for e in std::fs::read_dir(data.join(dir)).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            // The detached raw is read through its .nhdr.
            if name != "neghip_detached.raw" {
                out.push((p, Reader::Volume, name));
            }
        }
    }
    // Raw files: a small one, its layout from the name.
    out.push((
        data.join("volumes/neghip_64x64x64_uint8.raw"),
        Reader::Volume,
        "neghip_64x64x64_uint8.raw".into(),
    ));
    for e in std::fs::read_dir(data.join("scenes")).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        out.push((p, Reader::Scene, name));
    }
    out.push((
        repo().join("experiments/default.toml"),
        Reader::Experiment,
        "experiment.toml".into(),
    ));
    out.push((
        data.join("splats/fruit_drops_minimal_inria.ply"),
        Reader::Cloud,
        "fruit.ply".into(),
    ));
    // Made in memory by `splat_seed`; the path only has to exist.
    out.push((
        data.join("splats/fruit_drops_minimal_inria.ply"),
        Reader::Cloud,
        "generated.splat".into(),
    ));
    // A saved cache level is a PLY file too, read through `GsCache::load`.
    out.push((
        data.join("splats/fruit_drops_minimal_inria.ply"),
        Reader::SavedCache,
        "length_1.ply".into(),
    ));
    // Made in memory (`seed_partial`, `seed_shard`); the path only has to exist.
    out.push((
        data.join("scenes/default.toml"),
        Reader::PartialFilm,
        "part.gspartial".into(),
    ));
    out.push((
        data.join("scenes/default.toml"),
        Reader::ExperimentShard,
        "shard.json".into(),
    ));
    out.push((
        data.join("scenes/default.toml"),
        Reader::Exr,
        "image.exr".into(),
    ));
    // Made by `template_store`; the path only has to exist.
    for part in ["group.zarr.json", "array.zarr.json", "chunk.zst"] {
        out.push((data.join("scenes/default.toml"), Reader::Store, part.into()));
    }
    out.retain(|(p, ..)| p.exists());
    out
}

/// A small OME-Zarr store the store seeds are taken from and staged in: neghip written by
/// `gscache convert`'s writer in 16^3 chunks, two levels (made once a run).
fn template_store() -> PathBuf {
    static STORE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    STORE
        .get_or_init(|| {
            let dir =
                std::env::temp_dir().join(format!("gscache-fuzz-store-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            let store = dir.join("cells.ome.zarr");
            let volume = volume_pt::io::read_volume(
                &repo().join("data/volumes/neghip_64x64x64_uint8.raw"),
                &Default::default(),
            )
            .unwrap();
            let options = volume_pt::io::StoreOptions {
                chunk: 16,
                max_levels: 2,
                ..Default::default()
            };
            volume_pt::io::write_ome_zarr(&volume, &store, &options).unwrap();
            store
        })
        .clone()
}

/// The file of a store a store seed's name stands for.
fn store_part(name: &str) -> &'static str {
    match name {
        "group.zarr.json" => "zarr.json",
        "array.zarr.json" => "s0/zarr.json",
        _ => "s0/c/1/1/1",
    }
}

/// Copies the folder `from` to `to`.
fn copy_folder(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let target = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_folder(&p, &target);
        } else {
            std::fs::copy(&p, &target).unwrap();
        }
    }
}

/// Writes `bytes` as `name` in a fresh folder `dir`, with what a reader needs beside it: the
/// volumes a scene names, the detached data of an `.nhdr`.
fn stage(dir: &Path, reader: Reader, name: &str, bytes: &[u8]) -> PathBuf {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).unwrap();
    let data = repo().join("data");
    match reader {
        Reader::Scene => {
            // Scenes name `../volumes/...`: give them a sibling `volumes` folder.
            let scenes = dir.join("scenes");
            std::fs::create_dir_all(&scenes).unwrap();
            let vols = dir.join("volumes");
            std::fs::create_dir_all(&vols).unwrap();
            for e in std::fs::read_dir(data.join("volumes")).unwrap() {
                let p = e.unwrap().path();
                if p.is_file() {
                    let _ =
                        std::fs::hard_link(&p, vols.join(p.file_name().unwrap())).or_else(|_| {
                            std::fs::copy(&p, vols.join(p.file_name().unwrap())).map(|_| ())
                        });
                }
            }
            let path = scenes.join(name);
            std::fs::write(&path, bytes).unwrap();
            return path;
        }
        Reader::Store => {
            // A corpus entry is a whole store; a fuzz case replaces one file of the template.
            let store = dir.join("cells.ome.zarr");
            copy_folder(&template_store(), &store);
            std::fs::write(store.join(store_part(name)), bytes).unwrap();
            return store;
        }
        Reader::Volume if name.ends_with(".nhdr") => {
            std::fs::copy(
                data.join("fixtures/neghip_detached.raw"),
                dir.join("neghip_detached.raw"),
            )
            .unwrap();
        }
        Reader::SavedCache => {
            let path = dir.join("length_1.ply");
            std::fs::write(&path, bytes).unwrap();
            // Signed as a save would sign it, so that the mutated level reaches the PLY reader
            // behind the manifest's checksum (whose own refusals gs-cache's tests hold).
            let manifest = serde_json::json!({
                "format": "gs-cache levels",
                "version": 1,
                "levels": [{
                    "file": "length_1.ply",
                    "gaussians": 0,
                    "bytes": bytes.len(),
                    "fnv1a64": format!(
                        "{:016x}",
                        render_base::hash::fnv1a64(bytes, render_base::hash::FNV_OFFSET)
                    ),
                }],
                "config": gs_cache::CacheConfig::default(),
            });
            std::fs::write(dir.join("manifest.json"), manifest.to_string()).unwrap();
            return path;
        }
        _ => {}
    }
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

fn reader_for_corpus_file(name: &str) -> Reader {
    if name.ends_with(".ply") || name.ends_with(".splat") {
        Reader::Cloud
    } else if name.ends_with(".gspartial") {
        Reader::PartialFilm
    } else if name.ends_with(".exr") {
        Reader::Exr
    } else if name.starts_with("shard") && name.ends_with(".json") {
        Reader::ExperimentShard
    } else if name.ends_with(".toml") {
        if name.starts_with("experiment") {
            Reader::Experiment
        } else {
            Reader::Scene
        }
    } else {
        Reader::Volume
    }
}

#[test]
fn the_regression_corpus_is_refused_cleanly() {
    let corpus = repo().join("tests/fuzz-corpus");
    let scratch = std::env::temp_dir().join(format!("gscache-corpus-seeds-{}", std::process::id()));
    let expected = expected(&scratch);
    let mut failures = Vec::new();
    let mut count = 0;
    for e in std::fs::read_dir(&corpus).expect("tests/fuzz-corpus exists") {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if name == "README.md" {
            continue;
        }
        count += 1;
        let dir = std::env::temp_dir().join(format!("gscache-corpus-{}", std::process::id()));
        if p.is_dir() {
            // A hostile store, kept whole.
            let _ = std::fs::remove_dir_all(&dir);
            let staged = dir.join(&name);
            copy_folder(&p, &staged);
            if let Err(why) = run_reader(Reader::Store, &staged, &expected) {
                failures.push(format!("{name}: {why}"));
            }
            continue;
        }
        let reader = reader_for_corpus_file(&name);
        let staged = stage(&dir, reader, &name, &std::fs::read(&p).unwrap());
        if let Err(why) = run_reader(reader, &staged, &expected) {
            failures.push(format!("{name}: {why}"));
        }
    }
    assert!(count >= 8, "the corpus has only {count} files");
    assert!(
        failures.is_empty(),
        "corpus failures:\n{}",
        failures.join("\n")
    );
}

#[test]
fn mutated_files_never_panic_or_hang() {
    let seconds: f64 = std::env::var("GSCACHE_FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20.0);
    let seeds = seeds();
    assert!(seeds.len() >= 12, "only {} seed files", seeds.len());
    let per_seed = Duration::from_secs_f64(seconds / seeds.len() as f64);
    let failures_dir = repo().join("target/fuzz-failures");
    let scratch = std::env::temp_dir().join(format!("gscache-fuzz-seeds-{}", std::process::id()));
    let expected = expected(&scratch);
    let mut failures = Vec::new();
    let mut total = 0u64;
    // Per format: cases, refused cleanly, read (correctly, for the checksummed formats).
    let mut per_reader: std::collections::BTreeMap<String, [u64; 3]> = Default::default();
    for (seed_path, reader, name) in &seeds {
        let seed = seed_bytes(seed_path, name, &scratch);
        let dir = std::env::temp_dir().join(format!(
            "gscache-fuzz-{}-{}",
            std::process::id(),
            name.replace('.', "_")
        ));
        let start = Instant::now();
        let mut case = 0u64;
        while start.elapsed() < per_seed || case < 8 {
            let mut n = Numbers::new(name, case);
            let bytes = mutant(&seed, &mut n);
            let staged = stage(&dir, *reader, name, &bytes);
            let kind = match reader {
                Reader::Volume | Reader::Cloud => name.rsplit('.').next().unwrap_or("").to_string(),
                other => format!("{other:?}"),
            };
            let counts = per_reader.entry(kind).or_default();
            counts[0] += 1;
            match run_reader(*reader, &staged, &expected) {
                Ok(Outcome::Refused) => counts[1] += 1,
                Ok(_) => counts[2] += 1,
                Err(why) => {
                    std::fs::create_dir_all(&failures_dir).unwrap();
                    let kept = failures_dir.join(format!("{name}.case{case}"));
                    std::fs::write(&kept, &bytes).unwrap();
                    failures.push(format!("{name} case {case} ({}): {why}", kept.display()));
                }
            }
            case += 1;
        }
        total += case;
        let _ = std::fs::remove_dir_all(&dir);
    }
    eprintln!(
        "fuzz: {total} cases over {} seed files in {seconds} s; per format (cases, refused \
         cleanly, read): {per_reader:?}",
        seeds.len()
    );
    let _ = std::fs::remove_dir_all(&scratch);
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
