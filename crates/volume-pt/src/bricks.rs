//! Streamed voxels: a volume larger than memory, paged in from its store a brick at a time
//! into a cache bounded by a memory budget.
//!
//! **Bricks.** The grid is cut into boxes aligned with the store's chunks (its inner chunks
//! where it is sharded), so a brick is read by decoding one chunk, never a neighbour's. A
//! [`BrickSource`] reads a brick's voxels in their stored type; an OME-Zarr array is one
//! (`io::ome_zarr`), and so is an in-memory grid ([`WholeGrid`], for tests and benchmarks).
//!
//! **The hot path.** A lookup goes to its brick through a page table (a slot per brick that
//! holds the brick while it is resident) behind a per-thread shortcut to the last brick used:
//! consecutive lookups in one brick (nearly all of a free flight's) cost an integer comparison,
//! with no lock, no hash and no shared counter touched. Moving to another brick reads its slot
//! once (`arc-swap`'s wait-free load) and marks it as used. A trilinear lookup whose eight
//! voxels straddle bricks (one in 20 with 64-voxel bricks) gathers them one by one. Every
//! lookup reads the same stored numbers and does the same f32 arithmetic as the in-memory
//! grid's, so a streamed render is bit for bit the render of the volume read whole, whichever
//! bricks were resident.
//!
//! **The budget.** It bounds the streamed volume's memory: the page table and majorant
//! structures take their share, the bricks the rest (the capacity). Loading a brick adds its
//! bytes to the resident total; past the capacity, a clock sweep (second chance: a brick used
//! since the last sweep is kept once more) empties slots until the total is 7/8 of it. A thread
//! still reading an emptied brick keeps it alive through its reference until it moves on, so
//! the bound is the capacity plus a brick per thread.
//!
//! **The survey.** Delta tracking needs, per macrocell, the range of every voxel interpolation
//! can touch there (`majorant`); a mean-downsampled pyramid does not bound it. [`Bricks::survey`]
//! streams every brick once (in parallel, within the budget) and gathers, exactly as the
//! in-memory grid would compute them, each macrocell's range, the whole range and the strided
//! sample the automatic scene takes its histogram from. A survey is kept in a cache folder
//! (see [`survey_cache_folder`]) keyed by the store's identity and its files' sizes and times,
//! so the next run of the same store starts without reading it.

use crate::error::{Error, Result};
use crate::grid::Voxels;
use arc_swap::ArcSwapOption;
use glam::UVec3;
use rayon::prelude::*;
use std::cell::RefCell;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// Where a streamed grid's bricks come from.
pub trait BrickSource: Send + Sync + std::fmt::Debug {
    /// The store and array, for messages.
    fn name(&self) -> String;
    /// The brick edge per axis (x, y, z): the store's chunk (or inner chunk) shape.
    fn brick_size(&self) -> UVec3;
    /// The stored type's name as [`Voxels::type_name`] gives it.
    fn type_name(&self) -> &'static str;
    /// The voxels of the box `lo .. lo + size` (inside the grid), x fastest, in the stored
    /// type (the same type for every brick).
    fn read(&self, lo: UVec3, size: UVec3) -> Result<Voxels>;
    /// Whether the store holds no data for the box `lo .. lo + size` (its voxels are all the
    /// fill value); `false` where it cannot tell cheaply.
    fn is_absent(&self, _lo: UVec3, _size: UVec3) -> bool {
        false
    }
    /// A string that changes whenever the stored voxels may have changed (the files' sizes and
    /// modification times), and that names the data (store, array, selection); `None`: never
    /// cache this source's survey.
    fn identity(&self) -> Option<String>;
}

/// One resident brick: its voxels, x fastest, and its size (smaller than the brick edge at the
/// grid's far faces).
#[derive(Debug)]
pub struct Brick {
    pub voxels: Voxels,
    pub size: UVec3,
}

/// What one streaming pass over every brick found (values as stored, before the grid's
/// intensity scaling).
#[derive(Debug, Clone, PartialEq)]
pub struct Survey {
    /// Macrocell edge the ranges are for.
    pub cell_size: u32,
    /// Per macrocell (x fastest), the smallest and largest stored value interpolation can reach
    /// in it: its voxels and a one-voxel halo, as `majorant::ValueRanges` defines it.
    pub cell_ranges: Vec<(f32, f32)>,
    /// Smallest and largest stored value of the whole grid.
    pub range: (f32, f32),
    /// The stored values at every `stride`-th voxel along each axis (the automatic scene's
    /// histogram sample), in no particular order.
    pub stride: u32,
    pub sample: Vec<f32>,
}

