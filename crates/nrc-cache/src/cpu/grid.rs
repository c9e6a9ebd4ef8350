//! Hash-grid passes over a whole batch (the Flex implementation of the encoding custom op).
//!
//! The backward scatter runs one task per level: levels own disjoint parts of the table, so the
//! gradient needs neither atomics nor per-thread copies.

use rayon::prelude::*;

use burn::tensor::f16;

use crate::encoding::hash_grid::{FastLevel, HashGrid};

/// Hints the cache to fetch the line holding `p` into L1 (a no-op off x86-64).
#[inline(always)]
pub fn prefetch<T>(p: *const T) {
    prefetch_hint::<3, T>(p); // _MM_HINT_T0
}

/// Hints the cache to fetch the line holding `p` into L2 (and the levels above it), not L1
/// (a no-op off x86-64). The encoding's table lines are requested this way: on the Zen 3
/// machine of `docs/benchmarks-log.md` it cut the one-thread encode with random positions by 30–45 %
/// against [`prefetch`] (L1), presumably because a request into L2 does not hold one of the
/// few L1 miss buffers while it waits on memory, so more of them are in flight.
#[inline(always)]
pub fn prefetch_l2<T>(p: *const T) {
    prefetch_hint::<2, T>(p); // _MM_HINT_T1
}

#[cfg(target_arch = "x86_64")]
const _: () = assert!(
    std::arch::x86_64::_MM_HINT_T0 == 3 && std::arch::x86_64::_MM_HINT_T1 == 2,
    "the hints above"
);

