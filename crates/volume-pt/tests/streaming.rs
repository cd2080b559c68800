//! A streamed volume (bricks paged in within a memory budget) against the same volume read
//! whole: every lookup, every macrocell range and every rendered pixel bit for bit, with a
//! budget of a few bricks so that bricks are evicted and read again many times over.

use glam::{UVec3, Vec3};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use volume_pt::bricks::{Bricks, WholeGrid};
use volume_pt::grid::{Filter, ScalarGrid, Voxels};
use volume_pt::io::{LoadedVolume, ReadHints, StoreOptions, read_volume, write_ome_zarr};
use volume_pt::scene::{SceneFile, build_scene_with_volume};
use volume_pt::{Control, Film, Scene};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("volume-pt-streaming-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The smallest budget a streamed grid takes: its fixed structures and `(2 x threads).max(4)`
/// bricks.
fn tight_budget(dims: UVec3, chunk: UVec3, bytes_per_voxel: usize) -> u64 {
    volume_pt::bricks::min_budget(dims, chunk, bytes_per_voxel)
}

fn streamed(grid: &ScalarGrid, chunk: UVec3, budget: u64) -> ScalarGrid {
    let voxels = Arc::new(grid.voxels().unwrap().clone());
    let bpv = voxels.bytes_per_voxel();
    let source = WholeGrid {
        dims: grid.dims(),
        voxels,
        brick: chunk,
    };
    ScalarGrid::streamed(
        Bricks::new(grid.dims(), Arc::new(source), bpv, budget).unwrap(),
        1.0,
        0.0,
    )
    .unwrap()
}

/// A grid of `dims` with a value pattern that changes at every voxel.
fn patterned(dims: UVec3, voxels: impl Fn(usize) -> Voxels) -> ScalarGrid {
    let n = (dims.x * dims.y * dims.z) as usize;
    ScalarGrid::from_voxels(dims, voxels(n), 1.0, 0.0).unwrap()
}

fn hash(i: u32) -> u32 {
    render_base::hash::hash32(&[0x5eed, i])
}

/// Every lookup a renderer makes (trilinear and nearest at points inside and outside the box,
/// single voxels), the macrocell ranges at several sizes and the histogram sample, for every
/// stored type, with power-of-two and other brick sizes and the tightest budget.
#[test]
fn streamed_lookups_equal_the_whole_grid_bit_for_bit() {
    own_cache_folder();
    let dims = UVec3::new(45, 38, 33);
    let grids = [
        patterned(dims, |n| {
            Voxels::U8((0..n as u32).map(|i| hash(i) as u8).collect())
        }),
        patterned(dims, |n| {
            Voxels::I16((0..n as u32).map(|i| hash(i) as i16).collect())
        }),
        patterned(dims, |n| {
            Voxels::F32(
                (0..n as u32)
                    .map(|i| (hash(i) % 10_000) as f32 * 1e-3)
                    .collect(),
            )
        }),
    ];
    for whole in &grids {
        for chunk in [
            UVec3::splat(16),
            UVec3::new(5, 20, 7),
            UVec3::new(64, 4, 16),
        ] {
            let budget = tight_budget(dims, chunk, whole.bytes_per_voxel());
            let s = streamed(whole, chunk, budget);
            let what = format!("{} in chunks of {chunk}", whole.type_name());
            assert_eq!(s.range(), whole.range(), "{what}");
            assert_eq!(s.type_name(), whole.type_name());
            for k in 0..20_000u32 {
                let u = Vec3::new(
                    render_base::hash::unit_f32(hash(3 * k + 100)) * (dims.x as f32 + 2.0) - 1.0,
                    render_base::hash::unit_f32(hash(3 * k + 101)) * (dims.y as f32 + 2.0) - 1.0,
                    render_base::hash::unit_f32(hash(3 * k + 102)) * (dims.z as f32 + 2.0) - 1.0,
                );
                for filter in [Filter::Trilinear, Filter::Nearest] {
                    assert_eq!(
                        s.sample(u, filter).to_bits(),
                        whole.sample(u, filter).to_bits(),
                        "{what}: {filter:?} at {u}"
                    );
                }
            }
            assert_eq!(s.to_f32(), whole.to_f32(), "{what}");
            for cell in [1, 4, 8, 7, 1000] {
                assert_eq!(
                    s.cell_ranges(cell).unwrap(),
                    whole.cell_ranges(cell).unwrap(),
                    "{what}: macrocells of {cell}"
                );
            }
            let mut a = s.strided_values(3).unwrap();
            let mut b = whole.strided_values(3).unwrap();
            a.sort_by(f32::total_cmp);
            b.sort_by(f32::total_cmp);
            assert_eq!(a, b, "{what}: the histogram sample");
            let bricks = s.bricks().unwrap();
            assert!(
                bricks.resident_bytes() <= bricks.budget(),
                "{what}: {} resident over a budget of {}",
                bricks.resident_bytes(),
                bricks.budget()
            );
            assert!(
                bricks.loads() > 3 * bricks.brick_count() as u64,
                "{what}: {} loads of {} bricks: the budget should force many re-reads",
                bricks.loads(),
                bricks.brick_count()
            );
            assert!(bricks.failure().is_none());
        }
    }
}

/// Surveys go to a folder of this test run's own, never the user's cache.
fn own_cache_folder() {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    let dir = DIR.get_or_init(|| scratch("cache"));
    volume_pt::bricks::set_cache_folder(Some(Some(dir.clone())));
}

fn render(scene: &Scene) -> Vec<u32> {
    let mut settings = scene.settings;
    settings.spp = 2;
    let camera = scene.camera.with_size(64, 48).unwrap();
    let mut film = Film::new(64, 48);
    volume_pt::render(
        &scene.media,
        &camera,
        &settings,
        &mut film,
        &Control::none(),
    );
    film.image()
        .pixels()
        .iter()
        .flat_map(|p| p.to_array())
        .map(f32::to_bits)
        .collect()
}

fn default_scene_with(grid: ScalarGrid) -> Scene {
    let path = repo().join("data/scenes/default.toml");
    let desc: SceneFile = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let loaded = LoadedVolume {
        grid,
        spacing: None,
        units: None,
        notes: Vec::new(),
    };
    build_scene_with_volume(&path, desc, loaded, "streamed".into()).unwrap()
}

/// The default scene rendered from its volume streamed within a budget of a few bricks
/// (evicted and re-read throughout the render) is the render of the volume read whole, bit
/// for bit; so is the same volume written as an OME-Zarr store and streamed from it, and the
/// store's survey is kept and reused.
#[test]
fn a_streamed_volume_renders_bit_for_bit_as_read_whole() {
    own_cache_folder();
    let whole_scene = volume_pt::load_scene(&repo().join("data/scenes/default.toml")).unwrap();
    let whole = whole_scene.media.medium.grid().clone();
    let reference = render(&default_scene_with(whole.clone()));

    let chunk = UVec3::splat(16);
    let s = streamed(&whole, chunk, tight_budget(whole.dims(), chunk, 1));
    let image = render(&default_scene_with(s.clone()));
    assert!(reference.iter().any(|&v| f32::from_bits(v) > 0.0));
    assert!(image == reference, "the streamed render differs");
    let bricks = s.bricks().unwrap();
    assert!(
        bricks.loads() > 2 * bricks.brick_count() as u64,
        "{} loads",
        bricks.loads()
    );

    // Straight from the raw file, a row of a brick at a time.
    let raw_hints = ReadHints {
        memory_budget: Some(tight_budget(whole.dims(), UVec3::new(64, 32, 32), 1)),
        ..Default::default()
    };
    let raw = read_volume(
        &repo().join("data/volumes/neghip_64x64x64_uint8.raw"),
        &raw_hints,
    )
    .unwrap();
    assert!(raw.grid.bricks().is_some(), "{:?}", raw.notes);
    assert!(
        render(&default_scene_with(raw.grid)) == reference,
        "the raw file streamed"
    );

    // Through an OME-Zarr store.
    let dir = scratch("store");
    let store = dir.join("neghip.ome.zarr");
    let loaded = LoadedVolume {
        grid: whole.clone(),
        spacing: None,
        units: None,
        notes: Vec::new(),
    };
    let options = StoreOptions {
        chunk: 16,
        max_levels: 1,
        ..Default::default()
    };
    write_ome_zarr(&loaded, &store, &options).unwrap();
    let hints = ReadHints {
        memory_budget: Some(tight_budget(whole.dims(), chunk, 1)),
        ..Default::default()
    };
    let from_store = read_volume(&store, &hints).unwrap();
    assert!(from_store.grid.bricks().is_some(), "{:?}", from_store.notes);
    assert!(
        from_store.notes.iter().any(|n| n.contains("streamed")),
        "{:?}",
        from_store.notes
    );
    assert!(render(&default_scene_with(from_store.grid)) == reference);
    // The survey was kept; a second reading finds it (and renders the same).
    let kept = std::fs::read_dir(volume_pt::bricks::survey_cache_folder().unwrap())
        .unwrap()
        .count();
    assert!(kept >= 1, "no survey kept");
    let again = read_volume(&store, &hints).unwrap();
    assert_eq!(again.grid.range(), whole.range());
    assert_eq!(
        again.grid.bricks().unwrap().loads(),
        0,
        "the kept survey was not used"
    );
    assert!(render(&default_scene_with(again.grid)) == reference);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A brick that cannot be read while rendering is reported (never a silent zero), and a budget
/// too small for the bricks is refused with the size it needs.
#[test]
fn unreadable_bricks_and_tiny_budgets_are_reported() {
    own_cache_folder();
    let dir = scratch("broken");
    let store = dir.join("v.ome.zarr");
    let dims = UVec3::new(32, 32, 32);
    let grid = patterned(dims, |n| {
        Voxels::U8((0..n as u32).map(|i| hash(i) as u8).collect())
    });
    let loaded = LoadedVolume {
        grid,
        spacing: None,
        units: None,
        notes: Vec::new(),
    };
    let options = StoreOptions {
        chunk: 16,
        max_levels: 1,
        ..Default::default()
    };
    write_ome_zarr(&loaded, &store, &options).unwrap();
    let tiny = ReadHints {
        memory_budget: Some(1000),
        ..Default::default()
    };
    let e = read_volume(&store, &tiny).unwrap_err().to_string();
    assert!(
        e.contains("memory budget") && e.contains("expected a budget of at least"),
        "{e}"
    );

    let hints = ReadHints {
        memory_budget: Some(tight_budget(dims, UVec3::splat(16), 1)),
        ..Default::default()
    };
    let v = read_volume(&store, &hints).unwrap();
    // A chunk truncated after the survey: the next read of it fails and is recorded.
    let chunk = walk(&store)
        .into_iter()
        .find(|p| p.ends_with("c/1/1/1"))
        .expect("chunk c/1/1/1 of level 0");
    let bytes = std::fs::read(&chunk).unwrap();
    std::fs::write(&chunk, &bytes[..bytes.len() / 2]).unwrap();
    let mut hit = false;
    for z in 0..32 {
        for y in 0..32 {
            for x in 0..32 {
                v.grid.voxel(x, y, z);
            }
        }
        hit |= v.grid.bricks().unwrap().failure().is_some();
    }
    let failure = v.grid.bricks().unwrap().failure().map(str::to_string);
    assert!(hit, "the truncated chunk was read without an error");
    let failure = failure.unwrap();
    assert!(failure.contains("v.ome.zarr"), "{failure}");
    let _ = std::fs::remove_dir_all(&dir);
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// `convert` of a streamed volume (a raw file larger than the budget, a store larger than it)
/// writes a store a chunk at a time: read back whole it is the volume, and its level 1 is the
/// level 1 the in-memory writer makes (the same 2x2x2 block means).
#[test]
fn a_streamed_volume_converts_to_the_same_store() {
    own_cache_folder();
    let dir = scratch("convert");
    let raw_path = repo().join("data/volumes/neghip_64x64x64_uint8.raw");
    let whole = read_volume(&raw_path, &ReadHints::default()).unwrap();
    let options = StoreOptions {
        chunk: 16,
        max_levels: 3,
        ..Default::default()
    };
    let reference = dir.join("whole.ome.zarr");
    write_ome_zarr(&whole, &reference, &options).unwrap();
    let hints = ReadHints {
        memory_budget: Some(tight_budget(whole.grid.dims(), UVec3::new(64, 32, 32), 1)),
        ..Default::default()
    };
    let streamed = read_volume(&raw_path, &hints).unwrap();
    assert!(streamed.grid.bricks().is_some());
    let from_raw = dir.join("from_raw.ome.zarr");
    write_ome_zarr(&streamed, &from_raw, &options).unwrap();
    // And from that store, streamed within a few of its 16^3 bricks.
    let store_hints = ReadHints {
        memory_budget: Some(tight_budget(whole.grid.dims(), UVec3::splat(16), 1)),
        ..Default::default()
    };
    let streamed_store = read_volume(&from_raw, &store_hints).unwrap();
    assert!(streamed_store.grid.bricks().is_some());
    let from_store = dir.join("from_store.ome.zarr");
    write_ome_zarr(&streamed_store, &from_store, &options).unwrap();
    for level in [0u32, 1, 2] {
        let at = |p: &Path| {
            let h = ReadHints {
                zarr: volume_pt::io::ZarrSelection {
                    level: Some(level),
                    ..Default::default()
                },
                ..Default::default()
            };
            read_volume(p, &h).unwrap().grid.to_f32()
        };
        let expected = at(&reference);
        assert_eq!(at(&from_raw), expected, "level {level} from the raw file");
        assert_eq!(at(&from_store), expected, "level {level} from the store");
    }
    assert_eq!(
        read_volume(&from_store, &ReadHints::default())
            .unwrap()
            .grid
            .to_f32(),
        whole.grid.to_f32()
    );
    let _ = std::fs::remove_dir_all(&dir);
}
