//! Headerless raw voxels. The layout comes from the scene, or from the Open SciVis file-name
//! convention `name_XxYxZ_dtype.raw` (for example `neghip_64x64x64_uint8.raw`).

use super::{ByteOrder, DType, LoadedVolume, check_volume_size, decode_voxels_owned, grid_for};
use crate::error::{Error, Result};
use glam::UVec3;
use std::path::Path;

/// What a raw file does not say about itself.
#[derive(Debug, Clone, Default)]
pub struct RawLayout {
    pub dims: Option<UVec3>,
    pub dtype: Option<DType>,
    pub byte_order: ByteOrder,
    /// Bytes to skip before the first voxel.
    pub header_bytes: u64,
}

/// Dims and dtype from a name like `embryo_256x256x256_uint8.raw`.
pub fn parse_raw_file_name(path: &Path) -> Option<(UVec3, DType)> {
    let stem = path.file_stem()?.to_str()?;
    let mut parts = stem.rsplit('_');
    let dtype = DType::parse(parts.next()?)?;
    let dims: Vec<u32> = parts
        .next()?
        .split('x')
        .map(|s| s.parse().ok())
        .collect::<Option<_>>()?;
    match dims[..] {
        [x, y, z] => Some((UVec3::new(x, y, z), dtype)),
        _ => None,
    }
}

pub(super) fn read(path: &Path, layout: &RawLayout) -> Result<LoadedVolume> {
    let from_name = parse_raw_file_name(path);
    let dims = layout.dims.or(from_name.map(|n| n.0)).ok_or_else(|| {
        Error::format(
            path,
            "raw volume without dims: give `dims = [x, y, z]` in the scene or name the file \
             like `name_64x64x64_uint8.raw`",
        )
    })?;
    let dtype = layout.dtype.or(from_name.map(|n| n.1)).ok_or_else(|| {
        Error::format(
            path,
            "raw volume without dtype: give `dtype = \"uint8\"` (or int8, uint16, int16, uint32, \
             int32, float32, float64) in the scene or name the file like `name_64x64x64_uint8.raw`",
        )
    })?;
    let size = check_volume_size(path, [dims.x as i64, dims.y as i64, dims.z as i64], dtype)?;
    // The file's length is known before it is read: compare it with the layout first, so a
    // wrong layout costs no read and a huge file is never loaded.
    let (_, len) = super::budget::open_regular(path)?;
    let want = layout
        .header_bytes
        .saturating_add(size.payload_bytes as u64);
    if len != want {
        let what = if len < want { "truncated" } else { "oversized" };
        return Err(Error::format(
            path,
            format!(
                "raw file is {what}: it has {len} bytes, expected {want} ({}x{}x{} voxels of {dtype} \
                 after {} header bytes); check dims, dtype and header_bytes",
                dims.x, dims.y, dims.z, layout.header_bytes
            ),
        ));
    }
    let bytes = super::budget::read_regular(path, want, "a raw volume")?;
    if bytes.len() as u64 != want {
        return Err(Error::format(
            path,
            "raw file changed while it was being read",
        ));
    }
    let values = decode_voxels_owned(
        bytes,
        layout.header_bytes as usize,
        dtype,
        layout.byte_order,
    );
    Ok(LoadedVolume {
        grid: grid_for(path, dims, values)?,
        spacing: None,
        units: None,
        notes: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_name_convention() {
        let p = Path::new("/x/lidc2_chest_ct_256x256x133_uint8.raw");
        assert_eq!(
            parse_raw_file_name(p),
            Some((UVec3::new(256, 256, 133), DType::U8))
        );
        assert_eq!(
            parse_raw_file_name(Path::new("h_64x64x64_float32.raw")),
            Some((UVec3::new(64, 64, 64), DType::F32))
        );
        assert_eq!(parse_raw_file_name(Path::new("head.raw")), None);
        assert_eq!(parse_raw_file_name(Path::new("h_64x64_uint8.raw")), None);
    }
}
