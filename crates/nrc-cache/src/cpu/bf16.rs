//! Products with bfloat16 operands and f32 sums, for the MLP with `"precision": "bf16"`.
//!
//! Operands are rounded to bfloat16 (8-bit significand, f32's exponent range) and kept in
//! **pairs** along the inner dimension: one `u32` holds elements `2p` (low half) and `2p + 1`
//! (high half). Each step of a product multiplies one pair of `A` by one pair of `B` and adds
//! both products to the f32 sum, odd element first: exactly what AVX-512 BF16's `vdpbf16ps`
//! does, which on this project's CPUs (AMD Zen 4) multiplies-adds twice as many values per
//! cycle as the f32 fused multiply-add. A product of two bfloat16 values is exact in f32, so
//! each addition rounds once, as a fused multiply-add does: machines without AVX-512 BF16 get
//! the same bits from fused multiply-adds on the halves in that order (except where a sum falls
//! below f32's normal range, which `vdpbf16ps` flushes to zero) — with AVX2 a kernel that
//! splits the pairs in registers ([`PairKernel::Avx2`]), elsewhere the f32 loops on the pairs
//! expanded ([`gemm_pairs_expanded`]).
//!
//! The bfloat16 rounding is to nearest even; subnormal inputs become zero and NaN stays NaN,
//! as `vcvtneps2bf16` does.

use super::gemm::{Rows, Store, Strided, gemm};

/// Whether this machine has the AVX-512 BF16 kernels (detected once).
pub fn has_bf16() -> bool {
    static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *HAS.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            std::is_x86_feature_detected!("avx512bf16")
                && std::is_x86_feature_detected!("avx512bw")
                && std::is_x86_feature_detected!("avx512f")
                && super::gemm::has_avx2_fma()
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    })
}

/// `v` rounded to bfloat16 (the high 16 bits of an f32): to nearest even; subnormals become
/// signed zero; NaN stays a (quiet) NaN. Written with selects, so loops over it vectorise.
#[inline]
pub fn to_bf16(v: f32) -> u16 {
    let bits = v.to_bits();
    let rounded = bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) >> 16;
    let nan = (bits & 0x7fff_ffff) > 0x7f80_0000;
    let tiny = bits & 0x7f80_0000 == 0; // zero or subnormal
    let out = if nan {
        (bits >> 16) | 0x40
    } else if tiny {
        (bits >> 16) & 0x8000
    } else {
        rounded
    };
    out as u16
}

/// The f32 value of a bfloat16.
#[inline]
pub fn from_bf16(h: u16) -> f32 {
    f32::from_bits(u32::from(h) << 16)
}

/// A pair of bfloat16 values (`even` in the low half).
#[inline]
fn pair(even: f32, odd: f32) -> u32 {
    u32::from(to_bf16(even)) | (u32::from(to_bf16(odd)) << 16)
}

/// Pairs along the columns: `out[i·cols/2 + p] = (src[i·stride + 2p], src[i·stride + 2p + 1])`
/// for `rows` rows of `cols` (even) columns.
pub fn pairs_along_columns(src: &[f32], rows: usize, cols: usize, stride: usize, out: &mut [u32]) {
    assert!(cols.is_multiple_of(2), "pairs along {cols} columns");
    let half = cols / 2;
    assert!(out.len() >= rows * half, "pair buffer too short");
    if rows == 0 {
        return;
    }
    assert!((rows - 1) * stride + cols <= src.len(), "source too short");
    for i in 0..rows {
        let s = &src[i * stride..i * stride + cols];
        let o = &mut out[i * half..(i + 1) * half];
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if has_bf16() {
            // SAFETY: AVX-512 BF16 detected; `s` holds `2·o.len()` values.
            done = unsafe { avx512::convert_row(s, o) };
        } else if super::gemm::has_avx2_fma() {
            // SAFETY: AVX2 detected; `s` holds `2·o.len()` values.
            done = unsafe { avx2::convert_row(s, o) };
        }
        for p in done..half {
            o[p] = pair(s[2 * p], s[2 * p + 1]);
        }
    }
}

