//! NRRD (`.nrrd` with attached data, `.nhdr` with a detached data file), raw, gzip and ASCII
//! encodings. No NRRD crate exists; the header is plain text (teem's NRRD0001-5 formats).
//!
//! Used fields: `type`, `dimension`, `sizes`, `endian`, `encoding`, `data file`, `byte skip`,
//! `line skip`, `spacings` and `space directions` (their lengths give the spacing). An origin or
//! a rotation in `space origin` / `space directions` is reported as a note, not applied: the
//! scene places the volume.

use super::budget::read_bounded;
use super::{
    ByteOrder, DType, LoadedVolume, check_volume_size, decode_voxels, grid_for, read_file,
};
use crate::error::{Error, Result};
use flate2::read::GzDecoder;
use glam::Vec3;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn nrrd_type(s: &str) -> Option<DType> {
    Some(match s {
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => DType::U8,
        "signed char" | "int8" | "int8_t" => DType::I8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            DType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => DType::U16,
        "int" | "signed int" | "int32" | "int32_t" => DType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => DType::U32,
        "float" => DType::F32,
        "double" => DType::F64,
        _ => return None,
    })
}

/// Splits the header from attached data: the header ends at the first empty line.
fn split_header(bytes: &[u8]) -> (&[u8], Option<&[u8]>) {
    let mut start = 0;
    while start < bytes.len() {
        let end = bytes[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|p| start + p)
            .unwrap_or(bytes.len());
        let line = &bytes[start..end];
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if line.is_empty() {
            return (&bytes[..start], Some(&bytes[(end + 1).min(bytes.len())..]));
        }
        start = end + 1;
    }
    (bytes, None)
}

fn parse_vector(s: &str) -> Option<Vec3> {
    let inner = s.trim().strip_prefix('(')?.strip_suffix(')')?;
    let v: Vec<f32> = inner
        .split(',')
        .map(|t| t.trim().parse().ok())
        .collect::<Option<_>>()?;
    match v[..] {
        [x, y, z] => Some(Vec3::new(x, y, z)),
        _ => None,
    }
}

pub(super) fn read(path: &Path) -> Result<LoadedVolume> {
    let bytes = read_file(path)?;
    if !bytes.starts_with(b"NRRD000") {
        return Err(Error::format(
            path,
            "not an NRRD file: expected the magic line `NRRD0001`..`NRRD0005`",
        ));
    }
    let (header, attached) = split_header(&bytes);
    let header = Header::parse(path, header)?;
    let (dtype, size) = header.voxel_layout()?;
    let dims = size.dims;
    let encoding = header.need("encoding")?.to_ascii_lowercase();
    let order = header.byte_order(dtype, &encoding)?;
    let (spacing, notes) = header.geometry();
    let payload = header.payload(attached)?;
    let payload = header.skip_lines(&payload)?;
    let byte_skip = header.byte_skip()?;

    let want = size.payload_bytes;
    let decoded: Vec<u8>;
    let data: &[u8] = match encoding.as_str() {
        "raw" => payload,
        "gzip" | "gz" => {
            if byte_skip < 0 {
                return Err(header.bad(
                    "NRRD `byte skip: -1` is allowed only with raw encoding (teem's rule)".into(),
                ));
            }
            // Never inflate past the skipped bytes plus the voxels the header promises.
            let limit = usize::try_from(byte_skip)
                .unwrap_or(usize::MAX)
                .saturating_add(want);
            decoded = read_bounded(path, GzDecoder::new(payload), limit, "NRRD gzip data")?;
            &decoded
        }
        "ascii" | "text" | "txt" => {
            let values = header.ascii_values(payload, size.voxels, dims)?;
            return Ok(LoadedVolume {
                grid: grid_for(path, dims, crate::grid::Voxels::F32(values))?,
                spacing,
                units: header.units(),
                notes,
            });
        }
        other => {
            return Err(header.bad(format!(
                "NRRD encoding `{other}` is not supported: expected raw, gzip or ascii"
            )));
        }
    };
    // byte skip -1: the data are the last bytes of the (decoded) payload.
    let data = if byte_skip < 0 {
        if data.len() < want {
            &data[..0]
        } else {
            &data[data.len() - want..]
        }
    } else {
        &data[usize::try_from(byte_skip).map_or(data.len(), |b| b.min(data.len()))..]
    };
    if data.len() != want {
        let what = if data.len() < want {
            "truncated"
        } else {
            "oversized"
        };
        return Err(header.bad(format!(
            "NRRD data is {what}: {} bytes, expected {want} ({}x{}x{} voxels of {dtype})",
            data.len(),
            dims.x,
            dims.y,
            dims.z
        )));
    }
    let values = decode_voxels(data, dtype, order);
    Ok(LoadedVolume {
        grid: grid_for(path, dims, values)?,
        spacing,
        units: header.units(),
        notes,
    })
}

