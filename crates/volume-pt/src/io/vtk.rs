//! VTK image data: legacy `.vtk` STRUCTURED_POINTS and XML `.vti` ImageData. The first scalar
//! point-data array (one component) is the volume. VTK's point samples map to our voxel
//! centres; the file's origin is reported as a note, the scene places the volume.
//!
//! vtkio reads the legacy files and the uncompressed XML ones, with two of its faults worked
//! around. Its legacy parser rejects the blank lines that old VTK writers put between header
//! sections (see [`tidy_legacy_header`]). Its handling of zlib-compressed XML arrays is unsafe
//! to use: 0.6.3 decoded only the first 32 KiB block and dropped larger arrays without an
//! error, and 0.7.0-rc2 slices the data by the header's block sizes unchecked, so a damaged
//! header panics inside it. Compressed `.vti` files are therefore read here
//! ([`read_compressed_xml`], [`decode_compressed_array`]), every size checked against the file.

use super::budget::VolumeSize;
use super::{DType, LoadedVolume, check_volume_size, grid_for};
use crate::error::{Error, Result};
use crate::grid::Voxels;
use base64::Engine as _;
use base64::engine::general_purpose::STANDARD as BASE64;
use glam::Vec3;
use std::path::Path;
use vtkio::model::{Attribute, DataSet, Extent, IOBuffer, Piece};

/// vtkio's array in our voxel types (8- and 16-bit kept, the rest as f32).
fn to_voxels(buf: IOBuffer) -> Option<Voxels> {
    Some(match buf {
        IOBuffer::U8(v) => Voxels::U8(v),
        IOBuffer::I8(v) => Voxels::I8(v),
        IOBuffer::U16(v) => Voxels::U16(v),
        IOBuffer::I16(v) => Voxels::I16(v),
        IOBuffer::U32(v) => Voxels::F32(v.into_iter().map(|x| x as f32).collect()),
        IOBuffer::I32(v) => Voxels::F32(v.into_iter().map(|x| x as f32).collect()),
        IOBuffer::U64(v) => Voxels::F32(v.into_iter().map(|x| x as f32).collect()),
        IOBuffer::I64(v) => Voxels::F32(v.into_iter().map(|x| x as f32).collect()),
        IOBuffer::F32(v) => Voxels::F32(v),
        IOBuffer::F64(v) => Voxels::F32(v.into_iter().map(|x| x as f32).collect()),
        IOBuffer::Bit(_) => return None,
    })
}

/// Legacy files written by old VTK versions put blank lines between header sections, which VTK
/// itself accepts but vtkio's parser does not: drop them from the text header (everything up to
/// the SCALARS line and its optional LOOKUP_TABLE line), leaving binary data untouched.
fn tidy_legacy_header(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len());
    let mut rest = bytes;
    let mut after_scalars = false;
    while let Some(nl) = rest.iter().position(|&b| b == b'\n') {
        let line = &rest[..=nl];
        let text = String::from_utf8_lossy(line);
        let trimmed = text.trim();
        if trimmed.is_empty() {
            rest = &rest[nl + 1..];
            continue;
        }
        let upper = trimmed.to_ascii_uppercase();
        if after_scalars && !upper.starts_with("LOOKUP_TABLE") {
            break;
        }
        out.extend_from_slice(line);
        rest = &rest[nl + 1..];
        if upper.starts_with("LOOKUP_TABLE") {
            break;
        }
        after_scalars = upper.starts_with("SCALARS");
    }
    out.extend_from_slice(rest);
    out
}