/// Voxels paged in from a [`BrickSource`] within a memory budget (see the module docs).
pub struct Bricks {
    /// Distinguishes this grid in the per-thread shortcut (never reused in a process).
    id: u64,
    dims: UVec3,
    brick: UVec3,
    /// log2 of each brick edge, where all three are powers of two (a shift, not a division).
    shift: Option<UVec3>,
    counts: UVec3,
    source: Arc<dyn BrickSource>,
    slots: Box<[ArcSwapOption<Brick>]>,
    used: Box<[AtomicBool]>,
    resident_bytes: AtomicU64,
    budget: u64,
    /// The bytes bricks may take: the budget less the page table and the majorant structures
    /// ([`fixed_bytes`]).
    capacity: u64,
    bytes_per_voxel: usize,
    clock_hand: Mutex<usize>,
    loads: AtomicU64,
    failure: OnceLock<String>,
    surveys: Mutex<Vec<Arc<Survey>>>,
}

impl std::fmt::Debug for Bricks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bricks")
            .field("source", &self.source.name())
            .field("dims", &self.dims)
            .field("brick", &self.brick)
            .field("budget", &self.budget)
            .finish_non_exhaustive()
    }
}

/// The smallest brick edge kept: thinner chunks (a microscope's single planes) are grouped so
/// that a free flight does not change brick at every step.
const MIN_BRICK_EDGE: u32 = 16;
/// The largest brick edge: a larger chunk is read in parts (each part decodes the chunk).
const MAX_BRICK_EDGE: u32 = 256;
/// Bricks a streamed volume may have at most (2^24: 512 GiB of uint8 in 32^3 chunks, 256 TiB in
/// 256^3 ones): past it the chunks are too small for the volume, and a store that claims more
/// is refused before its page table is allocated or its chunks listed.
const MAX_BRICKS: u64 = 1 << 24;

/// The brick edge for a chunk edge `chunk` (see [`MIN_BRICK_EDGE`], [`MAX_BRICK_EDGE`]).
pub fn brick_edge(chunk: u32) -> u32 {
    let chunk = chunk.max(1);
    if chunk >= MAX_BRICK_EDGE {
        MAX_BRICK_EDGE
    } else {
        chunk * MIN_BRICK_EDGE.div_ceil(chunk)
    }
}

/// The macrocell edge a streamed grid of `dims` uses unless the scene names one: the in-memory
/// default (8) or larger, so that the majorant grid stays under about 2^24 cells (256 MiB with
/// its ranges and the survey) however large the volume.
pub fn streamed_macrocell(dims: UVec3, default: u32) -> u32 {
    let mut cell = default.max(1);
    let cells =
        |c: u32| dims.x.div_ceil(c) as u64 * dims.y.div_ceil(c) as u64 * dims.z.div_ceil(c) as u64;
    while cells(cell) > 1 << 24 && cell < dims.max_element() {
        cell *= 2;
    }
    cell
}

/// Bricks that must fit at once: two a thread (a lookup's and the next), at least four.
fn min_bricks() -> u64 {
    (2 * rayon::current_num_threads() as u64).max(4)
}

/// Bytes of a streamed grid's memory besides its bricks: the page table (a slot and a flag a
/// brick, and a reading's transient buffers) and the majorant structures at the default
/// streamed macrocell (per cell: the survey's ranges, the grid's scaled copy, the majorants and
/// controls, and the survey pass's accumulators: 40 bytes).
fn fixed_bytes(dims: UVec3, bricks: u64) -> u64 {
    let cell = streamed_macrocell(dims, crate::medium::DEFAULT_MACROCELL);
    let cells =
        dims.x.div_ceil(cell) as u64 * dims.y.div_ceil(cell) as u64 * dims.z.div_ceil(cell) as u64;
    bricks * 73 + cells * 40
}

/// The smallest memory budget a grid of `dims` streamed in chunks of `chunk` voxels (x, y, z)
/// of `bytes_per_voxel` takes: [`fixed_bytes`] and [`min_bricks`] bricks.
pub fn min_budget(dims: UVec3, chunk: UVec3, bytes_per_voxel: usize) -> u64 {
    let brick = UVec3::new(
        brick_edge(chunk.x),
        brick_edge(chunk.y),
        brick_edge(chunk.z),
    )
    .min(dims.max(UVec3::ONE));
    let counts = (dims + brick - 1) / brick;
    let n = counts.x as u64 * counts.y as u64 * counts.z as u64;
    let largest = brick.x as u64 * brick.y as u64 * brick.z as u64 * bytes_per_voxel as u64;
    fixed_bytes(dims, n) + largest * min_bricks()
}

