//! Shards: one render split into independent pieces that merge exactly.
//!
//! Every sample of pixel `p` with index `s` draws its own counter-based random numbers, so a
//! render is a pure function of its scene and settings, and any split of its sample indices
//! gives the same samples. A [`Shard`] `i/n` takes one contiguous range of the sample indices
//! for every pixel; its film is kept as a [`PartialRender`] (exact fixed-point sums and counts,
//! see [`crate::film`]), and partials of disjoint ranges merge, in any order and grouping, into
//! the one-process film bit for bit. That lets a job array, a Dask cluster or a laptop's two
//! processes share one high-spp render with no other coordination.
//!
//! A partial carries a key that names its render (the caller's hash of the scene and
//! settings: [`RenderKey`]); a merge refuses parts of another render and any sample range
//! given twice, so a stale or repeated shard cannot slip into an image.
//!
//! The file is `GSPARTIAL 1\n`, one line of JSON (the header), then per pixel, row-major,
//! three little-endian i128 sums and a u32 count (52 bytes).

use crate::error::{Error, Result};
use crate::film::{ExactRgb, Film};
use serde::{Deserialize, Serialize};
use std::io::Read;
use std::ops::Range;
use std::path::Path;

/// Shard `index` of `count`: the `index`-th of `count` near-equal ranges of sample indices.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    index: u32,
    count: u32,
}

impl Shard {
    /// Shard `index` of `count`; refused unless `index < count`.
    pub fn new(index: u32, count: u32) -> Result<Self> {
        if count == 0 || index >= count {
            return Err(Error::Invalid(format!(
                "shard {index}/{count}: expected I/N with 0 <= I < N"
            )));
        }
        Ok(Self { index, count })
    }

    /// Parses `I/N` (as given on a command line).
    pub fn parse(text: &str) -> Result<Self> {
        let bad = || Error::Invalid(format!("shard `{text}`: expected I/N, as in 0/4"));
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        Self::new(
            i.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        )
    }

    pub fn index(&self) -> u32 {
        self.index
    }
    pub fn count(&self) -> u32 {
        self.count
    }

    /// This shard's sample indices out of `spp`: `[i spp / n, (i + 1) spp / n)`. Empty when
    /// there are more shards than samples.
    pub fn samples(&self, spp: u32) -> Range<u32> {
        let at = |i: u32| (i as u64 * spp as u64 / self.count as u64) as u32;
        at(self.index)..at(self.index + 1)
    }

