//! A row of pixels walking its band's list of Gaussians once, front to back: each chunk's
//! chords on the row, and the pixels' rays evaluated in windows of [`LANES`] from a chord's
//! first.

use super::*;

/// One row's working memory, kept from row to row of a thread. The arrays read in lanes have
/// [`LANES`] - 1 pixels of padding past the row's end: a chord's window of [`LANES`] pixels
/// starts at any pixel of the row.
pub(super) struct Row {
    /// Each pixel's transmittance so far.
    pub(super) transmittance: Vec<f32>,
    /// Each pixel's next threshold ([`draw_thresholds`]): the transmittance falling below it
    /// fills a slot.
    pub(super) next: Vec<f32>,
    /// Each pixel's slots' thresholds ([`draw_thresholds`]), `slots` a pixel.
    pub(super) thresholds: Vec<f32>,
    /// Each pixel's slots filled (with a hit).
    pub(super) filled: Vec<usize>,
    /// Each pixel's filled slots' colours summed.
    pub(super) colour: Vec<Vec3>,
    /// Each pixel's 1 while it takes part, 0 once its slots are all filled (and in the
    /// padding): a window's [`LANES`] of them read as one word ([`taking_part_bits`]).
    pub(super) taking_part: Vec<u8>,
    /// Each pixel's estimates summed.
    pub(super) sums: Vec<DVec3>,
}

impl Row {
    /// Every pixel of row `y` at the start of `sample`: its slots' numbers drawn, none filled,
    /// the transmittance 1. Inlined into the walk, in its lanes' instruction set.
    #[inline(always)]
    pub(super) fn start<L: Lanes>(&mut self, token: L::Token, walk: &Walk, y: u32, sample: u32) {
        let width = walk.width;
        self.transmittance.fill(1.0);
        self.filled.fill(0);
        self.colour.fill(Vec3::ZERO);
        self.taking_part[..width].fill(1);
        for (x, thresholds) in self.thresholds.chunks_exact_mut(walk.slots).enumerate() {
            let key = SampleKey::new(walk.seed, y * width as u32 + x as u32, sample);
            self.next[x] = draw_thresholds::<L>(token, &key, thresholds);
        }
    }

    pub(super) fn new(walk: &Walk) -> Self {
        let padded = walk.width + LANES - 1;
        Self {
            transmittance: vec![1.0; padded],
            next: vec![-1.0; padded],
            thresholds: vec![0.0; walk.width * walk.slots],
            filled: vec![0; walk.width],
            colour: vec![Vec3::ZERO; walk.width],
            taking_part: vec![0; padded],
            sums: vec![DVec3::ZERO; walk.width],
        }
    }
}

/// What every row's walk reads.
pub(super) struct Walk<'a> {
    pub(super) grid: &'a ScreenGrid,
    pub(super) plane: RayDirections,
    /// Each column's ray on the camera's plane z = 1 (its x), with [`Row`]'s padding (whose
    /// lanes never take part).
    pub(super) columns: Vec<f32>,
    pub(super) width: usize,
    pub(super) slots: usize,
    pub(super) seed: u32,
    pub(super) background: Vec3,
}

impl<'a> Walk<'a> {
    pub(super) fn new(
        grid: &'a ScreenGrid,
        camera: &Camera,
        samples_per_traversal: u32,
        seed: u32,
        background: Vec3,
    ) -> Self {
        let plane = camera.ray_directions();
        let width = camera.width as usize;
        let columns = (0..width + LANES - 1)
            .map(|x| plane.on_plane(x as f32 + 0.5, 0.5)[0])
            .collect();
        Self {
            grid,
            plane,
            columns,
            width,
            slots: slot_count(samples_per_traversal),
            seed,
            background,
        }
    }

