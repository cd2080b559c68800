//! Hostile files, one test per class of fault found by trying them as a new user would: sizes a
//! header takes on trust, streams that never end or inflate without bound, files read at the
//! wrong offset, and numbers that NaN or infinity slip past. Each is refused with a message that
//! names the file and the fault, quickly and without a large allocation, or is read correctly.

mod common;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD as BASE64;
use common::*;
use flate2::Compression;
use flate2::write::{GzEncoder, ZlibEncoder};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use volume_pt::io::{ReadHints, read_volume};
use volume_pt::load_scene;

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("volume-pt-hostile-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::best());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Reads `path`, expecting an error that names the file and mentions every needle, within
/// `limit` (a hang or a gigabyte allocation would blow through it).
fn refused(path: &Path, needles: &[&str], limit: Duration) -> String {
    let t = Instant::now();
    let result = read_volume(path, &ReadHints::default());
    let elapsed = t.elapsed();
    let e = match result {
        Ok(v) => panic!(
            "{}: expected an error, read {:?}",
            path.display(),
            v.grid.dims()
        ),
        Err(e) => e.to_string(),
    };
    let name = path.file_name().unwrap().to_string_lossy();
    assert!(e.contains(&*name), "error `{e}` does not name {name}");
    for n in needles {
        assert!(e.contains(n), "error `{e}` does not mention `{n}`");
    }
    assert!(elapsed < limit, "{}: took {elapsed:?}", path.display());
    e
}

const QUICK: Duration = Duration::from_secs(2);

fn nrrd(fields: &str, payload: &[u8]) -> Vec<u8> {
    let mut out = format!("NRRD0004\n{fields}\n").into_bytes();
    out.extend_from_slice(payload);
    out
}

#[test]
fn header_sizes_are_checked_before_allocating() {
    let d = scratch("sizes");
    // A 300-byte gzip NRRD that claims 10^15 voxels: refused by the memory budget.
    let f = d.join("huge.nrrd");
    let body = gzip(&[0u8; 1000]);
    std::fs::write(
        &f,
        nrrd(
            "type: uchar\ndimension: 3\nsizes: 100000 100000 100000\nencoding: gzip\n",
            &body,
        ),
    )
    .unwrap();
    refused(&f, &["100000x100000x100000", "available"], QUICK);
    // Dims whose product wraps past 2^64 (2^22 cubed).
    let f = d.join("wrap.nrrd");
    std::fs::write(
        &f,
        nrrd(
            "type: uchar\ndimension: 3\nsizes: 4194304 4194304 4194304\nencoding: raw\n",
            &[0; 64],
        ),
    )
    .unwrap();
    refused(&f, &["more voxels than memory"], QUICK);
    // The same through the raw reader, dims from the file name.
    let f = d.join("v_4194304x4194304x4194304_uint8.raw");
    std::fs::write(&f, [0u8; 64]).unwrap();
    refused(&f, &["more voxels than memory"], QUICK);
    // A negative size.
    let f = d.join("negative.nrrd");
    std::fs::write(
        &f,
        nrrd(
            "type: uchar\ndimension: 3\nsizes: 4 -4 4\nencoding: raw\n",
            &[0; 64],
        ),
    )
    .unwrap();
    refused(&f, &["axis 1 has -4 voxels"], QUICK);
    // NIfTI dims, from a valid file with dim[1..3] set to 32767 (3.5e13 voxels of float32).
    let mut nii = std::fs::read(data_dir().join("fixtures/hydrogen.nii")).unwrap();
    for i in 0..3 {
        nii[42 + 2 * i..44 + 2 * i].copy_from_slice(&32767i16.to_le_bytes());
    }
    let f = d.join("huge.nii");
    std::fs::write(&f, nii).unwrap();
    refused(&f, &["32767x32767x32767", "available"], QUICK);
}

#[test]
fn streams_are_bounded_by_what_the_header_promises() {
    let d = scratch("streams");
    // `line skip` of 2^64 - 1 over a short payload: a loop that never ended.
    let f = d.join("skip.nrrd");
    std::fs::write(
        &f,
        nrrd(
            "type: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\nline skip: 18446744073709551615\n",
            &[1; 8],
        ),
    )
    .unwrap();
    refused(&f, &["line skip", "passes the end of the data"], QUICK);
    // A gzip stream of 64 MiB of zeros (65 KiB on disk) behind a header promising 512 bytes.
    let f = d.join("bomb.nrrd");
    std::fs::write(
        &f,
        nrrd(
            "type: uchar\ndimension: 3\nsizes: 8 8 8\nencoding: gzip\n",
            &gzip(&vec![0u8; 64 << 20]),
        ),
    )
    .unwrap();
    refused(&f, &["more than the 512 bytes"], QUICK);
    // The same in a .vti zlib block: 8 voxels promised, 16 MiB inflated.
    let f = d.join("bomb.vti");
    std::fs::write(&f, vti_with_block(&vec![0u8; 16 << 20], "0 1 0 1 0 1")).unwrap();
    refused(&f, &["inflates past"], QUICK);
    // A device and a FIFO are not volumes (a FIFO would block the reader forever).
    if Path::new("/dev/zero").exists() {
        let scene = d.join("zero.toml");
        std::fs::write(
            &scene,
            format!(
                "[volume]\nfile = \"/dev/zero\"\nformat = \"raw\"\ndims = [8, 8, 8]\ndtype = \"uint8\"\n\
                 [transfer]\ndensity_scale = 1.0\npoints = [ {{ value = 0.0, color = [1, 1, 1], opacity = 1.0 }} ]\n\
                 {CAMERA}"
            ),
        )
        .unwrap();
        let e = load_scene(&scene).unwrap_err().to_string();
        assert!(
            e.contains("/dev/zero") && e.contains("not a regular file"),
            "{e}"
        );
        let e = load_scene(Path::new("/dev/zero")).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
    }
    let fifo = d.join("pipe_8x8x8_uint8.raw");
    if std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success())
    {
        refused(&fifo, &["not a regular file"], QUICK);
    }
}

