//! Adam and the weight EMA on the CPU: dense for the MLP, sparse (lazy) for the hash table.
//!
//! The table's state is stored per entry as one record `[w (F) | m (F) | v (F) | q (F)]`
//! ([`RECORD`] · F floats), so an update touches one or two cache lines instead of four: the
//! sparse step is bound by memory traffic.
//!
//! **Sparse semantics for the hash table** (PyTorch `SparseAdam`): an entry not referenced by
//! any sample of a step keeps its weights and Adam moments unchanged that step; referenced
//! entries get the standard Adam update with the global step's bias correction.
//!
//! **The table's EMA as a scaled gap.** The raw EMA `e` of every entry moves every step, also
//! where the weight does not: `e ← α·e + (1 − α)·w`. While `w` is constant the gap `e − w`
//! shrinks by `α` per step, so the record stores it scaled to a base step `b` shared by the
//! whole table: `q = (e_t − w_t)·α^−(t−b)`, which is constant while the entry is not
//! referenced. At any step `t`, `e_t = w_t + α^(t−b)·q`. A referenced entry's update from
//! `w_old` to `w_new` at step `t` adds `α^(1−(t−b))·(w_old − w_new)` to `q` (from
//! `e_t = α·e_(t−1) + (1 − α)·w_new`). No per-entry step count is stored or read (it cost a
//! fifth of the sparse step's memory traffic), and the update needs one multiply-add. The scale
//! `α^−(t−b)` grows with `t`; every [`ema_rebase_interval`] steps the whole table is rebased
//! (`q ← α^(t−b)·q`, `b ← t`) so it stays below 2^40.

use burn::tensor::f16;

use crate::config::AdamParams;

/// Per-step constants of Adam and the EMA.
#[derive(Clone, Debug)]
pub struct StepConstants {
    /// Adam parameters.
    pub adam: AdamParams,
    /// EMA decay α (None: no EMA).
    pub ema: Option<f32>,
    /// The step being taken, counted from 1.
    pub step: u32,
    /// `1 − β1^t`.
    pub bc1: f32,
    /// `1 − β2^t`.
    pub bc2: f32,
    /// `learning rate / (1 − β1^t)`.
    pub step_size: f32,
    /// `1 / (1 − β2^t)`.
    pub inv_bc2: f32,
    /// `α^(1 − (step − base))`: the factor of a weight change in the table's EMA gap.
    pub gap_growth: f32,
}

impl StepConstants {
    /// Constants of step `step` (≥ 1), the table's EMA gap scaled to step `ema_base` (< `step`;
    /// see the module documentation).
    pub fn new(adam: AdamParams, ema: Option<f32>, step: u32, ema_base: u32) -> Self {
        assert!(
            ema_base < step,
            "EMA base {ema_base} not before step {step}"
        );
        let t = step.min(i32::MAX as u32) as i32;
        let (bc1, bc2) = (1.0 - adam.beta1.powi(t), 1.0 - adam.beta2.powi(t));
        Self {
            adam,
            ema,
            step,
            bc1,
            bc2,
            step_size: adam.learning_rate / bc1,
            inv_bc2: 1.0 / bc2,
            gap_growth: ema.map_or(1.0, |alpha| 1.0 / decay_pow(alpha, step - 1 - ema_base)),
        }
    }

    /// One Adam update of a single weight; returns the new weight. Non-finite gradients are
    /// treated as zero so that no weight ever becomes non-finite.
    #[inline(always)]
    pub fn adam(&self, w: &mut f32, m: &mut f32, v: &mut f32, g: f32) {
        let a = &self.adam;
        let g = if g.is_finite() {
            g + a.l2_reg * *w
        } else {
            a.l2_reg * *w
        };
        *m = a.beta1 * *m + (1.0 - a.beta1) * g;
        *v = a.beta2 * *v + (1.0 - a.beta2) * g * g;
        // lr · (m / (1 − β1^t)) / (sqrt(v / (1 − β2^t)) + ε), divisions hoisted per step.
        let upd = self.step_size * *m / ((*v * self.inv_bc2).sqrt() + a.epsilon);
        if upd.is_finite() {
            *w -= upd;
        }
    }
}

