//! The screen grid: the Gaussians in front of the camera sorted by centre depth and listed,
//! eight to a chunk, in the bands of rows their silhouettes reach.

use super::*;

/// The Gaussians in front of the camera, sorted by centre depth (ties by index), and per band
/// of rows the ones whose silhouettes may reach it, in that order.
#[derive(Default)]
pub(super) struct ScreenGrid {
    /// Each rank's terms for its alphas on the camera's rays.
    pub(super) facing: Vec<Facing>,
    /// Band `b`'s Gaussians are `listed[starts[b]..starts[b + 1]]`, in depth order, a
    /// [`LANES`] of them a chunk: a row reads its band's in order, not scattered over the
    /// ranks, and solves a chunk's chords together.
    pub(super) starts: Vec<usize>,
    pub(super) listed: Vec<ListedChunk>,
    /// The building's working memory, kept for the next camera or cloud.
    pub(super) scratch: GridScratch,
}

/// What [`ScreenGrid::rebuild`] makes and drops: kept so that a grid rebuilt every frame
/// writes to memory it already has (fresh, it cost the kernel a page fault each 4 KiB).
#[derive(Default)]
pub(super) struct GridScratch {
    pub(super) keys: Vec<u64>,
    pub(super) sort: Vec<u64>,
    pub(super) order: Vec<u32>,
    /// Each rank's place on the screen; `None` off the screen.
    pub(super) placed: Vec<Option<Placed>>,
    pub(super) next: Vec<usize>,
}

/// [`LANES`] Gaussians of a band's list, by lane: their ranks, and what their chords on a row
/// need ([`Placed::chord_terms`]). Lanes past the end of the list meet no row.
#[derive(Clone, Copy)]
pub(super) struct ListedChunk {
    pub(super) rank: [u32; LANES],
    /// The first and last row (inclusive) each may cover; +inf and -inf in an empty lane.
    pub(super) rows: [[f32; LANES]; 2],
    /// The first and last column (inclusive).
    pub(super) columns: [[f32; LANES]; 2],
    /// The silhouette's centre, x and y.
    pub(super) centre: [[f32; LANES]; 2],
    /// [`Placed::chord_terms`].
    pub(super) terms: [[f32; LANES]; 3],
}

impl ListedChunk {
    const EMPTY: Self = Self {
        rank: [0; LANES],
        rows: [[f32::INFINITY; LANES], [f32::NEG_INFINITY; LANES]],
        columns: [[0.0; LANES]; 2],
        centre: [[0.0; LANES]; 2],
        terms: [[0.0; LANES]; 3],
    };

    pub(super) fn set(&mut self, lane: usize, rank: u32, p: &Placed) {
        self.rank[lane] = rank;
        for k in 0..2 {
            self.rows[k][lane] = p.rows[k] as f32;
            self.columns[k][lane] = p.columns[k] as f32;
            self.centre[k][lane] = p.centre[k];
        }
        for k in 0..3 {
            self.terms[k][lane] = p.chord_terms[k];
        }
    }

