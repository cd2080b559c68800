//! Time series kept as files: a folder of volume files, or a file-name pattern with `*`
//! (`frames/step_*.nrrd`), one file a time point in natural order (`step_2` before `step_10`).
//!
//! A folder's time points are its files of the volume format most of them share (a folder of
//! `.nhdr` headers with their detached `.raw` data, or of `.nii.gz` files with a stray
//! `.json`, is read as the headers or the NIfTI files). An OME-Zarr store is not a series:
//! its time axis is its own (`io::ome_zarr`).

use super::Format;
use crate::error::{Error, Result};
use std::cmp::Ordering;
use std::path::{Path, PathBuf};

/// The most files a series may have.
pub const MAX_TIME_POINTS: usize = 100_000;

/// Whether `path` names a series: a folder that is not an OME-Zarr store, or a name with `*`.
pub fn is_series(path: &Path) -> bool {
    let pattern = path
        .file_name()
        .is_some_and(|n| n.to_string_lossy().contains('*'));
    pattern || (path.is_dir() && Format::from_path(path) != Some(Format::OmeZarr))
}

/// The files of the series `path` names, in time order; an error names the folder or pattern
/// when nothing matches.
pub fn series_files(path: &Path) -> Result<Vec<PathBuf>> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (folder, pattern) = if name.contains('*') {
        (
            path.parent().unwrap_or(Path::new(".")).to_path_buf(),
            Some(name),
        )
    } else {
        (path.to_path_buf(), None)
    };
    let entries = std::fs::read_dir(&folder).map_err(|e| Error::io(&folder, e))?;
    let mut files: Vec<(PathBuf, String)> = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(&folder, e))?;
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let p = entry.path();
        let keep = match &pattern {
            Some(pattern) => matches(pattern, &file_name),
            None => Format::from_path(&p).is_some_and(|f| f != Format::OmeZarr),
        };
        if keep && p.is_file() {
            files.push((p, file_name));
        }
        if files.len() > MAX_TIME_POINTS {
            return Err(Error::format(
                path,
                format!(
                    "more than {MAX_TIME_POINTS} files: expected a series of at most that many"
                ),
            ));
        }
    }
    if pattern.is_none() {
        // The format most files share (a header's detached data is not a time point).
        let suffix = |n: &str| {
            let lower = n.to_ascii_lowercase();
            if lower.ends_with(".nii.gz") {
                ".nii.gz".to_string()
            } else {
                lower
                    .rsplit_once('.')
                    .map(|(_, e)| format!(".{e}"))
                    .unwrap_or_default()
            }
        };
        let mut counts: Vec<(String, usize)> = Vec::new();
        for (_, n) in &files {
            let s = suffix(n);
            match counts.iter_mut().find(|(k, _)| *k == s) {
                Some(c) => c.1 += 1,
                None => counts.push((s, 1)),
            }
        }
        // Ties go to the header formats, whose data files would otherwise be taken.
        let header =
            |s: &str| matches!(s, ".nhdr" | ".nrrd" | ".nii" | ".nii.gz" | ".vti" | ".vtk");
        if let Some((best, _)) = counts
            .iter()
            .max_by(|a, b| a.1.cmp(&b.1).then(header(&a.0).cmp(&header(&b.0))))
            .cloned()
        {
            files.retain(|(_, n)| suffix(n) == best);
        }
    }
    if files.is_empty() {
        return Err(Error::format(
            path,
            "a time series with no volume file: expected a folder of volume files or a pattern \
             such as frames/step_*.nrrd that names some",
        ));
    }
    files.sort_by(|a, b| natural(&a.1, &b.1));
    Ok(files.into_iter().map(|(p, _)| p).collect())
}

/// Whether `name` matches `pattern`, where `*` stands for any run of characters.
fn matches(pattern: &str, name: &str) -> bool {
    let parts: Vec<&str> = pattern.split('*').collect();
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !name.starts_with(first) || name.len() < first.len() + last.len() || !name.ends_with(last) {
        return false;
    }
    let mut rest = &name[first.len()..name.len() - last.len()];
    for part in &parts[1..parts.len() - 1] {
        match rest.find(part) {
            Some(i) => rest = &rest[i + part.len()..],
            None => return false,
        }
    }
    true
}

/// Natural order: runs of digits compare as numbers (`step_2` before `step_10`).
fn natural(a: &str, b: &str) -> Ordering {
    let (mut a, mut b) = (a.as_bytes(), b.as_bytes());
    loop {
        match (a.first(), b.first()) {
            (None, None) => return Ordering::Equal,
            (None, _) => return Ordering::Less,
            (_, None) => return Ordering::Greater,
            (Some(x), Some(y)) if x.is_ascii_digit() && y.is_ascii_digit() => {
                let run = |s: &[u8]| s.iter().take_while(|c| c.is_ascii_digit()).count();
                let (n, m) = (run(a), run(b));
                let trim = |s: &[u8]| {
                    let z = s.iter().take_while(|&&c| c == b'0').count();
                    s[z..].to_vec()
                };
                let (da, db) = (trim(&a[..n]), trim(&b[..m]));
                let order = da.len().cmp(&db.len()).then(da.cmp(&db)).then(n.cmp(&m));
                if order != Ordering::Equal {
                    return order;
                }
                a = &a[n..];
                b = &b[m..];
            }
            (Some(x), Some(y)) => {
                if x != y {
                    return x.cmp(y);
                }
                a = &a[1..];
                b = &b[1..];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_and_natural_order() {
        assert!(matches("step_*.nrrd", "step_10.nrrd"));
        assert!(!matches("step_*.nrrd", "step_10.nhdr"));
        assert!(matches("*", "anything"));
        assert!(matches("a*b*c", "a12b34c"));
        assert!(!matches("a*b*c", "a12c34b"));
        let mut names = vec!["s10", "s2", "s1", "s02b", "s02"];
        names.sort_by(|a, b| natural(a, b));
        assert_eq!(names, vec!["s1", "s2", "s02", "s02b", "s10"]);
    }
}