static NEXT_GRID_ID: AtomicU64 = AtomicU64::new(1);

struct LastBrick {
    grid: u64,
    index: usize,
    brick: Arc<Brick>,
}

thread_local! {
    /// The brick this thread used last (see the module docs).
    static LAST_BRICK: RefCell<Option<LastBrick>> = const { RefCell::new(None) };
}

impl Bricks {
    /// A streamed grid of `dims` over `source`, keeping at most about `budget` bytes of voxels
    /// resident. Refuses a chunking too fine for the page table.
    pub fn new(
        dims: UVec3,
        source: Arc<dyn BrickSource>,
        bytes_per_voxel: usize,
        budget: u64,
    ) -> Result<Self> {
        let chunk = source.brick_size();
        let brick = UVec3::new(
            brick_edge(chunk.x),
            brick_edge(chunk.y),
            brick_edge(chunk.z),
        )
        .min(dims.max(UVec3::ONE));
        let counts = UVec3::new(
            dims.x.div_ceil(brick.x),
            dims.y.div_ceil(brick.y),
            dims.z.div_ceil(brick.z),
        );
        let n = counts.x as u64 * counts.y as u64 * counts.z as u64;
        if n > MAX_BRICKS {
            return Err(Error::Invalid(format!(
                "{}: {}x{}x{} voxels in bricks of {}x{}x{} make {n} bricks, more than the \
                 {MAX_BRICKS} a streamed volume may have: expected larger chunks",
                source.name(),
                dims.x,
                dims.y,
                dims.z,
                brick.x,
                brick.y,
                brick.z
            )));
        }
        let needed = min_budget(dims, chunk, bytes_per_voxel);
        if budget < needed {
            return Err(Error::Invalid(format!(
                "{}: a memory budget of {} is too small for {}x{}x{} voxels in bricks of \
                 {}x{}x{} (its page table, majorant ranges and {} bricks): expected a budget \
                 of at least {}",
                source.name(),
                crate::io::human_bytes(budget),
                dims.x,
                dims.y,
                dims.z,
                brick.x,
                brick.y,
                brick.z,
                min_bricks(),
                crate::io::human_bytes(needed)
            )));
        }
        let capacity = budget - fixed_bytes(dims, n);
        let shift =
            (brick.x.is_power_of_two() && brick.y.is_power_of_two() && brick.z.is_power_of_two())
                .then(|| {
                    UVec3::new(
                        brick.x.trailing_zeros(),
                        brick.y.trailing_zeros(),
                        brick.z.trailing_zeros(),
                    )
                });
        Ok(Self {
            id: NEXT_GRID_ID.fetch_add(1, Ordering::Relaxed),
            dims,
            brick,
            shift,
            counts,
            source,
            slots: (0..n).map(|_| ArcSwapOption::empty()).collect(),
            used: (0..n).map(|_| AtomicBool::new(false)).collect(),
            resident_bytes: AtomicU64::new(0),
            budget,
            capacity,
            bytes_per_voxel,
            clock_hand: Mutex::new(0),
            loads: AtomicU64::new(0),
            failure: OnceLock::new(),
            surveys: Mutex::new(Vec::new()),
        })
    }

    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    /// The brick edge per axis.
    pub fn brick_size(&self) -> UVec3 {
        self.brick
    }

    pub fn brick_count(&self) -> usize {
        self.slots.len()
    }

    /// The memory budget for resident voxels, in bytes.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Bytes of voxels resident now.
    pub fn resident_bytes(&self) -> u64 {
        self.resident_bytes.load(Ordering::Relaxed)
    }

    /// Bricks read from the source so far (a brick evicted and read again counts twice).
    pub fn loads(&self) -> u64 {
        self.loads.load(Ordering::Relaxed)
    }

    pub fn bytes_per_voxel(&self) -> usize {
        self.bytes_per_voxel
    }

