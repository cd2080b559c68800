//! Bad input gives a clear error that names the file and the fault; nothing panics.

mod common;

use common::*;
use std::path::{Path, PathBuf};
use volume_pt::load_scene;

/// A fresh folder for one test's files.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("volume-pt-bad-input-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const TF: &str = r#"
[transfer]
window = [0, 255]
density_scale = 1.0
points = [ { value = 0.0, color = [1, 1, 1], opacity = 0.0 }, { value = 1.0, color = [1, 1, 1], opacity = 1.0 } ]
"#;

const CAMERA: &str = r#"
[camera]
eye = [0, 0, 30]
target = [0, 0, 0]
fov_y = 30
width = 8
height = 8
"#;

fn write_scene(dir: &Path, volume: &str, transfer: &str, camera: &str) -> PathBuf {
    let p = dir.join("scene.toml");
    std::fs::write(&p, format!("{volume}\n{transfer}\n{camera}")).unwrap();
    p
}

/// Loads the scene, expecting an error that mentions every one of `needles`.
fn expect_error(scene: &Path, needles: &[&str]) {
    let e = match load_scene(scene) {
        Ok(_) => panic!("{}: expected an error", scene.display()),
        Err(e) => e.to_string(),
    };
    for n in needles {
        assert!(e.contains(n), "error `{e}` does not mention `{n}`");
    }
}

#[test]
fn truncated_and_oversized_raw_files() {
    let d = scratch("raw-size");
    let f = d.join("v_8x8x8_uint8.raw");
    std::fs::write(&f, vec![7u8; 500]).unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"v_8x8x8_uint8.raw\"", TF, CAMERA);
    expect_error(
        &s,
        &[
            "v_8x8x8_uint8.raw",
            "truncated",
            "500 bytes",
            "expected 512",
        ],
    );
    std::fs::write(&f, vec![7u8; 520]).unwrap();
    expect_error(&s, &["v_8x8x8_uint8.raw", "oversized", "520 bytes"]);
    std::fs::write(&f, vec![7u8; 512]).unwrap();
    load_scene(&s).expect("the right size loads");
}

#[test]
fn wrong_dtype_is_caught() {
    let d = scratch("dtype");
    std::fs::write(d.join("v.raw"), vec![7u8; 512]).unwrap();
    // A u8 file declared as uint16: the size no longer matches.
    let s = write_scene(
        &d,
        "[volume]\nfile = \"v.raw\"\ndims = [8, 8, 8]\ndtype = \"uint16\"",
        TF,
        CAMERA,
    );
    expect_error(&s, &["v.raw", "truncated", "uint16"]);
    // A dtype that does not exist.
    let s = write_scene(
        &d,
        "[volume]\nfile = \"v.raw\"\ndims = [8, 8, 8]\ndtype = \"uint12\"",
        TF,
        CAMERA,
    );
    expect_error(&s, &["scene.toml", "uint12"]);
    // No dtype at all and no file-name convention.
    let s = write_scene(
        &d,
        "[volume]\nfile = \"v.raw\"\ndims = [8, 8, 8]",
        TF,
        CAMERA,
    );
    expect_error(&s, &["v.raw", "without dtype"]);
}

#[test]
fn nan_voxels_are_rejected() {
    let d = scratch("nan");
    let mut bytes = Vec::new();
    for i in 0..8 {
        let v = if i == 5 { f32::NAN } else { i as f32 };
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(d.join("n_2x2x2_float32.raw"), bytes).unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"n_2x2x2_float32.raw\"", TF, CAMERA);
    expect_error(&s, &["n_2x2x2_float32.raw", "voxel (1, 0, 1) is NaN"]);
}

