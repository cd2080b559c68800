//! Sizes a file states are checked before anything is allocated for them.
//!
//! A header can claim any size: `sizes: 100000 100000 100000` in a 300-byte NRRD, dims whose
//! product wraps past 2^64, a gzip stream that inflates to gigabytes. Every reader turns such a
//! claim into a [`VolumeSize`] first: the voxel count is computed with checked arithmetic, and
//! the memory the load will take (the payload as read plus the grid as kept) is compared with the
//! memory this machine has available before a byte is reserved. Only then is the payload read,
//! through [`read_bounded`], which never takes more than the size the header promised.

use super::DType;
use crate::error::{Error, Result};
use glam::UVec3;
use std::io::Read;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// A volume size that has passed the checks: its voxel and payload byte counts fit in memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VolumeSize {
    pub dims: UVec3,
    pub voxels: usize,
    /// Bytes of the payload as stored in the file (voxels x the element size).
    pub payload_bytes: usize,
}

/// Memory available to this process, in bytes: the smaller of the machine's `MemAvailable`
/// (free memory plus what the kernel can reclaim) and the headroom under this process's cgroup
/// memory limit, which SLURM, Docker and systemd set (a job's volume that "fits" the machine
/// but not its limit would be killed instead of refused with the estimate). Where neither can
/// be read, 8 GiB as a cautious guess.
pub fn available_memory() -> u64 {
    const FALLBACK: u64 = 8 << 30;
    let machine = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| {
            let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
            let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
            kib.checked_mul(1024)
        });
    let job = std::fs::read_to_string("/proc/self/cgroup")
        .ok()
        .and_then(|text| cgroup_headroom(&text, &|p| std::fs::read_to_string(p).ok()));
    match (machine, job) {
        (Some(m), Some(j)) => m.min(j),
        (Some(m), None) => m,
        (None, Some(j)) => j,
        (None, None) => FALLBACK,
    }
}

/// A limit at or above this is "no limit" (cgroup v1 writes 2^63 rounded to a page).
const NO_LIMIT: u64 = 1 << 60;

/// The headroom under the memory limit of the cgroup that `/proc/self/cgroup` (`proc_cgroup`)
/// names, reading files through `read`: limit minus what the group uses, not counting the
/// inactive file cache the kernel reclaims first (as container runtimes count a working set).
/// cgroup v2 (`0::/path`: `memory.max`, `memory.current`, `memory.stat`'s `inactive_file`) and
/// v1 (`N:memory:/path`: `memory.limit_in_bytes`, `memory.usage_in_bytes`,
/// `total_inactive_file`), at the group's path or, in a container that shows its own group as
/// the root, at the controller's root. None where no limit is set or nothing can be read.
pub fn cgroup_headroom(proc_cgroup: &str, read: &dyn Fn(&str) -> Option<String>) -> Option<u64> {
    let number = |text: String| text.trim().parse::<u64>().ok();
    let stat_value = |text: String, key: &str| {
        text.lines().find_map(|l| {
            let (k, v) = l.split_once(' ')?;
            (k == key).then(|| v.trim().parse::<u64>().ok()).flatten()
        })
    };
    let headroom = |limit: u64, usage: u64, inactive: u64| {
        (limit < NO_LIMIT).then(|| limit.saturating_sub(usage.saturating_sub(inactive)))
    };
    for line in proc_cgroup.lines() {
        let mut parts = line.splitn(3, ':');
        let (id, controllers, path) = (parts.next()?, parts.next()?, parts.next()?);
        let path = path.trim_end_matches('/');
        if id == "0" && controllers.is_empty() {
            for dir in [
                format!("/sys/fs/cgroup{path}"),
                "/sys/fs/cgroup".to_string(),
            ] {
                let Some(max) = read(&format!("{dir}/memory.max")) else {
                    continue;
                };
                if max.trim() == "max" {
                    return None;
                }
                let limit = number(max)?;
                let usage = read(&format!("{dir}/memory.current")).and_then(number)?;
                let inactive = read(&format!("{dir}/memory.stat"))
                    .and_then(|t| stat_value(t, "inactive_file"))
                    .unwrap_or(0);
                return headroom(limit, usage, inactive);
            }
        } else if controllers.split(',').any(|c| c == "memory") {
            for dir in [
                format!("/sys/fs/cgroup/memory{path}"),
                "/sys/fs/cgroup/memory".to_string(),
            ] {
                let Some(limit) = read(&format!("{dir}/memory.limit_in_bytes")).and_then(number)
                else {
                    continue;
                };
                let usage = read(&format!("{dir}/memory.usage_in_bytes")).and_then(number)?;
                let inactive = read(&format!("{dir}/memory.stat"))
                    .and_then(|t| stat_value(t, "total_inactive_file"))
                    .unwrap_or(0);
                return headroom(limit, usage, inactive);
            }
        }
    }
    None
}