/// `α^k` (the decay of an EMA over `k` steps).
#[inline(always)]
pub fn decay_pow(alpha: f32, k: u32) -> f32 {
    alpha.powi(k.min(i32::MAX as u32) as i32)
}

/// Steps between rebases of the table's EMA gap for decay `alpha`: the gap's scale
/// `α^−(t−b)` stays at most 2^40 (so `α^(t−b)` does not underflow either). One step for
/// `alpha = 0` (whose EMA is the weight itself).
pub fn ema_rebase_interval(alpha: f32) -> u32 {
    let per_step = -f64::from(alpha).ln();
    if per_step.is_nan() || per_step <= 0.0 {
        return u32::MAX; // α ≥ 1: the scale never grows (the configuration rejects such α)
    }
    ((40.0 * std::f64::consts::LN_2 / per_step).floor() as u32).max(1)
}

/// Dense Adam + EMA over a parameter group (the MLP), consuming `grad`.
pub fn dense_step(
    c: &StepConstants,
    w: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    ema: &mut [f32],
    grad: &[f32],
) {
    for i in 0..w.len() {
        c.adam(&mut w[i], &mut m[i], &mut v[i], grad[i]);
        if let Some(alpha) = c.ema {
            ema[i] = alpha * ema[i] + (1.0 - alpha) * w[i];
        }
    }
}

/// Floats per feature in a table record (weight, first moment, second moment, EMA).
pub const RECORD: usize = 4;

/// Packs separate arrays into records `[w | m | v | ema]` of `f` features each.
pub fn pack_records(f: usize, w: &[f32], m: &[f32], v: &[f32], ema: &[f32]) -> Vec<f32> {
    let entries = w.len() / f.max(1);
    let mut out = super::huge::huge_vec(w.len() * RECORD, 0f32);
    for e in 0..entries {
        let r = &mut out[e * RECORD * f..(e + 1) * RECORD * f];
        r[..f].copy_from_slice(&w[e * f..(e + 1) * f]);
        r[f..2 * f].copy_from_slice(&m[e * f..(e + 1) * f]);
        r[2 * f..3 * f].copy_from_slice(&v[e * f..(e + 1) * f]);
        r[3 * f..].copy_from_slice(&ema[e * f..(e + 1) * f]);
    }
    out
}

/// Splits records back into (w, m, v, ema).
pub fn unpack_records(f: usize, records: &[f32]) -> [Vec<f32>; 4] {
    let n = records.len() / RECORD;
    let mut out = [vec![0f32; n], vec![0f32; n], vec![0f32; n], vec![0f32; n]];
    for (e, r) in records.chunks_exact(RECORD * f).enumerate() {
        for (k, o) in out.iter_mut().enumerate() {
            o[e * f..(e + 1) * f].copy_from_slice(&r[k * f..(k + 1) * f]);
        }
    }
    out
}

/// The weights of the records (`f` features per entry) rounded to half precision, as
/// [`TableValue::from_f32`] rounds them: the table the training forward reads with
/// `"training_precision": "f16"`.
pub fn half_weights(f: usize, records: &[f32]) -> Vec<f16> {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 14;
    let mut out = super::huge::huge_vec(records.len() / RECORD, f16::ZERO);
    out.par_chunks_mut(CHUNK * f)
        .zip(records.par_chunks(CHUNK * f * RECORD))
        .for_each(|(o, r)| {
            for (o, r) in o.chunks_exact_mut(f).zip(r.chunks_exact(RECORD * f)) {
                for (o, w) in o.iter_mut().zip(&r[..f]) {
                    *o = TableValue::from_f32(*w);
                }
            }
        });
    out
}

