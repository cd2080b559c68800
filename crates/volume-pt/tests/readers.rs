//! Every reader gives the same voxels as the raw file beside it. The NRRD and NIfTI files were
//! written by independent writers (pynrrd, nibabel; see tools/make_fixtures.py); the VTK files
//! are the originals the raws were converted from (data/SOURCES.md).

mod common;

use common::*;
use glam::Vec3;
use std::path::Path;
use volume_pt::io::{ReadHints, read_volume};

fn read(p: &Path) -> volume_pt::io::LoadedVolume {
    read_volume(p, &ReadHints::default()).unwrap_or_else(|e| panic!("{e}"))
}

fn same_voxels(a: &Path, b: &Path, f: impl Fn(f32) -> f32) {
    let va = read(a);
    let vb = read(b);
    assert_eq!(
        va.grid.dims(),
        vb.grid.dims(),
        "{} vs {}",
        a.display(),
        b.display()
    );
    let mismatches = va
        .grid
        .to_f32()
        .iter()
        .zip(vb.grid.to_f32())
        .filter(|(x, y)| f(**x) != *y)
        .count();
    assert_eq!(mismatches, 0, "{} vs {}", a.display(), b.display());
}

#[test]
fn vtk_legacy_and_xml_match_the_raw_files() {
    let d = data_dir().join("volumes");
    same_voxels(
        &d.join("ironProt_68x68x68_uint8.raw"),
        &d.join("original/ironProt.vtk"),
        |v| v,
    );
    same_voxels(
        &d.join("hydrogen_orbital_64x64x64_float32.raw"),
        &d.join("original/hydrogen.vti"),
        |v| v,
    );
    assert_eq!(
        read(&d.join("original/hydrogen.vti")).spacing,
        Some(Vec3::ONE)
    );
}

/// The uncompressed XML forms (ASCII and inline base64), read by vtkio; the compressed form
/// (hydrogen.vti above) is read by the project's own decoder. Both fixtures hold the ramp
/// (7 (x + 2y + 3z)) mod 256 on 6x5x4 points with spacing 1 2 3.
#[test]
fn uncompressed_vti_files_read_their_values() {
    let d = data_dir().join("fixtures");
    for name in ["ramp_ascii.vti", "ramp_binary.vti"] {
        let v = read(&d.join(name));
        assert_eq!(v.grid.dims(), glam::UVec3::new(6, 5, 4), "{name}");
        assert_eq!(v.spacing, Some(Vec3::new(1.0, 2.0, 3.0)), "{name}");
        let expected: Vec<f32> = (0..4)
            .flat_map(|z| {
                (0..5)
                    .flat_map(move |y| (0..6).map(move |x| ((x + 2 * y + 3 * z) * 7 % 256) as f32))
            })
            .collect();
        assert_eq!(v.grid.to_f32(), expected, "{name}");
    }
}

#[test]
fn nrrd_attached_detached_gzip_and_big_endian_match() {
    let d = data_dir();
    let headsq = d.join("volumes/headsq_quarter_64x64x93_uint16.raw");
    same_voxels(&headsq, &d.join("fixtures/headsq_gzip.nrrd"), |v| v);
    same_voxels(&headsq, &d.join("fixtures/headsq_be_int16.nrrd"), |v| v);
    same_voxels(
        &d.join("volumes/neghip_64x64x64_uint8.raw"),
        &d.join("fixtures/neghip_detached.nhdr"),
        |v| v,
    );
    let g = read(&d.join("fixtures/headsq_gzip.nrrd"));
    assert_eq!(g.spacing, Some(Vec3::new(3.2, 3.2, 1.5)));
    let b = read(&d.join("fixtures/headsq_be_int16.nrrd"));
    let s = b.spacing.unwrap();
    assert!(
        (s - Vec3::new(3.2, 3.2, 1.5)).abs().max_element() < 1e-6,
        "{s}"
    );
    assert!(
        b.notes.iter().any(|n| n.contains("space origin")),
        "{:?}",
        b.notes
    );
}

#[test]
fn nifti_plain_gzip_and_scaled_match() {
    let d = data_dir();
    let neghip = d.join("volumes/neghip_64x64x64_uint8.raw");
    same_voxels(&neghip, &d.join("fixtures/neghip.nii.gz"), |v| v);
    same_voxels(&neghip, &d.join("fixtures/neghip_scaled.nii.gz"), |v| {
        2.0 * v - 10.0
    });
    same_voxels(
        &d.join("volumes/hydrogen_orbital_64x64x64_float32.raw"),
        &d.join("fixtures/hydrogen.nii"),
        |v| v,
    );
    assert_eq!(
        read(&d.join("fixtures/hydrogen.nii")).spacing,
        Some(Vec3::splat(0.5))
    );
}

/// The bundled copies are the shared originals. Needs `../shared` beside the clone, so it is
/// ignored by default (a user sees "ignored", not a pass); CI runs it with `--ignored`.
#[test]
#[ignore = "needs ../shared/data beside the clone; run with `cargo test -- --ignored`"]
fn shared_originals_match() {
    let shared = data_dir().join("../../shared/data/volumes");
    assert!(
        shared.exists(),
        "{} is missing: this test needs the shared data (see data/SOURCES.md)",
        shared.display()
    );
    same_voxels(
        &shared.join("ironProt_68x68x68_uint8.raw"),
        &shared.join("original/ironProt.vtk"),
        |v| v,
    );
    same_voxels(
        &shared.join("hydrogen_orbital_64x64x64_float32.raw"),
        &shared.join("original/hydrogen.vti"),
        |v| v,
    );
}

