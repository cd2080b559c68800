//! Dense products for the network's thin matrices: `out += a @ b` tiled in registers, a dot
//! product, a transpose. The network's layers are 16 to 64 wide and a block is 128 rows, so
//! every operand stays in the first-level cache; what decides the speed is how many loads each
//! multiply-add costs, which the 4-row by 16-column register tile sets (6 loads for 64
//! multiply-adds).
//!
//! **The same bits on every machine.** Products and sums are separate operations, never a fused
//! multiply-add, and each sum runs in the order written here (LLVM does not reorder
//! floating-point arithmetic). The kernels are compiled twice, for the baseline instruction set
//! and for AVX2 (see [`has_avx2`]); both compute the same bits, only in wider registers.

/// Rows of `a` (and `out`) a register tile covers.
const TILE_ROWS: usize = 4;
/// Columns of `b` (and `out`) a register tile covers: two AVX2 registers, four SSE ones.
const TILE_COLS: usize = 16;

/// `out += a @ b` for `a` of `m x k`, `b` of `k x n` and `out` of `m x n`, all row-major. Each
/// entry of `out` adds its `k` products in order of `k`.
///
/// # Panics
/// If a slice is shorter than its shape says (a caller's bug, not an input's).
#[inline(always)]
pub fn add_product(a: &[f32], b: &[f32], out: &mut [f32], m: usize, k: usize, n: usize) {
    assert!(
        a.len() >= m * k && b.len() >= k * n && out.len() >= m * n,
        "add_product: slices shorter than {m}x{k} @ {k}x{n}"
    );
    let whole_tiles = n - n % TILE_COLS;
    let mut row = 0;
    while row + TILE_ROWS <= m {
        add_product_rows::<TILE_ROWS>(a, b, out, row, k, n, whole_tiles);
        row += TILE_ROWS;
    }
    while row < m {
        add_product_rows::<1>(a, b, out, row, k, n, whole_tiles);
        row += 1;
    }
}

/// [`add_product`] for rows `row..row + R`: whole column tiles in registers, then the columns
/// past the last whole tile one at a time (the same order of `k`).
#[inline(always)]
fn add_product_rows<const R: usize>(
    a: &[f32],
    b: &[f32],
    out: &mut [f32],
    row: usize,
    k: usize,
    n: usize,
    whole_tiles: usize,
) {
    let a_rows: [&[f32]; R] = std::array::from_fn(|r| &a[(row + r) * k..][..k]);
    for col in (0..whole_tiles).step_by(TILE_COLS) {
        let mut acc = [[0.0f32; TILE_COLS]; R];
        for (r, acc_row) in acc.iter_mut().enumerate() {
            acc_row.copy_from_slice(&out[(row + r) * n + col..][..TILE_COLS]);
        }
        for i in 0..k {
            let b_row: &[f32; TILE_COLS] = b[i * n + col..][..TILE_COLS]
                .try_into()
                .expect("a tile is TILE_COLS wide");
            for (acc_row, a_row) in acc.iter_mut().zip(&a_rows) {
                let x = a_row[i];
                for (s, w) in acc_row.iter_mut().zip(b_row) {
                    *s += x * w;
                }
            }
        }
        for (r, acc_row) in acc.iter().enumerate() {
            out[(row + r) * n + col..][..TILE_COLS].copy_from_slice(acc_row);
        }
    }
    for (r, a_row) in a_rows.iter().enumerate() {
        for col in whole_tiles..n {
            let mut s = out[(row + r) * n + col];
            for (i, x) in a_row.iter().enumerate() {
                s += x * b[i * n + col];
            }
            out[(row + r) * n + col] = s;
        }
    }
}

/// `sum a[i] b[i]` over the shorter length: eight interleaved partial sums (one register), then
/// those added pairwise in a fixed order, then the tail.
#[inline(always)]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let len = a.len().min(b.len());
    let (a_chunks, a_tail) = a[..len].as_chunks::<8>();
    let (b_chunks, b_tail) = b[..len].as_chunks::<8>();
    let mut partial = [0.0f32; 8];
    for (x, y) in a_chunks.iter().zip(b_chunks) {
        for lane in 0..8 {
            partial[lane] += x[lane] * y[lane];
        }
    }
    let quads = [
        partial[0] + partial[4],
        partial[1] + partial[5],
        partial[2] + partial[6],
        partial[3] + partial[7],
    ];
    let mut s = (quads[0] + quads[2]) + (quads[1] + quads[3]);
    for (x, y) in a_tail.iter().zip(b_tail) {
        s += x * y;
    }
    s
}