/// `prefetch` with the x86 hint `HINT`.
#[inline(always)]
fn prefetch_hint<const HINT: i32, T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching never faults, whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<HINT>(p.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Samples whose table lines are requested ahead of the one being interpolated: enough
/// misses in flight to cover memory latency, few enough that the requests are not dropped.
const AHEAD: usize = 64;

/// Runs `body(i, fetch(i))` for `i` in `0..n`, calling `fetch` `N` items early (it
/// computes a sample's table entries and prefetches their lines), so the cache misses of the
/// following samples overlap the work on this one. `empty` fills the ring before it is used.
#[inline(always)]
fn pipelined<T: Copy, const N: usize>(
    n: usize,
    empty: T,
    mut fetch: impl FnMut(usize) -> T,
    mut body: impl FnMut(usize, T),
) {
    let mut ring = [empty; N];
    for (i, r) in ring.iter_mut().enumerate().take(N.min(n)) {
        *r = fetch(i);
    }
    for i in 0..n {
        let x = ring[i % N];
        if i + N < n {
            ring[i % N] = fetch(i + N);
        }
        body(i, x);
    }
}

/// A hash table as the encoding reads it.
#[derive(Clone, Copy, Debug)]
pub enum Table<'a> {
    /// Single-precision features, `stride` floats per entry with the entry's features first
    /// (the plain table: `F`; the training records `[w | m | v | ema]`: `4F`).
    F32(&'a [f32], usize),
    /// `F` half-precision features per entry (the inference table at
    /// [`crate::encoding::hash_grid::TablePrecision::F16`]).
    F16(&'a [f16]),
}

impl Table<'_> {
    /// Values the table holds (floats or halves).
    fn len(&self) -> usize {
        match self {
            Self::F32(t, _) => t.len(),
            Self::F16(t) => t.len(),
        }
    }

    /// Values per entry.
    fn stride(&self, f: usize) -> usize {
        match self {
            Self::F32(_, s) => *s,
            Self::F16(_) => f,
        }
    }
}

/// Encodes the hash grid of `m` samples into columns `col..col + L·F` of `out` (row stride
/// `stride`), level by level, from `table`. Software-pipelined: while sample `i` is
/// interpolated, the vertices of sample `i + AHEAD` are computed and their table lines
/// prefetched, so the cache misses of the fine levels overlap.
///
/// With two features per level (the presets) on a CPU with AVX2, eight samples are encoded
/// per register ([`encode_tile_avx2`]; a half-precision table also needs F16C); the portable
/// loop sums the eight products in the same tree order, so both give the same bits.
#[inline(always)]
pub fn encode_tile(
    grid: &HashGrid,
    levels: &[FastLevel],
    table: Table,
    m: usize,
    position: impl Fn(usize) -> [f32; 3],
    out: &mut [f32],
    stride: usize,
    col: usize,
) {
    let f = grid.features();
    let entries = grid
        .levels
        .last()
        .map_or(0, |l| l.offset + l.entries as usize);
    let table_stride = table.stride(f);
    assert!(
        table.len() >= entries * table_stride && table_stride >= f,
        "hash table too short"
    );
    assert!(m == 0 || (m - 1) * stride + col + levels.len() * f <= out.len());
    #[cfg(target_arch = "x86_64")]
    if f == 2
        && (entries * table_stride) < i32::MAX as usize
        && super::gemm::has_avx2_fma()
        && has_f16c()
    {
        // SAFETY (both calls): AVX2, FMA and F16C were detected; every corner index is below
        // `entries` (hashed indices are masked to the level, dense ones range-checked), so the
        // gathers stay inside `table`, whose length was checked above, as was `out`'s.
        unsafe {
            match table {
                Table::F32(t, s) => {
                    encode_tile_avx2::<false>(levels, t.as_ptr(), s, m, position, out, stride, col)
                }
                Table::F16(t) => encode_tile_avx2::<true>(
                    levels,
                    t.as_ptr().cast(),
                    1,
                    m,
                    position,
                    out,
                    stride,
                    col,
                ),
            }
        }
        return;
    }
    encode_tile_portable(levels, f, table, m, position, out, stride, col);
}

/// Whether the CPU converts halves in hardware (F16C; every CPU with AVX2 has it).
#[cfg(target_arch = "x86_64")]
pub fn has_f16c() -> bool {
    std::is_x86_feature_detected!("f16c")
}

/// The portable loop of [`encode_tile`] (used where AVX2 is missing, or the features per
/// level are not two); the same bits as the AVX2 kernel.
#[inline(always)]
pub fn encode_tile_portable(
    levels: &[FastLevel],
    f: usize,
    table: Table,
    m: usize,
    position: impl Fn(usize) -> [f32; 3],
    out: &mut [f32],
    stride: usize,
    col: usize,
) {
    match table {
        Table::F32(t, s) => {
            let at = |e: usize| t.as_ptr().wrapping_add(e * s).cast::<u8>();
            encode_levels(levels, f, m, &position, out, stride, col, at, |e, j| {
                t[e * s + j]
            });
        }
        Table::F16(t) => {
            let at = |e: usize| t.as_ptr().wrapping_add(e * f).cast::<u8>();
            encode_levels(levels, f, m, &position, out, stride, col, at, |e, j| {
                t[e * f + j].to_f32()
            });
        }
    }
}

/// [`encode_tile_portable`] for a table whose entry `e` starts at `at(e)` and whose feature
/// `j` of entry `e` is `feature(e, j)`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn encode_levels(
    levels: &[FastLevel],
    f: usize,
    m: usize,
    position: &impl Fn(usize) -> [f32; 3],
    out: &mut [f32],
    stride: usize,
    col: usize,
    at: impl Fn(usize) -> *const u8,
    feature: impl Fn(usize, usize) -> f32,
) {
    for (l, level) in levels.iter().enumerate() {
        let fetch = |i: usize| {
            let c = level.corners(position(i));
            for &e in &c.0 {
                prefetch_l2(at(e as usize));
            }
            c
        };
        let o = col + l * f;
        pipelined::<_, AHEAD>(m, ([0u32; 8], [0f32; 8]), fetch, |i, (idx, w)| {
            let dst = &mut out[i * stride + o..i * stride + o + f];
            if f == 2 {
                let mut a = [0f32; 8];
                let mut b = [0f32; 8];
                for k in 0..8 {
                    let e = idx[k] as usize;
                    a[k] = w[k] * feature(e, 0);
                    b[k] = w[k] * feature(e, 1);
                }
                dst[0] = tree_sum(a);
                dst[1] = tree_sum(b);
            } else {
                dst.fill(0.0);
                for k in 0..8 {
                    let e = idx[k] as usize;
                    for (j, d) in dst.iter_mut().enumerate() {
                        *d += w[k] * feature(e, j);
                    }
                }
            }
        });
    }
}