#[test]
fn unsorted_or_empty_transfer_functions() {
    let d = scratch("tf");
    std::fs::write(d.join("v_2x2x2_uint8.raw"), vec![1u8; 8]).unwrap();
    let vol = "[volume]\nfile = \"v_2x2x2_uint8.raw\"";
    let unsorted = TF.replace("value = 1.0", "value = -1.0");
    expect_error(
        &write_scene(&d, vol, &unsorted, CAMERA),
        &["scene.toml", "not sorted"],
    );
    let empty = "[transfer]\ndensity_scale = 1.0\npoints = []";
    expect_error(
        &write_scene(&d, vol, empty, CAMERA),
        &["scene.toml", "no control points"],
    );
    let none = "[transfer]\ndensity_scale = 1.0";
    expect_error(
        &write_scene(&d, vol, none, CAMERA),
        &["scene.toml", "needs `points"],
    );
    let albedo = TF.replace(
        "color = [1, 1, 1], opacity = 1.0",
        "color = [1.5, 1, 1], opacity = 1.0",
    );
    expect_error(
        &write_scene(&d, vol, &albedo, CAMERA),
        &["scene.toml", "albedo"],
    );
    let window = TF.replace("[0, 255]", "[5, 5]");
    expect_error(
        &write_scene(&d, vol, &window, CAMERA),
        &["scene.toml", "window"],
    );
}

#[test]
fn missing_files_and_zero_image_size() {
    let d = scratch("missing");
    let s = write_scene(
        &d,
        "[volume]\nfile = \"nowhere_8x8x8_uint8.raw\"",
        TF,
        CAMERA,
    );
    expect_error(&s, &["nowhere_8x8x8_uint8.raw", "no such file"]);
    expect_error(&d.join("absent.toml"), &["absent.toml", "no such file"]);
    std::fs::write(d.join("v_2x2x2_uint8.raw"), vec![1u8; 8]).unwrap();
    let vol = "[volume]\nfile = \"v_2x2x2_uint8.raw\"";
    let cam = CAMERA.replace("width = 8", "width = 0");
    expect_error(
        &write_scene(&d, vol, TF, &cam),
        &["scene.toml", "0x8", "at least 1"],
    );
    let typo = format!("{vol}\nspaceing = [1, 1, 1]");
    expect_error(
        &write_scene(&d, &typo, TF, CAMERA),
        &["scene.toml", "spaceing"],
    );
}

#[test]
fn corrupt_headers_name_the_file() {
    let d = scratch("headers");
    std::fs::write(
        d.join("bad.nrrd"),
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 4 4\nencoding: raw\n\n0123",
    )
    .unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"bad.nrrd\"", TF, CAMERA);
    expect_error(&s, &["bad.nrrd", "NRRD data is truncated", "expected 64"]);
    std::fs::write(d.join("bad.nii"), b"not a nifti file at all").unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"bad.nii\"", TF, CAMERA);
    expect_error(&s, &["bad.nii", "NIfTI"]);
    std::fs::write(d.join("bad.vti"), b"<VTKFile type=\"ImageData\">").unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"bad.vti\"", TF, CAMERA);
    expect_error(&s, &["bad.vti", "VTK"]);
    let _ = data_dir();
}

/// A scene can take its colours from a ParaView preset and its opacity from the scene.
#[test]
fn preset_with_scene_opacity_loads() {
    let d = scratch("preset");
    std::fs::write(
        d.join("v_2x2x2_uint8.raw"),
        vec![0u8, 255, 0, 255, 0, 255, 0, 255],
    )
    .unwrap();
    std::fs::write(
        d.join("p.json"),
        r#"{"Name": "x", "RGBPoints": [0, 0, 0, 1, 10, 1, 0, 0]}"#,
    )
    .unwrap();
    let tf = "[transfer]\nwindow = [0, 255]\ndensity_scale = 2.0\npreset = \"p.json\"\nopacity = [[0.0, 0.0], [1.0, 0.5]]";
    let s = load_scene(&write_scene(
        &d,
        "[volume]\nfile = \"v_2x2x2_uint8.raw\"",
        tf,
        CAMERA,
    ))
    .unwrap();
    let tf = s.media.medium.transfer_function();
    assert_eq!(tf.albedo(255.0), glam::Vec3::new(1.0, 0.0, 0.0));
    assert_eq!(tf.extinction(255.0), 1.0);
    assert_eq!(tf.extinction(0.0), 0.0);
    // Without opacity anywhere, the error says what to add.
    let tf = "[transfer]\ndensity_scale = 2.0\npreset = \"p.json\"";
    expect_error(
        &write_scene(&d, "[volume]\nfile = \"v_2x2x2_uint8.raw\"", tf, CAMERA),
        &["scene.toml", "opacity"],
    );
}