    /// The stored type's name.
    pub fn type_name(&self) -> &'static str {
        self.source.type_name()
    }

    pub fn source_name(&self) -> String {
        self.source.name()
    }

    /// The first brick that could not be read while rendering, if any: the image that read it
    /// is wrong (its voxels were taken as 0) and must be refused by whoever rendered it.
    pub fn failure(&self) -> Option<&str> {
        self.failure.get().map(String::as_str)
    }

    /// The brick holding voxel `i` and the voxel's position in it.
    #[inline(always)]
    fn locate(&self, i: UVec3) -> (UVec3, UVec3) {
        let b = match self.shift {
            Some(s) => i >> s,
            None => i / self.brick,
        };
        (b, i - b * self.brick)
    }

    #[inline(always)]
    fn flat(&self, b: UVec3) -> usize {
        b.x as usize
            + self.counts.x as usize * (b.y as usize + self.counts.y as usize * b.z as usize)
    }

    /// Runs `f` on brick `index`, through this thread's shortcut to its last brick.
    #[inline(always)]
    fn with_brick<R>(&self, index: usize, f: impl Fn(&Brick) -> R) -> R {
        let hit = LAST_BRICK.with_borrow(|last| match last {
            Some(l) if l.grid == self.id && l.index == index => Some(f(&l.brick)),
            _ => None,
        });
        if let Some(r) = hit {
            return r;
        }
        // The borrow is not held while the brick is fetched: reading a chunk may run other
        // rayon work on this thread, which samples too.
        let brick = self.fetch(index);
        let r = f(&brick);
        LAST_BRICK.with_borrow_mut(|last| {
            *last = Some(LastBrick {
                grid: self.id,
                index,
                brick,
            })
        });
        r
    }

    /// Brick `index`, from its slot or read from the source.
    fn fetch(&self, index: usize) -> Arc<Brick> {
        self.used[index].store(true, Ordering::Relaxed);
        if let Some(brick) = self.slots[index].load_full() {
            return brick;
        }
        let brick = Arc::new(self.read_brick(index).unwrap_or_else(|e| {
            let _ = self.failure.set(e.to_string());
            self.zero_brick(index)
        }));
        self.loads.fetch_add(1, Ordering::Relaxed);
        let previous = self.slots[index].compare_and_swap(&None::<Arc<Brick>>, Some(brick.clone()));
        if let Some(theirs) = previous.as_ref() {
            // Another thread read it first: use theirs, so one copy is resident.
            return theirs.clone();
        }
        let bytes = (brick.voxels.len() * self.bytes_per_voxel) as u64;
        let total = self.resident_bytes.fetch_add(bytes, Ordering::Relaxed) + bytes;
        if total > self.capacity {
            self.evict();
        }
        brick
    }

    /// Empties slots by the clock (second chance) until 7/8 of the capacity is resident; a
    /// thread that finds another sweeping leaves it to them.
    fn evict(&self) {
        let Ok(mut hand) = self.clock_hand.try_lock() else {
            return;
        };
        let target = self.capacity / 8 * 7;
        let n = self.slots.len();
        for _ in 0..2 * n {
            if self.resident_bytes.load(Ordering::Relaxed) <= target {
                break;
            }
            let i = *hand;
            *hand = (i + 1) % n;
            if self.used[i].swap(false, Ordering::Relaxed) {
                continue;
            }
            if let Some(old) = self.slots[i].swap(None) {
                let bytes = (old.voxels.len() * self.bytes_per_voxel) as u64;
                self.resident_bytes.fetch_sub(bytes, Ordering::Relaxed);
            }
        }
    }

    /// The box of brick `index`: its first voxel and its size.
    fn brick_box(&self, index: usize) -> (UVec3, UVec3) {
        let (cx, cy) = (self.counts.x as usize, self.counts.y as usize);
        let b = UVec3::new(
            (index % cx) as u32,
            ((index / cx) % cy) as u32,
            (index / (cx * cy)) as u32,
        );
        let lo = b * self.brick;
        (lo, self.brick.min(self.dims - lo))
    }

    /// Reads brick `index` from the source, checking what came back.
    fn read_brick(&self, index: usize) -> Result<Brick> {
        let (lo, size) = self.brick_box(index);
        let voxels = self.source.read(lo, size)?;
        let expected = size.x as usize * size.y as usize * size.z as usize;
        if voxels.len() != expected || voxels.bytes_per_voxel() != self.bytes_per_voxel {
            return Err(Error::Invalid(format!(
                "{}: the brick at voxel {lo} came back with {} voxels of {} bytes: expected \
                 {expected} of {}",
                self.source.name(),
                voxels.len(),
                voxels.bytes_per_voxel(),
                self.bytes_per_voxel
            )));
        }
        if let Voxels::F32(v) = &voxels
            && let Some(k) = v.iter().position(|x| !x.is_finite())
        {
            let at = lo
                + UVec3::new(
                    (k % size.x as usize) as u32,
                    ((k / size.x as usize) % size.y as usize) as u32,
                    (k / (size.x as usize * size.y as usize)) as u32,
                );
            return Err(Error::Invalid(format!(
                "{}: voxel {at} is {}: every voxel must be a finite number",
                self.source.name(),
                v[k]
            )));
        }
        Ok(Brick { voxels, size })
    }

    /// A brick of zeros standing for one that could not be read (the failure is recorded).
    fn zero_brick(&self, index: usize) -> Brick {
        let (_, size) = self.brick_box(index);
        let n = size.x as usize * size.y as usize * size.z as usize;
        let voxels = match self.bytes_per_voxel {
            1 => Voxels::U8(vec![0; n]),
            2 => Voxels::U16(vec![0; n]),
            _ => Voxels::F32(vec![0.0; n]),
        };
        Brick { voxels, size }
    }

    /// The voxels of the box `lo .. lo + size` (inside the grid), x fastest, read brick by
    /// brick (for converting a streamed volume; a brick that cannot be read is an error).
    pub fn copy_box(&self, lo: UVec3, size: UVec3) -> Result<Voxels> {
        let hi = lo + size - 1;
        let (first, _) = self.locate(lo);
        let (last, _) = self.locate(hi);
        let n = size.x as usize * size.y as usize * size.z as usize;
        let mut parts: Vec<(UVec3, UVec3, Arc<Brick>)> = Vec::new();
        for bz in first.z..=last.z {
            for by in first.y..=last.y {
                for bx in first.x..=last.x {
                    let b = UVec3::new(bx, by, bz);
                    let index = self.flat(b);
                    let brick = match self.slots[index].load_full() {
                        Some(brick) => brick,
                        None => Arc::new(self.read_brick(index)?),
                    };
                    parts.push((b * self.brick, brick.size, brick));
                }
            }
        }
        // Gathered as f32 (exact for every stored type), then narrowed back to it.
        let mut out = vec![0.0f32; n];
        for (origin, bsize, brick) in &parts {
            let a = lo.max(*origin);
            let b = hi.min(*origin + *bsize - 1);
            for z in a.z..=b.z {
                for y in a.y..=b.y {
                    for x in a.x..=b.x {
                        let l = UVec3::new(x, y, z) - *origin;
                        let k = l.x as usize
                            + bsize.x as usize * (l.y as usize + bsize.y as usize * l.z as usize);
                        let o = (x - lo.x) as usize
                            + size.x as usize
                                * ((y - lo.y) as usize + size.y as usize * (z - lo.z) as usize);
                        out[o] = brick.voxels.get(k);
                    }
                }
            }
        }
        Ok(match self.type_name() {
            "uint8" => Voxels::U8(out.into_iter().map(|v| v as u8).collect()),
            "int8" => Voxels::I8(out.into_iter().map(|v| v as i8).collect()),
            "uint16" => Voxels::U16(out.into_iter().map(|v| v as u16).collect()),
            "int16" => Voxels::I16(out.into_iter().map(|v| v as i16).collect()),
            _ => Voxels::F32(out),
        })
    }

    /// The stored value of voxel `i` (inside the grid). Not inlined into the grid's lookups:
    /// an in-memory grid's hot path stays as small as it was before streaming existed.
    #[inline(never)]
    pub fn stored(&self, i: UVec3) -> f32 {
        let (b, local) = self.locate(i);
        self.with_brick(self.flat(b), |brick| {
            let k = local.x as usize
                + brick.size.x as usize
                    * (local.y as usize + brick.size.y as usize * local.z as usize);
            brick.voxels.get(k)
        })
    }

    /// The stored values of the eight voxels of a trilinear lookup from `i0` to `i1` (each
    /// coordinate of `i1` is that of `i0` or one more), in the in-memory grid's order. Not
    /// inlined (see [`Bricks::stored`]).
    #[inline(never)]
    pub fn corners(&self, i0: UVec3, i1: UVec3) -> [f32; 8] {
        let (b, local0) = self.locate(i0);
        let local1 = local0 + (i1 - i0);
        if local1.cmplt(self.brick).all() {
            return self.with_brick(self.flat(b), |brick| {
                let sy = brick.size.x as usize;
                let sz = sy * brick.size.y as usize;
                let corner = crate::grid::Corner {
                    base: local0.x as usize + sy * local0.y as usize + sz * local0.z as usize,
                    dx: (i1.x - i0.x) as usize,
                    dy: (i1.y - i0.y) as usize * sy,
                    dz: (i1.z - i0.z) as usize * sz,
                };
                crate::grid::gather_voxels(&brick.voxels, corner)
            });
        }
        // Straddling bricks: voxel by voxel, in the same order.
        let at = |x: u32, y: u32, z: u32| self.stored(UVec3::new(x, y, z));
        [
            at(i0.x, i0.y, i0.z),
            at(i1.x, i0.y, i0.z),
            at(i0.x, i1.y, i0.z),
            at(i1.x, i1.y, i0.z),
            at(i0.x, i0.y, i1.z),
            at(i1.x, i0.y, i1.z),
            at(i0.x, i1.y, i1.z),
            at(i1.x, i1.y, i1.z),
        ]
    }

    /// The survey for macrocells of `cell_size` (clamped as `majorant::ValueRanges` clamps it)
    /// and histogram stride `stride`: from this grid's memory, the cache folder, or a pass over
    /// every brick (kept in both).
    pub fn survey(&self, cell_size: u32, stride: u32) -> Result<Arc<Survey>> {
        let cell_size = cell_size.clamp(1, self.dims.max_element());
        let mut kept = self.surveys.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(s) = kept
            .iter()
            .find(|s| s.cell_size == cell_size && s.stride == stride)
        {
            return Ok(s.clone());
        }
        let key = self.source.identity().map(|id| {
            format!(
                "{id}|dims {}|brick {}|bytes {}|cell {cell_size}|stride {stride}",
                self.dims, self.brick, self.bytes_per_voxel
            )
        });
        let cached = key.as_deref().and_then(load_survey);
        let survey = Arc::new(match cached {
            Some(s) => s,
            None => {
                let s = self.survey_pass(cell_size, stride)?;
                if let Some(key) = &key {
                    store_survey(key, &s);
                }
                s
            }
        });
        kept.push(survey.clone());
        Ok(survey)
    }

    /// Streams every brick once (see [`Bricks::survey`]); bricks that fit the budget stay
    /// resident, so a volume that fits is warm after it.
    fn survey_pass(&self, cell_size: u32, stride: u32) -> Result<Survey> {
        let dims = self.dims;
        let cells = UVec3::new(
            dims.x.div_ceil(cell_size),
            dims.y.div_ceil(cell_size),
            dims.z.div_ceil(cell_size),
        );
        let cell_count = cells.x as usize * cells.y as usize * cells.z as usize;
        let lows: Vec<AtomicU32> = (0..cell_count)
            .map(|_| AtomicU32::new(f32::INFINITY.to_bits()))
            .collect();
        let highs: Vec<AtomicU32> = (0..cell_count)
            .map(|_| AtomicU32::new(f32::NEG_INFINITY.to_bits()))
            .collect();
        let samples: Vec<Vec<f32>> = (0..self.slots.len())
            .into_par_iter()
            .map(|index| -> Result<Vec<f32>> {
                let (lo, size) = self.brick_box(index);
                // A brick no chunk of the store holds is the fill value throughout: one voxel
                // read gives it (a store that claims a huge array and holds little data is
                // surveyed in time proportional to its bricks, not its voxels).
                let brick = if self.source.is_absent(lo, size) {
                    let one = self.source.read(lo, UVec3::ONE)?;
                    Surveyed::Constant(one.get(0))
                } else {
                    Surveyed::Read(self.read_brick(index)?)
                };
                let hi = lo + size - 1;
                // Cells whose reach [c*B - 1, (c+1)*B] meets this brick.
                let first = (lo / cell_size).saturating_sub(UVec3::ONE);
                let last = ((hi + 1) / cell_size).min(cells - 1);
                for cz in first.z..=last.z {
                    for cy in first.y..=last.y {
                        for cx in first.x..=last.x {
                            let c = UVec3::new(cx, cy, cz);
                            let reach_lo = (c * cell_size).saturating_sub(UVec3::ONE);
                            let reach_hi = (c + 1).saturating_mul(UVec3::splat(cell_size));
                            let (a, b) = (reach_lo.max(lo), reach_hi.min(hi));
                            if a.cmpgt(b).any() {
                                continue;
                            }
                            let (mn, mx) = match &brick {
                                Surveyed::Read(brick) => brick_range(brick, a - lo, b - lo),
                                Surveyed::Constant(v) => (*v, *v),
                            };
                            let k = cx as usize
                                + cells.x as usize * (cy as usize + cells.y as usize * cz as usize);
                            atomic_min(&lows[k], mn);
                            atomic_max(&highs[k], mx);
                        }
                    }
                }
                let mut sample = Vec::new();
                let s = stride as usize;
                let start = |l: u32| (l as usize).div_ceil(s) * s - l as usize;
                let (sx, sy) = (size.x as usize, size.y as usize);
                for z in (start(lo.z)..size.z as usize).step_by(s) {
                    for y in (start(lo.y)..sy).step_by(s) {
                        for x in (start(lo.x)..sx).step_by(s) {
                            sample.push(match &brick {
                                Surveyed::Read(brick) => brick.voxels.get(x + sx * (y + sy * z)),
                                Surveyed::Constant(v) => *v,
                            });
                        }
                    }
                }
                if let Surveyed::Read(brick) = brick {
                    self.keep_if_room(index, brick);
                }
                Ok(sample)
            })
            .collect::<Result<_>>()?;
        let cell_ranges: Vec<(f32, f32)> = lows
            .iter()
            .zip(&highs)
            .map(|(l, h)| {
                (
                    f32::from_bits(l.load(Ordering::Relaxed)),
                    f32::from_bits(h.load(Ordering::Relaxed)),
                )
            })
            .collect();
        let range = cell_ranges
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &(l, h)| {
                (a.min(l), b.max(h))
            });
        Ok(Survey {
            cell_size,
            cell_ranges,
            range,
            stride,
            sample: samples.concat(),
        })
    }

    /// Puts a brick read by the survey into its slot while the budget has room for it.
    fn keep_if_room(&self, index: usize, brick: Brick) {
        let bytes = (brick.voxels.len() * self.bytes_per_voxel) as u64;
        let total = self.resident_bytes.fetch_add(bytes, Ordering::Relaxed) + bytes;
        if total > self.capacity / 8 * 7
            || self.slots[index]
                .compare_and_swap(&None::<Arc<Brick>>, Some(Arc::new(brick)))
                .is_some()
        {
            self.resident_bytes.fetch_sub(bytes, Ordering::Relaxed);
        } else {
            self.loads.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// A brick as the survey saw it.
enum Surveyed {
    Read(Brick),
    /// No chunk holds it: the fill value throughout.
    Constant(f32),
}

/// Smallest and largest stored value in the box `a..=b` of a brick (local coordinates).
fn brick_range(brick: &Brick, a: UVec3, b: UVec3) -> (f32, f32) {
    let (sx, sy) = (brick.size.x as usize, brick.size.y as usize);
    let mut r = (f32::INFINITY, f32::NEG_INFINITY);
    for z in a.z..=b.z {
        for y in a.y..=b.y {
            let start = a.x as usize + sx * (y as usize + sy * z as usize);
            r = crate::grid::fold_range(&brick.voxels, start..start + (b.x - a.x) as usize + 1, r);
        }
    }
    r
}

fn atomic_min(cell: &AtomicU32, v: f32) {
    let _ = cell.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |old| {
        (v < f32::from_bits(old)).then_some(v.to_bits())
    });
}

fn atomic_max(cell: &AtomicU32, v: f32) {
    let _ = cell.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |old| {
        (v > f32::from_bits(old)).then_some(v.to_bits())
    });
}