/// The header's fields (names lower-cased), with the file they came from for errors.
struct Header<'a> {
    path: &'a Path,
    fields: HashMap<String, String>,
}

impl<'a> Header<'a> {
    /// Reads `field: value` lines after the magic line (comments and `key:=value` pairs
    /// skipped).
    fn parse(path: &'a Path, header: &[u8]) -> Result<Self> {
        let header = std::str::from_utf8(header)
            .map_err(|_| Error::format(path, "NRRD header is not text"))?;
        let mut fields: HashMap<String, String> = HashMap::new();
        for line in header.lines().skip(1) {
            let line = line.trim_end_matches('\r');
            if line.starts_with('#') || line.contains(":=") {
                continue;
            }
            if let Some((k, v)) = line.split_once(": ") {
                fields.insert(k.trim().to_ascii_lowercase(), v.trim().to_string());
            } else if !line.trim().is_empty() {
                return Err(Error::format(
                    path,
                    format!("NRRD header line `{line}` is not `field: value`"),
                ));
            }
        }
        Ok(Self { path, fields })
    }

    fn bad(&self, message: String) -> Error {
        Error::format(self.path, message)
    }

    fn field(&self, key: &str) -> Option<&str> {
        self.fields.get(key).map(String::as_str)
    }

    fn need(&self, key: &str) -> Result<&str> {
        self.field(key)
            .ok_or_else(|| self.bad(format!("NRRD header has no `{key}:` field")))
    }

    /// The voxel type and the grid's size (a 3D scalar volume, checked against memory).
    fn voxel_layout(&self) -> Result<(DType, super::budget::VolumeSize)> {
        let dtype = nrrd_type(self.need("type")?).ok_or_else(|| {
            self.bad(format!(
                "NRRD type `{}` is not supported: expected an integer of 8, 16 or 32 bits, float or double",
                self.field("type").unwrap_or_default()
            ))
        })?;
        let dimension: usize = self
            .need("dimension")?
            .parse()
            .map_err(|_| self.bad("NRRD `dimension` is not an integer".into()))?;
        let sizes: Vec<i64> = self
            .need("sizes")?
            .split_whitespace()
            .map(|s| s.parse().ok())
            .collect::<Option<_>>()
            .ok_or_else(|| self.bad("NRRD `sizes` are not integers".into()))?;
        if sizes.len() != dimension {
            return Err(self.bad(format!(
                "NRRD `sizes` lists {} axes but `dimension` is {dimension}",
                sizes.len()
            )));
        }
        // A leading axis of size 1 (a scalar "component" axis) is accepted.
        let spatial = match sizes[..] {
            [x, y, z] | [1, x, y, z] => [x, y, z],
            _ => {
                return Err(self.bad(format!(
                    "NRRD volume has sizes {sizes:?}: expected a 3D scalar volume (3 axes)"
                )));
            }
        };
        Ok((dtype, check_volume_size(self.path, spatial, dtype)?))
    }

    /// `endian:`, needed only where voxels have more than one byte and are not text.
    fn byte_order(&self, dtype: DType, encoding: &str) -> Result<ByteOrder> {
        match self.field("endian") {
            Some("little") => Ok(ByteOrder::Little),
            Some("big") => Ok(ByteOrder::Big),
            // Text and single bytes have no byte order.
            None if dtype.size() == 1 || matches!(encoding, "ascii" | "text" | "txt") => {
                Ok(ByteOrder::Little)
            }
            None => {
                Err(self
                    .bad("NRRD header has no `endian:` field, needed for multi-byte voxels".into()))
            }
            Some(other) => Err(self.bad(format!("NRRD endian `{other}` is not `little` or `big`"))),
        }
    }

    /// The voxel spacing (`spacings`, or the lengths of `space directions`) and notes on what
    /// is not applied (a rotation, an origin).
    fn geometry(&self) -> (Option<Vec3>, Vec<String>) {
        let mut notes = Vec::new();
        let mut spacing = None;
        if let Some(s) = self.field("spacings") {
            let v: Vec<f32> = s
                .split_whitespace()
                .filter_map(|t| t.parse().ok())
                .collect();
            if v.len() >= 3 {
                let v = &v[v.len() - 3..];
                spacing = Some(Vec3::new(v[0], v[1], v[2]));
            }
        }
        if let Some(s) = self.field("space directions") {
            let dirs: Vec<Vec3> = s.split_whitespace().filter_map(parse_vector).collect();
            if dirs.len() == 3 {
                spacing = Some(Vec3::new(
                    dirs[0].length(),
                    dirs[1].length(),
                    dirs[2].length(),
                ));
                let off_axis = dirs.iter().enumerate().any(|(i, d)| {
                    let l = d.length();
                    (0..3).any(|j| j != i && d[j].abs() > 1e-6 * l)
                });
                if off_axis {
                    notes.push(format!(
                        "space directions {s} are not axis-aligned: only their lengths are used"
                    ));
                }
            }
        }
        if let Some(o) = self.field("space origin") {
            notes.push(format!(
                "space origin {o} is not applied: the scene places the volume"
            ));
        }
        (spacing, notes)
    }

