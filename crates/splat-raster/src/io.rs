//! Reading and writing Gaussian clouds: the standard 3DGS PLY (read and write) and the
//! antimatter15 `.splat` format (read).
//!
//! PLY properties are found by name, so files with extra properties (or another order) load;
//! the SH degree is inferred from the number of `f_rest_*` properties (0, 9, 24 or 45). 3DGS
//! meanings: `scale_*` are log standard deviations, `opacity` is a logit, `rot_0..3` is a
//! quaternion with `rot_0 = w`, colour is `0.5 + 0.28209479 f_dc` plus the rest of the SH with
//! `f_rest` stored channel-major (all of R, then G, then B).

use crate::cloud::{ColorModel, GaussianCloud};
use crate::sh::coeffs_for_degree;
use std::io::Write;
use std::path::{Path, PathBuf};

use render_base::SH_C0;

/// Why a cloud could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

fn fmt_err(path: &Path, message: impl Into<String>) -> IoError {
    IoError::Format {
        path: path.into(),
        message: message.into(),
    }
}

#[derive(Debug, Clone, Copy)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    fn read(self, b: &[u8], big: bool) -> f32 {
        macro_rules! rd {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                (if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }) as f32
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f32,
            Scalar::U8 => b[0] as f32,
            Scalar::I16 => rd!(i16, 2),
            Scalar::U16 => rd!(u16, 2),
            Scalar::I32 => rd!(i32, 4),
            Scalar::U32 => rd!(u32, 4),
            Scalar::F32 => rd!(f32, 4),
            Scalar::F64 => rd!(f64, 8),
        }
    }
}

/// Reads a whole regular file; a directory, device or FIFO has no size and may never end.
fn read_regular(path: &Path) -> Result<Vec<u8>, IoError> {
    let io = |e| IoError::Io {
        path: path.into(),
        source: e,
    };
    if !std::fs::metadata(path).map_err(io)?.is_file() {
        return Err(fmt_err(
            path,
            "is not a regular file (a directory, device, FIFO or socket): expected a cloud file",
        ));
    }
    std::fs::read(path).map_err(io)
}

/// A PLY element of the header: its name, record count and properties (name, type).
struct PlyElement {
    name: String,
    count: usize,
    properties: Vec<(String, Scalar)>,
}

/// Reads a 3DGS PLY file (binary, either byte order).
pub fn read_ply(path: &Path) -> Result<GaussianCloud<f32>, IoError> {
    let bytes = read_regular(path)?;
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or_else(|| fmt_err(path, "no `end_header` line: not a PLY file"))?;
    let header =
        std::str::from_utf8(&bytes[..end]).map_err(|_| fmt_err(path, "PLY header is not text"))?;
    let (big, elements) = read_ply_header(path, header)?;
    let mut offset = end + 11;
    for element in &elements {
        let (name, count) = (&element.name, element.count);
        let stride: usize = element.properties.iter().map(|p| p.1.size()).sum();
        // Counts come from the header: checked, so a huge count cannot wrap into a small one.
        let end = count
            .checked_mul(stride)
            .and_then(|len| offset.checked_add(len))
            .filter(|&end| end <= bytes.len())
            .ok_or_else(|| {
                fmt_err(
                    path,
                    format!(
                        "file is truncated: element `{name}` has {count} records of {stride} \
                         bytes, more than the {} bytes after its start",
                        bytes.len() - offset
                    ),
                )
            })?;
        if name != "vertex" {
            offset = end;
            continue;
        }
        return read_ply_vertices(path, element, &bytes[offset..end], stride, big);
    }
    Err(fmt_err(path, "no `vertex` element"))
}