/// `((p0 + p4) + (p2 + p6)) + ((p1 + p5) + (p3 + p7))`: the order of the AVX2 reduction.
#[inline(always)]
fn tree_sum(p: [f32; 8]) -> f32 {
    let q = [p[0] + p[4], p[1] + p[5], p[2] + p[6], p[3] + p[7]];
    (q[0] + q[2]) + (q[1] + q[3])
}

/// Samples per AVX2 group: one per lane.
const LANES: usize = 8;

/// The AVX2 form of [`encode_tile`] for two features per level, eight samples per register:
/// lane `j` of every vector belongs to sample `j` of a group, so the cell, weights and hashes
/// of eight samples take one instruction each; each corner's two f32 features of four samples
/// come with one 64-bit gather, or (`HALF`) its two half features of eight samples with one
/// 32-bit gather and two conversions. Groups are software-pipelined like the portable loop:
/// the table lines of group `g + AHEAD/8` are prefetched while group `g` is interpolated.
///
/// # Safety
/// The CPU has AVX2 and FMA, and F16C when `HALF`; `base` is the table, entry `e` starting at
/// byte `4 · e · table_stride` (an entry of two halves is 4 bytes: `table_stride` 1); every
/// corner index of `levels` times `table_stride` is below `i32::MAX` and its entry's two
/// features are inside the table; `out` holds `m` rows of `stride` from `col` on.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn encode_tile_avx2<const HALF: bool>(
    levels: &[FastLevel],
    base: *const f32,
    table_stride: usize,
    m: usize,
    position: impl Fn(usize) -> [f32; 3],
    out: &mut [f32],
    stride: usize,
    col: usize,
) {
    use std::arch::x86_64::*;
    // The tile's positions, one array per axis, padded to whole groups (padding lanes sit at
    // the origin and are never stored).
    let groups = m.div_ceil(LANES);
    let mut soa = vec![0f32; 3 * groups * LANES];
    let (xs, rest) = soa.split_at_mut(groups * LANES);
    let (ys, zs) = rest.split_at_mut(groups * LANES);
    for i in 0..m {
        [xs[i], ys[i], zs[i]] = position(i);
    }
    let scale = _mm256_set1_epi32(table_stride as i32);
    // Lanes 0–3 and 4–7 of a weight vector, each repeated for the entry's two features.
    let (dup_lo, dup_hi) = (
        _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3),
        _mm256_setr_epi32(4, 4, 5, 5, 6, 6, 7, 7),
    );
    for (l, level) in levels.iter().enumerate() {
        let fetch = |g: usize| {
            let at = g * LANES;
            // SAFETY: `xs`, `ys`, `zs` hold `groups · LANES` floats.
            let (idx, w) = unsafe {
                level
                    .corners_x8(
                        _mm256_loadu_ps(xs.as_ptr().add(at)),
                        _mm256_loadu_ps(ys.as_ptr().add(at)),
                        _mm256_loadu_ps(zs.as_ptr().add(at)),
                    )
                    .unwrap_or_else(|| scalar_corners_x8(level, xs, ys, zs, at))
            };
            let idx = if table_stride == 1 {
                idx
            } else {
                idx.map(|v| _mm256_mullo_epi32(v, scale))
            };
            // Corners k and k ^ 1 differ in the lowest hash bit, so they share a line: four
            // prefetches per sample.
            let mut lanes = [0i32; 4 * LANES];
            for (k, chunk) in lanes.chunks_exact_mut(LANES).enumerate() {
                // SAFETY: eight lanes written to an eight-element chunk.
                unsafe { _mm256_storeu_si256(chunk.as_mut_ptr().cast(), idx[2 * k]) };
            }
            for e in lanes {
                prefetch_l2(base.wrapping_add(e as usize));
            }
            (idx, w)
        };
        let o = col + l * 2;
        let empty = ([_mm256_setzero_si256(); 8], [_mm256_setzero_ps(); 8]);
        pipelined::<_, { AHEAD / LANES }>(groups, empty, fetch, |g, (idx, w)| {
            // Per corner: (feature 0, feature 1) of samples 0–3 in `lo`, of 4–7 in `hi`,
            // weighted; summed over the corners in the portable loop's tree order.
            let products = |k: usize| {
                // SAFETY: the caller guarantees the gathered entries are inside the table.
                unsafe {
                    if HALF {
                        // Lanes hold (feature 0, feature 1) of samples 0–7 as two halves.
                        let g = _mm256_i32gather_epi32::<4>(base.cast(), idx[k]);
                        return (
                            _mm256_mul_ps(
                                _mm256_permutevar8x32_ps(w[k], dup_lo),
                                _mm256_cvtph_ps(_mm256_castsi256_si128(g)),
                            ),
                            _mm256_mul_ps(
                                _mm256_permutevar8x32_ps(w[k], dup_hi),
                                _mm256_cvtph_ps(_mm256_extracti128_si256::<1>(g)),
                            ),
                        );
                    }
                    let lo =
                        _mm256_i32gather_epi64::<4>(base.cast(), _mm256_castsi256_si128(idx[k]));
                    let hi = _mm256_i32gather_epi64::<4>(
                        base.cast(),
                        _mm256_extracti128_si256::<1>(idx[k]),
                    );
                    (
                        _mm256_mul_ps(
                            _mm256_permutevar8x32_ps(w[k], dup_lo),
                            _mm256_castsi256_ps(lo),
                        ),
                        _mm256_mul_ps(
                            _mm256_permutevar8x32_ps(w[k], dup_hi),
                            _mm256_castsi256_ps(hi),
                        ),
                    )
                }
            };
            let p: [(__m256, __m256); 8] = std::array::from_fn(products);
            let add = |a: (__m256, __m256), b: (__m256, __m256)| {
                (_mm256_add_ps(a.0, b.0), _mm256_add_ps(a.1, b.1))
            };
            let (lo, hi) = add(
                add(add(p[0], p[4]), add(p[2], p[6])),
                add(add(p[1], p[5]), add(p[3], p[7])),
            );
            let first = g * LANES;
            let halves = [
                _mm256_castps256_ps128(lo),
                _mm256_extractf128_ps::<1>(lo),
                _mm256_castps256_ps128(hi),
                _mm256_extractf128_ps::<1>(hi),
            ];
            for (h, pair) in halves.into_iter().enumerate() {
                for (j, v) in [pair, _mm_movehl_ps(pair, pair)].into_iter().enumerate() {
                    let i = first + 2 * h + j;
                    if i < m {
                        // SAFETY: the caller guarantees `out` holds row `i`'s columns `o`,
                        // `o + 1`.
                        unsafe {
                            _mm_store_sd(
                                out.as_mut_ptr().add(i * stride + o).cast(),
                                _mm_castps_pd(v),
                            )
                        };
                    }
                }
            }
        });
    }
}