/// Sparse Adam + EMA over part of a hash-grid level (`grad.len() / f` entries): for every
/// entry whose bit is set in `touched`, updates its record (`f` features) from `grad` (which is
/// zeroed), including its EMA gap; with `half`, also stores the new weights there rounded to
/// half precision (as [`half_weights`]). The bitmap is cleared.
pub fn sparse_step(
    c: &StepConstants,
    f: usize,
    touched: &mut [u64],
    records: &mut [f32],
    grad: &mut [f32],
    half: Option<&mut [f16]>,
) {
    if let Some(h) = &half {
        assert_eq!(h.len(), grad.len(), "one half per gradient value");
    }
    match f {
        1 => sparse_step_f::<1>(c, touched, records, grad, half),
        2 => sparse_step_f::<2>(c, touched, records, grad, half),
        4 => sparse_step_f::<4>(c, touched, records, grad, half),
        8 => sparse_step_f::<8>(c, touched, records, grad, half),
        _ => panic!("unsupported features per level {f}"),
    }
}

/// [`sparse_step`] for `F` features (a compile-time constant, so the record loop unrolls). With
/// two features on a CPU with AVX2, four entries are updated at once
/// ([`sparse_step_f2_avx2`]); the same operations per value, so the same bits.
fn sparse_step_f<const F: usize>(
    c: &StepConstants,
    touched: &mut [u64],
    records: &mut [f32],
    grad: &mut [f32],
    half: Option<&mut [f16]>,
) {
    let entries = grad.len() / F;
    assert!(records.len() >= entries * RECORD * F);
    assert!(touched.len() * 64 <= entries.next_multiple_of(64));
    #[cfg(target_arch = "x86_64")]
    if F == 2 && super::gemm::has_avx2_fma() && super::grid::has_f16c() {
        // SAFETY: AVX2, FMA and F16C were detected; every touched entry is below `entries`
        // (the bitmap's bits beyond the last entry are never set by the scatter, and the
        // indices are checked again inside), and the slices' lengths were checked above.
        unsafe { sparse_step_f2_avx2(c, touched, records, grad, half) };
        return;
    }
    sparse_step_portable::<F>(c, touched, records, grad, half);
}

/// The portable loop of [`sparse_step`] for `F` features (public for the test that compares it
/// with the AVX2 kernel).
pub fn sparse_step_portable<const F: usize>(
    c: &StepConstants,
    touched: &mut [u64],
    records: &mut [f32],
    grad: &mut [f32],
    mut half: Option<&mut [f16]>,
) {
    drain_bits(touched, |e| {
        update_entry::<F>(c, e, records, grad, half.as_deref_mut())
    });
}

/// Calls `f` with the index of every set bit of `bits`, in increasing order, and clears them.
#[inline(always)]
fn drain_bits(bits: &mut [u64], mut f: impl FnMut(usize)) {
    for (word_index, word) in bits.iter_mut().enumerate() {
        let mut w = std::mem::take(word);
        while w != 0 {
            f(word_index * 64 + w.trailing_zeros() as usize);
            w &= w - 1;
        }
    }
}

/// Adam and the EMA gap of one table entry (and its half-precision weights).
#[inline(always)]
fn update_entry<const F: usize>(
    c: &StepConstants,
    e: usize,
    records: &mut [f32],
    grad: &mut [f32],
    half: Option<&mut [f16]>,
) {
    let r = &mut records[e * RECORD * F..(e + 1) * RECORD * F];
    let g = &mut grad[e * F..(e + 1) * F];
    for j in 0..F {
        let w_old = r[j];
        let (mut w, mut m, mut v) = (r[j], r[F + j], r[2 * F + j]);
        c.adam(&mut w, &mut m, &mut v, g[j]);
        r[j] = w;
        r[F + j] = m;
        r[2 * F + j] = v;
        g[j] = 0.0;
        if c.ema.is_some() {
            r[3 * F + j] += c.gap_growth * (w_old - w);
        }
    }
    if let Some(h) = half {
        for (h, w) in h[e * F..(e + 1) * F].iter_mut().zip(&r[..F]) {
            *h = TableValue::from_f32(*w);
        }
    }
}

