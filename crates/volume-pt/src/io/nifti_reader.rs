//! NIfTI-1 (`.nii`, `.nii.gz`, and `.hdr`/`.img` pairs): the header through the nifti crate, the
//! voxels read here. The intensity scaling `scl_slope`/`scl_inter` is applied on lookup;
//! `pixdim` gives the spacing; the affine (qform and sform) is reported, not applied: the scene
//! places the volume.

use super::budget::check_volume_size;
use super::{ByteOrder, DType, LoadedVolume, decode_voxels, read_file, scaled_grid_for};
use crate::error::{Error, Result};
use flate2::read::GzDecoder;
use glam::Vec3;
use nifti::{Endianness, NiftiHeader, NiftiType};
use std::io::Read;
use std::path::{Path, PathBuf};

/// Bytes in a NIfTI-1 header; the data of a single `.nii` file start at `vox_offset` >= 352
/// (the header plus the 4-byte extender and any extensions or padding).
const HEADER_BYTES: usize = 348;
const SINGLE_FILE_MIN_OFFSET: usize = 352;

fn dtype_of(t: NiftiType) -> Option<DType> {
    Some(match t {
        NiftiType::Uint8 => DType::U8,
        NiftiType::Int8 => DType::I8,
        NiftiType::Uint16 => DType::U16,
        NiftiType::Int16 => DType::I16,
        NiftiType::Uint32 => DType::U32,
        NiftiType::Int32 => DType::I32,
        NiftiType::Float32 => DType::F32,
        NiftiType::Float64 => DType::F64,
        _ => return None,
    })
}

/// A stream over a file's bytes, inflated if they are gzip (whatever the file's name says).
fn maybe_gzip(bytes: &[u8]) -> Box<dyn Read + '_> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        Box::new(GzDecoder::new(bytes))
    } else {
        Box::new(bytes)
    }
}

/// The `.img` (or `.img.gz`) beside a `.hdr`.
fn image_file_for(header_path: &Path) -> Option<PathBuf> {
    let name = header_path.file_name()?.to_str()?;
    let stem = name
        .strip_suffix(".hdr")
        .or_else(|| name.strip_suffix(".hdr.gz"))?;
    ["img", "img.gz"]
        .iter()
        .map(|ext| header_path.with_file_name(format!("{stem}.{ext}")))
        .find(|p| p.exists())
}