pub(super) fn read(path: &Path) -> Result<LoadedVolume> {
    let bad = |m: String| Error::format(path, m);
    let is_legacy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vtk"));
    let bytes = super::read_file(path)?;
    // The size the file states is checked before vtkio allocates anything for it.
    let (stated, dtype) = stated_size(&bytes, is_legacy).map_err(bad)?;
    let size = check_volume_size(path, stated, dtype)?;
    if !is_legacy && let Some(loaded) = read_compressed_xml(path, &bytes, &size)? {
        return Ok(loaded);
    }
    let vtk = if is_legacy {
        vtkio::Vtk::parse_legacy_be(&tidy_legacy_header(&bytes)[..])
    } else {
        vtkio::Vtk::parse_xml(&bytes[..])
    }
    .map_err(|e| {
        // vtkio's own message is a parser's ("Parse error: Alt"): say what was expected.
        let expected = if is_legacy {
            "a legacy VTK file: `# vtk DataFile Version x.y`, a title line, ASCII or BINARY, \
             `DATASET STRUCTURED_POINTS` with DIMENSIONS, SPACING (or ASPECT_RATIO) and ORIGIN, \
             then `POINT_DATA n` and one `SCALARS name type` array"
        } else {
            "a VTK XML ImageData file (.vti) with one point-data array"
        };
        bad(format!(
            "cannot parse VTK file (the parser said: {e}): expected {expected}"
        ))
    })?;
    let DataSet::ImageData {
        extent,
        origin,
        spacing,
        pieces,
        ..
    } = vtk.data
    else {
        return Err(bad(
            "VTK data set is not image data: expected STRUCTURED_POINTS (.vtk) or ImageData (.vti)"
                .into(),
        ));
    };
    let parsed = match extent {
        Extent::Dims(d) => d.map(i64::from),
        Extent::Ranges(r) => {
            [0, 1, 2].map(|i| i64::from(*r[i].end()) - i64::from(*r[i].start()) + 1)
        }
    };
    if parsed != stated {
        return Err(bad(format!(
            "VTK extent {parsed:?} differs from the header's {stated:?}"
        )));
    }
    let dims = size.dims;
    if pieces.len() != 1 {
        return Err(bad(format!(
            "VTK image data has {} pieces: expected exactly one inline piece",
            pieces.len()
        )));
    }
    let piece = match pieces.into_iter().next() {
        Some(Piece::Inline(p)) => p,
        _ => {
            return Err(bad(
                "VTK piece is stored in another file: expected inline data".into(),
            ));
        }
    };
    let array = piece.data.point.into_iter().find_map(|a| match a {
        Attribute::DataArray(da) if da.elem.num_comp() == 1 => Some(da),
        _ => None,
    });
    let (name, values) = match array {
        Some(array) => {
            let name = array.name.clone();
            let values = to_voxels(array.data)
                .ok_or_else(|| bad(format!("VTK array `{name}` is a bit array")))?;
            (name, values)
        }
        None => return Err(bad("VTK file has no one-component point-data array".into())),
    };
    let n = size.voxels;
    if values.len() != n {
        return Err(bad(format!(
            "VTK array `{name}` has {} values, expected {n} for dims {}x{}x{}",
            values.len(),
            dims.x,
            dims.y,
            dims.z
        )));
    }
    let mut notes = vec![format!("read point-data array `{name}`")];
    if origin != [0.0; 3] {
        notes.push(format!(
            "file origin {origin:?} is not applied: the scene places the volume"
        ));
    }
    Ok(LoadedVolume {
        grid: grid_for(path, dims, values)?,
        spacing: Some(Vec3::from_array(spacing)),
        units: None,
        notes,
    })
}

/// A `.vti` whose arrays are zlib-compressed is read here, not by vtkio: 0.6.3 decoded only its
/// first 32 KiB block, and 0.7.0-rc2 slices the data by the header's block sizes unchecked (a
/// mutated header panicked inside it; the fuzzer found it). The image data's Spacing and
/// Origin come from its tag, the array from [`decode_compressed_array`], which checks every
/// size against the file and the extent. `None`: the file is not compressed.
fn read_compressed_xml(
    path: &Path,
    bytes: &[u8],
    size: &VolumeSize,
) -> Result<Option<LoadedVolume>> {
    let voxels = size.voxels;
    let bad = |m: String| Error::format(path, m);
    let text = std::str::from_utf8(bytes).map_err(|_| {
        bad("VTK XML file is not UTF-8 text: expected inline (not appended raw) data".into())
    })?;
    let root_start = text
        .find("<VTKFile")
        .ok_or_else(|| bad("VTK XML file has no <VTKFile> element".into()))?;
    let root = &text[root_start..root_start + text[root_start..].find('>').unwrap_or(0)];
    if xml_attr(root, "compressor").is_none() {
        return Ok(None);
    }
    let pieces = text.matches("<Piece").count();
    if pieces != 1 {
        return Err(bad(format!(
            "VTK image data has {pieces} pieces: expected exactly one inline piece"
        )));
    }
    let start = text
        .find("<ImageData")
        .ok_or_else(|| bad("VTK XML file has no <ImageData> element".into()))?;
    let tag = &text[start..start + text[start..].find('>').unwrap_or(0)];
    let triple = |name: &str, default: [f32; 3]| -> Result<[f32; 3]> {
        let Some(value) = xml_attr(tag, name) else {
            return Ok(default);
        };
        let v: Option<Vec<f32>> = value.split_whitespace().map(|t| t.parse().ok()).collect();
        match v.as_deref() {
            Some(&[a, b, c]) if [a, b, c].iter().all(|x| x.is_finite()) => Ok([a, b, c]),
            _ => Err(bad(format!(
                "VTK <ImageData> {name} `{value}` is not three finite numbers"
            ))),
        }
    };
    let spacing = triple("Spacing", [1.0; 3])?;
    let origin = triple("Origin", [0.0; 3])?;
    let (name, values) = decode_compressed_array(text, voxels * 8).map_err(bad)?;
    if values.len() != voxels {
        return Err(bad(format!(
            "VTK array `{name}` has {} values, expected {voxels} for its extent",
            values.len()
        )));
    }
    let mut notes = vec![format!("read point-data array `{name}`")];
    if origin != [0.0; 3] {
        notes.push(format!(
            "file origin {origin:?} is not applied: the scene places the volume"
        ));
    }
    Ok(Some(LoadedVolume {
        grid: grid_for(path, size.dims, values)?,
        spacing: Some(Vec3::from_array(spacing)),
        units: None,
        notes,
    }))
}