/// A `.vti` with one zlib-compressed block holding `raw`, for an extent of `extent`.
fn vti_with_block(raw: &[u8], extent: &str) -> String {
    let mut z = ZlibEncoder::new(Vec::new(), Compression::best());
    z.write_all(raw).unwrap();
    let block = z.finish().unwrap();
    let header: Vec<u8> = [1u32, raw.len() as u32, raw.len() as u32, block.len() as u32]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"UInt32\" compressor=\"vtkZLibDataCompressor\">\n\
         <ImageData WholeExtent=\"{extent}\" Origin=\"0 0 0\" Spacing=\"1 1 1\">\n\
         <Piece Extent=\"{extent}\">\n<PointData Scalars=\"v\">\n\
         <DataArray type=\"UInt8\" Name=\"v\" format=\"binary\">\n{}{}\n</DataArray>\n\
         </PointData>\n<CellData>\n</CellData>\n</Piece>\n</ImageData>\n</VTKFile>\n",
        BASE64.encode(&header),
        BASE64.encode(&block)
    )
}

/// `hydrogen.nii` (written by nibabel, vox_offset 352) with `gap` bytes inserted after the
/// extender and vox_offset moved past them; `extension` sets the extender's flag and makes the
/// gap one extension (NIfTI-1: esize, ecode, then esize - 8 bytes of data).
fn padded_nifti(gap: usize, extension: bool) -> Vec<u8> {
    let nii = std::fs::read(data_dir().join("fixtures/hydrogen.nii")).unwrap();
    assert_eq!(f32::from_le_bytes(nii[108..112].try_into().unwrap()), 352.0);
    let mut out = nii[..352].to_vec();
    out[108..112].copy_from_slice(&((352 + gap) as f32).to_le_bytes());
    let mut pad = vec![0xA5u8; gap];
    if extension {
        out[348] = 1;
        pad[..4].copy_from_slice(&(gap as i32).to_le_bytes());
        pad[4..8].copy_from_slice(&6i32.to_le_bytes()); // NIFTI_ECODE_COMMENT
    }
    out.extend_from_slice(&pad);
    out.extend_from_slice(&nii[352..]);
    out
}