/// The header after its `ply` line: whether the data are big-endian, and the elements.
fn read_ply_header(path: &Path, header: &str) -> Result<(bool, Vec<PlyElement>), IoError> {
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(fmt_err(path, "first line is not `ply`"));
    }
    let mut big = false;
    let mut elements: Vec<PlyElement> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", "binary_little_endian", _] => big = false,
            ["format", "binary_big_endian", _] => big = true,
            ["format", other, ..] => {
                return Err(fmt_err(
                    path,
                    format!(
                        "PLY format `{other}` is not supported: expected binary_little_endian or binary_big_endian"
                    ),
                ));
            }
            ["element", name, count] => {
                let count = count.parse().map_err(|_| {
                    fmt_err(
                        path,
                        format!("element `{name}` count `{count}` is not a number"),
                    )
                })?;
                elements.push(PlyElement {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            ["property", "list", ..] => {
                let el = elements.last().map(|e| e.name.clone()).unwrap_or_default();
                if el == "vertex" || elements.iter().all(|e| e.name != "vertex") {
                    return Err(fmt_err(
                        path,
                        format!(
                            "list property in element `{el}` before or in the vertices: not a 3DGS PLY"
                        ),
                    ));
                }
            }
            ["property", ty, name] => {
                let s = Scalar::parse(ty).ok_or_else(|| {
                    fmt_err(path, format!("property `{name}` has unknown type `{ty}`"))
                })?;
                match elements.last_mut() {
                    Some(e) => e.properties.push((name.to_string(), s)),
                    None => {
                        return Err(fmt_err(
                            path,
                            format!("property `{name}` before any element"),
                        ));
                    }
                }
            }
            _ => {}
        }
    }
    Ok((big, elements))
}

/// The Gaussians of the `vertex` element, whose records (`stride` bytes each) are `data`.
fn read_ply_vertices(
    path: &Path,
    vertex: &PlyElement,
    data: &[u8],
    stride: usize,
    big: bool,
) -> Result<GaussianCloud<f32>, IoError> {
    let (props, count) = (&vertex.properties, vertex.count);
    let find = |n: &str| -> Option<(usize, Scalar)> {
        let mut off = 0;
        for (pn, s) in props {
            if pn == n {
                return Some((off, *s));
            }
            off += s.size();
        }
        None
    };
    let need = |n: &str| {
        find(n).ok_or_else(|| {
            fmt_err(
                path,
                format!("vertex property `{n}` is missing: expected a 3DGS PLY"),
            )
        })
    };
    let n_rest = (0..)
        .take_while(|i| find(&format!("f_rest_{i}")).is_some())
        .count();
    let degree = match n_rest {
        0 => 0,
        9 => 1,
        24 => 2,
        45 => 3,
        k => {
            return Err(fmt_err(
                path,
                format!("{k} `f_rest_*` properties: expected 0, 9, 24 or 45 (SH degree 0-3)"),
            ));
        }
    };
    let k = coeffs_for_degree(degree);
    let pos = [need("x")?, need("y")?, need("z")?];
    let scale = [need("scale_0")?, need("scale_1")?, need("scale_2")?];
    let rot = [
        need("rot_0")?,
        need("rot_1")?,
        need("rot_2")?,
        need("rot_3")?,
    ];
    let dc = [need("f_dc_0")?, need("f_dc_1")?, need("f_dc_2")?];
    let opacity = need("opacity")?;
    let rest: Vec<(usize, Scalar)> = (0..n_rest)
        .map(|i| find(&format!("f_rest_{i}")).unwrap())
        .collect();
    let mut cloud = GaussianCloud::<f32>::new(ColorModel::Sh(degree));
    cloud.means.reserve(3 * count);
    let mut color = vec![0.0f32; 3 * k];
    for v in 0..count {
        let rec = &data[v * stride..(v + 1) * stride];
        let get = |(o, s): (usize, Scalar)| s.read(&rec[o..], big);
        for c in 0..3 {
            color[c] = get(dc[c]);
            for j in 1..k {
                color[3 * j + c] = get(rest[c * (k - 1) + (j - 1)]);
            }
        }
        cloud.push(
            pos.map(get),
            scale.map(get),
            rot.map(get),
            &color,
            get(opacity),
        );
    }
    Ok(cloud)
}

