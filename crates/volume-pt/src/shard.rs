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
//! The file is `GSPARTIAL 2\n`, one line of JSON (the header), then per pixel, row-major,
//! three little-endian i128 sums and a u32 count (52 bytes); when the header says `features`,
//! each pixel is followed by its feature sums ([`ExactFeatures`]: six i64, one i128 and a u32,
//! 68 bytes). The header carries a checksum of
//! itself and the pixels, and a file is read as a fresh render would be checked: no pixel holds
//! more samples than its ranges, no sum more than its samples can carry, and a merge's
//! arithmetic is checked, so a damaged or edited file is refused rather than merged into wrong
//! pixels.

use crate::error::{Error, Result};
use crate::film::{ExactFeatures, ExactRgb, Film, PixelFeatures};
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
        Self(render_base::hash::FNV_OFFSET)
    }

    /// Adds one part, its length first, so parts cannot run into each other.
    pub fn part(mut self, bytes: &[u8]) -> Self {
        use render_base::hash::fnv1a64;
        self.0 = fnv1a64(bytes, fnv1a64(&(bytes.len() as u64).to_le_bytes(), self.0));
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
    /// How the scene asks its PNG to be made (exposure in stops, tone map), so that a merge
    /// tone-maps as a one-process render would; absent for partials that carry none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    output: Option<(f32, hdr_image::ToneMap)>,
    /// Whether each pixel carries feature sums (absent, and so false, in files without).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    features: bool,
    /// FNV-1a of the header (with this field empty) and the pixel bytes, 16 hex digits.
    #[serde(default)]
    checksum: String,
}

const MAGIC: &[u8] = b"GSPARTIAL 2\n";

/// The largest fixed-point sum one sample adds to a channel: [`crate::film::MAX_SAMPLE_RADIANCE`]
/// in 2^-56 steps (2^95). A pixel's sums are at most its count times this.
const MAX_STEPS_PER_SAMPLE: i128 = 1 << 95;

/// The checksum of a header (its own checksum left empty) and the pixel bytes.
fn checksum(header: &Header, pixels: &[u8]) -> String {
    let unsigned = Header {
        checksum: String::new(),
        ..header.clone()
    };
    let text = serde_json::to_string(&unsigned).expect("the header serialises");
    RenderKey::new().part(text.as_bytes()).part(pixels).hex()
}
const BYTES_PER_PIXEL: u64 = 3 * 16 + 4;
/// The feature sums' bytes a pixel: six i64, an i128 and a u32.
const FEATURE_BYTES_PER_PIXEL: u64 = 6 * 8 + 16 + 4;
/// The header line's longest allowed length: a header is a few hundred bytes.
const MAX_HEADER: usize = 1 << 20;

/// The exact film of some sample ranges of one render, ready to merge with the others.
#[derive(Debug, Clone, PartialEq)]
pub struct PartialRender {
    header: Header,
    /// Row-major, one per pixel.
    sums: Vec<ExactRgb>,
    counts: Vec<u32>,
    /// Row-major feature sums; empty when the header says there are none.
    features: Vec<ExactFeatures>,
}