/// [`sparse_step_portable`] for two features, four touched entries at a time: their records
/// `[w0 w1 | m0 m1 | v0 v1 | q0 q1]` are transposed (as 64-bit pairs) into one register each of
/// weights, moments and EMA gaps, so one square root and one division serve eight values. Each
/// value goes through the same IEEE operations in the same order as [`StepConstants::adam`]
/// (no fused multiply-adds), so the results are bit-identical. A remainder of fewer than four
/// entries takes the scalar update.
///
/// # Safety
/// The CPU has AVX2 and F16C; `records` holds four floats per value of `grad` (and `half`, if
/// any, one half).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn sparse_step_f2_avx2(
    c: &StepConstants,
    touched: &mut [u64],
    records: &mut [f32],
    grad: &mut [f32],
    mut half: Option<&mut [f16]>,
) {
    use std::arch::x86_64::*;
    let a = &c.adam;
    let set = _mm256_set1_ps;
    let (l2, b1, nb1, b2, nb2) = (
        set(a.l2_reg),
        set(a.beta1),
        set(1.0 - a.beta1),
        set(a.beta2),
        set(1.0 - a.beta2),
    );
    let (step_size, inv_bc2, eps) = (set(c.step_size), set(c.inv_bc2), set(a.epsilon));
    let gap_growth = set(c.gap_growth);
    let zero = _mm256_setzero_ps();
    let (half_lowest, half_highest) = (set(-HALF_MAX), set(HALF_MAX));
    let rec = records.as_mut_ptr();
    let update4 = |es: [usize; 4], grad: &mut [f32], half: Option<&mut [f16]>| {
        let mut g = [0f64; 4];
        for (q, &e) in es.iter().enumerate() {
            let gp = &mut grad[2 * e..2 * e + 2];
            g[q] = f64::from_bits(u64::from(gp[0].to_bits()) | (u64::from(gp[1].to_bits()) << 32));
            gp.fill(0.0);
        }
        // SAFETY (whole block): `2e + 2 ≤ grad.len()` was checked by the indexing above, so
        // each record `rec[8e..8e + 8]` is inside `records`.
        unsafe {
            let load = |e: usize| _mm256_loadu_pd(rec.add(8 * e).cast::<f64>().cast_const());
            let (ra, rb, rc, rd) = (load(es[0]), load(es[1]), load(es[2]), load(es[3]));
            let t0 = _mm256_unpacklo_pd(ra, rb); // [Aw Bw Av Bv]
            let t1 = _mm256_unpackhi_pd(ra, rb); // [Am Bm Ae Be]
            let t2 = _mm256_unpacklo_pd(rc, rd);
            let t3 = _mm256_unpackhi_pd(rc, rd);
            let w = _mm256_castpd_ps(_mm256_permute2f128_pd::<0x20>(t0, t2));
            let v = _mm256_castpd_ps(_mm256_permute2f128_pd::<0x31>(t0, t2));
            let m = _mm256_castpd_ps(_mm256_permute2f128_pd::<0x20>(t1, t3));
            let e = _mm256_castpd_ps(_mm256_permute2f128_pd::<0x31>(t1, t3));
            let g = _mm256_castpd_ps(_mm256_loadu_pd(g.as_ptr()));
            // Adam, as `StepConstants::adam`.
            let finite = |x: __m256| _mm256_cmp_ps::<_CMP_EQ_OQ>(_mm256_sub_ps(x, x), zero);
            let l2w = _mm256_mul_ps(l2, w);
            let g = _mm256_blendv_ps(l2w, _mm256_add_ps(g, l2w), finite(g));
            let m = _mm256_add_ps(_mm256_mul_ps(b1, m), _mm256_mul_ps(nb1, g));
            let v = _mm256_add_ps(
                _mm256_mul_ps(b2, v),
                _mm256_mul_ps(_mm256_mul_ps(nb2, g), g),
            );
            let upd = _mm256_div_ps(
                _mm256_mul_ps(step_size, m),
                _mm256_add_ps(_mm256_sqrt_ps(_mm256_mul_ps(v, inv_bc2)), eps),
            );
            let w_new = _mm256_blendv_ps(w, _mm256_sub_ps(w, upd), finite(upd));
            if let Some(h) = half {
                // The four entries' two weights as halves, clamped and rounded to nearest even
                // as `TableValue::from_f32`.
                let clamped = _mm256_min_ps(_mm256_max_ps(w_new, half_lowest), half_highest);
                let pairs = _mm256_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(clamped);
                let h = bytemuck::cast_slice_mut::<f16, u32>(h);
                h[es[0]] = _mm_extract_epi32::<0>(pairs) as u32;
                h[es[1]] = _mm_extract_epi32::<1>(pairs) as u32;
                h[es[2]] = _mm_extract_epi32::<2>(pairs) as u32;
                h[es[3]] = _mm_extract_epi32::<3>(pairs) as u32;
            }
            let e = if c.ema.is_some() {
                _mm256_add_ps(e, _mm256_mul_ps(gap_growth, _mm256_sub_ps(w, w_new)))
            } else {
                e
            };
            // Back to records.
            let (w, m, v, e) = (
                _mm256_castps_pd(w_new),
                _mm256_castps_pd(m),
                _mm256_castps_pd(v),
                _mm256_castps_pd(e),
            );
            let u0 = _mm256_unpacklo_pd(w, m); // [Aw Am Cw Cm]
            let u1 = _mm256_unpackhi_pd(w, m); // [Bw Bm Dw Dm]
            let u2 = _mm256_unpacklo_pd(v, e); // [Av Ae Cv Ce]
            let u3 = _mm256_unpackhi_pd(v, e);
            let store = |e: usize, x: __m256d| _mm256_storeu_pd(rec.add(8 * e).cast::<f64>(), x);
            store(es[0], _mm256_permute2f128_pd::<0x20>(u0, u2));
            store(es[1], _mm256_permute2f128_pd::<0x20>(u1, u3));
            store(es[2], _mm256_permute2f128_pd::<0x31>(u0, u2));
            store(es[3], _mm256_permute2f128_pd::<0x31>(u1, u3));
        }
    };
    // The touched entries in increasing order, each group's records requested 64 entries
    // (about 9 KiB of records) before they are updated: with the hardware prefetchers alone the
    // loads of the records waited on memory (most of this loop's time, by `perf`); the software
    // requests cut the update's time by 10–25 % (docs/benchmarks-log.md). The order, and so every bit of
    // the result, is unchanged.
    const AHEAD_ENTRIES: usize = 64;
    ORDER.with_borrow_mut(|order| {
        order.clear();
        drain_bits(touched, |e| order.push(e as u32));
        let groups = order.len() / 4;
        for q in 0..groups {
            for &e in order.iter().skip(4 * q + AHEAD_ENTRIES).take(4) {
                super::grid::prefetch(rec.wrapping_add(8 * e as usize).cast_const());
            }
            let g = &order[4 * q..4 * q + 4];
            update4(
                [g[0], g[1], g[2], g[3]].map(|e| e as usize),
                grad,
                half.as_deref_mut(),
            );
        }
        for &e in &order[4 * groups..] {
            update_entry::<2>(c, e as usize, records, grad, half.as_deref_mut());
        }
    });
}

