//! Small dense products for the fused MLP: `C (+)= A·B` on cache-resident tiles.
//!
//! `A` is read through strides (so `Xᵀ` costs nothing), `B` row by row. The x86-64 kernels are a
//! 6×16 register block (12 AVX accumulators, two B loads and one broadcast per step of the
//! inner dimension — the BLIS Haswell shape), chosen at run time when AVX2 and FMA are present,
//! and a 12×32 block in AVX-512 registers (24 accumulators: half the instructions per
//! multiply-add) where AVX-512F is present too; other machines use the portable loops, which are
//! also the reference of the tests.

/// Operand `A` of [`gemm`]: element `(i, p)` is `data[i·row_stride + p·col_stride]` (f32, or
/// bfloat16 pairs for [`super::bf16::gemm_pairs`]).
#[derive(Clone, Copy, Debug)]
pub struct Strided<'a, T = f32> {
    /// Backing storage.
    pub data: &'a [T],
    /// Distance between rows.
    pub row_stride: usize,
    /// Distance between columns.
    pub col_stride: usize,
}

/// Operand `B`/`C` of [`gemm`]: row `p` starts at `data[p·stride]` and is contiguous.
#[derive(Debug)]
pub struct Rows<T> {
    /// Backing storage.
    pub data: T,
    /// Distance between rows.
    pub stride: usize,
}

/// What happens to the product before it is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Store {
    /// `C = A·B`.
    Overwrite,
    /// `C = max(A·B, 0)` (a ReLU layer).
    Relu,
    /// `C += A·B`.
    Accumulate,
}

/// The kernels behind [`gemm`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Plain loops ([`gemm_portable`]).
    Portable,
    /// 6×16 blocks in AVX2 registers, with FMA.
    Avx2,
    /// 12×32 blocks in AVX-512 registers (the rest of the matrix by the AVX2 kernel): the same
    /// bits as [`Kernel::Avx2`].
    Avx512,
}

impl Kernel {
    /// The fastest kernel this machine has (detected once).
    pub fn best() -> Self {
        static BEST: std::sync::OnceLock<Kernel> = std::sync::OnceLock::new();
        *BEST.get_or_init(|| {
            #[cfg(target_arch = "x86_64")]
            if has_avx2_fma() {
                return if std::is_x86_feature_detected!("avx512f") {
                    Kernel::Avx512
                } else {
                    Kernel::Avx2
                };
            }
            Kernel::Portable
        })
    }
}

/// `C[m×n] (op)= A[m×k] · B[k×n]` with the fastest kernel; `n` must be a multiple of 8.
pub fn gemm(
    m: usize,
    n: usize,
    k: usize,
    a: Strided<'_>,
    b: Rows<&[f32]>,
    c: Rows<&mut [f32]>,
    store: Store,
) {
    gemm_with(Kernel::best(), m, n, k, a, b, c, store);
}

/// [`gemm`] with a given kernel (which the machine must have: at most [`Kernel::best`]).
#[allow(clippy::too_many_arguments)]
pub fn gemm_with(
    kernel: Kernel,
    m: usize,
    n: usize,
    k: usize,
    a: Strided<'_>,
    b: Rows<&[f32]>,
    c: Rows<&mut [f32]>,
    store: Store,
) {
    let rank = |k: Kernel| k as u8;
    assert!(
        rank(kernel) <= rank(Kernel::best()),
        "gemm: this machine has no {kernel:?} kernel"
    );
    assert!(n.is_multiple_of(8), "gemm: n = {n} must be a multiple of 8");
    if !check_bounds(m, n, k, &a, &b, &c) {
        return;
    }
    match kernel {
        // SAFETY (both): the machine has the kernel's features (checked above, detected at run
        // time) and all accesses were bounds-checked above.
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512 => unsafe { avx512::gemm(m, n, k, a, b, c, store) },
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => unsafe { avx2::gemm(m, n, k, a, b, c, store) },
        _ => gemm_portable(m, n, k, a, b, c, store),
    }
}

/// Checks that the operands of `C[m×n] (op)= A[m×k] · B[k×n]` hold every element the product
/// touches (panics otherwise); false when there is nothing to compute.
pub(super) fn check_bounds<T>(
    m: usize,
    n: usize,
    k: usize,
    a: &Strided<'_, T>,
    b: &Rows<&[T]>,
    c: &Rows<&mut [f32]>,
) -> bool {
    if m == 0 || n == 0 {
        return false;
    }
    if k > 0 {
        assert!(
            (m - 1) * a.row_stride + (k - 1) * a.col_stride < a.data.len(),
            "gemm: A out of bounds"
        );
        assert!(
            (k - 1) * b.stride + n <= b.data.len(),
            "gemm: B out of bounds"
        );
    }
    assert!(
        (m - 1) * c.stride + n <= c.data.len(),
        "gemm: C out of bounds"
    );
    true
}

