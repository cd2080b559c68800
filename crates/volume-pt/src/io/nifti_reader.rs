//! NIfTI-1 (`.nii`, `.nii.gz`, and `.hdr`/`.img` pairs) through the nifti crate. The intensity
//! scaling `scl_slope`/`scl_inter` is applied; `pixdim` gives the spacing; the affine (qform and
//! sform) is reported, not applied: the scene places the volume.

use super::{LoadedVolume, grid_for};
use crate::error::{Error, Result};
use glam::{UVec3, Vec3};
use nifti::{NiftiObject, NiftiType, ReaderOptions};
use std::path::Path;

pub(super) fn read(path: &Path) -> Result<LoadedVolume> {
    let bad = |m: String| Error::format(path, m);
    let obj = ReaderOptions::new()
        .read_file(path)
        .map_err(|e| bad(format!("cannot read NIfTI file: {e}")))?;
    let header = obj.header().clone();
    let rank = header.dim[0] as usize;
    let d = header.dim;
    let dims = match rank {
        3 => UVec3::new(d[1] as u32, d[2] as u32, d[3] as u32),
        4.. if d[4..=rank].iter().all(|&x| x == 1) => {
            UVec3::new(d[1] as u32, d[2] as u32, d[3] as u32)
        }
        _ => {
            return Err(bad(format!(
                "NIfTI image has {rank} dimensions {:?}: expected a 3D scalar volume",
                &d[1..=rank.min(7)]
            )));
        }
    };
    let datatype = header.data_type().map_err(|e| {
        bad(format!(
            "NIfTI datatype {} is unknown: {e}",
            header.datatype
        ))
    })?;
    let volume = obj.into_volume();
    let typed = |e: nifti::NiftiError| bad(format!("NIfTI voxel data cannot be decoded: {e}"));
    let mut values: Vec<f32> = match datatype {
        NiftiType::Uint8 => volume
            .into_nifti_typed_data::<u8>()
            .map_err(typed)?
            .into_iter()
            .map(f32::from)
            .collect(),
        NiftiType::Int8 => volume
            .into_nifti_typed_data::<i8>()
            .map_err(typed)?
            .into_iter()
            .map(f32::from)
            .collect(),
        NiftiType::Uint16 => volume
            .into_nifti_typed_data::<u16>()
            .map_err(typed)?
            .into_iter()
            .map(f32::from)
            .collect(),
        NiftiType::Int16 => volume
            .into_nifti_typed_data::<i16>()
            .map_err(typed)?
            .into_iter()
            .map(f32::from)
            .collect(),
        NiftiType::Uint32 => volume
            .into_nifti_typed_data::<u32>()
            .map_err(typed)?
            .into_iter()
            .map(|v| v as f32)
            .collect(),
        NiftiType::Int32 => volume
            .into_nifti_typed_data::<i32>()
            .map_err(typed)?
            .into_iter()
            .map(|v| v as f32)
            .collect(),
        NiftiType::Float32 => volume.into_nifti_typed_data::<f32>().map_err(typed)?,
        NiftiType::Float64 => volume
            .into_nifti_typed_data::<f64>()
            .map_err(typed)?
            .into_iter()
            .map(|v| v as f32)
            .collect(),
        other => {
            return Err(bad(format!(
                "NIfTI datatype {other:?} is not supported: expected a scalar integer or float type"
            )));
        }
    };
    let n = dims.x as usize * dims.y as usize * dims.z as usize;
    values.truncate(n.min(values.len()));
    let (slope, inter) = (header.scl_slope, header.scl_inter);
    let mut notes = Vec::new();
    if slope != 0.0 && slope.is_finite() && inter.is_finite() && (slope != 1.0 || inter != 0.0) {
        for v in &mut values {
            *v = slope * *v + inter;
        }
        notes.push(format!("applied intensity scaling {slope} * v + {inter}"));
    }
    if header.qform_code != 0 || header.sform_code != 0 {
        notes.push("NIfTI qform/sform affine is not applied: the scene places the volume".into());
    }
    let p = header.pixdim;
    let spacing = Vec3::new(p[1].abs(), p[2].abs(), p[3].abs());
    let spacing = (spacing.min_element() > 0.0 && spacing.is_finite()).then_some(spacing);
    Ok(LoadedVolume {
        grid: grid_for(path, dims, values)?,
        spacing,
        notes,
    })
}