/// The dims (and element type, where the text says it) that a VTK file's text states, read
/// before the file is parsed so that a huge claim is refused before anything is allocated.
fn stated_size(bytes: &[u8], legacy: bool) -> std::result::Result<([i64; 3], DType), String> {
    let ints =
        |s: &str| -> Option<Vec<i64>> { s.split_whitespace().map(|t| t.parse().ok()).collect() };
    // The header is text; binary data follow it. 64 KiB holds any real header.
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(1 << 16)]);
    if legacy {
        let line = head
            .lines()
            .find(|l| {
                l.trim_start()
                    .to_ascii_uppercase()
                    .starts_with("DIMENSIONS")
            })
            .ok_or("VTK file has no DIMENSIONS line: expected STRUCTURED_POINTS")?;
        let dims = ints(line.trim_start()["DIMENSIONS".len()..].trim())
            .filter(|v| v.len() == 3)
            .ok_or_else(|| format!("VTK line `{}` is not `DIMENSIONS x y z`", line.trim()))?;
        let dtype = head
            .lines()
            .find_map(|l| {
                let mut w = l.split_whitespace();
                (w.next()?.eq_ignore_ascii_case("SCALARS"))
                    .then(|| DType::parse(w.nth(1)?))
                    .flatten()
            })
            .unwrap_or(DType::F64);
        Ok(([dims[0], dims[1], dims[2]], dtype))
    } else {
        let start = head
            .find("<ImageData")
            .ok_or("VTK XML file has no <ImageData> element")?;
        let tag = &head[start..start + head[start..].find('>').unwrap_or(head.len() - start)];
        let extent =
            xml_attr(tag, "WholeExtent").ok_or("VTK <ImageData> has no WholeExtent attribute")?;
        let e = ints(extent)
            .filter(|v| v.len() == 6)
            .ok_or_else(|| format!("VTK WholeExtent `{extent}` is not six integers"))?;
        // Every extent (the whole one and each piece's) must run forwards: vtkio subtracts
        // them unchecked (a piece's `0 -1` panicked inside it; the fuzzer found it).
        let mut rest: &str = &head;
        while let Some(at) = rest.find("Extent=\"") {
            let value = &rest[at + 8..];
            let value = &value[..value.find('"').unwrap_or(value.len())];
            let v = ints(value)
                .filter(|v| v.len() == 6)
                .ok_or_else(|| format!("VTK extent `{value}` is not six integers"))?;
            if (0..3).any(|i| v[2 * i + 1] < v[2 * i]) {
                return Err(format!(
                    "VTK extent `{value}` runs backwards: expected x0 x1 y0 y1 z0 z1 with each \
                     end at or after its start"
                ));
            }
            rest = &rest[at + 8..];
        }
        let axis = |i: usize| e[2 * i + 1].saturating_sub(e[2 * i]).saturating_add(1);
        Ok(([axis(0), axis(1), axis(2)], DType::F64))
    }
}

/// The value of `name="..."` in an XML start tag.
fn xml_attr<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let start = tag.find(&key)? + key.len();
    let len = tag[start..].find('"')?;
    Some(&tag[start..start + len])
}