    /// Item `k` of a list belongs to this shard when `k mod n = i` (experiments: units).
    pub fn owns(&self, k: usize) -> bool {
        k % self.count as usize == self.index as usize
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// A render's identity: a 64-bit FNV-1a hash over the parts that decide its pixels (the scene
/// file's text, the volume's bytes or size, the settings), printed as 16 hex digits. Not a
/// cryptographic hash: it guards against mistakes, not against an adversary.
#[derive(Debug, Clone)]
pub struct RenderKey(u64);

impl RenderKey {
    pub fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    /// Adds one part, its length first, so parts cannot run into each other.
    pub fn part(mut self, bytes: &[u8]) -> Self {
        for b in (bytes.len() as u64).to_le_bytes().iter().chain(bytes) {
            self.0 ^= *b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

impl Default for RenderKey {
    fn default() -> Self {
        Self::new()
    }
}

/// The header of a partial render file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    key: String,
    width: u32,
    height: u32,
    /// The whole render's samples per pixel (the ranges below are parts of `0..spp`).
    spp: u32,
    ranges: Vec<[u32; 2]>,
    nonfinite_samples: u64,
}

const MAGIC: &[u8] = b"GSPARTIAL 1\n";
const BYTES_PER_PIXEL: u64 = 3 * 16 + 4;
/// The header line's longest allowed length: a header is a few hundred bytes.
const MAX_HEADER: usize = 1 << 20;

/// The exact film of some sample ranges of one render, ready to merge with the others.
#[derive(Debug, Clone, PartialEq)]
pub struct PartialRender {
    header: Header,
    /// Row-major, one per pixel.
    sums: Vec<ExactRgb>,
    counts: Vec<u32>,
}

impl PartialRender {
    /// The partial of `film`, which holds samples `samples` of a `spp`-sample render `key`.
    pub fn from_film(film: &Film, key: &str, spp: u32, samples: Range<u32>) -> Self {
        let (sums, counts) = film.exact_sums();
        Self {
            header: Header {
                key: key.to_string(),
                width: film.width(),
                height: film.height(),
                spp,
                ranges: if samples.is_empty() {
                    Vec::new()
                } else {
                    vec![[samples.start, samples.end]]
                },
                nonfinite_samples: film.nonfinite_samples,
            },
            sums,
            counts,
        }
    }

    pub fn key(&self) -> &str {
        &self.header.key
    }
    pub fn width(&self) -> u32 {
        self.header.width
    }
    pub fn height(&self) -> u32 {
        self.header.height
    }
    /// The whole render's samples per pixel.
    pub fn spp(&self) -> u32 {
        self.header.spp
    }
    /// The sample ranges this partial holds, sorted.
    pub fn ranges(&self) -> Vec<Range<u32>> {
        let mut r: Vec<Range<u32>> = self.header.ranges.iter().map(|r| r[0]..r[1]).collect();
        r.sort_by_key(|r| r.start);
        r
    }
    pub fn nonfinite_samples(&self) -> u64 {
        self.header.nonfinite_samples
    }
    /// Samples per pixel, row-major (a cancelled shard's pixels may hold fewer than its ranges).
    pub fn counts(&self) -> &[u32] {
        &self.counts
    }

    /// Whether the ranges cover every sample `0..spp`.
    pub fn is_complete(&self) -> bool {
        let mut next = 0;
        for r in self.ranges() {
            if r.start != next {
                return false;
            }
            next = r.end;
        }
        next == self.header.spp
    }

    /// Adds `other` in: refused when it belongs to another render or repeats a sample range.
    pub fn merge(&mut self, other: &PartialRender) -> Result<()> {
        let (a, b) = (&self.header, &other.header);
        if a.key != b.key || a.width != b.width || a.height != b.height || a.spp != b.spp {
            return Err(Error::Invalid(format!(
                "partial of render {} ({}x{}, {} spp) cannot merge with one of render {} ({}x{}, {} spp): they are different renders",
                b.key, b.width, b.height, b.spp, a.key, a.width, a.height, a.spp
            )));
        }
        for r in &b.ranges {
            if let Some(o) = a.ranges.iter().find(|o| r[0] < o[1] && o[0] < r[1]) {
                return Err(Error::Invalid(format!(
                    "samples {}..{} are given twice (a part already holds {}..{}): each shard may be merged once",
                    r[0], r[1], o[0], o[1]
                )));
            }
        }
        for (s, o) in self.sums.iter_mut().zip(&other.sums) {
            *s += *o;
        }
        for (c, o) in self.counts.iter_mut().zip(&other.counts) {
            *c = c.saturating_add(*o);
        }
        // Kept sorted and coalesced, so a complete merge holds the one range `0..spp`.
        let mut ranges = std::mem::take(&mut self.header.ranges);
        ranges.extend(b.ranges.iter().copied());
        ranges.sort_by_key(|r| r[0]);
        for r in ranges {
            match self.header.ranges.last_mut() {
                Some(last) if last[1] == r[0] => last[1] = r[1],
                _ => self.header.ranges.push(r),
            }
        }
        self.header.nonfinite_samples += b.nonfinite_samples;
        Ok(())
    }

    /// Merges `parts` (at least one) in the order given; the result does not depend on it.
    pub fn merge_all(parts: impl IntoIterator<Item = PartialRender>) -> Result<PartialRender> {
        let mut it = parts.into_iter();
        let mut out = it
            .next()
            .ok_or_else(|| Error::Invalid("no partial renders to merge".into()))?;
        for p in it {
            out.merge(&p)?;
        }
        Ok(out)
    }

    /// Each pixel's mean, as [`Film::image`] computes it.
    pub fn image(&self) -> hdr_image::RgbImage {
        let pixels = self
            .sums
            .iter()
            .zip(&self.counts)
            .map(|(s, &c)| if c > 0 { s.mean(c) } else { glam::Vec3::ZERO })
            .collect();
        hdr_image::RgbImage::from_pixels(self.header.width, self.header.height, pixels)
            .expect("a partial holds one sum per pixel")
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let header = serde_json::to_string(&self.header).expect("the header serialises");
        let mut out = Vec::with_capacity(
            MAGIC.len() + header.len() + 1 + self.counts.len() * BYTES_PER_PIXEL as usize,
        );
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(header.as_bytes());
        out.push(b'\n');
        for (s, c) in self.sums.iter().zip(&self.counts) {
            for v in s.0 {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&c.to_le_bytes());
        }
        out
    }

    /// Reads a partial from its bytes; `origin` names them in errors. Every size is checked
    /// against the bytes present before anything is allocated.
    pub fn from_bytes(bytes: &[u8], origin: &Path) -> Result<Self> {
        let bad = |m: String| Error::format(origin, format!("partial render: {m}"));
        let rest = bytes.strip_prefix(MAGIC).ok_or_else(|| {
            bad("not a partial render (expected a file written by `gscache render --partial` or `Partial.write`)".into())
        })?;
        let end = rest
            .iter()
            .take(MAX_HEADER)
            .position(|&b| b == b'\n')
            .ok_or_else(|| bad("the header line is missing or too long".into()))?;
        let text =
            std::str::from_utf8(&rest[..end]).map_err(|_| bad("the header is not UTF-8".into()))?;
        let header: Header = serde_json::from_str(text).map_err(|e| bad(format!("header: {e}")))?;
        let data = &rest[end + 1..];
        let pixels = header.width as u64 * header.height as u64;
        if pixels == 0 || data.len() as u64 != pixels * BYTES_PER_PIXEL {
            return Err(bad(format!(
                "{} bytes of pixels for {}x{}: expected {} (52 a pixel)",
                data.len(),
                header.width,
                header.height,
                pixels * BYTES_PER_PIXEL
            )));
        }
        for r in &header.ranges {
            if !(r[0] < r[1] && r[1] <= header.spp) {
                return Err(bad(format!(
                    "sample range {}..{} is not inside 0..{}",
                    r[0], r[1], header.spp
                )));
            }
        }
        let mut sums = Vec::with_capacity(pixels as usize);
        let mut counts = Vec::with_capacity(pixels as usize);
        for px in data.chunks_exact(BYTES_PER_PIXEL as usize) {
            let mut s = [0i128; 3];
            for (k, v) in s.iter_mut().enumerate() {
                *v = i128::from_le_bytes(px[16 * k..16 * k + 16].try_into().expect("16 bytes"));
                if *v < 0 {
                    return Err(bad("a negative sum (the file is damaged)".into()));
                }
            }
            sums.push(ExactRgb(s));
            counts.push(u32::from_le_bytes(px[48..52].try_into().expect("4 bytes")));
        }
        Ok(Self {
            header,
            sums,
            counts,
        })
    }

    /// Writes the file atomically ([`render_base::write_atomically`]).
    pub fn write(&self, path: &Path) -> Result<()> {
        let bytes = self.to_bytes();
        render_base::write_atomically(path, |file| {
            std::io::Write::write_all(file, &bytes).map_err(|e| e.to_string())
        })
        .map_err(|e| Error::Invalid(e.to_string()))
    }

    /// Reads a file written by [`PartialRender::write`]; only regular files, and none larger
    /// than a partial can be.
    pub fn read(path: &Path) -> Result<Self> {
        let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        if !meta.is_file() {
            return Err(Error::format(
                path,
                "not a regular file: expected a partial render",
            ));
        }
        let limit = MAGIC.len() as u64 + MAX_HEADER as u64 + BYTES_PER_PIXEL * (1u64 << 32);
        if meta.len() > limit {
            return Err(Error::format(
                path,
                format!("{} bytes is larger than any partial render", meta.len()),
            ));
        }
        let mut bytes = Vec::with_capacity(meta.len() as usize);
        std::fs::File::open(path)
            .and_then(|f| f.take(limit).read_to_end(&mut bytes))
            .map_err(|e| Error::io(path, e))?;
        Self::from_bytes(&bytes, path)
    }
}
