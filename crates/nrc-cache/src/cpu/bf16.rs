//! Products with bfloat16 operands and f32 sums, for the MLP with `"precision": "bf16"`.
//!
//! Operands are rounded to bfloat16 (8-bit significand, f32's exponent range) and kept in
//! **pairs** along the inner dimension: one `u32` holds elements `2p` (low half) and `2p + 1`
//! (high half). Each step of a product multiplies one pair of `A` by one pair of `B` and adds
//! both products to the f32 sum, odd element first: exactly what AVX-512 BF16's `vdpbf16ps`
//! does, which on this project's CPUs (AMD Zen 4) multiplies-adds twice as many values per
//! cycle as the f32 fused multiply-add. A product of two bfloat16 values is exact in f32, so
//! each addition rounds once, as a fused multiply-add does: machines without AVX-512 BF16 get
//! the same bits from the f32 kernels ([`super::gemm`]) on the pairs expanded in that order
//! (except where a sum falls below f32's normal range, which `vdpbf16ps` flushes to zero).
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
/// signed zero; NaN stays a (quiet) NaN.
#[inline]
pub fn to_bf16(v: f32) -> u16 {
    let bits = v.to_bits();
    if v.is_nan() {
        return ((bits >> 16) | 0x40) as u16;
    }
    if v != 0.0 && v.abs() < f32::MIN_POSITIVE {
        return ((bits >> 16) & 0x8000) as u16;
    }
    let round = 0x7fff + ((bits >> 16) & 1);
    (bits.wrapping_add(round) >> 16) as u16
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
        if let (true, Some(odd)) = (has_bf16(), odd) {
            // SAFETY: AVX-512 BF16 detected; both rows hold `o.len()` values.
            done = unsafe { avx512::interleave_rows(even, odd, o) };
        }
        for j in done..cols {
            o[j] = pair(even[j], odd.map_or(0.0, |r| r[j]));
        }
    }
}

/// Operand `A` of [`gemm_pairs`]: pair `(i, p)` is `data[i·row_stride + p·col_stride]`.
pub type Pairs<'a> = Strided<'a, u32>;

/// `C[m×n] (op)= A[m×2kp] · B[2kp×n]` with both operands in bfloat16 pairs along the inner
/// dimension (`A` as [`Pairs`], `B` as rows of `n` pairs) and f32 sums; `n` must be a multiple
/// of 16. The AVX-512 BF16 kernel where the machine has it, otherwise the f32 kernels on the
/// expanded pairs (the same bits; see the module documentation).
pub fn gemm_pairs(
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
    #[cfg(target_arch = "x86_64")]
    if has_bf16() {
        // SAFETY: AVX-512 BF16 detected; every access was bounds-checked above.
        unsafe { avx512::gemm(m, n, kp, a, b, c, store) };
        return;
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

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::super::gemm::Block;
    use super::super::gemm::avx512::store_block;
    use super::{Pairs, Rows, Store};
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
    #[target_feature(enable = "avx512f,avx512bf16,avx512bw")]
    pub(super) unsafe fn gemm(
        m: usize,
        n: usize,
        kp: usize,
        a: Pairs<'_>,
        b: Rows<&[u32]>,
        mut c: Rows<&mut [f32]>,
        store: Store,
    ) {
        let o = Block::new(kp, &a, &b, &mut c, store);
        let mut i = 0;
        // SAFETY: rows i..i + MR ≤ m, columns below n (checked by the caller).
        unsafe {
            for (mr, block) in [
                (12, row_block::<12> as unsafe fn(usize, Block<u32>)),
                (4, row_block::<4>),
                (1, row_block::<1>),
            ] {
                while i + mr <= m {
                    block(n, o.at(i, 0));
                    i += mr;
                }
            }
        }
    }

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
                let fast = run(gemm_pairs, store);
                assert_eq!(fast, expanded, "{m}×{n}×{k} {store:?}: kernel bits differ");
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
        println!("AVX-512 BF16 kernel tested: {}", has_bf16());
    }
}