    /// The spacing's unit: `space units` when it names one unit for every axis (quoted
    /// strings, at most 16 characters each, no control characters).
    fn units(&self) -> Option<String> {
        let field = self.field("space units")?;
        let units: Vec<&str> = field.split('"').skip(1).step_by(2).map(str::trim).collect();
        let first = *units.first()?;
        let plausible = !first.is_empty()
            && first.chars().count() <= 16
            && !first.chars().any(char::is_control);
        (plausible && units.iter().all(|u| *u == first)).then(|| first.to_string())
    }

    /// The data's bytes: the detached `data file` (beside the header) or what follows the
    /// header's blank line.
    fn payload(&self, attached: Option<&[u8]>) -> Result<Vec<u8>> {
        match self.field("data file").or(self.field("datafile")) {
            Some(name) => {
                if name.starts_with("LIST") || name.contains('%') {
                    return Err(self.bad(format!(
                        "NRRD `data file: {name}` lists several files: expected one data file"
                    )));
                }
                let data_path: PathBuf = self.path.parent().unwrap_or(Path::new(".")).join(name);
                read_file(&data_path)
            }
            None => Ok(attached
                .ok_or_else(|| {
                    self.bad(
                        "NRRD header has no `data file:` and no data after the header's blank line"
                            .into(),
                    )
                })?
                .to_vec()),
        }
    }

    /// A skip count (`names`: the field's two spellings), 0 when absent. i128 holds every count
    /// a header can write, so a huge one is reported as too large by its user instead of as
    /// "not an integer".
    fn skip(&self, names: [&str; 2]) -> Result<i128> {
        match self.field(names[0]).or(self.field(names[1])) {
            None => Ok(0),
            Some(v) => v.parse().map_err(|_| {
                self.bad(format!(
                    "NRRD `{}: {v}` is not an integer: expected a count of {}",
                    names[0],
                    if names[0] == "line skip" {
                        "lines"
                    } else {
                        "bytes, or -1"
                    }
                ))
            }),
        }
    }

    /// `payload` after the `line skip` lines.
    fn skip_lines<'p>(&self, payload: &'p [u8]) -> Result<&'p [u8]> {
        let line_skip = self.skip(["line skip", "lineskip"])?;
        if line_skip < 0 {
            return Err(self.bad(format!(
                "NRRD `line skip: {line_skip}` is negative: expected a count of lines"
            )));
        }
        let mut payload = payload;
        // Bounded by the payload: each step consumes a line or fails.
        for skipped in 0..line_skip {
            let next = payload.iter().position(|&b| b == b'\n').ok_or_else(|| {
                self.bad(format!(
                    "NRRD `line skip: {line_skip}` passes the end of the data after {skipped} lines"
                ))
            })?;
            payload = &payload[next + 1..];
        }
        Ok(payload)
    }

    /// `byte skip`: a count of bytes, or -1 (the data are the payload's last bytes).
    fn byte_skip(&self) -> Result<i128> {
        let byte_skip = self.skip(["byte skip", "byteskip"])?;
        if byte_skip < -1 {
            return Err(self.bad(format!(
                "NRRD `byte skip: {byte_skip}` is negative: expected a count of bytes, or -1"
            )));
        }
        Ok(byte_skip)
    }

    /// The `n` numbers of ASCII-encoded data (separated by white space or commas).
    fn ascii_values(&self, payload: &[u8], n: usize, dims: glam::UVec3) -> Result<Vec<f32>> {
        let mut values: Vec<f32> = Vec::new();
        let text = std::str::from_utf8(payload)
            .map_err(|_| self.bad("NRRD ascii data is not text".into()))?;
        let mut tokens = text
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty());
        // One more than expected is enough to call the data oversized.
        for token in tokens.by_ref().take(n + 1) {
            let v: f64 = token.parse().map_err(|e| {
                self.bad(format!("NRRD ascii data holds a non-number `{token}`: {e}"))
            })?;
            values.push(v as f32);
        }
        if values.len() != n {
            return Err(self.bad(format!(
                "NRRD ascii data has {}{} values, expected {n} ({}x{}x{})",
                if values.len() > n { "more than " } else { "" },
                values.len().min(n),
                dims.x,
                dims.y,
                dims.z
            )));
        }
        Ok(values)
    }
}