/// The cache folder [`set_cache_folder`] chose: `None` while unset.
static CACHE_FOLDER: Mutex<Option<Option<PathBuf>>> = Mutex::new(None);

/// Sets this process's cache folder (surveys go in its `surveys` folder); `Some(None)` keeps no
/// cache, `None` returns to the default (see [`survey_cache_folder`]).
pub fn set_cache_folder(folder: Option<Option<PathBuf>>) {
    *CACHE_FOLDER.lock().unwrap_or_else(|p| p.into_inner()) = folder;
}

/// The folder surveys are kept in: under the folder [`set_cache_folder`] set, else
/// `$GSCACHE_CACHE_DIR`, else `$XDG_CACHE_HOME/gscache`, else `~/.cache/gscache`;
/// `GSCACHE_CACHE_DIR=none` keeps none (each run surveys the store again).
pub fn survey_cache_folder() -> Option<PathBuf> {
    if let Some(chosen) = CACHE_FOLDER
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .clone()
    {
        return chosen.map(|d| d.join("surveys"));
    }
    match std::env::var_os("GSCACHE_CACHE_DIR") {
        Some(d) if d == "none" => None,
        Some(d) if !d.is_empty() => Some(PathBuf::from(d)),
        _ => std::env::var_os("XDG_CACHE_HOME")
            .filter(|d| !d.is_empty())
            .map(|d| PathBuf::from(d).join("gscache"))
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/gscache"))),
    }
    .map(|d| d.join("surveys"))
}