/// Whether the AVX2 + FMA kernel is used on this machine.
pub fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Plain loops (the reference, and the kernel without AVX2).
pub fn gemm_portable(
    m: usize,
    n: usize,
    k: usize,
    a: Strided<'_>,
    b: Rows<&[f32]>,
    c: Rows<&mut [f32]>,
    store: Store,
) {
    let mut acc = vec![0f32; n];
    for i in 0..m {
        acc.fill(0.0);
        for p in 0..k {
            let av = a.data[i * a.row_stride + p * a.col_stride];
            let row = &b.data[p * b.stride..p * b.stride + n];
            for (s, bv) in acc.iter_mut().zip(row) {
                *s += av * bv;
            }
        }
        let out = &mut c.data[i * c.stride..i * c.stride + n];
        match store {
            Store::Overwrite => out.copy_from_slice(&acc),
            Store::Relu => out.iter_mut().zip(&acc).for_each(|(o, s)| *o = s.max(0.0)),
            Store::Accumulate => out.iter_mut().zip(&acc).for_each(|(o, s)| *o += s),
        }
    }
}

/// The raw operands of a register block: `k` steps of the inner dimension, A at `a` (row stride
/// `ars`, column stride `acs`), B at `b` (row stride `ldb`), C at `c` (row stride `ldc`). The
/// operands are f32, or bfloat16 pairs (`u32`) for [`super::bf16`].
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(super) struct Block<T = f32> {
    pub(super) k: usize,
    pub(super) a: *const T,
    pub(super) ars: usize,
    pub(super) acs: usize,
    pub(super) b: *const T,
    pub(super) ldb: usize,
    pub(super) c: *mut f32,
    pub(super) ldc: usize,
    pub(super) store: Store,
}

#[cfg(target_arch = "x86_64")]
impl<T> Block<T> {
    /// The whole product's operands (the caller checked their bounds).
    pub(super) fn new(
        k: usize,
        a: &Strided<'_, T>,
        b: &Rows<&[T]>,
        c: &mut Rows<&mut [f32]>,
        store: Store,
    ) -> Self {
        Self {
            k,
            a: a.data.as_ptr(),
            ars: a.row_stride,
            acs: a.col_stride,
            b: b.data.as_ptr(),
            ldb: b.stride,
            c: c.data.as_mut_ptr(),
            ldc: c.stride,
            store,
        }
    }