/// `bytes` for people: "3.2 GiB".
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["bytes", "KiB", "MiB", "GiB", "TiB", "PiB"];
    let mut v = bytes as f64;
    let mut unit = 0;
    while v >= 1024.0 && unit + 1 < UNITS.len() {
        v /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} bytes")
    } else {
        format!("{v:.1} {}", UNITS[unit])
    }
}

/// Checks dims a file states (as the file's own integers, so negative or huge values are caught
/// here, not wrapped by a cast) and the memory loading them would take.
pub fn check_volume_size(path: &Path, dims: [i64; 3], dtype: DType) -> Result<VolumeSize> {
    let (size, needed) = measure_volume(path, dims, dtype)?;
    let available = available_memory();
    if needed > available {
        return Err(Error::format(
            path,
            format!(
                "volume {}x{}x{} of {dtype} needs about {} to load ({} as read + {} as kept), \
                 but this machine has {} available",
                dims[0],
                dims[1],
                dims[2],
                human_bytes(needed),
                human_bytes(size.payload_bytes as u64),
                human_bytes(size.voxels as u64 * dtype.bytes_in_memory() as u64),
                human_bytes(available)
            ),
        ));
    }
    Ok(size)
}

/// Checks dims a file states as [`check_volume_size`] does, without comparing them with the
/// memory available; also gives the bytes reading the volume whole would take (payload as read
/// plus grid as kept).
pub fn measure_volume(path: &Path, dims: [i64; 3], dtype: DType) -> Result<(VolumeSize, u64)> {
    let bad = |m: String| Error::format(path, m);
    let shown = format!("{}x{}x{}", dims[0], dims[1], dims[2]);
    let mut d = [0u32; 3];
    for (axis, (&n, out)) in dims.iter().zip(&mut d).enumerate() {
        *out = u32::try_from(n).ok().filter(|&n| n >= 1).ok_or_else(|| {
            bad(format!(
                "volume dims {shown}: axis {axis} has {n} voxels, expected 1 to {}",
                u32::MAX
            ))
        })?;
    }
    let voxels = (d[0] as u64)
        .checked_mul(d[1] as u64)
        .and_then(|n| n.checked_mul(d[2] as u64));
    let too_many = || {
        bad(format!(
            "volume dims {shown} hold more voxels than memory can address"
        ))
    };
    let voxels = voxels.ok_or_else(too_many)?;
    let payload = voxels
        .checked_mul(dtype.size() as u64)
        .ok_or_else(too_many)?;
    let kept = voxels
        .checked_mul(dtype.bytes_in_memory() as u64)
        .ok_or_else(too_many)?;
    let needed = kept.checked_add(payload).ok_or_else(too_many)?;
    Ok((
        VolumeSize {
            dims: UVec3::from_array(d),
            voxels: usize::try_from(voxels).map_err(|_| too_many())?,
            payload_bytes: usize::try_from(payload).map_err(|_| too_many())?,
        },
        needed,
    ))
}

/// The process's memory budget for voxels set by [`set_memory_budget`]; 0: not set.
static MEMORY_BUDGET: AtomicU64 = AtomicU64::new(0);

/// Sets the bytes a volume's voxels may take in memory for the rest of this process (the
/// program's `--memory-budget`); `None` returns to the default (see [`memory_budget`]).
pub fn set_memory_budget(bytes: Option<u64>) {
    MEMORY_BUDGET.store(bytes.unwrap_or(0), Ordering::Relaxed);
}