    /// The lanes whose Gaussians meet a pixel of row `y` (a bit each), with the first and last
    /// pixel they may meet there, `ceil(lo)..=floor(hi)`, as the bits of those whole numbers
    /// plus [`PIXEL_BIAS`]. A bounded silhouette (`k2 > 0`) is narrowed to the ellipse's
    /// chord at the row's centre, `dx = k3 dy +- sqrt(k1 dy^2 + k2)`, a pixel wider each way
    /// (pixel x's centre is x + 0.5); the rest keep their rectangle's columns. Plain multiplies
    /// and adds (no fused multiply-adds), so AVX2 and the baseline's lanes give the same
    /// chords.
    #[inline(always)]
    pub(super) fn chords<L: Lanes>(
        &self,
        token: L::Token,
        y: u32,
        first_pixel: &mut [u32; LANES],
        last_pixel: &mut [u32; LANES],
    ) -> u32 {
        let c = |v: f32| L::splat(token, v);
        let (row, centre) = (y as f32, y as f32 + 0.5);
        let mut meets = 0;
        for first in (0..LANES).step_by(L::N) {
            let load = |v: &[f32; LANES]| L::load(token, &v[first..]);
            let in_rows = load(&self.rows[0]).le(c(row)) & c(row).le(load(&self.rows[1]));
            let [k1, k2, k3] = self.terms.each_ref().map(load);
            let (columns_from, columns_to) = (load(&self.columns[0]), load(&self.columns[1]));
            let dy = c(centre) - load(&self.centre[1]);
            let squared = dy * dy * k1 + k2;
            let (mid, half) = (load(&self.centre[0]) + dy * k3, squared.sqrt());
            // NaN (no chord) fails `le` and `ge`; `max` and `min` give their second operand,
            // so `lo` and `hi` are in the rectangle's columns, 0..=32767 (`MAX_IMAGE_SIDE`).
            let bounded = k2.gt(c(0.0));
            let lo = L::select(
                bounded,
                (mid - half - c(1.5)).max(columns_from),
                columns_from,
            );
            let hi = L::select(bounded, (mid + half + c(0.5)).min(columns_to), columns_to);
            // Adding 2^23 rounds to the nearest whole number, exactly (the spacing of floats
            // there is 1); one more or less where that went the wrong way.
            let bias = c(PIXEL_BIAS);
            let (lo_near, hi_near) = (lo + bias, hi + bias);
            let from = L::select((lo_near - bias).lt(lo), lo_near + c(1.0), lo_near);
            let to = L::select((hi_near - bias).gt(hi), hi_near - c(1.0), hi_near);
            let chord = squared.ge(c(0.0)) | L::and_not(in_rows, bounded);
            from.store_bits(&mut first_pixel[first..]);
            to.store_bits(&mut last_pixel[first..]);
            meets |= L::bits(in_rows & chord & from.le(to)) << first;
        }
        meets
    }
}

impl ScreenGrid {
    /// The grid of `g` seen by `camera`, in the memory this grid holds.
    pub(super) fn rebuild(&mut self, g: &TraceGaussians, camera: &Camera) {
        let bands = camera.height.div_ceil(BAND) as usize;
        let forward = camera.axes().2;
        let screen = Screen::new(camera);
        let isa = Isa::detect();
        let GridScratch {
            keys,
            sort,
            order,
            placed,
            next,
        } = &mut self.scratch;
        // The Gaussians in front of the camera by depth, ties by index: one order on any
        // thread count. A positive depth's bits order as it does ([`depth_order`]'s keys).
        let depth = |i: usize| depth_of(g, camera, forward, i);
        keys.clear();
        keys.extend((0..g.len()).filter_map(|i| {
            let d = depth(i);
            (d > 0.0).then_some((d.to_bits() as u64) << 32 | i as u64)
        }));
        order.clear();
        order.resize(keys.len(), 0);
        depth_order(keys, sort, order);
        // Then placed and faced (the silhouette and the facing terms share their canonical
        // frame) in that order, straight into the grid's arrays; every entry is overwritten,
        // so only a longer array's new tail is filled first.
        placed.resize(order.len(), None);
        self.facing.resize(order.len(), Facing::default());
        placed
            .par_chunks_mut(PLACE_BLOCK)
            .zip(self.facing.par_chunks_mut(PLACE_BLOCK))
            .zip(order.par_chunks(PLACE_BLOCK))
            .for_each(|((placed, facing), ranked)| {
                screen.place_block_on(isa, g, &depth, ranked, placed, facing)
            });

        // A counting sort of the ranks by band, each band's in rank order, each band's list
        // padded to whole chunks.
        let bands_of = |p: &Placed| (p.rows[0] / BAND) as usize..=(p.rows[1] / BAND) as usize;
        let starts = &mut self.starts;
        starts.clear();
        starts.resize(bands + 1, 0);
        for p in placed.iter().flatten() {
            for b in bands_of(p) {
                starts[b + 1] += 1;
            }
        }
        for b in 0..bands {
            starts[b + 1] = starts[b] + starts[b + 1].div_ceil(LANES) * LANES;
        }
        self.listed.clear();
        self.listed
            .resize(starts[bands] / LANES, ListedChunk::EMPTY);
        next.clear();
        next.extend_from_slice(&starts[..bands]);
        for (rank, p) in placed.iter().enumerate() {
            let Some(p) = p else { continue };
            for b in bands_of(p) {
                self.listed[next[b] / LANES].set(next[b] % LANES, rank as u32, p);
                next[b] += 1;
            }
        }
    }

    /// Band `b`'s Gaussians, front to back, in chunks.
    pub(super) fn band(&self, b: u32) -> &[ListedChunk] {
        &self.listed[self.starts[b as usize] / LANES..self.starts[b as usize + 1] / LANES]
    }
}