/// [`FastLevel::corners`] of group `at..at + 8` in the layout of [`FastLevel::corners_x8`]
/// (its fallback where a dense level wraps).
#[cfg(target_arch = "x86_64")]
fn scalar_corners_x8(
    level: &FastLevel,
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    at: usize,
) -> (
    [std::arch::x86_64::__m256i; 8],
    [std::arch::x86_64::__m256; 8],
) {
    use std::arch::x86_64::*;
    let mut idx = [[0u32; LANES]; 8];
    let mut w = [[0f32; LANES]; 8];
    for j in 0..LANES {
        let (ij, wj) = level.corners([xs[at + j], ys[at + j], zs[at + j]]);
        for k in 0..8 {
            idx[k][j] = ij[k];
            w[k][j] = wj[k];
        }
    }
    // SAFETY: eight-element arrays read as eight lanes; AVX loads, and this runs only inside
    // the AVX2 kernel, whose caller detected the CPU features.
    unsafe {
        (
            idx.map(|v| _mm256_loadu_si256(v.as_ptr().cast())),
            w.map(|v| _mm256_loadu_ps(v.as_ptr())),
        )
    }
}

/// Splits a per-entry array (`f` values per entry) into one mutable slice per level.
pub fn split_levels<'a, T>(grid: &HashGrid, f: usize, mut data: &'a mut [T]) -> Vec<&'a mut [T]> {
    let mut out = Vec::with_capacity(grid.levels.len());
    for level in &grid.levels {
        let (head, tail) = data.split_at_mut(level.entries as usize * f);
        out.push(head);
        data = tail;
    }
    out
}