/// Writes the standard 3DGS PLY (binary little endian, 62 floats per Gaussian for degree 3).
/// An RGB cloud is written as SH degree 0 (`f_dc = (rgb - 0.5) / 0.28209479`), which renders
/// the same colours in any 3DGS viewer.
pub fn write_ply(path: &Path, cloud: &GaussianCloud<f32>) -> Result<(), IoError> {
    cloud.check().map_err(|m| fmt_err(path, m))?;
    let (degree, rgb) = match cloud.color_model {
        ColorModel::Rgb => (0, true),
        ColorModel::Sh(d) => (d, false),
    };
    let k = coeffs_for_degree(degree);
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n",
        cloud.len()
    );
    for name in [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ] {
        header += &format!("property float {name}\n");
    }
    for i in 0..3 * (k - 1) {
        header += &format!("property float f_rest_{i}\n");
    }
    for name in [
        "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
    ] {
        header += &format!("property float {name}\n");
    }
    header += "end_header\n";
    let mut out = Vec::with_capacity(header.len() + cloud.len() * (17 + 3 * k) * 4);
    out.extend_from_slice(header.as_bytes());
    let stride = cloud.color_stride();
    let mut put = |v: f32| out.extend_from_slice(&v.to_le_bytes());
    for g in 0..cloud.len() {
        for i in 0..3 {
            put(cloud.means[3 * g + i]);
        }
        for _ in 0..3 {
            put(0.0);
        }
        let c = &cloud.colors[g * stride..(g + 1) * stride];
        for ch in 0..3 {
            put(if rgb { (c[ch] - 0.5) / SH_C0 } else { c[ch] });
        }
        for ch in 0..3 {
            for j in 1..k {
                put(c[3 * j + ch]);
            }
        }
        put(cloud.opacity_logits[g]);
        for i in 0..3 {
            put(cloud.log_scales[3 * g + i]);
        }
        for i in 0..4 {
            put(cloud.rotations[4 * g + i]);
        }
    }
    // Atomically, like every file written for a user: a cache saved over an old one is whole
    // or not written, and a link planted in a shared folder is replaced, not written through.
    render_base::write_atomically(path, |f| f.write_all(&out).map_err(|e| e.to_string())).map_err(
        |e| IoError::Io {
            path: path.into(),
            source: std::io::Error::other(e.message),
        },
    )
}

/// Reads an antimatter15 `.splat` file: 32-byte records of position (3 f32), linear scale
/// (3 f32), RGBA (4 u8) and quaternion (4 u8, `(q - 128) / 128`, first byte w).
pub fn read_splat(path: &Path) -> Result<GaussianCloud<f32>, IoError> {
    let bytes = read_regular(path)?;
    if bytes.len() % 32 != 0 {
        return Err(fmt_err(
            path,
            format!(
                "{} bytes is not a whole number of 32-byte .splat records",
                bytes.len()
            ),
        ));
    }
    let mut cloud = GaussianCloud::<f32>::new(ColorModel::Sh(0));
    let f = |b: &[u8], i: usize| f32::from_le_bytes(b[4 * i..4 * i + 4].try_into().unwrap());
    for r in bytes.chunks_exact(32) {
        let pos = [f(r, 0), f(r, 1), f(r, 2)];
        let scale = [f(r, 3).ln(), f(r, 4).ln(), f(r, 5).ln()];
        let rgba = &r[24..28];
        let color = [0, 1, 2].map(|c| (rgba[c] as f32 / 255.0 - 0.5) / SH_C0);
        let a = (rgba[3] as f32 / 255.0).clamp(0.5 / 255.0, 254.5 / 255.0);
        let q = [0, 1, 2, 3].map(|i| (r[28 + i] as f32 - 128.0) / 128.0);
        cloud.push(pos, scale, q, &color, (a / (1.0 - a)).ln());
    }
    Ok(cloud)
}

/// Reads a cloud by extension: `.ply` or `.splat`.
pub fn read_cloud(path: &Path) -> Result<GaussianCloud<f32>, IoError> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("ply") => read_ply(path),
        Some("splat") => read_splat(path),
        _ => Err(fmt_err(
            path,
            "unknown Gaussian cloud format: expected .ply or .splat",
        )),
    }
}