thread_local! {
    /// Each thread's list of touched entries for [`sparse_step_f2_avx2`], kept between calls
    /// (one call per bin, hundreds per step).
    static ORDER: std::cell::RefCell<Vec<u32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Applies `f` to every entry's `(w, q)` pairs of the records (`features` per entry), in
/// parallel.
fn for_each_gap(features: usize, records: &mut [f32], f: impl Fn(f32, &mut f32) + Sync) {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 14;
    let rec = RECORD * features;
    records.par_chunks_mut(CHUNK * rec).for_each(|chunk| {
        for r in chunk.chunks_exact_mut(rec) {
            let (w, rest) = r.split_at_mut(features);
            for (w, q) in w.iter().zip(&mut rest[2 * features..]) {
                f(*w, q);
            }
        }
    });
}

/// Turns the records' raw EMA into the EMA gap at base step "now" (`q = e − w`).
pub fn ema_gap_from_raw(features: usize, records: &mut [f32]) {
    for_each_gap(features, records, |w, q| *q -= w);
}

/// Turns the records' EMA gap into the raw EMA `shift` steps after its base
/// (`e = w + α^shift·q`).
pub fn ema_raw_from_gap(alpha: f32, shift: u32, features: usize, records: &mut [f32]) {
    let a = decay_pow(alpha, shift);
    for_each_gap(features, records, |w, q| *q = w + a * *q);
}

/// Sets the records' EMA slot to `scale·w` (see [`crate::ops::EmaConversion::ScaledWeights`]).
pub fn ema_scaled_weights(scale: f32, features: usize, records: &mut [f32]) {
    for_each_gap(features, records, |w, q| *q = scale * w);
}

/// Moves the base of the records' EMA gap `shift` steps on (`q ← α^shift·q`).
pub fn rebase_ema_gap(alpha: f32, shift: u32, features: usize, records: &mut [f32]) {
    let a = decay_pow(alpha, shift);
    for_each_gap(features, records, |_, q| *q *= a);
}

/// Bias-corrected EMA weights of a table at `step` without modifying the state (records of `f`
/// features): `(w + α^(step−base)·q) / (1 − α^step)` with the EMA gap `q` at base `base`, or
/// `e / (1 − α^step)` with `base = None` (the records hold the raw EMA `e` at `step`); the
/// weights themselves at step 0 or without EMA.
pub fn materialize_grid(
    alpha: Option<f32>,
    step: u32,
    base: Option<u32>,
    f: usize,
    records: &[f32],
    out: &mut [f32],
) {
    // SAFETY: `MaybeUninit<f32>` has the layout of `f32`, and `materialize_grid_into` only
    // writes initialised values through the view.
    let out = unsafe {
        std::slice::from_raw_parts_mut(
            out.as_mut_ptr().cast::<std::mem::MaybeUninit<f32>>(),
            out.len(),
        )
    };
    materialize_grid_into(alpha, step, base, f, records, out);
}

/// A value type of the materialised inference table: `f32`, or `f16` (see
/// [`crate::encoding::hash_grid::TablePrecision`]).
pub trait TableValue: Copy + Send + Sync {
    /// Whether the value is a half (the AVX2 loop converts eight at once).
    const HALF: bool;
    /// The value nearest `v` (halves clamp to ±65504 rather than overflow).
    fn from_f32(v: f32) -> Self;
}

impl TableValue for f32 {
    const HALF: bool = false;
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
}

impl TableValue for f16 {
    const HALF: bool = true;
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        f16::from_f32(v.clamp(-HALF_MAX, HALF_MAX))
    }
}