#[test]
fn nifti_voxels_are_read_at_vox_offset() {
    let d = scratch("nifti");
    let reference = read_volume(
        &data_dir().join("fixtures/hydrogen.nii"),
        &ReadHints::default(),
    )
    .unwrap()
    .grid;
    // The raw file the fixture was written from, read by another reader.
    let raw = read_volume(
        &data_dir().join("volumes/hydrogen_orbital_64x64x64_float32.raw"),
        &ReadHints::default(),
    )
    .unwrap()
    .grid;
    assert_eq!(reference.to_f32(), raw.to_f32());
    for (name, gap, extension) in [
        ("padded.nii", 48, false),
        ("extension.nii", 32, true),
        ("padded_far.nii", 4096, false),
    ] {
        let bytes = padded_nifti(gap, extension);
        for (file, data) in [
            (name.to_string(), bytes.clone()),
            (format!("{name}.gz"), gzip(&bytes)),
        ] {
            let f = d.join(&file);
            std::fs::write(&f, data).unwrap();
            let v = read_volume(&f, &ReadHints::default())
                .unwrap_or_else(|e| panic!("{file}: {e}"))
                .grid;
            assert_eq!(v.dims(), raw.dims(), "{file}");
            assert!(v.to_f32() == raw.to_f32(), "{file}: voxels shifted");
        }
    }
    // vox_offset inside the header, not a whole number, or past the end of the data.
    let mut bytes = padded_nifti(0, false);
    for (offset, needle) in [
        (100.0f32, "vox_offset 100"),
        (352.5, "vox_offset 352.5"),
        (f32::NAN, "vox_offset NaN"),
        (1e7, "truncated"),
    ] {
        bytes[108..112].copy_from_slice(&offset.to_le_bytes());
        let f = d.join("bad_offset.nii");
        std::fs::write(&f, &bytes).unwrap();
        refused(&f, &[needle], QUICK);
    }
}

#[test]
fn truncated_and_malformed_headers() {
    let d = scratch("malformed");
    let cases: [(&str, Vec<u8>, &[&str]); 5] = [
        (
            "short.nii",
            b"\x5c\x01\x00\x00 too short".to_vec(),
            &["348"],
        ),
        (
            "skip.nrrd",
            nrrd(
                "type: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\nbyte skip: lots\n",
                &[0; 8],
            ),
            &["byte skip: lots", "not an integer"],
        ),
        (
            "gzip_skip.nrrd",
            nrrd(
                "type: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\nbyte skip: -1\n",
                &gzip(&[0; 8]),
            ),
            &["only with raw encoding"],
        ),
        (
            "ascii.nrrd",
            nrrd(
                "type: float\ndimension: 3\nsizes: 2 2 2\nencoding: ascii\n",
                b"1 2 3 4 5 6 7 8 9 10",
            ),
            &["more than 8 values"],
        ),
        (
            "dims.vtk",
            b"# vtk DataFile Version 3.0\nx\nBINARY\nDATASET STRUCTURED_POINTS\nDIMENSIONS 100000 100000 100000\n"
                .to_vec(),
            &["100000x100000x100000", "available"],
        ),
    ];
    for (name, bytes, needles) in cases {
        let f = d.join(name);
        std::fs::write(&f, bytes).unwrap();
        refused(&f, needles, QUICK);
    }
}

const CAMERA: &str =
    "[camera]\neye = [0, 0, 30]\ntarget = [0, 0, 0]\nfov_y = 30\nwidth = 8\nheight = 8\n";