const SURVEY_MAGIC: &[u8; 8] = b"GSSURV01";

fn survey_file(key: &str) -> Option<PathBuf> {
    let hash = render_base::hash::fnv1a64(key.as_bytes(), 0xcbf2_9ce4_8422_2325);
    Some(survey_cache_folder()?.join(format!("{hash:016x}.survey")))
}

/// A kept survey whose stored key is `key` (a file that does not match or is damaged is
/// ignored: the store is surveyed again).
fn load_survey(key: &str) -> Option<Survey> {
    let bytes = std::fs::read(survey_file(key)?).ok()?;
    let mut r = Reader(bytes.strip_prefix(SURVEY_MAGIC)?);
    let key_len = r.u64()? as usize;
    if r.take(key_len)? != key.as_bytes() {
        return None;
    }
    let cell_size = u32::try_from(r.u64()?).ok()?;
    let stride = u32::try_from(r.u64()?).ok()?;
    let cells = r.u64()? as usize;
    let samples = r.u64()? as usize;
    let ranges = r.floats(cells.checked_mul(2)?)?;
    let sample = r.floats(samples)?;
    let cell_ranges: Vec<(f32, f32)> = ranges.chunks_exact(2).map(|p| (p[0], p[1])).collect();
    let range = cell_ranges
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &(l, h)| {
            (a.min(l), b.max(h))
        });
    Some(Survey {
        cell_size,
        cell_ranges,
        range,
        stride,
        sample,
    })
}