impl PartialRender {
    /// The partial of `film`, which holds samples `samples` of a `spp`-sample render `key`.
    pub fn from_film(film: &Film, key: &str, spp: u32, samples: Range<u32>) -> Self {
        let (sums, counts) = film.exact_sums();
        let features = film.exact_features().unwrap_or_default();
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
                output: None,
                features: !features.is_empty(),
                checksum: String::new(),
            },
            sums,
            counts,
            features,
        }
    }

    /// The same partial carrying the scene's PNG settings (exposure in stops, tone map).
    pub fn with_output(mut self, exposure: f32, tonemap: hdr_image::ToneMap) -> Self {
        self.header.output = Some((exposure, tonemap));
        self
    }

    /// The PNG settings the render's scene asks for, when the partial carries them.
    pub fn output(&self) -> Option<(f32, hdr_image::ToneMap)> {
        self.header.output
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
        if a.features != b.features {
            return Err(Error::Invalid(format!(
                "a partial {} feature buffers cannot merge with one {}: render every shard with \
                 the same --features setting",
                if b.features { "with" } else { "without" },
                if a.features { "with" } else { "without" },
            )));
        }
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
        // Checked before anything changes: a sum or a count that would overflow is refused
        // (a partial read from a file has been checked, but two valid ones can still add up to
        // more samples than a pixel holds).
        let overflow = |what: &str| {
            Error::Invalid(format!(
                "merging these partials overflows a pixel's {what}: they cannot be parts of one render"
            ))
        };
        let mut sums = self.sums.clone();
        for (s, o) in sums.iter_mut().zip(&other.sums) {
            for (a, b) in s.0.iter_mut().zip(o.0) {
                *a = a.checked_add(b).ok_or_else(|| overflow("sum"))?;
            }
        }
        let mut counts = self.counts.clone();
        for (c, o) in counts.iter_mut().zip(&other.counts) {
            *c = c.checked_add(*o).ok_or_else(|| overflow("sample count"))?;
        }
        let mut features = self.features.clone();
        for (f, o) in features.iter_mut().zip(&other.features) {
            *f = f.checked_add(o).ok_or_else(|| overflow("feature sums"))?;
        }
        self.sums = sums;
        self.counts = counts;
        self.features = features;
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
        self.header.nonfinite_samples = self
            .header
            .nonfinite_samples
            .saturating_add(b.nonfinite_samples);
        // Parts of one render carry one scene's PNG settings, or none (a Python partial).
        self.header.output = self.header.output.or(b.output);
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

    /// Each pixel's mean features, as [`Film::features`] computes them; `None` when the
    /// partial carries none.
    pub fn features(&self) -> Option<Vec<PixelFeatures>> {
        self.header.features.then(|| {
            self.features
                .iter()
                .zip(&self.counts)
                .map(|(f, &c)| f.mean(c))
                .collect()
        })
    }

    /// [`PartialRender::features`] as images.
    pub fn feature_images(&self) -> Option<hdr_image::FeatureImages> {
        let f = self.features()?;
        Some(crate::film::feature_images(self.width(), self.height(), &f))
    }

    /// The bytes one pixel takes in the file.
    fn bytes_per_pixel(&self) -> u64 {
        BYTES_PER_PIXEL
            + if self.header.features {
                FEATURE_BYTES_PER_PIXEL
            } else {
                0
            }
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut pixels = Vec::with_capacity(self.counts.len() * self.bytes_per_pixel() as usize);
        for (k, (s, c)) in self.sums.iter().zip(&self.counts).enumerate() {
            for v in s.0 {
                pixels.extend_from_slice(&v.to_le_bytes());
            }
            pixels.extend_from_slice(&c.to_le_bytes());
            if let Some(f) = self.features.get(k) {
                for v in f.albedo.iter().chain(&f.normal) {
                    pixels.extend_from_slice(&v.to_le_bytes());
                }
                pixels.extend_from_slice(&f.depth.to_le_bytes());
                pixels.extend_from_slice(&f.hits.to_le_bytes());
            }
        }
        let header = Header {
            checksum: checksum(&self.header, &pixels),
            ..self.header.clone()
        };
        let header = serde_json::to_string(&header).expect("the header serialises");
        let mut out = Vec::with_capacity(MAGIC.len() + header.len() + 1 + pixels.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(header.as_bytes());
        out.push(b'\n');
        out.extend_from_slice(&pixels);
        out
    }

    /// Reads a partial from its bytes; `origin` names them in errors. Every size is checked
    /// against the bytes present before anything is allocated.
    pub fn from_bytes(bytes: &[u8], origin: &Path) -> Result<Self> {
        let bad = |m: String| Error::format(origin, format!("partial render: {m}"));
        if bytes.starts_with(b"GSPARTIAL ") && !bytes.starts_with(MAGIC) {
            return Err(bad(
                "written by an older version of gscache (no checksum): render the shard again"
                    .into(),
            ));
        }
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
        let mut header: Header =
            serde_json::from_str(text).map_err(|e| bad(format!("header: {e}")))?;
        let data = &rest[end + 1..];
        let pixels = header.width as u64 * header.height as u64;
        // Checked: a header can state sides whose bytes pass 2^64 (the fuzzer found the
        // overflow this once was).
        let per_pixel = BYTES_PER_PIXEL
            + if header.features {
                FEATURE_BYTES_PER_PIXEL
            } else {
                0
            };
        let need = pixels.checked_mul(per_pixel);
        if pixels == 0 || need != Some(data.len() as u64) {
            return Err(bad(format!(
                "{} bytes of pixels for {}x{}: expected {} ({per_pixel} a pixel)",
                data.len(),
                header.width,
                header.height,
                need.map_or("more than 2^64".to_string(), |n| n.to_string())
            )));
        }
        let stated = std::mem::take(&mut header.checksum);
        if stated.is_empty() {
            return Err(bad(
                "the checksum is missing: the file was edited after it was written (every partial gscache writes has one)"
                    .into(),
            ));
        }
        if checksum(&header, data) != stated {
            return Err(bad(
                "the checksum does not match: the file was changed or damaged after it was written"
                    .into(),
            ));
        }
        for r in &header.ranges {
            if !(r[0] < r[1] && r[1] <= header.spp) {
                return Err(bad(format!(
                    "sample range {}..{} is not inside 0..{}",
                    r[0], r[1], header.spp
                )));
            }
        }
        // Ranges that overlap, or more samples than a pixel's count can hold, are refused
        // like a merge of the same shard twice.
        let mut sorted = header.ranges.clone();
        sorted.sort_by_key(|r| r[0]);
        if sorted.windows(2).any(|w| w[1][0] < w[0][1]) {
            return Err(bad("sample ranges overlap".into()));
        }
        let range_samples: u64 = sorted.iter().map(|r| (r[1] - r[0]) as u64).sum();
        let mut sums = Vec::with_capacity(pixels as usize);
        let mut counts = Vec::with_capacity(pixels as usize);
        let mut features = Vec::new();
        for (i, px) in data.chunks_exact(per_pixel as usize).enumerate() {
            let at = || {
                let w = header.width as usize;
                format!("pixel ({}, {})", i % w, i / w)
            };
            let count = u32::from_le_bytes(px[48..52].try_into().expect("4 bytes"));
            if count as u64 > range_samples {
                return Err(bad(format!(
                    "{} holds {count} samples, but its sample ranges hold {range_samples}",
                    at()
                )));
            }
            let most = count as i128 * MAX_STEPS_PER_SAMPLE;
            let mut s = [0i128; 3];
            for (k, v) in s.iter_mut().enumerate() {
                *v = i128::from_le_bytes(px[16 * k..16 * k + 16].try_into().expect("16 bytes"));
                if !(0..=most).contains(v) {
                    return Err(bad(format!(
                        "{} has a sum its {count} samples cannot carry (negative, or above \
                         {count} x the largest sample)",
                        at()
                    )));
                }
            }
            sums.push(ExactRgb(s));
            counts.push(count);
            if header.features {
                let f = read_features(&px[BYTES_PER_PIXEL as usize..]);
                if !f.is_possible(count) {
                    return Err(bad(format!(
                        "{} has feature sums its {count} samples cannot carry",
                        at()
                    )));
                }
                features.push(f);
            }
        }
        Ok(Self {
            header,
            sums,
            counts,
            features,
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
        let limit = MAGIC.len() as u64
            + MAX_HEADER as u64
            + (BYTES_PER_PIXEL + FEATURE_BYTES_PER_PIXEL) * (1u64 << 32);
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

/// One pixel's feature sums from their 68 bytes (see the module docs).
fn read_features(b: &[u8]) -> ExactFeatures {
    let i64_at = |k: usize| i64::from_le_bytes(b[8 * k..8 * k + 8].try_into().expect("8 bytes"));
    ExactFeatures {
        albedo: [i64_at(0), i64_at(1), i64_at(2)],
        normal: [i64_at(3), i64_at(4), i64_at(5)],
        depth: i128::from_le_bytes(b[48..64].try_into().expect("16 bytes")),
        hits: u32::from_le_bytes(b[64..68].try_into().expect("4 bytes")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3x2 partial of samples 2..6 of an 8-sample render: every pixel 4 samples of 0.5.
    fn partial() -> PartialRender {
        let mut film = Film::new(3, 2);
        let sample = ExactRgb::from_sample(glam::Vec3::splat(0.5)).unwrap();
        let (mut sums, counts) = film.exact_sums();
        for s in &mut sums {
            for _ in 0..4 {
                *s += sample;
            }
        }
        film.nonfinite_samples = 0;
        let mut p = PartialRender::from_film(&film, "key", 8, 2..6);
        p.sums = sums;
        p.counts = counts.iter().map(|_| 4).collect();
        p
    }

    /// The bytes of `p` as written, with its pixels edited by `edit` and the checksum made to
    /// match again: what the value checks behind the checksum must catch on their own.
    fn resigned(p: &PartialRender, edit: impl FnOnce(&mut PartialRender)) -> Vec<u8> {
        let mut q = p.clone();
        edit(&mut q);
        q.to_bytes()
    }

    fn refusal(bytes: &[u8]) -> String {
        match PartialRender::from_bytes(bytes, Path::new("t.gspartial")) {
            Ok(_) => panic!("a tampered partial was read"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn every_flipped_byte_is_caught_by_the_checksum() {
        let p = partial();
        let bytes = p.to_bytes();
        assert_eq!(
            PartialRender::from_bytes(&bytes, Path::new("t")).unwrap(),
            PartialRender {
                header: Header {
                    checksum: String::new(),
                    ..p.header.clone()
                },
                ..p.clone()
            }
        );
        let header_end = MAGIC.len()
            + bytes[MAGIC.len()..]
                .iter()
                .position(|&b| b == b'\n')
                .unwrap();
        // Every byte of the pixels, and every byte of the header's values (flipping its
        // punctuation breaks the JSON first, which is refused too).
        for i in MAGIC.len()..bytes.len() {
            if i == header_end {
                continue;
            }
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert!(
                PartialRender::from_bytes(&b, Path::new("t")).is_err(),
                "byte {i} flipped was read"
            );
        }
        let mut old = bytes.clone();
        old[..MAGIC.len()].copy_from_slice(b"GSPARTIAL 1\n");
        assert!(refusal(&old).contains("older version"));
    }

    #[test]
    fn values_no_render_can_hold_are_refused_behind_the_checksum() {
        let p = partial();
        let e = refusal(&resigned(&p, |q| q.sums[1].0[0] = i128::MAX));
        assert!(
            e.contains("pixel (1, 0)") && e.contains("cannot carry"),
            "{e}"
        );
        let e = refusal(&resigned(&p, |q| q.sums[4].0[2] = -1));
        assert!(e.contains("pixel (1, 1)"), "{e}");
        let e = refusal(&resigned(&p, |q| q.counts[2] = u32::MAX));
        assert!(e.contains("holds 4294967295 samples"), "{e}");
        let e = refusal(&resigned(&p, |q| q.counts[0] = 0));
        assert!(
            e.contains("pixel (0, 0)") && e.contains("cannot carry"),
            "{e}"
        );
        let e = refusal(&resigned(&p, |q| q.header.ranges = vec![[2, 6], [4, 8]]));
        assert!(e.contains("overlap"), "{e}");
    }

    /// Partials that have been read are checked, so no two possible ones overflow on merge;
    /// the merge's own arithmetic is checked all the same (partials made in memory are not read
    /// from a file), and a refused merge leaves the partial merged into as it was.
    #[test]
    fn a_merge_that_would_overflow_is_refused() {
        let mut a = partial();
        let mut b = partial();
        b.header.ranges = vec![[6, 8]];
        a.sums[0].0[0] = i128::MAX - 5;
        b.sums[0].0[0] = 10;
        let before = a.clone();
        let e = a.merge(&b).unwrap_err().to_string();
        assert!(e.contains("overflows"), "{e}");
        assert_eq!(a, before);
    }
}