/// The largest finite half.
const HALF_MAX: f32 = 65504.0;

/// [`materialize_grid`] into memory not yet initialised, as `T`: writes every element of `out`
/// (`f` per record), so a fresh buffer needs no zero fill (whose page faults, on one thread,
/// cost more than the pass itself on a 2^19 table).
pub fn materialize_grid_into<T: TableValue>(
    alpha: Option<f32>,
    step: u32,
    base: Option<u32>,
    f: usize,
    records: &[f32],
    out: &mut [std::mem::MaybeUninit<T>],
) {
    assert_eq!(
        out.len() * RECORD,
        records.len(),
        "one output per record feature"
    );
    let Some(alpha) = alpha.filter(|_| step > 0) else {
        for (o, r) in out
            .chunks_exact_mut(f)
            .zip(records.chunks_exact(RECORD * f))
        {
            for (o, r) in o.iter_mut().zip(&r[..f]) {
                o.write(T::from_f32(*r));
            }
        }
        return;
    };
    let inv = 1.0 / (1.0 - decay_pow(alpha, step));
    // `None`: the raw EMA, `e · inv`.
    let a = base.map(|b| {
        assert!(b <= step, "EMA base {b} after step {step}");
        decay_pow(alpha, step - b)
    });
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if f == 2 && super::gemm::has_avx2_fma() && super::grid::has_f16c() {
        // SAFETY: AVX2, FMA and F16C were detected; the lengths of `records` and `out` were
        // checked above.
        done = unsafe { materialize_pairs_avx2(a, inv, records, out) };
    }
    for (o, r) in out[done * f..]
        .chunks_exact_mut(f)
        .zip(records[done * RECORD * f..].chunks_exact(RECORD * f))
    {
        for j in 0..f {
            let e = match a {
                Some(a) => r[j] + a * r[3 * f + j],
                None => r[3 * f + j],
            };
            o[j].write(T::from_f32(e * inv));
        }
    }
}