fn scene_with(d: &Path, transfer: &str) -> PathBuf {
    std::fs::write(d.join("v_4x4x4_uint8.raw"), (0..64u8).collect::<Vec<_>>()).unwrap();
    let p = d.join("scene.toml");
    std::fs::write(
        &p,
        format!("[volume]\nfile = \"v_4x4x4_uint8.raw\"\n{transfer}\n{CAMERA}"),
    )
    .unwrap();
    p
}

#[test]
fn numbers_that_nan_or_infinity_slip_past_are_refused() {
    let d = scratch("numbers");
    // TOML has `nan` and `inf` literals.
    for (transfer, needle) in [
        (
            "[transfer]\nwindow = [0, 63]\ndensity_scale = 1.0\npoints = [ { value = 0.0, color = [nan, 0.5, 0.5], opacity = 1.0 } ]",
            "albedo",
        ),
        (
            "[transfer]\nwindow = [-3e38, 3e38]\ndensity_scale = 1.0\npoints = [ { value = 0.0, color = [1, 1, 1], opacity = 1.0 } ]",
            "finite width",
        ),
        (
            "[transfer]\nwindow = [0, inf]\ndensity_scale = 1.0\npoints = [ { value = 0.0, color = [1, 1, 1], opacity = 1.0 } ]",
            "window",
        ),
        (
            "[transfer]\nwindow = [0, 63]\ndensity_scale = nan\npoints = [ { value = 0.0, color = [1, 1, 1], opacity = 1.0 } ]",
            "density_scale",
        ),
        // Tables after the camera's: the scene file's own spp and exposure.
        (
            "[transfer]\nwindow = [0, 63]\ndensity_scale = 1.0\npoints = [ { value = 0.0, color = [1, 1, 1], opacity = 1.0 } ]\n[render]\nspp = 0",
            "spp = 0",
        ),
        (
            "[transfer]\nwindow = [0, 63]\ndensity_scale = 1.0\npoints = [ { value = 0.0, color = [1, 1, 1], opacity = 1.0 } ]\n[output]\nexposure = nan",
            "exposure = NaN",
        ),
    ] {
        let e = load_scene(&scene_with(&d, transfer))
            .err()
            .unwrap_or_else(|| panic!("accepted {transfer}"))
            .to_string();
        assert!(e.contains("scene.toml") && e.contains(needle), "{e}");
    }
}

/// A macrocell size of any u32 loads: larger than the grid means one global majorant (the
/// arithmetic that sized the majorant grid used to wrap and leave it empty).
#[test]
fn any_macrocell_size_loads() {
    let d = scratch("macrocell");
    let tf = "[transfer]\nwindow = [0, 63]\ndensity_scale = 1.0\npoints = [ { value = 0.0, color = [1, 1, 1], opacity = 1.0 } ]";
    let scene = scene_with(&d, tf);
    let text = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("[volume]\n", "[volume]\nmacrocell = 4294967295\n");
    std::fs::write(&scene, text).unwrap();
    let s = load_scene(&scene).unwrap();
    assert_eq!(s.media.medium.majorants().cell_count(), 1);
    assert!(s.media.medium.majorants().global_max() > 0.0);
}

#[test]
fn an_implausible_optical_depth_is_warned_about() {
    let d = scratch("optical-depth");
    let tf = |scale: &str| {
        format!(
            "[transfer]\nwindow = [0, 63]\ndensity_scale = {scale}\npoints = [ {{ value = 0.0, color = [1, 1, 1], opacity = 1.0 }} ]"
        )
    };
    // A 4-voxel box, diagonal 6.9 units: 1e3 per unit is 6.9e3 across (plausible), 1e4 is 6.9e4.
    let quiet = load_scene(&scene_with(&d, &tf("1e3"))).unwrap();
    assert!(
        !quiet.notes.iter().any(|n| n.contains("optical depth")),
        "{:?}",
        quiet.notes
    );
    let loud = load_scene(&scene_with(&d, &tf("1e4"))).unwrap();
    assert!(
        loud.notes
            .iter()
            .any(|n| n.starts_with("warning: ") && n.contains("optical depth")),
        "{:?}",
        loud.notes
    );
}