/// `dst = src^T` for `src` of `rows x cols` (row-major), `dst` of `cols x rows`.
#[inline(always)]
pub fn transpose(src: &[f32], rows: usize, cols: usize, dst: &mut [f32]) {
    for (r, src_row) in src[..rows * cols].chunks_exact(cols).enumerate() {
        for (c, &x) in src_row.iter().enumerate() {
            dst[c * rows + r] = x;
        }
    }
}

/// Whether the kernels' AVX2 compilation can run here: callers keep a baseline and an AVX2
/// copy of their hot function (an `#[inline(always)]` body and a `#[target_feature(enable =
/// "avx2")]` wrapper), and both give the same bits (module docs).
#[inline]
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n as u32)
            .map(|i| {
                let h = (i ^ seed).wrapping_mul(0x9e37_79b9).rotate_left(13) ^ seed;
                (h % 2001) as f32 / 1000.0 - 1.0
            })
            .collect()
    }

    /// The tiled product against a plain triple loop in f64, on shapes with row and column
    /// tails (m not a multiple of 4, n not a multiple of 16) and on an accumulating `out`.
    #[test]
    fn add_product_matches_the_definition() {
        for &(m, k, n) in &[
            (1, 1, 1),
            (4, 16, 16),
            (7, 13, 35),
            (128, 64, 64),
            (3, 128, 64),
        ] {
            let a = values(m * k, 1);
            let b = values(k * n, 2);
            let start = values(m * n, 3);
            let mut out = start.clone();
            add_product(&a, &b, &mut out, m, k, n);
            for r in 0..m {
                for c in 0..n {
                    let exact = start[r * n + c] as f64
                        + (0..k)
                            .map(|i| a[r * k + i] as f64 * b[i * n + c] as f64)
                            .sum::<f64>();
                    let got = out[r * n + c] as f64;
                    assert!(
                        (got - exact).abs() <= 1e-5 * (k as f64 + 1.0),
                        "{m}x{k}x{n} at ({r}, {c}): {got} against {exact}"
                    );
                }
            }
        }
    }

    /// Both compilations give the same bits (the module's promise), here on a shape with every
    /// kind of tail.
    #[test]
    fn every_instruction_set_gives_the_same_bits() {
        let (m, k, n) = (9, 37, 35);
        let a = values(m * k, 4);
        let b = values(k * n, 5);
        let mut best = vec![0.0; m * n];
        let mut baseline = vec![0.0; m * n];
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn in_avx2(a: &[f32], b: &[f32], out: &mut [f32], (m, k, n): (usize, usize, usize)) -> f32 {
            add_product(a, b, out, m, k, n);
            dot(a, b)
        }
        if !has_avx2() {
            eprintln!("no AVX2 here: only the baseline compilation is tested");
            return;
        }
        // SAFETY: the processor has AVX2 (checked above).
        let best_dot = unsafe { in_avx2(&a, &b, &mut best, (m, k, n)) };
        add_product(&a, &b, &mut baseline, m, k, n);
        assert_eq!(best, baseline);
        assert_eq!(best_dot.to_bits(), dot(&a, &b).to_bits());
    }

    #[test]
    fn dot_and_transpose_match_their_definitions() {
        for len in [0, 1, 7, 8, 9, 64, 67] {
            let a = values(len, 6);
            let b = values(len, 7);
            let exact: f64 = a.iter().zip(&b).map(|(x, y)| *x as f64 * *y as f64).sum();
            assert!((dot(&a, &b) as f64 - exact).abs() <= 1e-5 * (len as f64 + 1.0));
        }
        let src = values(6 * 5, 8);
        let mut dst = vec![0.0; 30];
        transpose(&src, 6, 5, &mut dst);
        for r in 0..6 {
            for c in 0..5 {
                assert_eq!(dst[c * 6 + r], src[r * 5 + c]);
            }
        }
    }
}