/// The bytes a volume's voxels may take in memory: what [`set_memory_budget`] set, else
/// `GSCACHE_MEMORY_BUDGET` (as [`parse_bytes`] reads it), else half the memory this process
/// may use ([`available_memory`], cgroup-aware). A store larger than it is streamed (see
/// [`crate::bricks`]); other formats are read whole if they fit the memory available.
pub fn memory_budget() -> Result<u64> {
    match MEMORY_BUDGET.load(Ordering::Relaxed) {
        0 => match std::env::var("GSCACHE_MEMORY_BUDGET") {
            Ok(text) => parse_bytes(&text)
                .map_err(|e| Error::Invalid(format!("GSCACHE_MEMORY_BUDGET={text:?}: {e}"))),
            Err(_) => Ok(available_memory() / 2),
        },
        n => Ok(n),
    }
}

/// A size in bytes: a number with an optional unit, `K`, `M`, `G`, `T` (powers of 1024, with or
/// without `iB`/`B`), e.g. `4G`, `512 MiB`, `1.5GB`, `1000000`.
pub fn parse_bytes(text: &str) -> std::result::Result<u64, String> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| format!("expected a size such as 4G or 512MiB, got {text:?}"))?;
    let scale = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1u64,
        "k" | "kb" | "kib" => 1 << 10,
        "m" | "mb" | "mib" => 1 << 20,
        "g" | "gb" | "gib" => 1 << 30,
        "t" | "tb" | "tib" => 1 << 40,
        other => {
            return Err(format!(
                "unknown unit {other:?} in {text:?}: expected K, M, G or T"
            ));
        }
    };
    let bytes = value * scale as f64;
    // Written so that NaN fails.
    if !(bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!("{text:?}: expected a size of at least 1 byte"));
    }
    Ok(bytes as u64)
}

/// Opens `path` for reading, refusing anything that is not a regular file (a FIFO, a device such
/// as `/dev/zero`, a directory): those have no size to check and may never end.
pub fn open_regular(path: &Path) -> Result<(std::fs::File, u64)> {
    let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound if path.to_string_lossy().contains("shared/data") => {
            Error::format(
                path,
                "no such file: this volume is in the project's shared data (../shared/data beside \
                 a clone), which this machine does not have; data/SOURCES.md says where to get \
                 it and how to place it",
            )
        }
        std::io::ErrorKind::NotFound => Error::format(path, "no such file"),
        _ => Error::io(path, e),
    })?;
    if !meta.is_file() {
        return Err(Error::format(
            path,
            "is not a regular file (a directory, device, FIFO or socket): expected a file",
        ));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    Ok((file, meta.len()))
}

/// Reads a whole regular file whose size is at most `max_bytes`, into a buffer reserved once at
/// the file's size (a gigavoxel is never copied by doubling) and backed by huge pages where the
/// system offers them ([`advise_huge_pages`]).
pub fn read_regular(path: &Path, max_bytes: u64, what: &str) -> Result<Vec<u8>> {
    let (file, len) = open_regular(path)?;
    if len > max_bytes {
        return Err(Error::format(
            path,
            format!(
                "is {} long, more than the {} expected for {what}",
                human_bytes(len),
                human_bytes(max_bytes)
            ),
        ));
    }
    let mut out = Vec::new();
    // One more byte than the file, so reading to its end needs no second allocation.
    out.try_reserve_exact(len as usize + 1).map_err(|_| {
        Error::format(
            path,
            format!("{what} of {} cannot be allocated", human_bytes(len)),
        )
    })?;
    advise_huge_pages(&mut out);
    read_bounded_into(path, file, max_bytes as usize, what, out)
}