/// Encodes `positions` (`[N][3]`) into `out` (`[N][L·F]`).
pub fn forward(grid: &HashGrid, table: &[f32], positions: &[f32], out: &mut [f32]) {
    let d = grid.output_dims();
    let levels = grid.fast_levels();
    out.par_chunks_mut(d * 256)
        .zip(positions.par_chunks(3 * 256))
        .for_each(|(o, p)| {
            let m = p.len() / 3;
            encode_tile(
                grid,
                &levels,
                Table::F32(table, grid.features()),
                m,
                |i| [p[3 * i], p[3 * i + 1], p[3 * i + 2]],
                o,
                d,
                0,
            );
        });
}

/// Gradient of the table for `dout` (`[N][L·F]`), written into `grad` (zeroed first).
pub fn backward_table(grid: &HashGrid, positions: &[f32], dout: &[f32], grad: &mut [f32]) {
    let f = grid.features();
    grad.fill(0.0);
    let levels = split_levels(grid, f, grad);
    levels.into_par_iter().enumerate().for_each(|(l, g)| {
        scatter_level(
            grid,
            l,
            positions.len() / 3,
            |i| [positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]],
            |i| &dout[i * grid.output_dims() + l * f..i * grid.output_dims() + (l + 1) * f],
            g,
            None,
        );
    });
}

/// Scatters level `l`'s gradient of `n` samples into that level's table gradient `grad`
/// (level-local entries), marking referenced entries in `touched` when given. Pipelined like
/// [`encode_tile`]: the gradient lines of sample `i + AHEAD` are prefetched while sample `i`
/// is accumulated.
#[inline(always)]
pub fn scatter_level<'p, 'd>(
    grid: &HashGrid,
    l: usize,
    n: usize,
    position: impl Fn(usize) -> [f32; 3] + 'p,
    dout: impl Fn(usize) -> &'d [f32],
    grad: &mut [f32],
    mut touched: Option<&mut [u64]>,
) {
    let f = grid.features();
    let fast = FastLevel::new(&grid.levels[l]);
    let offset = grid.levels[l].offset as u32;
    let lines = grad.as_ptr();
    let fetch = |i: usize| {
        let (mut idx, w) = fast.corners(position(i));
        for e in idx.iter_mut() {
            *e -= offset;
            prefetch(lines.wrapping_add(*e as usize * f));
        }
        (idx, w)
    };
    pipelined::<_, AHEAD>(n, ([0u32; 8], [0f32; 8]), fetch, |i, (idx, w)| {
        let d = dout(i);
        for k in 0..8 {
            let e = idx[k] as usize;
            for j in 0..f {
                grad[e * f + j] += w[k] * d[j];
            }
            if let Some(t) = touched.as_deref_mut() {
                t[e / 64] |= 1u64 << (e % 64);
            }
        }
    });
}