/// Pairs along the rows: `out[p·cols + j] = (src[2p·stride + j], src[(2p + 1)·stride + j])`
/// for `rows` rows of `cols` columns (an odd last row is paired with zeros).
pub fn pairs_along_rows(src: &[f32], rows: usize, cols: usize, stride: usize, out: &mut [u32]) {
    let pairs = rows.div_ceil(2);
    assert!(out.len() >= pairs * cols, "pair buffer too short");
    if rows == 0 {
        return;
    }
    assert!((rows - 1) * stride + cols <= src.len(), "source too short");
    for p in 0..pairs {
        let even = &src[2 * p * stride..2 * p * stride + cols];
        let odd =
            (2 * p + 1 < rows).then(|| &src[(2 * p + 1) * stride..(2 * p + 1) * stride + cols]);
        let o = &mut out[p * cols..(p + 1) * cols];
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if let Some(odd) = odd {
            if has_bf16() {
                // SAFETY: AVX-512 BF16 detected; both rows hold `o.len()` values.
                done = unsafe { avx512::interleave_rows(even, odd, o) };
            } else if super::gemm::has_avx2_fma() {
                // SAFETY: AVX2 detected; both rows hold `o.len()` values.
                done = unsafe { avx2::interleave_rows(even, odd, o) };
            }
        }
        for j in done..cols {
            o[j] = pair(even[j], odd.map_or(0.0, |r| r[j]));
        }
    }
}

/// Operand `A` of [`gemm_pairs`]: pair `(i, p)` is `data[i·row_stride + p·col_stride]`.
pub type Pairs<'a> = Strided<'a, u32>;

/// The kernels behind [`gemm_pairs`] (all give the same bits; see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PairKernel {
    /// The f32 loops on the expanded pairs ([`gemm_pairs_expanded`]).
    Expanded,
    /// Pairs split into their halves in AVX2 registers, two fused multiply-adds per pair.
    Avx2,
    /// `vdpbf16ps` (AVX-512 BF16).
    Avx512Bf16,
}

impl PairKernel {
    /// The fastest kernel this machine has.
    pub fn best() -> Self {
        if has_bf16() {
            Self::Avx512Bf16
        } else if super::gemm::has_avx2_fma() {
            Self::Avx2
        } else {
            Self::Expanded
        }
    }
}

/// `C[m×n] (op)= A[m×2kp] · B[2kp×n]` with both operands in bfloat16 pairs along the inner
/// dimension (`A` as [`Pairs`], `B` as rows of `n` pairs) and f32 sums; `n` must be a multiple
/// of 16. The fastest kernel the machine has ([`PairKernel::best`]).
pub fn gemm_pairs(
    m: usize,
    n: usize,
    kp: usize,
    a: Pairs<'_>,
    b: Rows<&[u32]>,
    c: Rows<&mut [f32]>,
    store: Store,
) {
    gemm_pairs_with(PairKernel::best(), m, n, kp, a, b, c, store);
}

/// [`gemm_pairs`] with a given kernel (which the machine must have: at most
/// [`PairKernel::best`]).
#[allow(clippy::too_many_arguments)]
pub fn gemm_pairs_with(
    kernel: PairKernel,
    m: usize,
    n: usize,
    kp: usize,
    a: Pairs<'_>,
    b: Rows<&[u32]>,
    c: Rows<&mut [f32]>,
    store: Store,
) {
    assert!(
        n.is_multiple_of(16),
        "gemm_pairs: n = {n} must be a multiple of 16"
    );
    if !super::gemm::check_bounds(m, n, kp, &a, &b, &c) {
        return;
    }
    let rank = |k: PairKernel| k as u8;
    assert!(
        rank(kernel) <= rank(PairKernel::best()),
        "gemm_pairs: this machine has no {kernel:?} kernel"
    );
    #[cfg(target_arch = "x86_64")]
    {
        let blocks: &[(usize, RowKernel)] = match kernel {
            PairKernel::Avx512Bf16 => &avx512::BLOCKS,
            PairKernel::Avx2 => &avx2::BLOCKS,
            PairKernel::Expanded => &[],
        };
        if !blocks.is_empty() {
            let mut c = c;
            let o = super::gemm::Block::new(kp, &a, &b, &mut c, store);
            // SAFETY: the machine has the kernel's features (checked above, detected at run
            // time) and every access was bounds-checked above.
            unsafe { over_rows(m, n, o, blocks) };
            return;
        }
    }
    gemm_pairs_expanded(m, n, kp, a, b, c, store);
}

