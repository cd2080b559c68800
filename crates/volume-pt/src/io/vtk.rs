//! VTK image data through vtkio: legacy `.vtk` STRUCTURED_POINTS and XML `.vti` ImageData.
//! The first scalar point-data array (one component) is the volume. VTK's point samples map to
//! our voxel centres; the file's origin is reported as a note, the scene places the volume.

use super::{LoadedVolume, grid_for};
use crate::error::{Error, Result};
use glam::{UVec3, Vec3};
use std::path::Path;
use vtkio::model::{Attribute, DataSet, Extent, IOBuffer, Piece};

fn to_f32(buf: IOBuffer) -> Option<Vec<f32>> {
    Some(match buf {
        IOBuffer::U8(v) => v.into_iter().map(f32::from).collect(),
        IOBuffer::I8(v) => v.into_iter().map(f32::from).collect(),
        IOBuffer::U16(v) => v.into_iter().map(f32::from).collect(),
        IOBuffer::I16(v) => v.into_iter().map(f32::from).collect(),
        IOBuffer::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        IOBuffer::I32(v) => v.into_iter().map(|x| x as f32).collect(),
        IOBuffer::U64(v) => v.into_iter().map(|x| x as f32).collect(),
        IOBuffer::I64(v) => v.into_iter().map(|x| x as f32).collect(),
        IOBuffer::F32(v) => v,
        IOBuffer::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        IOBuffer::Bit(_) => return None,
    })
}

pub(super) fn read(path: &Path) -> Result<LoadedVolume> {
    let bad = |m: String| Error::format(path, m);
    let vtk = vtkio::Vtk::import(path).map_err(|e| bad(format!("cannot parse VTK file: {e}")))?;
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
    let dims = match extent {
        Extent::Dims(d) => UVec3::from_array(d),
        Extent::Ranges(r) => UVec3::new(
            (r[0].end() - r[0].start() + 1) as u32,
            (r[1].end() - r[1].start() + 1) as u32,
            (r[2].end() - r[2].start() + 1) as u32,
        ),
    };
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
    let array = piece
        .data
        .point
        .into_iter()
        .find_map(|a| match a {
            Attribute::DataArray(da) if da.elem.num_comp() == 1 => Some(da),
            _ => None,
        })
        .ok_or_else(|| bad("VTK file has no one-component point-data array".into()))?;
    let name = array.name.clone();
    let values =
        to_f32(array.data).ok_or_else(|| bad(format!("VTK array `{name}` is a bit array")))?;
    let n = dims.x as usize * dims.y as usize * dims.z as usize;
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
        notes,
    })
}