/// Entries per bin of [`scatter_binned`]: a bin's gradient (2¹³ · F floats, 64 KiB at two
/// features) stays in L2 while its contributions are summed and its update runs.
pub const BIN_ENTRIES: usize = 1 << 13;

/// One sample's weighted gradient for one table entry (level-local index).
#[derive(Clone, Copy, Debug)]
struct Contribution<const F: usize> {
    entry: u32,
    grad: [f32; F],
}

/// Reusable buffers of [`scatter_binned`] (one per thread, so that steps do not page-fault
/// fresh megabytes).
#[derive(Debug, Default)]
pub struct BinScratch {
    /// Contributions sorted by bin, in sample and corner order within a bin (as raw words:
    /// the record type depends on `F`).
    sorted: Vec<u32>,
    /// Contributions per bin, then the bins' starts.
    starts: Vec<usize>,
    /// One bin's gradient, zero between bins.
    grad: Vec<f32>,
    /// One bin's referenced entries, clear between bins.
    touched: Vec<u64>,
    /// Levels that took counted bins (dense levels of several bins, and hashed levels where a
    /// bin of the first try overflowed).
    counted_levels: usize,
}

impl BinScratch {
    /// How many levels [`scatter_binned`] took counted bins for (dense levels of several bins,
    /// and hashed levels where a bin of the first try overflowed).
    pub fn counted_levels(&self) -> usize {
        self.counted_levels
    }
}