/// `[[light]]` takes a `type` (sphere when left out); each kind's keys are checked, and a key
/// of another kind, a missing key, an unknown type or a value out of range is named with the
/// light's index and kind.
#[test]
fn lights_are_typed_and_each_kind_is_checked() {
    let d = scratch("lights");
    std::fs::write(d.join("v.raw"), vec![7u8; 512]).unwrap();
    let volume = "[volume]\nfile = \"v.raw\"\ndims = [8, 8, 8]\ndtype = \"uint8\"";
    let with = |lights: &str| {
        let s = write_scene(&d, volume, TF, &format!("{CAMERA}\n{lights}"));
        (load_scene(&s), s)
    };
    let (ok, _) = with(
        "[[light]]\ncenter = [0, 40, 0]\nradius = 2\nradiance = [5, 5, 5]\n\
         [[light]]\ntype = \"distant\"\ndirection = [0, -2, 0]\nirradiance = [1, 1, 1]",
    );
    let lights = ok
        .expect("a sphere and a distant light load")
        .media
        .lights
        .lights;
    assert!(matches!(lights[0], volume_pt::Light::Sphere(_)));
    match lights[1] {
        volume_pt::Light::Distant(l) => assert_eq!(l.direction, glam::Vec3::NEG_Y),
        other => panic!("{other:?}"),
    }
    let cases: [(&str, &[&str]); 7] = [
        (
            "[[light]]\ntype = \"distant\"\nirradiance = [1, 1, 1]",
            &["light 0 (distant)", "missing `direction`"],
        ),
        (
            "[[light]]\ntype = \"distant\"\ndirection = [0, 0, 0]\nirradiance = [1, 1, 1]",
            &["light 0 (distant)", "non-zero"],
        ),
        (
            "[[light]]\ntype = \"distant\"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\nradius = 3",
            &[
                "light 0 (distant)",
                "`radius` is not a key of a distant light",
            ],
        ),
        (
            "[[light]]\ncenter = [0, 0, 50]\nradius = 1\nradiance = [1, 1, 1]\ndirection = [0, 0, 1]",
            &["light 0 (sphere)", "`direction`"],
        ),
        (
            "[[light]]\ntype = \"spot\"\ncenter = [0, 0, 50]",
            &["spot", "sphere", "distant"],
        ),
        (
            "[[light]]\ncenter = [0, 0, 50]\nradius = 1e30\nradiance = [1, 1, 1]",
            &["light 0 (sphere)", "radius", "at most"],
        ),
        (
            "[[light]]\ncenter = [0, 0, inf]\nradius = 1\nradiance = [1, 1, 1]",
            &["light 0 (sphere)", "center", "finite"],
        ),
    ];
    for (lights, needles) in cases {
        let (_, s) = with(lights);
        expect_error(&s, needles);
    }
}

/// A volume placed or sized past what f32 positions resolve (an origin of 1e9, a spacing of
/// 1e30 as a NIfTI `pixdim` once gave) is refused with the limit, not rendered as nonsense or
/// marched through forever.
#[test]
fn geometry_past_the_sanity_limits_is_refused() {
    let d = scratch("geometry");
    std::fs::write(d.join("v.raw"), vec![7u8; 512]).unwrap();
    let base = "[volume]\nfile = \"v.raw\"\ndims = [8, 8, 8]\ndtype = \"uint8\"";
    for (extra, needles) in [
        ("origin = [1e9, 0, 0]", &["origin", "1e6"][..]),
        ("spacing = [1e30, 1, 1]", &["spacing", "1e6"][..]),
        ("spacing = [1e-9, 1, 1]", &["spacing", "1e-6"][..]),
    ] {
        let s = write_scene(&d, &format!("{base}\n{extra}"), TF, CAMERA);
        expect_error(&s, needles);
    }
    let s = write_scene(
        &d,
        &format!("{base}\nspacing = [1e3, 1e3, 1e3]"),
        TF,
        CAMERA,
    );
    load_scene(&s).expect("8 km across is within the limits");
}