/// Asks the kernel to back the 2 MiB-aligned interior of `buf`'s reserved capacity with
/// transparent huge pages (Linux `madvise(MADV_HUGEPAGE)`), before anything is written to it.
///
/// Why: a volume's voxels are read at random along rays. With 4 KiB pages a gigavoxel spans
/// 262,144 pages, far more than the TLB holds, so most lookups also miss the TLB; with 2 MiB
/// pages it spans 512. Systems whose huge pages are set to `madvise` (a common default) give
/// them only to memory that asks. Elsewhere, and for buffers under 64 MiB, this does nothing.
pub fn advise_huge_pages<T>(buf: &mut Vec<T>) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = buf.capacity() * std::mem::size_of::<T>();
        if bytes < 64 << 20 {
            return;
        }
        let start = buf.as_mut_ptr() as usize;
        let aligned = start.next_multiple_of(HUGE);
        let end = (start + bytes) / HUGE * HUGE;
        if end > aligned {
            // SAFETY: `aligned..end` lies inside the allocation `buf` owns (its capacity), and
            // `buf` is borrowed mutably, so no other reference to that memory exists. The call
            // only advises how the kernel backs those pages: it reads and writes no memory,
            // moves nothing and changes no contents, so every Rust invariant of `buf` holds
            // whatever it returns. A failure (a kernel without huge pages) is harmless and
            // ignored on purpose.
            unsafe {
                libc::madvise(
                    aligned as *mut libc::c_void,
                    end - aligned,
                    libc::MADV_HUGEPAGE,
                );
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = buf;
}

/// The largest text file (scene, experiment, colour-map preset) the readers take: real ones are
/// a few kilobytes.
pub const MAX_TEXT_FILE_BYTES: u64 = 16 << 20;

/// Reads a text file (a scene, an experiment, a preset): a regular file of at most
/// [`MAX_TEXT_FILE_BYTES`], in UTF-8.
pub fn read_text_file(path: &Path, what: &str) -> Result<String> {
    let bytes = read_regular(path, MAX_TEXT_FILE_BYTES, what)?;
    String::from_utf8(bytes).map_err(|e| {
        Error::format(
            path,
            format!(
                "{what} is not UTF-8 text (byte {} is not)",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// Reads `source` to its end, failing as soon as it yields more than `max_bytes`: a compressed
/// stream cannot inflate past the size its header promised.
pub fn read_bounded(
    path: &Path,
    source: impl Read,
    max_bytes: usize,
    what: &str,
) -> Result<Vec<u8>> {
    read_bounded_into(path, source, max_bytes, what, Vec::new())
}

/// [`read_bounded`] appending to `out` (which may already hold the capacity it needs).
fn read_bounded_into(
    path: &Path,
    source: impl Read,
    max_bytes: usize,
    what: &str,
    mut out: Vec<u8>,
) -> Result<Vec<u8>> {
    source
        .take(max_bytes as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| Error::format(path, format!("{what} cannot be read: {e}")))?;
    if out.len() > max_bytes {
        return Err(Error::format(
            path,
            format!(
                "{what} holds more than the {max_bytes} bytes the header promises: \
                 expected exactly that many"
            ),
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {

    /// The job's memory limit is read for cgroup v2 and v1, at the group's own path or at the
    /// controller's root (a container), with the reclaimable file cache not counted; no limit
    /// (v2 "max", v1 2^63) and unreadable files give none.
    #[test]
    fn the_cgroup_headroom_is_read_for_both_versions() {
        let files = |pairs: &'static [(&'static str, &'static str)]| {
            move |p: &str| {
                pairs
                    .iter()
                    .find(|(k, _)| *k == p)
                    .map(|(_, v)| v.to_string())
            }
        };
        // v2, SLURM-style path: 4 GiB limit, 3 GiB used of which 1 GiB inactive cache.
        let v2 = files(&[
            ("/sys/fs/cgroup/slurm/job_7/memory.max", "4294967296\n"),
            ("/sys/fs/cgroup/slurm/job_7/memory.current", "3221225472\n"),
            (
                "/sys/fs/cgroup/slurm/job_7/memory.stat",
                "anon 1\ninactive_file 1073741824\n",
            ),
        ]);
        assert_eq!(cgroup_headroom("0::/slurm/job_7\n", &v2), Some(2 << 30));
        let unlimited = files(&[("/sys/fs/cgroup/memory.max", "max\n")]);
        assert_eq!(cgroup_headroom("0::/\n", &unlimited), None);
        // v1 in a container: the group's path is not mounted, the controller's root is.
        let v1 = files(&[
            (
                "/sys/fs/cgroup/memory/memory.limit_in_bytes",
                "2147483648\n",
            ),
            (
                "/sys/fs/cgroup/memory/memory.usage_in_bytes",
                "2684354560\n",
            ),
            (
                "/sys/fs/cgroup/memory/memory.stat",
                "cache 5\ntotal_inactive_file 1073741824\n",
            ),
        ]);
        let text = "5:devices:/\n4:memory:/process_api/abc\n0::/\n";
        assert_eq!(cgroup_headroom(text, &v1), Some(512 << 20));
        let v1_unlimited = files(&[
            (
                "/sys/fs/cgroup/memory/memory.limit_in_bytes",
                "9223372036854771712\n",
            ),
            (
                "/sys/fs/cgroup/memory/memory.usage_in_bytes",
                "10254323712\n",
            ),
        ]);
        assert_eq!(cgroup_headroom(text, &v1_unlimited), None);
        // Over the limit already: no headroom, not a wrapped number.
        let over = files(&[
            ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "1000\n"),
            ("/sys/fs/cgroup/memory/memory.usage_in_bytes", "5000\n"),
        ]);
        assert_eq!(cgroup_headroom(text, &over), Some(0));
        assert_eq!(cgroup_headroom("garbage", &over), None);
    }

    use super::*;

    #[test]
    fn sizes_that_wrap_or_do_not_fit_are_refused() {
        let p = Path::new("v.nrrd");
        // 2^22 cubed = 2^66 voxels: wraps a u64.
        let e = check_volume_size(p, [1 << 22, 1 << 22, 1 << 22], DType::U8).unwrap_err();
        assert!(e.to_string().contains("more voxels than memory"), "{e}");
        // 1e15 voxels fit in a u64 but not in any memory.
        let e = check_volume_size(p, [100_000; 3], DType::U8).unwrap_err();
        assert!(e.to_string().contains("available"), "{e}");
        for bad in [0, -1, 1 << 33] {
            let e = check_volume_size(p, [8, bad, 8], DType::U8).unwrap_err();
            assert!(e.to_string().contains("axis 1"), "{e}");
        }
        let ok = check_volume_size(p, [8, 8, 2], DType::U16).unwrap();
        assert_eq!((ok.voxels, ok.payload_bytes), (128, 256));
    }

    #[test]
    fn bounded_reads_stop_past_the_promise() {
        let p = Path::new("x");
        assert_eq!(
            read_bounded(p, &[1u8; 10][..], 10, "data").unwrap().len(),
            10
        );
        let e = read_bounded(p, std::io::repeat(0), 1000, "data").unwrap_err();
        assert!(e.to_string().contains("more than the 1000 bytes"), "{e}");
    }

    #[test]
    fn devices_are_not_volumes() {
        if Path::new("/dev/zero").exists() {
            let e = read_regular(Path::new("/dev/zero"), 1 << 20, "a volume").unwrap_err();
            assert!(e.to_string().contains("not a regular file"), "{e}");
        }
    }

    #[test]
    fn a_large_file_reads_back_whole_into_huge_pages() {
        // Past the 64 MiB at which the buffer asks for huge pages, and not a multiple of 2 MiB,
        // so the advised interior and the tails on either side are all read into.
        let len = (65 << 20) + 12_345;
        let bytes: Vec<u8> = (0..len).map(|i| (i * 7 + i / 4093) as u8).collect();
        let path = std::env::temp_dir().join(format!("volume-pt-huge-{}.raw", std::process::id()));
        std::fs::write(&path, &bytes).unwrap();
        let read = read_regular(&path, len as u64, "a volume");
        std::fs::remove_file(&path).unwrap();
        let read = read.unwrap();
        assert_eq!(read.len(), len);
        assert!(read == bytes, "the bytes read differ from the file's");
        let e = read_regular(Path::new("/nonexistent/v.raw"), 1, "a volume").unwrap_err();
        assert!(e.to_string().contains("no such file"), "{e}");
    }
}