    /// Estimate `sample` for each pixel of row `y`, added to the row's sums. The row's band is
    /// walked front to back once for all its rays; a ray takes part until every slot is
    /// filled, and the walk stops when no ray takes part. Each ray meets exactly the Gaussians
    /// [`reference_image`] finds on it, in the same order, with the same alphas.
    #[inline(always)]
    pub(super) fn estimate<L: Lanes>(&self, token: L::Token, row: &mut Row, y: u32, sample: u32) {
        let (slots, width) = (self.slots, self.width);
        row.start::<L>(token, self, y, sample);
        let mut left = width;
        let w = self.plane.on_plane(0.5, y as f32 + 0.5)[1];
        let (mut first, mut last) = ([0u32; LANES], [0u32; LANES]);
        for chunk in self.grid.band(y / BAND) {
            if left == 0 {
                break;
            }
            // The chunk's chords on this row in lanes; then its Gaussians that meet the row, in
            // depth order.
            let mut meets = chunk.chords::<L>(token, y, &mut first, &mut last);
            while meets != 0 {
                let l = meets.trailing_zeros() as usize;
                meets &= meets - 1;
                let facing = &self.grid.facing[chunk.rank[l] as usize];
                let on_row = FacingRow::new(facing, w);
                self.walk_chord::<L>(
                    token,
                    (
                        (first[l] - PIXEL_BIAS_BITS) as usize,
                        (last[l] - PIXEL_BIAS_BITS) as usize,
                    ),
                    facing.color,
                    &on_row,
                    row,
                    &mut left,
                );
            }
        }
        let Row {
            filled,
            colour,
            sums,
            ..
        } = row;
        for (x, sum) in sums.iter_mut().enumerate() {
            *sum += estimate(colour[x], filled[x], slots, self.background).as_dvec3();
        }
    }

    /// One Gaussian on the pixels `from..=to` of a row: each taking part moves its
    /// transmittance, and fills its slots where it falls below its next threshold. The chord
    /// is walked in windows of [`LANES`] pixels from `from` (not in groups aligned to the
    /// row), so that a chord of `n` pixels takes `ceil(n / LANES)` evaluations: a window's
    /// lanes past `to` miss the Gaussian, their alpha 0.
    #[inline(always)]
    pub(super) fn walk_chord<L: Lanes>(
        &self,
        token: L::Token,
        (from, to): (usize, usize),
        color: Vec3,
        on_row: &FacingRow,
        row: &mut Row,
        left: &mut usize,
    ) {
        let slots = self.slots;
        let Row {
            transmittance,
            next,
            thresholds,
            filled,
            colour,
            taking_part,
            ..
        } = row;
        for start in (from..=to).step_by(LANES) {
            let alive = taking_part_bits(&taking_part[start..start + LANES]);
            if alive == 0 {
                continue;
            }
            // Every lane's transmittance moves (a miss's alpha is 0, which leaves it as it
            // was, bit for bit); the lanes that fall below their next threshold fill slots.
            let mut crossed = 0u8;
            let (columns, here, next_here) = (
                &self.columns[start..start + LANES],
                &mut transmittance[start..start + LANES],
                &next[start..start + LANES],
            );
            for first in (0..LANES).step_by(L::N) {
                let alpha = on_row.alpha::<L>(token, L::load(token, &columns[first..]));
                let t = L::load(token, &here[first..]);
                let t = t * (L::splat(token, 1.0) - alpha);
                t.store(&mut here[first..]);
                crossed |= (L::bits(t.lt(L::load(token, &next_here[first..]))) << first) as u8;
            }
            crossed &= alive;
            while crossed != 0 {
                let x = start + crossed.trailing_zeros() as usize;
                crossed &= crossed - 1;
                let own = &thresholds[x * slots..(x + 1) * slots];
                next[x] = fill_slots::<L>(
                    token,
                    own,
                    &mut filled[x],
                    &mut colour[x],
                    transmittance[x],
                    color,
                );
                let done = filled[x] == slots;
                taking_part[x] &= !done as u8;
                *left -= done as usize;
            }
        }
    }

    /// [`Walk::estimate`] in `isa`'s lanes.
    pub(super) fn estimate_on(&self, isa: Isa, row: &mut Row, y: u32, sample: u32) {
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: an `Avx2Token` exists only where the processor runs AVX2 and FMA
            // (`Avx2Token::detect`), which is all `estimate_avx2_fma` requires.
            Isa::Avx2Fma(token) => unsafe { self.estimate_avx2_fma(token, row, y, sample) },
            Isa::Baseline => self.estimate::<Baseline>((), row, y, sample),
        }
    }

    /// [`Walk::estimate`] compiled for AVX2 and FMA, in their lanes.
    ///
    /// # Safety
    /// The processor must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn estimate_avx2_fma(
        &self,
        token: Avx2Token,
        row: &mut Row,
        y: u32,
        sample: u32,
    ) {
        self.estimate::<Avx2>(token, row, y, sample)
    }
}