/// [`gemm_pairs`] by the f32 kernels: the pairs expanded to f32, odd element first (public for
/// the test that compares it with the AVX-512 BF16 kernel).
pub fn gemm_pairs_expanded(
    m: usize,
    n: usize,
    kp: usize,
    a: Pairs<'_>,
    b: Rows<&[u32]>,
    c: Rows<&mut [f32]>,
    store: Store,
) {
    let k = 2 * kp;
    let halves = |x: u32| [from_bf16((x >> 16) as u16), from_bf16(x as u16)];
    let mut ax = vec![0f32; m * k];
    for i in 0..m {
        for p in 0..kp {
            let [odd, even] = halves(a.data[i * a.row_stride + p * a.col_stride]);
            ax[i * k + 2 * p] = odd;
            ax[i * k + 2 * p + 1] = even;
        }
    }
    let mut bx = vec![0f32; k * n];
    for p in 0..kp {
        for j in 0..n {
            let [odd, even] = halves(b.data[p * b.stride + j]);
            bx[2 * p * n + j] = odd;
            bx[(2 * p + 1) * n + j] = even;
        }
    }
    gemm(
        m,
        n,
        k,
        Strided {
            data: &ax,
            row_stride: k,
            col_stride: 1,
        },
        Rows {
            data: &bx,
            stride: n,
        },
        c,
        store,
    );
}

/// A kernel over a block of rows of a product: `(columns, operands at the block's first row)`.
#[cfg(target_arch = "x86_64")]
type RowKernel = unsafe fn(usize, super::gemm::Block<u32>);