/// Reads a kept survey's fields in order; `None` past its end.
struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let (head, tail) = self.0.split_at_checked(n)?;
        self.0 = tail;
        Some(head)
    }

    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }

    fn floats(&mut self, n: usize) -> Option<Vec<f32>> {
        let bytes = self.take(n.checked_mul(4)?)?;
        Some(
            bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    }
}

/// Keeps a survey under `key` (written to a temporary file and renamed, so a reader never sees
/// half of one); a folder that cannot be written is passed over silently: the cache only saves
/// time.
fn store_survey(key: &str, s: &Survey) {
    let Some(path) = survey_file(key) else {
        return;
    };
    let mut out = Vec::with_capacity(48 + key.len() + s.cell_ranges.len() * 8 + s.sample.len() * 4);
    out.extend_from_slice(SURVEY_MAGIC);
    out.extend_from_slice(&(key.len() as u64).to_le_bytes());
    out.extend_from_slice(key.as_bytes());
    for n in [
        s.cell_size as u64,
        s.stride as u64,
        s.cell_ranges.len() as u64,
        s.sample.len() as u64,
    ] {
        out.extend_from_slice(&n.to_le_bytes());
    }
    for &(l, h) in &s.cell_ranges {
        out.extend_from_slice(&l.to_le_bytes());
        out.extend_from_slice(&h.to_le_bytes());
    }
    for v in &s.sample {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let Some(folder) = path.parent() else {
        return;
    };
    if std::fs::create_dir_all(folder).is_err() {
        return;
    }
    let temporary = path.with_extension(format!("tmp{}", std::process::id()));
    if std::fs::write(&temporary, &out).is_ok() && std::fs::rename(&temporary, &path).is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
}

/// An in-memory grid served as bricks of a chosen size: for tests (a streamed render against
/// the same voxels read whole) and benchmarks.
#[derive(Debug)]
pub struct WholeGrid {
    pub dims: UVec3,
    pub voxels: Arc<Voxels>,
    pub brick: UVec3,
}

impl BrickSource for WholeGrid {
    fn name(&self) -> String {
        format!(
            "an in-memory grid of {}x{}x{}",
            self.dims.x, self.dims.y, self.dims.z
        )
    }

    fn brick_size(&self) -> UVec3 {
        self.brick
    }

    fn type_name(&self) -> &'static str {
        self.voxels.type_name()
    }

    fn read(&self, lo: UVec3, size: UVec3) -> Result<Voxels> {
        Ok(self.voxels.copy_box(self.dims, lo, size))
    }

    fn identity(&self) -> Option<String> {
        None
    }
}
