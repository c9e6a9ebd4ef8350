//! Adam and the weight EMA on the CPU: dense for the MLP, sparse (lazy) for the hash table.
//!
//! **Sparse semantics for the hash table** (PyTorch `SparseAdam`): an entry not referenced by
//! any sample of a step keeps its weights and Adam moments unchanged that step; referenced
//! entries get the standard Adam update with the global step's bias correction. Because an
//! unreferenced entry's weight is constant, its EMA can be brought up to date *exactly* later:
//! after `k` steps at constant weight `w`, `e ← α^k·e + (1 − α^k)·w`. Each entry records the step
//! its EMA is current at; the catch-up happens when the entry is next updated, and for all
//! entries when inference weights are materialised or a snapshot is written.

use crate::config::AdamParams;

/// Per-step constants of Adam and the EMA.
#[derive(Clone, Copy, Debug)]
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
}

impl StepConstants {
    /// Constants of step `step` (≥ 1).
    pub fn new(adam: AdamParams, ema: Option<f32>, step: u32) -> Self {
        let t = step.min(i32::MAX as u32) as i32;
        Self { adam, ema, step, bc1: 1.0 - adam.beta1.powi(t), bc2: 1.0 - adam.beta2.powi(t) }
    }

    /// One Adam update of a single weight; returns the new weight. Non-finite gradients are
    /// treated as zero so that no weight ever becomes non-finite.
    #[inline(always)]
    pub fn adam(&self, w: &mut f32, m: &mut f32, v: &mut f32, g: f32) {
        let a = &self.adam;
        let g = if g.is_finite() { g + a.l2_reg * *w } else { a.l2_reg * *w };
        *m = a.beta1 * *m + (1.0 - a.beta1) * g;
        *v = a.beta2 * *v + (1.0 - a.beta2) * g * g;
        let mh = *m / self.bc1;
        let vh = *v / self.bc2;
        let upd = a.learning_rate * mh / (vh.sqrt() + a.epsilon);
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

/// Dense Adam + EMA over a parameter group (the MLP), consuming `grad`.
pub fn dense_step(c: &StepConstants, w: &mut [f32], m: &mut [f32], v: &mut [f32], ema: &mut [f32], grad: &[f32]) {
    for i in 0..w.len() {
        c.adam(&mut w[i], &mut m[i], &mut v[i], grad[i]);
        if let Some(alpha) = c.ema {
            ema[i] = alpha * ema[i] + (1.0 - alpha) * w[i];
        }
    }
}

/// Sparse Adam + lazy EMA over one hash-grid level: for every entry whose bit is set in
/// `touched`, updates its `f` weights from `grad` (which is zeroed), catches its EMA up and
/// records the step in `last`. The bitmap is cleared.
pub fn sparse_step(
    c: &StepConstants,
    f: usize,
    touched: &mut [u64],
    w: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    ema: &mut [f32],
    grad: &mut [f32],
    last: &mut [u32],
) {
    for (word_index, word) in touched.iter_mut().enumerate() {
        let mut bits = *word;
        *word = 0;
        while bits != 0 {
            let e = word_index * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let k = c.step - last[e];
            last[e] = c.step;
            for i in e * f..(e + 1) * f {
                let w_old = w[i];
                c.adam(&mut w[i], &mut m[i], &mut v[i], grad[i]);
                grad[i] = 0.0;
                if let Some(alpha) = c.ema {
                    // e_t = α^k e_s + (α − α^k) w_old + (1 − α) w_new  (w_old held for k − 1 steps).
                    let ak = decay_pow(alpha, k);
                    ema[i] = ak * ema[i] + (alpha - ak) * w_old + (1.0 - alpha) * w[i];
                }
            }
        }
    }
}

/// Brings every entry's EMA of one level up to `step` (`e ← α^k e + (1 − α^k) w`).
pub fn catch_up(alpha: f32, step: u32, f: usize, w: &[f32], ema: &mut [f32], last: &mut [u32]) {
    for (e, l) in last.iter_mut().enumerate() {
        let k = step - *l;
        if k == 0 {
            continue;
        }
        *l = step;
        let ak = decay_pow(alpha, k);
        for i in e * f..(e + 1) * f {
            ema[i] = ak * ema[i] + (1.0 - ak) * w[i];
        }
    }
}

/// Bias-corrected EMA weights of one level at `step` without modifying the state:
/// `(α^k e + (1 − α^k) w) / (1 − α^t)`, or the weights themselves at step 0.
pub fn materialize_grid(alpha: f32, step: u32, f: usize, w: &[f32], ema: &[f32], last: &[u32], out: &mut [f32]) {
    if step == 0 {
        out.copy_from_slice(w);
        return;
    }
    let inv = 1.0 / (1.0 - decay_pow(alpha, step));
    for (e, l) in last.iter().enumerate() {
        let ak = decay_pow(alpha, step - *l);
        for i in e * f..(e + 1) * f {
            out[i] = (ak * ema[i] + (1.0 - ak) * w[i]) * inv;
        }
    }
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