/// Level `l`'s table gradient of a batch, bin by bin: the same sums as [`scatter_level`]
/// (each entry's contributions added in sample and corner order, so the same bits), without
/// read-modify-writes into a gradient table the size of the level. The weighted gradients are
/// written straight into their bin's place (on hashed levels into bins of twice the even
/// share, in one pass; on dense levels, or where such a bin overflows, into bins sized by a
/// counting pass first); then each bin's contributions are summed into a bin-sized buffer that
/// stays in L2.
///
/// `xyz` holds the positions one axis per slice, padded with zeros to whole groups of eight;
/// `dout` holds the level's `F` output gradients per sample. `per_bin(first, grad, touched)`
/// receives each bin that has contributions: the level entry it starts at, its gradient (`F`
/// per entry) and its referenced entries; it must leave `grad` zero and `touched` clear (as
/// [`super::optim::sparse_step`] does).
pub fn scatter_binned<const F: usize>(
    grid: &HashGrid,
    l: usize,
    xyz: [&[f32]; 3],
    dout: &[f32],
    scratch: &mut BinScratch,
    mut per_bin: impl FnMut(usize, &mut [f32], &mut [u64]),
) {
    assert_eq!(grid.features(), F, "features per level");
    let n = dout.len() / F;
    let groups = n.div_ceil(LANES);
    assert!(
        xyz.iter().all(|a| a.len() >= groups * LANES),
        "positions too short"
    );
    let level = &grid.levels[l];
    let entries = level.entries as usize;
    let fast = FastLevel::new(level);
    let offset = level.offset as u32;
    let bins = entries.div_ceil(BIN_ENTRIES);
    let avx2 = super::gemm::has_avx2_fma();
    let s = scratch;
    let total = 8 * n;
    let words = std::mem::size_of::<Contribution<F>>() / 4;
    // First try on hashed levels: every bin gets room for twice its even share of the
    // contributions (the spatial hash fills the bins evenly: 2048 ± 45 each at 2^14 samples),
    // written in one pass. Dense levels (whose bins are slabs of space, filled as unevenly as
    // the samples lie), and hashed levels where a bin overflows (a few distinct cells), take
    // counted bins: corners computed once to count each bin's contributions, then again to
    // write them.
    let room = if bins == 1 {
        total
    } else {
        (2 * total.div_ceil(bins) + 64).min(total)
    };
    s.starts.clear();
    s.starts.extend((0..=bins).map(|b| b * room));
    s.sorted.resize(bins * room * words, 0);
    let mut next = s.starts[..bins].to_vec();
    let level_input = LevelInput::<F> {
        fast: &fast,
        offset,
        xyz,
        dout,
        avx2,
    };
    let roomy =
        (bins == 1 || !level.dense) && level_input.write(true, &s.starts, &mut s.sorted, &mut next);
    if !roomy {
        s.counted_levels += 1;
        s.starts.fill(0);
        let mut corners = ([[0u32; LANES]; 8], [[0f32; LANES]; 8]);
        for g in 0..groups {
            group_corners(&fast, xyz, g * LANES, avx2, &mut corners);
            let idx = &corners.0;
            for j in 0..LANES.min(n - g * LANES) {
                for corner in idx {
                    s.starts[(corner[j] - offset) as usize / BIN_ENTRIES + 1] += 1;
                }
            }
        }
        for b in 0..bins {
            s.starts[b + 1] += s.starts[b];
        }
        s.sorted.resize(total * words, 0);
        next.copy_from_slice(&s.starts[..bins]);
        let counted = level_input.write(false, &s.starts, &mut s.sorted, &mut next);
        debug_assert!(counted, "counted bins cannot overflow");
    }
    let sorted = contributions_mut::<F>(&mut s.sorted);
    s.grad.resize(BIN_ENTRIES * F, 0.0);
    s.touched.resize(BIN_ENTRIES / 64, 0);
    for (b, (&lo, &hi)) in s.starts.iter().zip(&next).enumerate() {
        // Bin b's contributions: from its start to where its writing stopped.
        if lo == hi {
            continue;
        }
        let first = b * BIN_ENTRIES;
        let grad = &mut s.grad[..BIN_ENTRIES * F];
        let touched = &mut s.touched[..BIN_ENTRIES / 64];
        for c in &sorted[lo..hi] {
            let e = c.entry as usize - first;
            assert!(e < BIN_ENTRIES, "contribution outside its bin");
            // SAFETY: e < BIN_ENTRIES (checked above), and the slices hold BIN_ENTRIES · F and
            // BIN_ENTRIES / 64 elements.
            unsafe {
                for (q, v) in c.grad.iter().enumerate() {
                    *grad.get_unchecked_mut(e * F + q) += v;
                }
                *touched.get_unchecked_mut(e / 64) |= 1u64 << (e % 64);
            }
        }
        let len = BIN_ENTRIES.min(entries - first);
        per_bin(
            first,
            &mut s.grad[..len * F],
            &mut s.touched[..len.div_ceil(64)],
        );
        debug_assert!(s.touched.iter().all(|&t| t == 0), "per_bin left bits set");
    }
}

/// The contribution records held in a [`BinScratch`]'s words.
fn contributions_mut<const F: usize>(words: &mut [u32]) -> &mut [Contribution<F>] {
    let n = words.len() * 4 / std::mem::size_of::<Contribution<F>>();
    // SAFETY: `Contribution<F>` is plain data of `u32`/`f32` words (any bit pattern is valid,
    // alignment 4), and `words` holds `n` of them.
    unsafe { std::slice::from_raw_parts_mut(words.as_mut_ptr().cast::<Contribution<F>>(), n) }
}

/// One level's input to the write pass of [`scatter_binned`].
struct LevelInput<'a, const F: usize> {
    fast: &'a FastLevel,
    offset: u32,
    xyz: [&'a [f32]; 3],
    dout: &'a [f32],
    avx2: bool,
}

