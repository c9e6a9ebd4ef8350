//! Adam and the weight EMA on the CPU: dense for the MLP, sparse (lazy) for the hash table.
//!
//! The table's state is stored per entry as one record `[w (F) | m (F) | v (F) | ema (F)]`
//! ([`RECORD`] · F floats), so an update touches one or two cache lines instead of four: the
//! sparse step is bound by memory traffic.
//!
//! **Sparse semantics for the hash table** (PyTorch `SparseAdam`): an entry not referenced by
//! any sample of a step keeps its weights and Adam moments unchanged that step; referenced
//! entries get the standard Adam update with the global step's bias correction. Because an
//! unreferenced entry's weight is constant, its EMA can be brought up to date *exactly* later:
//! after `k` steps at constant weight `w`, `e ← α^k·e + (1 − α^k)·w`. Each entry records the step
//! its EMA is current at; the catch-up happens when the entry is next updated, and for all
//! entries when inference weights are materialised or a snapshot is written.

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
    step_size: f32,
    /// `1 / (1 − β2^t)`.
    inv_bc2: f32,
    /// `α^k` of the EMA catch-ups, built once per step rather than per sparse update.
    decay: DecayTable,
}

impl StepConstants {
    /// Constants of step `step` (≥ 1).
    pub fn new(adam: AdamParams, ema: Option<f32>, step: u32) -> Self {
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
            decay: DecayTable::new(ema.unwrap_or(0.0)),
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

/// `α^k` for an EMA catch-up over `k` steps.
#[inline(always)]
pub fn decay_pow(alpha: f32, k: u32) -> f32 {
    alpha.powi(k.min(i32::MAX as u32) as i32)
}

/// Table of `α^k` for small `k` (catch-ups are mostly a few steps; `powi` per entry costs
/// ~20% of the sparse update).
#[derive(Clone, Debug)]
pub struct DecayTable {
    alpha: f32,
    powers: Vec<f32>,
}

impl DecayTable {
    const LEN: usize = 1024;

    /// Powers of `alpha`, computed as [`decay_pow`] does so results are identical.
    pub fn new(alpha: f32) -> Self {
        Self {
            alpha,
            powers: (0..Self::LEN as u32).map(|k| decay_pow(alpha, k)).collect(),
        }
    }

    /// `α^k`.
    #[inline(always)]
    pub fn get(&self, k: u32) -> f32 {
        match self.powers.get(k as usize) {
            Some(p) => *p,
            None => decay_pow(self.alpha, k),
        }
    }
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
    let mut out = vec![f16::ZERO; records.len() / RECORD];
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

/// Sparse Adam + lazy EMA over one hash-grid level: for every entry whose bit is set in
/// `touched`, updates its record (`f` features) from `grad` (which is zeroed), catches its EMA
/// up and records the step in `last`; with `half`, also stores the new weights there rounded
/// to half precision (as [`half_weights`]). The bitmap is cleared.
pub fn sparse_step(
    c: &StepConstants,
    f: usize,
    touched: &mut [u64],
    records: &mut [f32],
    grad: &mut [f32],
    last: &mut [u32],
    half: Option<&mut [f16]>,
) {
    if let Some(h) = &half {
        assert_eq!(h.len(), last.len() * f, "one half per entry and feature");
    }
    match f {
        1 => sparse_step_f::<1>(c, touched, records, grad, last, half),
        2 => sparse_step_f::<2>(c, touched, records, grad, last, half),
        4 => sparse_step_f::<4>(c, touched, records, grad, last, half),
        8 => sparse_step_f::<8>(c, touched, records, grad, last, half),
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
    last: &mut [u32],
    half: Option<&mut [f16]>,
) {
    let entries = last.len();
    assert!(records.len() >= entries * RECORD * F && grad.len() >= entries * F);
    assert!(touched.len() * 64 <= entries.next_multiple_of(64));
    #[cfg(target_arch = "x86_64")]
    if F == 2 && super::gemm::has_avx2_fma() && super::grid::has_f16c() {
        // SAFETY: AVX2, FMA and F16C were detected; every touched entry is below `entries`
        // (the bitmap's bits beyond the last entry are never set by the scatter, and the
        // indices are checked again inside), and the slices' lengths were checked above.
        unsafe { sparse_step_f2_avx2(c, touched, records, grad, last, half) };
        return;
    }
    sparse_step_portable::<F>(c, touched, records, grad, last, half);
}

/// The portable loop of [`sparse_step`] for `F` features (public for the test that compares it
/// with the AVX2 kernel).
pub fn sparse_step_portable<const F: usize>(
    c: &StepConstants,
    touched: &mut [u64],
    records: &mut [f32],
    grad: &mut [f32],
    last: &mut [u32],
    mut half: Option<&mut [f16]>,
) {
    drain_bits(touched, |e| {
        update_entry::<F>(c, &c.decay, e, records, grad, last, half.as_deref_mut())
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

/// Adam and the EMA catch-up of one table entry (and its half-precision weights).
#[inline(always)]
fn update_entry<const F: usize>(
    c: &StepConstants,
    table: &DecayTable,
    e: usize,
    records: &mut [f32],
    grad: &mut [f32],
    last: &mut [u32],
    half: Option<&mut [f16]>,
) {
    let k = c.step - last[e];
    last[e] = c.step;
    // e_t = α^k e_s + (α − α^k) w_old + (1 − α) w_new  (w_old held for k − 1 steps).
    let ak = table.get(k);
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
        if let Some(alpha) = c.ema {
            r[3 * F + j] = ak * r[3 * F + j] + (alpha - ak) * w_old + (1.0 - alpha) * w;
        }
    }
    if let Some(h) = half {
        for (h, w) in h[e * F..(e + 1) * F].iter_mut().zip(&r[..F]) {
            *h = TableValue::from_f32(*w);
        }
    }
}

/// [`sparse_step_portable`] for two features, four touched entries at a time: their records
/// `[w0 w1 | m0 m1 | v0 v1 | e0 e1]` are transposed (as 64-bit pairs) into one register each of
/// weights, moments and EMA, so one square root and one division serve eight values. Each
/// value goes through the same IEEE operations in the same order as [`StepConstants::adam`]
/// (no fused multiply-adds), so the results are bit-identical. A remainder of fewer than four
/// entries takes the scalar update.
///
/// # Safety
/// The CPU has AVX2 and F16C; `records` holds `8·last.len()` floats and `grad` `2·last.len()`
/// (and `half`, if any, `2·last.len()` halves).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn sparse_step_f2_avx2(
    c: &StepConstants,
    touched: &mut [u64],
    records: &mut [f32],
    grad: &mut [f32],
    last: &mut [u32],
    mut half: Option<&mut [f16]>,
) {
    use std::arch::x86_64::*;
    let table = &c.decay;
    let a = &c.adam;
    let alpha = c.ema.unwrap_or(0.0);
    let set = _mm256_set1_ps;
    let (l2, b1, nb1, b2, nb2) = (
        set(a.l2_reg),
        set(a.beta1),
        set(1.0 - a.beta1),
        set(a.beta2),
        set(1.0 - a.beta2),
    );
    let (step_size, inv_bc2, eps) = (set(c.step_size), set(c.inv_bc2), set(a.epsilon));
    let (alpha_v, one_minus_alpha) = (set(alpha), set(1.0 - alpha));
    let zero = _mm256_setzero_ps();
    let (half_lowest, half_highest) = (set(-HALF_MAX), set(HALF_MAX));
    let rec = records.as_mut_ptr();
    let update4 = |es: [usize; 4], last: &mut [u32], grad: &mut [f32], half: Option<&mut [f16]>| {
        let mut ak = [0f32; 4];
        let mut g = [0f64; 4];
        for (q, &e) in es.iter().enumerate() {
            ak[q] = table.get(c.step - last[e]);
            last[e] = c.step;
            let gp = &mut grad[2 * e..2 * e + 2];
            g[q] = f64::from_bits(u64::from(gp[0].to_bits()) | (u64::from(gp[1].to_bits()) << 32));
            gp.fill(0.0);
        }
        // SAFETY (whole block): `e < last.len()` was checked by the indexing above, so each
        // record `rec[8e..8e + 8]` is inside `records`.
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
            let ak = _mm256_set_ps(ak[3], ak[3], ak[2], ak[2], ak[1], ak[1], ak[0], ak[0]);
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
                _mm256_add_ps(
                    _mm256_add_ps(
                        _mm256_mul_ps(ak, e),
                        _mm256_mul_ps(_mm256_sub_ps(alpha_v, ak), w),
                    ),
                    _mm256_mul_ps(one_minus_alpha, w_new),
                )
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
    // requests cut the update's time by 10–25 % (BENCHMARKS.md). The order, and so every bit of
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
                last,
                grad,
                half.as_deref_mut(),
            );
        }
        for &e in &order[4 * groups..] {
            update_entry::<2>(
                c,
                table,
                e as usize,
                records,
                grad,
                last,
                half.as_deref_mut(),
            );
        }
    });
}

thread_local! {
    /// Each thread's list of touched entries for [`sparse_step_f2_avx2`], kept between calls
    /// (one call per bin, hundreds per step).
    static ORDER: std::cell::RefCell<Vec<u32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Brings every entry's EMA of one level up to `step` (`e ← α^k e + (1 − α^k) w`).
pub fn catch_up(alpha: f32, step: u32, f: usize, records: &mut [f32], last: &mut [u32]) {
    let table = DecayTable::new(alpha);
    for (e, l) in last.iter_mut().enumerate() {
        let k = step - *l;
        if k == 0 {
            continue;
        }
        *l = step;
        let ak = table.get(k);
        let r = &mut records[e * RECORD * f..(e + 1) * RECORD * f];
        for j in 0..f {
            r[3 * f + j] = ak * r[3 * f + j] + (1.0 - ak) * r[j];
        }
    }
}

/// Bias-corrected EMA weights of one level at `step` without modifying the state:
/// `(α^k e + (1 − α^k) w) / (1 − α^t)`, or the weights themselves at step 0 or without EMA.
pub fn materialize_grid(
    alpha: Option<f32>,
    step: u32,
    f: usize,
    records: &[f32],
    last: &[u32],
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
    materialize_grid_into(alpha, step, f, records, last, out);
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
/// (`last.len() · f` of them), so a fresh buffer needs no zero fill (whose page faults, on one
/// thread, cost more than the pass itself on a 2^19 table).
pub fn materialize_grid_into<T: TableValue>(
    alpha: Option<f32>,
    step: u32,
    f: usize,
    records: &[f32],
    last: &[u32],
    out: &mut [std::mem::MaybeUninit<T>],
) {
    assert_eq!(
        out.len(),
        last.len() * f,
        "one output per entry and feature"
    );
    assert!(
        records.len() >= last.len() * RECORD * f,
        "records too short"
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
    let table = DecayTable::new(alpha);
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if f == 2 && super::gemm::has_avx2_fma() && super::grid::has_f16c() {
        // SAFETY: AVX2, FMA and F16C were detected; the lengths of `records`, `last` and `out`
        // were checked above.
        done = unsafe { materialize_pairs_avx2(&table, step, inv, records, last, out) };
    }
    for e in done..last.len() {
        materialize_entry(&table, step, inv, f, e, records, last, out);
    }
}

/// Entry `e` of [`materialize_grid_into`]: `(α^k e + (1 − α^k) w) · inv` per feature.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn materialize_entry<T: TableValue>(
    table: &DecayTable,
    step: u32,
    inv: f32,
    f: usize,
    e: usize,
    records: &[f32],
    last: &[u32],
    out: &mut [std::mem::MaybeUninit<T>],
) {
    let ak = table.get(step - last[e]);
    let r = &records[e * RECORD * f..(e + 1) * RECORD * f];
    for j in 0..f {
        out[e * f + j].write(T::from_f32((ak * r[3 * f + j] + (1.0 - ak) * r[j]) * inv));
    }
}

/// The AVX2 form of [`materialize_grid_into`]'s loop for two features, four entries per
/// register and the same operations in the same order (the same bits; halves are clamped and
/// rounded to nearest even, as [`TableValue::from_f32`]); a block of four with a catch-up
/// `step − last` beyond the power table takes the scalar form. Returns how many leading
/// entries it wrote (all but the last `len % 4`, which the caller's loop finishes).
///
/// # Safety
/// The CPU has AVX2, FMA and F16C; `records` holds `RECORD · 2` floats per entry of `last`, and
/// `out` two per entry.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn materialize_pairs_avx2<T: TableValue>(
    table: &DecayTable,
    step: u32,
    inv: f32,
    records: &[f32],
    last: &[u32],
    out: &mut [std::mem::MaybeUninit<T>],
) -> usize {
    use std::arch::x86_64::*;
    const REC: usize = RECORD * 2;
    let steps = _mm_set1_epi32(step as i32);
    let limit = _mm_set1_epi32(DecayTable::LEN as i32 - 1);
    let inv_scalar = inv;
    let (one, inv) = (_mm256_set1_ps(1.0), _mm256_set1_ps(inv));
    let (lowest, highest) = (_mm256_set1_ps(-HALF_MAX), _mm256_set1_ps(HALF_MAX));
    let pairs = _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3);
    let mut e = 0;
    // SAFETY (whole loop): entries e..e + 4 exist in `last`, `records` and `out`.
    unsafe {
        while e + 4 <= last.len() {
            let k = _mm_sub_epi32(steps, _mm_loadu_si128(last.as_ptr().add(e).cast()));
            // Unsigned k ≤ LEN − 1 in every lane, else this block takes the scalar form.
            if _mm_movemask_epi8(_mm_cmpeq_epi32(_mm_min_epu32(k, limit), k)) != 0xFFFF {
                for i in e..e + 4 {
                    materialize_entry(table, step, inv_scalar, 2, i, records, last, out);
                }
                e += 4;
                continue;
            }
            let ak = _mm256_permutevar8x32_ps(
                _mm256_castps128_ps256(_mm_i32gather_ps::<4>(table.powers.as_ptr(), k)),
                pairs,
            );
            // Record = [w0 w1 m0 m1 | v0 v1 e0 e1]: the weights are the low 64 bits of the
            // first half, the EMA the high 64 bits of the second.
            let r = |i: usize| records.as_ptr().add((e + i) * REC);
            let (w01, w23) = (
                _mm_unpacklo_pd(_mm_loadu_pd(r(0).cast()), _mm_loadu_pd(r(1).cast())),
                _mm_unpacklo_pd(_mm_loadu_pd(r(2).cast()), _mm_loadu_pd(r(3).cast())),
            );
            let (e01, e23) = (
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
            let ema = _mm256_castpd_ps(_mm256_set_m128d(e23, e01));
            let v = _mm256_mul_ps(
                _mm256_add_ps(
                    _mm256_mul_ps(ak, ema),
                    _mm256_mul_ps(_mm256_sub_ps(one, ak), w),
                ),
                inv,
            );
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