/// Decodes the first one-component point-data array of a `.vti` whose data are inline, base64,
/// zlib-compressed in blocks: header `[blocks, block size, last block size, compressed sizes...]`
/// of `header_type` integers, then the compressed blocks, all base64-encoded together.
fn decode_compressed_array(
    text: &str,
    max_bytes: usize,
) -> std::result::Result<(String, Voxels), String> {
    use std::io::Read;
    let root_start = text.find("<VTKFile").ok_or("no <VTKFile> element")?;
    let root =
        &text[root_start..root_start + text[root_start..].find('>').ok_or("unclosed <VTKFile>")?];
    if xml_attr(root, "compressor") != Some("vtkZLibDataCompressor") {
        return Err("VTK file has no readable one-component point-data array".into());
    }
    let big = xml_attr(root, "byte_order") == Some("BigEndian");
    let wide = xml_attr(root, "header_type") == Some("UInt64");
    let point_data = text
        .find("<PointData")
        .ok_or("VTK file has no <PointData>")?;
    let mut rest = &text[point_data..];
    loop {
        let open = rest
            .find("<DataArray")
            .ok_or("VTK file has no one-component point-data array")?;
        let tag_end = open + rest[open..].find('>').ok_or("unclosed <DataArray>")?;
        let tag = &rest[open..tag_end];
        let body_end = tag_end
            + rest[tag_end..]
                .find("</DataArray>")
                .ok_or("unclosed <DataArray>")?;
        let body = rest[tag_end + 1..body_end].trim();
        rest = &rest[body_end..];
        let comps = xml_attr(tag, "NumberOfComponents").unwrap_or("1");
        if comps != "1" {
            continue;
        }
        if xml_attr(tag, "format") != Some("binary") {
            return Err("VTK array is not inline binary data".into());
        }
        let name = xml_attr(tag, "Name").unwrap_or("").to_string();
        let ty = xml_attr(tag, "type").unwrap_or("");
        let (size, dtype) = match ty {
            "UInt8" => (1, super::DType::U8),
            "Int8" => (1, super::DType::I8),
            "UInt16" => (2, super::DType::U16),
            "Int16" => (2, super::DType::I16),
            "UInt32" => (4, super::DType::U32),
            "Int32" => (4, super::DType::I32),
            "Float32" => (4, super::DType::F32),
            "Float64" => (8, super::DType::F64),
            other => return Err(format!("VTK array `{name}` has unsupported type `{other}`")),
        };
        // VTK encodes the header and the compressed blocks as two separate base64 streams.
        let b64: String = body.split_whitespace().collect();
        let b64_err =
            |e: base64::DecodeError| format!("VTK array `{name}` is not valid base64: {e}");
        let hsize = if wide { 8 } else { 4 };
        let first = BASE64
            .decode(b64.get(..12).ok_or("VTK array is truncated")?)
            .map_err(b64_err)?;
        let read_int = |b: &[u8]| -> usize {
            let mut a = [0u8; 8];
            if big {
                a[8 - hsize..].copy_from_slice(b);
                u64::from_be_bytes(a) as usize
            } else {
                a[..hsize].copy_from_slice(b);
                u64::from_le_bytes(a) as usize
            }
        };
        let header_len = read_int(&first[..hsize])
            .checked_add(3)
            .and_then(|n| n.checked_mul(hsize))
            .filter(|&n| n <= b64.len())
            .ok_or_else(|| format!("VTK array `{name}`: block count is larger than the file"))?;
        let split = header_len.div_ceil(3) * 4;
        let header = BASE64
            .decode(b64.get(..split).ok_or("VTK array header is truncated")?)
            .map_err(b64_err)?;
        let bytes = BASE64.decode(&b64[split..]).map_err(b64_err)?;
        let int = |i: usize| -> std::result::Result<usize, String> {
            let b = header
                .get(i * hsize..(i + 1) * hsize)
                .ok_or_else(|| format!("VTK array `{name}`: compressed header is truncated"))?;
            Ok(read_int(b))
        };
        let blocks = int(0)?;
        let mut offset: usize = 0;
        let mut raw = Vec::new();
        for b in 0..blocks {
            let len = int(3 + b)?;
            let chunk = offset
                .checked_add(len)
                .and_then(|end| bytes.get(offset..end))
                .ok_or_else(|| format!("VTK array `{name}`: block {b} is truncated"))?;
            // No block may inflate the array past the size the extent promises.
            let room = (max_bytes - raw.len()) as u64;
            flate2::read::ZlibDecoder::new(chunk)
                .take(room + 1)
                .read_to_end(&mut raw)
                .map_err(|e| {
                    format!("VTK array `{name}`: block {b} cannot be decompressed: {e}")
                })?;
            if raw.len() > max_bytes {
                return Err(format!(
                    "VTK array `{name}` inflates past the {max_bytes} bytes its extent allows"
                ));
            }
            offset += len;
        }
        let order = if big {
            super::ByteOrder::Big
        } else {
            super::ByteOrder::Little
        };
        if raw.len() % size != 0 {
            return Err(format!(
                "VTK array `{name}`: {} bytes is not a whole number of {ty}",
                raw.len()
            ));
        }
        return Ok((name, super::decode_voxels(&raw, dtype, order)));
    }
}