/// Reads the header with the nifti crate, then the voxels from `vox_offset` itself: the crate
/// reads a single file's data from byte 352 unless the extender flags extensions, which shifts
/// every voxel of a file padded to a larger offset. Reading here also bounds every size and
/// every inflation by what the header promises.
pub(super) fn read(path: &Path) -> Result<LoadedVolume> {
    let bad = |m: String| Error::format(path, m);
    let file = read_file(path)?;
    let mut stream = maybe_gzip(&file);
    let mut head = [0u8; HEADER_BYTES];
    stream.read_exact(&mut head).map_err(|e| {
        bad(format!(
            "cannot read a NIfTI-1 header ({HEADER_BYTES} bytes): {e}"
        ))
    })?;
    // The byte order is told by dim[0] (1 to 7 in the file's order); with any other value the
    // reader guesses the other order and reports a nonsense sizeof_hdr. A header whose
    // sizeof_hdr is right in either order is a NIfTI-1 header: name the bad dim[0] instead.
    for (order, sizeof, dim0) in [
        (
            "little",
            i32::from_le_bytes(head[0..4].try_into().expect("4 bytes")),
            i16::from_le_bytes(head[40..42].try_into().expect("2 bytes")),
        ),
        (
            "big",
            i32::from_be_bytes(head[0..4].try_into().expect("4 bytes")),
            i16::from_be_bytes(head[40..42].try_into().expect("2 bytes")),
        ),
    ] {
        if sizeof == HEADER_BYTES as i32 && !(1..=7).contains(&dim0) {
            return Err(bad(format!(
                "NIfTI dim[0] is {dim0} ({order}-endian header): expected the number of \
                 dimensions, 3 to 7"
            )));
        }
    }
    let header = NiftiHeader::from_reader(&head[..])
        .map_err(|e| bad(format!("cannot read NIfTI file: {e}")))?;
    if header.sizeof_hdr != HEADER_BYTES as i32 {
        return Err(bad(format!(
            "NIfTI sizeof_hdr is {}: expected {HEADER_BYTES} (a NIfTI-1 file)",
            header.sizeof_hdr
        )));
    }
    let rank = header.dim[0] as usize;
    let d = header.dim;
    if !(3..=7).contains(&rank) || d[4..=rank].iter().any(|&x| x != 1) {
        return Err(bad(format!(
            "NIfTI image has {rank} dimensions {:?}: expected a 3D scalar volume",
            &d[1..=rank.clamp(1, 7)]
        )));
    }
    let datatype = header.data_type().map_err(|e| {
        bad(format!(
            "NIfTI datatype {} is unknown: {e}",
            header.datatype
        ))
    })?;
    let dtype = dtype_of(datatype).ok_or_else(|| {
        bad(format!(
            "NIfTI datatype {datatype:?} is not supported: expected a scalar integer or float type"
        ))
    })?;
    // NIfTI-1 stores dims as signed 16-bit integers.
    let signed = |i: usize| i64::from(d[i] as i16);
    let size = check_volume_size(path, [signed(1), signed(2), signed(3)], dtype)?;
    let single_file = &header.magic == b"n+1\0";
    let offset = header.vox_offset;
    let min_offset = if single_file {
        SINGLE_FILE_MIN_OFFSET
    } else {
        0
    };
    if !(offset.is_finite() && offset >= min_offset as f32 && offset.fract() == 0.0) {
        return Err(bad(format!(
            "NIfTI vox_offset {offset} is not a whole number of bytes from {min_offset} on"
        )));
    }
    let offset = offset as usize; // a finite f32 >= 0 saturates, never wraps
    let order = match header.endianness {
        Endianness::Little => ByteOrder::Little,
        Endianness::Big => ByteOrder::Big,
    };
    let mut notes = Vec::new();
    // The bytes before the voxels: the extender, extensions and padding of a single file (the
    // header is already read), or vox_offset bytes of a separate image file.
    let (mut source, skip, data_path): (Box<dyn Read + '_>, usize, PathBuf) = if single_file {
        (stream, offset - HEADER_BYTES, path.to_path_buf())
    } else {
        let img = image_file_for(path).ok_or_else(|| {
            bad("NIfTI header (magic `ni1`) has no `.img` or `.img.gz` file beside it".into())
        })?;
        let bytes = read_file(&img)?;
        let stream: Box<dyn Read> = Box::new(std::io::Cursor::new(bytes));
        let stream: Box<dyn Read> = if img.extension().is_some_and(|e| e == "gz") {
            Box::new(GzDecoder::new(stream))
        } else {
            stream
        };
        (stream, offset, img)
    };
    let read_err =
        |e: std::io::Error| Error::format(&data_path, format!("NIfTI data cannot be read: {e}"));
    let skipped = std::io::copy(&mut source.by_ref().take(skip as u64), &mut std::io::sink())
        .map_err(read_err)?;
    let mut data = Vec::new();
    if skipped == skip as u64 {
        source
            .by_ref()
            .take(size.payload_bytes as u64)
            .read_to_end(&mut data)
            .map_err(read_err)?;
    }
    if source.read(&mut [0u8; 1]).is_ok_and(|n| n > 0) {
        notes.push("bytes after the last voxel were ignored".to_string());
    }
    if data.len() != size.payload_bytes {
        return Err(bad(format!(
            "NIfTI data are truncated: {} bytes from vox_offset {offset}, expected {} ({}x{}x{} \
             voxels of {dtype})",
            data.len(),
            size.payload_bytes,
            size.dims.x,
            size.dims.y,
            size.dims.z
        )));
    }
    let dims = size.dims;
    let voxels = decode_voxels(&data, dtype, order);
    drop(data);
    // NIfTI: a slope of 0 means "no scaling"; a non-finite one is ignored as the crate did.
    let (mut slope, mut inter) = (header.scl_slope, header.scl_inter);
    if slope != 0.0 && slope.is_finite() && inter.is_finite() && (slope != 1.0 || inter != 0.0) {
        notes.push(format!("applied intensity scaling {slope} * v + {inter}"));
    } else {
        (slope, inter) = (1.0, 0.0);
    }
    if header.qform_code != 0 || header.sform_code != 0 {
        notes.push("NIfTI qform/sform affine is not applied: the scene places the volume".into());
    }
    let p = header.pixdim;
    let spacing = Vec3::new(p[1].abs(), p[2].abs(), p[3].abs());
    let spacing = (spacing.min_element() > 0.0 && spacing.is_finite()).then_some(spacing);
    // NIfTI's xyzt_units: the spatial unit in its low three bits.
    let units = match header.xyzt_units & 0x07 {
        1 => Some("m".to_string()),
        2 => Some("mm".to_string()),
        3 => Some("µm".to_string()),
        _ => None,
    };
    Ok(LoadedVolume {
        grid: scaled_grid_for(path, dims, voxels, slope, inter)?,
        spacing,
        units,
        notes,
    })
}