impl<const F: usize> LevelInput<'_, F> {
    /// The write pass: each sample's eight weighted gradients go to their bin's next place
    /// (`next[bin]`, advanced) in `words` (contribution records), in sample and corner order.
    /// Bin `b` ends at `starts[b + 1]`; with `check`, the pass stops and returns false when a
    /// bin is full; without it, the caller has sized the bins by counting.
    fn write(&self, check: bool, starts: &[usize], words: &mut [u32], next: &mut [usize]) -> bool {
        let (n, ends) = (self.dout.len() / F, &starts[1..]);
        let sorted = contributions_mut::<F>(words);
        assert!(ends.len() >= next.len() && ends.iter().all(|&e| e <= sorted.len()));
        let mut corners = ([[0u32; LANES]; 8], [[0f32; LANES]; 8]);
        for g in 0..n.div_ceil(LANES) {
            group_corners(self.fast, self.xyz, g * LANES, self.avx2, &mut corners);
            let (idx, w) = &corners;
            for j in 0..LANES.min(n - g * LANES) {
                let i = g * LANES + j;
                let d: [f32; F] = self.dout[i * F..(i + 1) * F].try_into().expect("F values");
                for k in 0..8 {
                    let entry = idx[k][j] - self.offset;
                    let bin = entry as usize / BIN_ENTRIES;
                    let p = next[bin];
                    if check && p == ends[bin] {
                        return false;
                    }
                    assert!(p < ends[bin], "bin {bin} overflows its counted size");
                    // The bin's write position 16 contributions (three lines) on: with 64 bins
                    // written at once the hardware does not fetch ahead of every stream, and the
                    // stores waited on their lines (scatter 15–30 % faster, docs/benchmarks-log.md).
                    prefetch(sorted.as_ptr().wrapping_add(p + 16));
                    // SAFETY: p < ends[bin] ≤ sorted.len() (checked above).
                    unsafe {
                        *sorted.get_unchecked_mut(p) = Contribution {
                            entry,
                            grad: d.map(|dq| w[k][j] * dq),
                        };
                    }
                    next[bin] = p + 1;
                }
            }
        }
        true
    }
}

/// Corner indices and weights of eight samples, as `[corner][lane]`.
type GroupCorners = ([[u32; LANES]; 8], [[f32; LANES]; 8]);

/// Writes the corner indices and weights of samples `at..at + 8` (positions one axis per
/// slice) into `out`: eight at once with AVX2 where `avx2` says the CPU has it. (An out
/// parameter: returned by value, the 512 bytes were copied by `memcpy` on every call.)
#[inline(always)]
fn group_corners(
    fast: &FastLevel,
    xyz: [&[f32]; 3],
    at: usize,
    avx2: bool,
    out: &mut GroupCorners,
) {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the caller detected AVX2 and FMA; the slices hold `at + 8` floats.
        unsafe { group_corners_avx2(fast, xyz, at, out) };
        return;
    }
    let _ = avx2;
    for j in 0..LANES {
        let (ij, wj) = fast.corners([xyz[0][at + j], xyz[1][at + j], xyz[2][at + j]]);
        for k in 0..8 {
            out.0[k][j] = ij[k];
            out.1[k][j] = wj[k];
        }
    }
}

/// [`group_corners`] with [`FastLevel::corners_x8`].
///
/// # Safety
/// The CPU has AVX2 and FMA; each slice of `xyz` holds `at + 8` floats.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn group_corners_avx2(
    fast: &FastLevel,
    xyz: [&[f32]; 3],
    at: usize,
    out: &mut GroupCorners,
) {
    use std::arch::x86_64::*;
    assert!(xyz.iter().all(|a| a.len() >= at + LANES));
    // SAFETY: eight floats at `at` in each slice (checked above).
    let (idx, w) = unsafe {
        let load = |a: &[f32]| _mm256_loadu_ps(a.as_ptr().add(at));
        match fast.corners_x8(load(xyz[0]), load(xyz[1]), load(xyz[2])) {
            Some(c) => c,
            None => scalar_corners_x8(fast, xyz[0], xyz[1], xyz[2], at),
        }
    };
    for k in 0..8 {
        // SAFETY: eight lanes into eight-element arrays.
        unsafe {
            _mm256_storeu_si256(out.0[k].as_mut_ptr().cast(), idx[k]);
            _mm256_storeu_ps(out.1[k].as_mut_ptr(), w[k]);
        }
    }
}