/// The AVX2 form of [`materialize_grid_into`]'s loop for two features, four entries per
/// register and the same operations in the same order (the same bits; halves are clamped and
/// rounded to nearest even, as [`TableValue::from_f32`]). Returns how many leading entries it
/// wrote (all but the last `len % 4`, which the caller's loop finishes).
///
/// # Safety
/// The CPU has AVX2, FMA and F16C; `records` holds `RECORD · 2` floats per entry, and `out` two
/// per entry.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn materialize_pairs_avx2<T: TableValue>(
    a: Option<f32>,
    inv: f32,
    records: &[f32],
    out: &mut [std::mem::MaybeUninit<T>],
) -> usize {
    use std::arch::x86_64::*;
    const REC: usize = RECORD * 2;
    let entries = out.len() / 2;
    let (raw, a, inv) = (
        a.is_none(),
        _mm256_set1_ps(a.unwrap_or(0.0)),
        _mm256_set1_ps(inv),
    );
    let (lowest, highest) = (_mm256_set1_ps(-HALF_MAX), _mm256_set1_ps(HALF_MAX));
    let mut e = 0;
    // SAFETY (whole loop): entries e..e + 4 exist in `records` and `out`.
    unsafe {
        while e + 4 <= entries {
            // Record = [w0 w1 m0 m1 | v0 v1 q0 q1]: the weights are the low 64 bits of the
            // first half, the EMA gap the high 64 bits of the second.
            let r = |i: usize| records.as_ptr().add((e + i) * REC);
            let (w01, w23) = (
                _mm_unpacklo_pd(_mm_loadu_pd(r(0).cast()), _mm_loadu_pd(r(1).cast())),
                _mm_unpacklo_pd(_mm_loadu_pd(r(2).cast()), _mm_loadu_pd(r(3).cast())),
            );
            let (q01, q23) = (
                _mm_unpackhi_pd(
                    _mm_loadu_pd(r(0).add(4).cast()),
                    _mm_loadu_pd(r(1).add(4).cast()),
                ),
                _mm_unpackhi_pd(
                    _mm_loadu_pd(r(2).add(4).cast()),
                    _mm_loadu_pd(r(3).add(4).cast()),
                ),
            );
            let w = _mm256_castpd_ps(_mm256_set_m128d(w23, w01));
            let q = _mm256_castpd_ps(_mm256_set_m128d(q23, q01));
            let ema = if raw {
                q
            } else {
                _mm256_add_ps(w, _mm256_mul_ps(a, q))
            };
            let v = _mm256_mul_ps(ema, inv);
            let dst = out.as_mut_ptr().add(e * 2);
            if T::HALF {
                let v = _mm256_min_ps(_mm256_max_ps(v, lowest), highest);
                _mm_storeu_si128(dst.cast(), _mm256_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(v));
            } else {
                _mm256_storeu_ps(dst.cast(), v);
            }
            e += 4;
        }
    }
    e
}

/// Bias-corrected EMA of a dense group: `e / (1 − α^t)`, or the weights at step 0.
pub fn materialize_dense(alpha: f32, step: u32, w: &[f32], ema: &[f32], out: &mut [f32]) {
    if step == 0 {
        out.copy_from_slice(w);
        return;
    }
    let inv = 1.0 / (1.0 - decay_pow(alpha, step));
    for i in 0..w.len() {
        out[i] = ema[i] * inv;
    }
}