    /// The block starting at row `i` and column `j` of C.
    ///
    /// # Safety
    /// Row `i` and column `j` lie inside the operands.
    pub(super) unsafe fn at(self, i: usize, j: usize) -> Self {
        // SAFETY: inside the operands (the caller's promise).
        unsafe {
            Self {
                a: self.a.add(i * self.ars),
                b: self.b.add(j),
                c: self.c.add(i * self.ldc + j),
                ..self
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod avx2 {
    use crate::cpu::gemm::{Block, Rows, Store, Strided};
    use std::arch::x86_64::*;

    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn gemm(
        m: usize,
        n: usize,
        k: usize,
        a: Strided<'_>,
        b: Rows<&[f32]>,
        mut c: Rows<&mut [f32]>,
        store: Store,
    ) {
        let whole = Block::new(k, &a, &b, &mut c, store);
        let mut i = 0;
        // SAFETY (all blocks): rows i..i+MR ≤ m and columns j..j+8·NV ≤ n, checked by the caller.
        unsafe {
            while i + 6 <= m {
                row_block::<6>(n, whole.at(i, 0));
                i += 6;
            }
            let rest = whole.at(i, 0);
            match m - i {
                1 => row_block::<1>(n, rest),
                2 => row_block::<2>(n, rest),
                3 => row_block::<3>(n, rest),
                4 => row_block::<4>(n, rest),
                5 => row_block::<5>(n, rest),
                _ => {}
            }
        }
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn row_block<const MR: usize>(n: usize, rows: Block) {
        let mut j = 0;
        // SAFETY: see `gemm`.
        unsafe {
            while j + 16 <= n {
                micro::<MR, 2>(rows.at(0, j));
                j += 16;
            }
            if j < n {
                micro::<MR, 1>(rows.at(0, j));
            }
        }
    }

    /// An `MR × 8·NV` block of C accumulated in registers over the whole inner dimension.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn micro<const MR: usize, const NV: usize>(o: Block) {
        // SAFETY: see `gemm`.
        unsafe {
            let mut acc = [[_mm256_setzero_ps(); NV]; MR];
            for p in 0..o.k {
                let brow = o.b.add(p * o.ldb);
                let mut bv = [_mm256_setzero_ps(); NV];
                for (v, bvv) in bv.iter_mut().enumerate() {
                    *bvv = _mm256_loadu_ps(brow.add(8 * v));
                }
                let acol = o.a.add(p * o.acs);
                for (i, acc_i) in acc.iter_mut().enumerate() {
                    let av = _mm256_broadcast_ss(&*acol.add(i * o.ars));
                    for v in 0..NV {
                        acc_i[v] = _mm256_fmadd_ps(av, bv[v], acc_i[v]);
                    }
                }
            }
            store_block(&acc, o);
        }
    }

    /// Stores (or adds) an `MR × 8·NV` block of sums at `o`'s C, as `o.store` says.
    ///
    /// # Safety
    /// The block lies inside C.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(in crate::cpu) unsafe fn store_block<T, const MR: usize, const NV: usize>(
        acc: &[[__m256; NV]; MR],
        o: Block<T>,
    ) {
        let zero = _mm256_setzero_ps();
        // SAFETY: inside C (the caller's promise).
        unsafe {
            for (i, acc_i) in acc.iter().enumerate() {
                let crow = o.c.add(i * o.ldc);
                for (v, accv) in acc_i.iter().enumerate() {
                    let dst = crow.add(8 * v);
                    let val = match o.store {
                        Store::Overwrite => *accv,
                        Store::Relu => _mm256_max_ps(*accv, zero),
                        Store::Accumulate => _mm256_add_ps(_mm256_loadu_ps(dst), *accv),
                    };
                    _mm256_storeu_ps(dst, val);
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod avx512 {
    use crate::cpu::gemm::{Block, Rows, Store, Strided};
    use std::arch::x86_64::*;

    /// Rows in blocks of 12 and columns in blocks of 32 (24 accumulators in the 32 zmm
    /// registers); the rows and columns left over go to the AVX2 kernel. Each element sums its
    /// products with fused multiply-adds in the inner dimension's order, as the AVX2 kernel does:
    /// the same bits.
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub(super) unsafe fn gemm(
        m: usize,
        n: usize,
        k: usize,
        a: Strided<'_>,
        b: Rows<&[f32]>,
        mut c: Rows<&mut [f32]>,
        store: Store,
    ) {
        const MR: usize = 12;
        let (m12, n32) = (m / MR * MR, n / 32 * 32);
        let whole = Block::new(k, &a, &b, &mut c, store);
        // SAFETY: rows i..i+12 ≤ m and columns j..j+32 ≤ n, bounds checked by the caller.
        unsafe {
            for i in (0..m12).step_by(MR) {
                for j in (0..n32).step_by(32) {
                    micro::<MR>(whole.at(i, j));
                }
            }
        }
        let (ars, ldb, ldc) = (a.row_stride, b.stride, c.stride);
        // SAFETY (both calls): sub-blocks of the checked operands; AVX2 and FMA are present.
        unsafe {
            if n32 < n && m12 > 0 {
                let b = Rows {
                    data: &b.data[n32..],
                    stride: ldb,
                };
                let c = Rows {
                    data: &mut c.data[n32..],
                    stride: ldc,
                };
                crate::cpu::gemm::avx2::gemm(m12, n - n32, k, a, b, c, store);
            }
            if m12 < m {
                let a = Strided {
                    data: &a.data[m12 * ars..],
                    ..a
                };
                let c = Rows {
                    data: &mut c.data[m12 * ldc..],
                    stride: ldc,
                };
                crate::cpu::gemm::avx2::gemm(m - m12, n, k, a, b, c, store);
            }
        }
    }

    /// An `MR × 32` block of C accumulated in registers over the whole inner dimension.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn micro<const MR: usize>(o: Block) {
        // SAFETY: see `gemm`.
        unsafe {
            let mut acc = [[_mm512_setzero_ps(); 2]; MR];
            for p in 0..o.k {
                let brow = o.b.add(p * o.ldb);
                let (b0, b1) = (_mm512_loadu_ps(brow), _mm512_loadu_ps(brow.add(16)));
                let acol = o.a.add(p * o.acs);
                for (i, acc_i) in acc.iter_mut().enumerate() {
                    let av = _mm512_set1_ps(*acol.add(i * o.ars));
                    acc_i[0] = _mm512_fmadd_ps(av, b0, acc_i[0]);
                    acc_i[1] = _mm512_fmadd_ps(av, b1, acc_i[1]);
                }
            }
            store_block(&acc, o);
        }
    }

    /// Stores (or adds) an `MR × 16·NV` block of sums at `o`'s C, as `o.store` says.
    ///
    /// # Safety
    /// The block lies inside C.
    #[inline]
    #[target_feature(enable = "avx512f")]
    pub(in crate::cpu) unsafe fn store_block<T, const MR: usize, const NV: usize>(
        acc: &[[__m512; NV]; MR],
        o: Block<T>,
    ) {
        let zero = _mm512_setzero_ps();
        // SAFETY: inside C (the caller's promise).
        unsafe {
            for (i, acc_i) in acc.iter().enumerate() {
                let crow = o.c.add(i * o.ldc);
                for (v, accv) in acc_i.iter().enumerate() {
                    let dst = crow.add(16 * v);
                    let val = match o.store {
                        Store::Overwrite => *accv,
                        Store::Relu => _mm512_max_ps(*accv, zero),
                        Store::Accumulate => _mm512_add_ps(_mm512_loadu_ps(dst), *accv),
                    };
                    _mm512_storeu_ps(dst, val);
                }
            }
        }
    }
}
