//! Headerless raw voxels. The layout comes from the scene, or from the Open SciVis file-name
//! convention `name_XxYxZ_dtype.raw` (for example `neghip_64x64x64_uint8.raw`).

use super::{
    ByteOrder, DType, LoadedVolume, check_volume_size, decode_voxels, decode_voxels_owned,
    grid_for, human_bytes, measure_volume,
};
use crate::bricks::{BrickSource, Bricks};
use crate::error::{Error, Result};
use crate::grid::{ScalarGrid, Voxels};
use glam::UVec3;
use std::path::{Path, PathBuf};
use std::sync::Arc;

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

/// Reads a raw volume: whole where that takes at most `budget` bytes, else streamed within it
/// (bricks read row by row from the file: see [`RawBricks`]).
pub(super) fn read(path: &Path, layout: &RawLayout, budget: u64) -> Result<LoadedVolume> {
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
    let claimed = [dims.x as i64, dims.y as i64, dims.z as i64];
    let (size, needed) = measure_volume(path, claimed, dtype)?;
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
    if needed > budget {
        let source = RawBricks {
            file: std::fs::File::open(path).map_err(|e| Error::io(path, e))?,
            path: path.to_path_buf(),
            dims,
            dtype,
            layout: layout.clone(),
        };
        let bricks = Bricks::new(dims, Arc::new(source), dtype.bytes_in_memory(), budget)?;
        return Ok(LoadedVolume {
            grid: ScalarGrid::streamed(bricks, 1.0, 0.0)
                .map_err(|e| Error::format(path, e.to_string()))?,
            spacing: None,
            units: None,
            notes: vec![format!(
                "{}x{}x{} {dtype}, streamed within a memory budget of {}",
                dims.x,
                dims.y,
                dims.z,
                human_bytes(budget)
            )],
        });
    }
    check_volume_size(path, claimed, dtype)?;
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

/// A raw file read a brick at a time: each x-row of a brick is one positioned read (no seek
/// shared between threads), decoded as the whole file would be.
#[derive(Debug)]
struct RawBricks {
    file: std::fs::File,
    path: PathBuf,
    dims: UVec3,
    dtype: DType,
    layout: RawLayout,
}

/// A raw file's brick: wide along x (fewer reads a voxel) and 32 voxels along y and z.
const RAW_BRICK: UVec3 = UVec3::new(64, 32, 32);

impl RawBricks {
    fn read_at(&self, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
        #[cfg(unix)]
        {
            std::os::unix::fs::FileExt::read_exact_at(&self.file, buf, offset)
        }
        #[cfg(not(unix))]
        {
            std::os::windows::fs::FileExt::seek_read(&self.file, buf, offset).and_then(|n| {
                if n == buf.len() {
                    Ok(())
                } else {
                    Err(std::io::ErrorKind::UnexpectedEof.into())
                }
            })
        }
    }
}

impl BrickSource for RawBricks {
    fn name(&self) -> String {
        self.path.display().to_string()
    }

    fn brick_size(&self) -> UVec3 {
        RAW_BRICK
    }

    fn type_name(&self) -> &'static str {
        self.dtype.kept_type_name()
    }

    fn read(&self, lo: UVec3, size: UVec3) -> Result<Voxels> {
        let d = self.dtype.size();
        let row = size.x as usize * d;
        let mut bytes = vec![0u8; row * size.y as usize * size.z as usize];
        for (k, chunk) in bytes.chunks_exact_mut(row).enumerate() {
            let (y, z) = (
                lo.y as u64 + (k as u64 % size.y as u64),
                lo.z as u64 + k as u64 / size.y as u64,
            );
            let voxel = (z * self.dims.y as u64 + y) * self.dims.x as u64 + lo.x as u64;
            let offset = self.layout.header_bytes + voxel * d as u64;
            self.read_at(chunk, offset)
                .map_err(|e| Error::io(&self.path, e))?;
        }
        Ok(decode_voxels(&bytes, self.dtype, self.layout.byte_order))
    }

    fn identity(&self) -> Option<String> {
        let path = std::fs::canonicalize(&self.path).ok()?;
        let meta = std::fs::metadata(&path).ok()?;
        let modified = meta
            .modified()
            .ok()?
            .duration_since(std::time::UNIX_EPOCH)
            .ok()?
            .as_nanos();
        Some(format!(
            "raw {}|{} bytes, modified {modified}|{:?}|{}|{:?}",
            path.display(),
            meta.len(),
            self.dims,
            self.dtype,
            self.layout
        ))
    }
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