/// Runs the row-block kernels `blocks` (rows per block, kernel; largest first, the last of one
/// row) down the `m` rows of the product `o` (`n` columns).
///
/// # Safety
/// The operands hold `m` rows and `n` columns; the machine has the kernels' features.
#[cfg(target_arch = "x86_64")]
unsafe fn over_rows(m: usize, n: usize, o: super::gemm::Block<u32>, blocks: &[(usize, RowKernel)]) {
    let mut i = 0;
    for &(rows, block) in blocks {
        while i + rows <= m {
            // SAFETY: rows i..i + rows lie inside the operands (the caller's promise).
            unsafe { block(n, o.at(i, 0)) };
            i += rows;
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::super::gemm::Block;
    use super::super::gemm::avx2::store_block;
    use std::arch::x86_64::*;

    /// Eight floats rounded to bfloat16 as [`super::to_bf16`] does, each in the low 16 bits of
    /// its lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn round8(v: __m256) -> __m256i {
        let bits = _mm256_castps_si256(v);
        let one = _mm256_set1_epi32(1);
        let lsb = _mm256_and_si256(_mm256_srli_epi32::<16>(bits), one);
        let bias = _mm256_add_epi32(_mm256_set1_epi32(0x7fff), lsb);
        let rounded = _mm256_srli_epi32::<16>(_mm256_add_epi32(bits, bias));
        let magnitude = _mm256_and_si256(bits, _mm256_set1_epi32(0x7fff_ffff));
        let nan = _mm256_cmpgt_epi32(magnitude, _mm256_set1_epi32(0x7f80_0000));
        let exponent = _mm256_and_si256(bits, _mm256_set1_epi32(0x7f80_0000));
        let tiny = _mm256_cmpeq_epi32(exponent, _mm256_setzero_si256());
        let high = _mm256_srli_epi32::<16>(bits);
        let quiet = _mm256_or_si256(high, _mm256_set1_epi32(0x40));
        let sign = _mm256_and_si256(high, _mm256_set1_epi32(0x8000));
        let out = _mm256_blendv_epi8(rounded, sign, tiny);
        _mm256_blendv_epi8(out, quiet, nan)
    }

    /// Converts `2·out.len()` floats to pairs, eight pairs per step; returns how many pairs it
    /// wrote (the caller converts the rest).
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn convert_row(src: &[f32], out: &mut [u32]) -> usize {
        let mut p = 0;
        // SAFETY: pairs p..p + 8 exist in `out`, values 2p..2p + 16 in `src`.
        unsafe {
            while p + 8 <= out.len() {
                let lo = round8(_mm256_loadu_ps(src.as_ptr().add(2 * p)));
                let hi = round8(_mm256_loadu_ps(src.as_ptr().add(2 * p + 8)));
                // Values 0–3 of lo, 0–3 of hi, 4–7 of lo, 4–7 of hi as halves: put in order.
                let packed = _mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_packus_epi32(lo, hi));
                _mm256_storeu_si256(out.as_mut_ptr().add(p).cast(), packed);
                p += 8;
            }
        }
        p
    }

    /// Pairs two rows element by element, eight pairs per step; returns how many it wrote.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn interleave_rows(even: &[f32], odd: &[f32], out: &mut [u32]) -> usize {
        let mut j = 0;
        // SAFETY: columns j..j + 8 exist in both rows and in `out`.
        unsafe {
            while j + 8 <= out.len() {
                let e = round8(_mm256_loadu_ps(even.as_ptr().add(j)));
                let o = round8(_mm256_loadu_ps(odd.as_ptr().add(j)));
                let pairs = _mm256_or_si256(e, _mm256_slli_epi32::<16>(o));
                _mm256_storeu_si256(out.as_mut_ptr().add(j).cast(), pairs);
                j += 8;
            }
        }
        j
    }

    /// Rows in blocks of 4 and columns in blocks of 16 (8 accumulators, 4 split B vectors), the
    /// rows left over one by one.
    pub(super) const BLOCKS: [(usize, super::RowKernel); 2] =
        [(4, row_block::<4> as super::RowKernel), (1, row_block::<1>)];

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn row_block<const MR: usize>(n: usize, rows: Block<u32>) {
        // SAFETY: see `gemm` (n is a multiple of 16).
        unsafe {
            for j in (0..n).step_by(16) {
                micro::<MR>(rows.at(0, j));
            }
        }
    }

    /// An `MR × 16` block: per pair step, each pair's odd half (its high 16 bits, masked) then
    /// its even half (shifted up) go through a fused multiply-add, as `vdpbf16ps` adds them.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn micro<const MR: usize>(o: Block<u32>) {
        // SAFETY: see `gemm`.
        unsafe {
            let high = _mm256_set1_epi32(0xffff_0000_u32 as i32);
            let odd = |x: __m256i| _mm256_castsi256_ps(_mm256_and_si256(x, high));
            let even = |x: __m256i| _mm256_castsi256_ps(_mm256_slli_epi32::<16>(x));
            let mut acc = [[_mm256_setzero_ps(); 2]; MR];
            for p in 0..o.k {
                let brow = o.b.add(p * o.ldb);
                let (b0, b1) = (
                    _mm256_loadu_si256(brow.cast()),
                    _mm256_loadu_si256(brow.add(8).cast()),
                );
                let (bo, be) = ([odd(b0), odd(b1)], [even(b0), even(b1)]);
                let acol = o.a.add(p * o.acs);
                for (i, acc_i) in acc.iter_mut().enumerate() {
                    let x = _mm256_set1_epi32(*acol.add(i * o.ars) as i32);
                    let (ao, ae) = (odd(x), even(x));
                    for v in 0..2 {
                        acc_i[v] = _mm256_fmadd_ps(ao, bo[v], acc_i[v]);
                        acc_i[v] = _mm256_fmadd_ps(ae, be[v], acc_i[v]);
                    }
                }
            }
            store_block(&acc, o);
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::super::gemm::Block;
    use super::super::gemm::avx512::store_block;
    use std::arch::x86_64::*;

    /// Converts `2·out.len()` floats to pairs, sixteen pairs per step; returns how many pairs
    /// it wrote (the caller converts the rest).
    #[target_feature(enable = "avx512f,avx512bf16,avx512bw")]
    pub(super) unsafe fn convert_row(src: &[f32], out: &mut [u32]) -> usize {
        let mut p = 0;
        // SAFETY: pairs p..p + 16 exist in `out`, values 2p..2p + 32 in `src`.
        unsafe {
            while p + 16 <= out.len() {
                let lo = _mm512_loadu_ps(src.as_ptr().add(2 * p));
                let hi = _mm512_loadu_ps(src.as_ptr().add(2 * p + 16));
                let packed = std::mem::transmute::<__m512bh, __m512i>(_mm512_cvtne2ps_pbh(hi, lo));
                _mm512_storeu_si512(out.as_mut_ptr().add(p).cast(), packed);
                p += 16;
            }
        }
        p
    }

    /// Pairs two rows element by element, sixteen pairs per step; returns how many it wrote.
    #[target_feature(enable = "avx512f,avx512bf16,avx512bw")]
    pub(super) unsafe fn interleave_rows(even: &[f32], odd: &[f32], out: &mut [u32]) -> usize {
        // Word indices: pair j takes even[j] (word j of the low half) and odd[j] (word 16 + j).
        let index = _mm512_set_epi16(
            31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20,
            4, 19, 3, 18, 2, 17, 1, 16, 0,
        );
        let mut j = 0;
        // SAFETY: columns j..j + 16 exist in both rows and in `out`.
        unsafe {
            while j + 16 <= out.len() {
                let e = _mm512_loadu_ps(even.as_ptr().add(j));
                let o = _mm512_loadu_ps(odd.as_ptr().add(j));
                let both = std::mem::transmute::<__m512bh, __m512i>(_mm512_cvtne2ps_pbh(o, e));
                let pairs = _mm512_permutexvar_epi16(index, both);
                _mm512_storeu_si512(out.as_mut_ptr().add(j).cast(), pairs);
                j += 16;
            }
        }
        j
    }

    /// Rows in blocks of 12 and columns in blocks of 32 (24 accumulators); the rows left over
    /// in blocks of 4 (the 64- and 128-row products leave 4 or 8), then one by one.
    pub(super) const BLOCKS: [(usize, super::RowKernel); 3] = [
        (12, row_block::<12> as super::RowKernel),
        (4, row_block::<4>),
        (1, row_block::<1>),
    ];

    #[inline]
    #[target_feature(enable = "avx512f,avx512bf16,avx512bw")]
    unsafe fn row_block<const MR: usize>(n: usize, rows: Block<u32>) {
        let mut j = 0;
        // SAFETY: see `gemm`.
        unsafe {
            while j + 32 <= n {
                micro::<MR, 2>(rows.at(0, j));
                j += 32;
            }
            if j < n {
                micro::<MR, 1>(rows.at(0, j));
            }
        }
    }

    /// An `MR × 16·NV` block of C summed in registers over the whole inner dimension (`o.k`
    /// pair steps).
    #[inline]
    #[target_feature(enable = "avx512f,avx512bf16,avx512bw")]
    unsafe fn micro<const MR: usize, const NV: usize>(o: Block<u32>) {
        let bf16 = |x: __m512i| -> __m512bh {
            // SAFETY: both are 512-bit vectors; every bit pattern is a valid `__m512bh`.
            unsafe { std::mem::transmute::<__m512i, __m512bh>(x) }
        };
        // SAFETY: see `gemm`.
        unsafe {
            let mut acc = [[_mm512_setzero_ps(); NV]; MR];
            for p in 0..o.k {
                let brow = o.b.add(p * o.ldb);
                let mut bv = [bf16(_mm512_setzero_si512()); NV];
                for (v, bvv) in bv.iter_mut().enumerate() {
                    *bvv = bf16(_mm512_loadu_si512(brow.add(16 * v).cast()));
                }
                let acol = o.a.add(p * o.acs);
                for (i, acc_i) in acc.iter_mut().enumerate() {
                    let av = bf16(_mm512_set1_epi32(*acol.add(i * o.ars) as i32));
                    for v in 0..NV {
                        acc_i[v] = _mm512_dpbf16_ps(acc_i[v], av, bv[v]);
                    }
                }
            }
            store_block(&acc, o);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// [`gemm_pairs`] by the AVX2 kernel.
    fn avx2_kernel(
        m: usize,
        n: usize,
        kp: usize,
        a: Pairs<'_>,
        b: Rows<&[u32]>,
        c: Rows<&mut [f32]>,
        store: Store,
    ) {
        gemm_pairs_with(PairKernel::Avx2, m, n, kp, a, b, c, store);
    }

    /// A product with operands in bfloat16 pairs.
    type Product = fn(usize, usize, usize, Pairs<'_>, Rows<&[u32]>, Rows<&mut [f32]>, Store);

    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut r = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| r.random_range(-1.0f32..1.0) * 10f32.powi(r.random_range(-3..3)))
            .collect()
    }

    #[test]
    fn rounding_is_to_nearest_even() {
        // 1 + 2^-8 lies halfway between 1 and 1 + 2^-7: ties go to the even significand (1).
        assert_eq!(from_bf16(to_bf16(1.0 + 2f32.powi(-8))), 1.0);
        assert_eq!(
            from_bf16(to_bf16(1.0 + 3.0 * 2f32.powi(-8))),
            1.0 + 2.0 * 2f32.powi(-7)
        );
        assert_eq!(
            from_bf16(to_bf16(1.0 + 2f32.powi(-8) + 2f32.powi(-20))),
            1.0 + 2f32.powi(-7)
        );
        assert_eq!(from_bf16(to_bf16(1e-40)), 0.0);
        assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
        assert_eq!(from_bf16(to_bf16(f32::INFINITY)), f32::INFINITY);
        assert_eq!(from_bf16(to_bf16(f32::MAX)), f32::INFINITY);
    }

    /// The vector packing (where the machine has it) gives the scalar rounding's bits, including
    /// ties, subnormals, infinities and NaN.
    #[test]
    fn packing_matches_the_scalar_rounding() {
        let mut src = values(40 * 64, 3);
        let specials = [
            1.0 + 2f32.powi(-8),
            1.0 + 3.0 * 2f32.powi(-8),
            -1.0 - 2f32.powi(-8),
            1e-40,
            -1e-40,
            0.0,
            -0.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN_POSITIVE,
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0x7f80_0001), // signalling NaN
        ];
        src[..specials.len()].copy_from_slice(&specials);
        let (rows, cols) = (40, 64);
        let mut by_cols = vec![0u32; rows * cols / 2];
        pairs_along_columns(&src, rows, cols, cols, &mut by_cols);
        for i in 0..rows {
            for p in 0..cols / 2 {
                let want = pair(src[i * cols + 2 * p], src[i * cols + 2 * p + 1]);
                assert_eq!(by_cols[i * cols / 2 + p], want, "row {i} pair {p}");
            }
        }
        let mut by_rows = vec![0u32; rows.div_ceil(2) * cols];
        pairs_along_rows(&src, rows - 1, cols, cols, &mut by_rows);
        for p in 0..rows.div_ceil(2) {
            for j in 0..cols {
                let odd = if 2 * p + 1 < rows - 1 {
                    src[(2 * p + 1) * cols + j]
                } else {
                    0.0
                };
                assert_eq!(
                    by_rows[p * cols + j],
                    pair(src[2 * p * cols + j], odd),
                    "pair {p} col {j}"
                );
            }
        }
        #[cfg(target_arch = "x86_64")]
        if super::super::gemm::has_avx2_fma() {
            // The AVX2 packing (used without AVX-512 BF16) against the same reference.
            let mut row = vec![0u32; cols / 2];
            let mut rows2 = vec![0u32; cols];
            for i in 0..rows - 1 {
                let s = &src[i * cols..(i + 1) * cols];
                // SAFETY: AVX2 detected; the rows hold `cols` values.
                let (a, b) = unsafe {
                    (
                        avx2::convert_row(s, &mut row),
                        avx2::interleave_rows(s, &src[(i + 1) * cols..(i + 2) * cols], &mut rows2),
                    )
                };
                assert_eq!((a, b), (cols / 2, cols));
                for p in 0..cols / 2 {
                    assert_eq!(
                        row[p],
                        pair(s[2 * p], s[2 * p + 1]),
                        "AVX2 row {i} pair {p}"
                    );
                }
                for j in 0..cols {
                    let want = pair(s[j], src[(i + 1) * cols + j]);
                    assert_eq!(rows2[j], want, "AVX2 rows {i}, {} col {j}", i + 1);
                }
            }
        }
        println!("vector packing tested: {}", has_bf16());
    }

    /// The product sums the bfloat16-rounded operands (within f32 rounding of the exact sum),
    /// not the f32 operands; and where the machine has AVX-512 BF16, its kernel gives the bits
    /// of the expanded f32 path for every shape of block.
    #[test]
    fn pair_products_match_the_expanded_reference() {
        for &(m, n, k) in &[
            (128usize, 64usize, 64usize),
            (13, 32, 30),
            (7, 16, 128),
            (25, 48, 2),
        ] {
            let a = values(m * k, 1 + m as u64);
            let b = values(k * n, 2 + n as u64);
            let mut a2 = vec![0u32; m * k / 2];
            pairs_along_columns(&a, m, k, k, &mut a2);
            let mut b2 = vec![0u32; k / 2 * n];
            pairs_along_rows(&b, k, n, n, &mut b2);
            let run = |f: Product, store| {
                let mut c = values(m * n, 9);
                f(
                    m,
                    n,
                    k / 2,
                    Pairs {
                        data: &a2,
                        row_stride: k / 2,
                        col_stride: 1,
                    },
                    Rows {
                        data: &b2,
                        stride: n,
                    },
                    Rows {
                        data: &mut c,
                        stride: n,
                    },
                    store,
                );
                c
            };
            for store in [Store::Overwrite, Store::Relu, Store::Accumulate] {
                let expanded = run(gemm_pairs_expanded, store);
                assert_eq!(
                    run(gemm_pairs, store),
                    expanded,
                    "{m}×{n}×{k} {store:?}: best kernel"
                );
                if PairKernel::best() != PairKernel::Expanded {
                    assert_eq!(
                        run(avx2_kernel, store),
                        expanded,
                        "{m}×{n}×{k} {store:?}: AVX2 kernel"
                    );
                }
            }
            // Against the exact sum of the rounded operands, and away from the f32 product.
            let c = run(gemm_pairs, Store::Overwrite);
            let r = |x: f32| f64::from(from_bf16(to_bf16(x)));
            let mut moved = 0;
            for i in 0..m {
                for j in 0..n {
                    let exact: f64 = (0..k).map(|p| r(a[i * k + p]) * r(b[p * n + j])).sum();
                    let size: f64 = (0..k)
                        .map(|p| (r(a[i * k + p]) * r(b[p * n + j])).abs())
                        .sum();
                    let got = f64::from(c[i * n + j]);
                    assert!(
                        (got - exact).abs() <= 1e-6 * size + 1e-30,
                        "{m}×{n}×{k} ({i},{j}): {got} vs {exact}"
                    );
                    let f32_exact: f64 = (0..k)
                        .map(|p| f64::from(a[i * k + p]) * f64::from(b[p * n + j]))
                        .sum();
                    if (got - f32_exact).abs() > 1e-5 * size {
                        moved += 1;
                    }
                }
            }
            assert!(
                moved > m * n / 2,
                "{m}×{n}×{k}: the operands were not rounded to bfloat16"
            );
        }
        println!("best kernel tested: {:?}", PairKernel::best());
    }
}