/// Messages that once misled (issue 32, item 10): a NIfTI `dim[0]` of 9 was reported as a
/// nonsense `sizeof_hdr`, a negative albedo as "above 1", a legacy VTK parse failure as
/// "Parse error: Alt", and a missing file's OS error printed twice.
#[test]
fn messages_name_the_real_fault() {
    let d = scratch("messages");
    let mut nii = std::fs::read(data_dir().join("fixtures/hydrogen.nii")).unwrap();
    nii[40..42].copy_from_slice(&9i16.to_le_bytes());
    std::fs::write(d.join("dims.nii"), &nii).unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"dims.nii\"", TF, CAMERA);
    expect_error(&s, &["dims.nii", "dim[0] is 9", "3 to 7"]);
    let e = load_scene(&s).unwrap_err().to_string();
    assert!(!e.contains("sizeof_hdr"), "{e}");

    std::fs::write(d.join("v.raw"), vec![7u8; 512]).unwrap();
    let volume = "[volume]\nfile = \"v.raw\"\ndims = [8, 8, 8]\ndtype = \"uint8\"";
    let negative = TF.replace(
        "color = [1, 1, 1], opacity = 1.0",
        "color = [1, -0.5, 1], opacity = 1.0",
    );
    let s = write_scene(&d, volume, &negative, CAMERA);
    let e = load_scene(&s).unwrap_err().to_string();
    assert!(e.contains("from 0 to 1") && !e.contains("above 1"), "{e}");

    std::fs::write(
        d.join("bad.vtk"),
        b"# vtk DataFile Version 3.0\ntitle\nASCII\nDATASET POLYDATA\n",
    )
    .unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"bad.vtk\"", TF, CAMERA);
    let e = load_scene(&s).unwrap_err().to_string();
    assert!(
        e.contains("bad.vtk") && e.contains("STRUCTURED_POINTS"),
        "{e}"
    );

    // A scene "inside" a file: the OS says "Not a directory", once.
    let err = load_scene(&d.join("v.raw/scene.toml")).unwrap_err();
    let chain = anyhow_like(&err);
    assert_eq!(chain.matches("os error").count(), 1, "{chain}");
}

/// The error with its sources, as `anyhow`'s `{:#}` prints a chain: "a: b: c".
fn anyhow_like(e: &(dyn std::error::Error + 'static)) -> String {
    let mut out = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        out.push_str(": ");
        out.push_str(&s.to_string());
        source = s.source();
    }
    out
}

/// A VTK XML piece whose extent runs backwards (`0 -1`) is refused before vtkio, which
/// subtracts extents unchecked and panicked on it (found by the fuzzer).
#[test]
fn a_backwards_vti_piece_extent_is_refused() {
    let d = scratch("vti-extent");
    let text = r#"<?xml version="1.0"?>
<VTKFile type="ImageData" version="0.1" byte_order="LittleEndian">
  <ImageData WholeExtent="0 3 0 3 0 3" Origin="0 0 0" Spacing="1 1 1">
    <Piece Extent="0 3 0 -1 0 3">
      <PointData Scalars="v"><DataArray type="UInt8" Name="v" format="ascii">0 1 2 3</DataArray></PointData>
    </Piece>
  </ImageData>
</VTKFile>
"#;
    std::fs::write(d.join("v.vti"), text).unwrap();
    let s = write_scene(&d, "[volume]\nfile = \"v.vti\"", TF, CAMERA);
    expect_error(&s, &["v.vti", "0 3 0 -1 0 3", "runs backwards"]);
}

/// A scene that reads the shared data, on a machine without it, says where to get it.
#[test]
fn a_missing_shared_volume_says_where_to_get_it() {
    let d = scratch("shared-missing");
    let s = write_scene(
        &d,
        "[volume]\nfile = \"nowhere/shared/data/volumes/embryo_256x256x256_uint8.raw\"",
        TF,
        CAMERA,
    );
    expect_error(
        &s,
        &[
            "embryo_256x256x256_uint8.raw",
            "no such file",
            "data/SOURCES.md",
        ],
    );
}