/// The spacing's unit where a file names one: NRRD's `space units` (one unit for every axis,
/// else none) and NIfTI's `xyzt_units` (byte 123 of the header: 2 is millimetres, 3
/// micrometres); a file that names none has none.
#[test]
fn units_are_read_where_a_file_names_them() {
    let d = data_dir();
    let dir = std::env::temp_dir().join(format!("gscache-units-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let raw = std::path::absolute(d.join("volumes/neghip_64x64x64_uint8.raw")).unwrap();
    for (units, expected) in [
        (r#""mm" "mm" "mm""#, Some("mm")),
        (r#""mm" "mm" "um""#, None),
        (r#""" "" """#, None),
    ] {
        let header = dir.join("units.nhdr");
        std::fs::write(
            &header,
            format!(
                "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 64 64 64\nencoding: raw\n\
                 space dimension: 3\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n\
                 space units: {units}\ndata file: {}\n",
                raw.display()
            ),
        )
        .unwrap();
        assert_eq!(read(&header).units.as_deref(), expected, "{units}");
    }
    let mut nifti = std::fs::read(d.join("fixtures/hydrogen.nii")).unwrap();
    assert_eq!(read(&d.join("fixtures/hydrogen.nii")).units, None);
    for (code, expected) in [(2u8, "mm"), (3, "µm"), (10, "mm")] {
        nifti[123] = code;
        let path = dir.join("units.nii");
        std::fs::write(&path, &nifti).unwrap();
        assert_eq!(
            read(&path).units.as_deref(),
            Some(expected),
            "xyzt_units {code}"
        );
    }
    assert_eq!(read(&d.join("fixtures/headsq_gzip.nrrd")).units, None);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `write_ome_zarr` then the OME-Zarr reader: level 0 is the volume bit for bit in its own
/// type, with its spacing and unit; the next level halves it and doubles the spacing; an
/// existing store is refused, untouched. (PyPI's ome-zarr reads the same stores in the
/// Python tests.)
#[test]
fn a_written_store_reads_back() {
    use volume_pt::io::{StoreOptions, ZarrSelection, write_ome_zarr};
    let d = data_dir();
    let dir = std::env::temp_dir().join(format!("gscache-store-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut volume = read(&d.join("volumes/headsq_quarter_64x64x93_uint16.raw"));
    volume.spacing = Some(Vec3::new(3.2, 3.2, 1.5));
    volume.units = Some("mm".into());
    let store = dir.join("headsq.ome.zarr");
    let options = StoreOptions {
        chunk: 32,
        ..Default::default()
    };
    let written = write_ome_zarr(&volume, &store, &options).unwrap();
    assert_eq!(written.levels.len(), 3, "{:?}", written.levels);
    let back = read(&store);
    assert_eq!(back.grid.voxels(), volume.grid.voxels());
    assert_eq!(back.grid.dims(), volume.grid.dims());
    assert_eq!(back.spacing, volume.spacing);
    assert_eq!(back.units.as_deref(), Some("mm"));
    let hints = ReadHints {
        memory_budget: None,
        zarr: ZarrSelection {
            level: Some(1),
            ..Default::default()
        },
        ..Default::default()
    };
    let half = read_volume(&store, &hints).unwrap();
    assert_eq!(half.grid.dims(), glam::UVec3::new(32, 32, 47));
    assert_eq!(half.spacing, Some(Vec3::new(6.4, 6.4, 3.0)));
    let refused = write_ome_zarr(&volume, &store, &options)
        .unwrap_err()
        .to_string();
    assert!(refused.contains("already exists"), "{refused}");
    assert_eq!(
        read(&store).grid.voxels(),
        volume.grid.voxels(),
        "untouched"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A time series as a folder of volume files or a pattern: time points in natural order
/// (`t2` before `t10`), the count reported, a time past the end refused with the count, and a
/// folder's stray files of another format left out.
#[test]
fn a_folder_or_pattern_of_files_is_a_time_series() {
    let dir = std::env::temp_dir().join(format!("volume-pt-series-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for t in [1u8, 2, 10] {
        std::fs::write(frames.join(format!("t{t}_4x3x2_uint8.raw")), vec![t; 24]).unwrap();
    }
    std::fs::write(frames.join("notes.txt"), "not a volume").unwrap();
    let at = |path: &std::path::Path, t: u32| {
        let hints = ReadHints {
            zarr: volume_pt::io::ZarrSelection {
                time: t,
                ..Default::default()
            },
            ..Default::default()
        };
        read_volume(path, &hints)
    };
    for series in [frames.clone(), frames.join("t*_4x3x2_uint8.raw")] {
        assert_eq!(
            volume_pt::io::time_points(&series, &ReadHints::default()).unwrap(),
            3
        );
        for (t, value) in [(0, 1.0), (1, 2.0), (2, 10.0)] {
            let v = at(&series, t).unwrap();
            assert_eq!(v.grid.dims(), glam::UVec3::new(4, 3, 2));
            assert_eq!(v.grid.voxel(3, 2, 1), value, "{} at {t}", series.display());
            assert!(
                v.notes
                    .iter()
                    .any(|n| n.contains(&format!("time point {t} of 3")))
            );
        }
        let e = at(&series, 3).unwrap_err().to_string();
        assert!(
            e.contains("time 3: the series has 3 time points (0 to 2)"),
            "{e}"
        );
    }
    let none = dir.join("frames/none_*.raw");
    let e = at(&none, 0).unwrap_err().to_string();
    assert!(e.contains("no volume file"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
