//! Turning plain records into the packed rows the kernels read, dropping bad samples.
//!
//! A training row is `[raw inputs (14) | reflectance factor (3) | target (3) | weight (1)]`,
//! an inference row `[raw inputs (14) | reflectance factor (3)]`.

use rayon::prelude::*;

use crate::record::{
    CacheQuery, RAW_INPUT_DIMS, SPHERICAL_GROUP, TrainingBatch, query_is_finite, raw_inputs,
    raw_inputs_group, reflectance_factor,
};

/// Floats per training row.
pub const TRAIN_ROW: usize = RAW_INPUT_DIMS + 7;
/// Floats per inference row.
pub const QUERY_ROW: usize = RAW_INPUT_DIMS + 3;
/// Offset of the reflectance factor in a row.
pub const FACTOR_AT: usize = RAW_INPUT_DIMS;
/// Offset of the target in a training row.
pub const TARGET_AT: usize = RAW_INPUT_DIMS + 3;
/// Offset of the weight in a training row.
pub const WEIGHT_AT: usize = RAW_INPUT_DIMS + 6;

/// Training samples that survived the checks, packed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PackedBatch {
    /// `len · TRAIN_ROW` floats.
    pub rows: Vec<f32>,
    /// Samples kept.
    pub len: usize,
    /// Samples dropped because a query field, target or weight was NaN or infinite.
    pub dropped_nonfinite: usize,
    /// Samples dropped because a target channel was negative or above `max_target`, or the
    /// weight negative.
    pub dropped_absurd: usize,
}

/// Why a training record is dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dropped {
    /// A query field, target or weight is NaN or infinite.
    NonFinite,
    /// A target channel is negative or above `max_target`, or the weight negative.
    Absurd,
}

/// The checks every cache puts on a training record (query `q`, target `t`, weight `w`).
pub fn check_record(q: &CacheQuery, t: &[f32; 3], w: f32, max_target: f32) -> Result<(), Dropped> {
    if !query_is_finite(q) || !t.iter().all(|v| v.is_finite()) || !w.is_finite() {
        return Err(Dropped::NonFinite);
    }
    if t.iter().any(|v| *v < 0.0 || *v > max_target) || w < 0.0 {
        return Err(Dropped::Absurd);
    }
    Ok(())
}

/// Packs a training batch, dropping and counting bad samples.
pub fn pack_training(
    batch: &TrainingBatch,
    max_target: f32,
) -> Result<PackedBatch, crate::CacheError> {
    let n = batch.queries.len();
    if batch.targets.len() != n {
        return Err(crate::CacheError::Input(format!(
            "training batch has {n} queries but {} targets",
            batch.targets.len()
        )));
    }
    if let Some(w) = &batch.weights
        && w.len() != n
    {
        return Err(crate::CacheError::Input(format!(
            "training batch has {n} queries but {} weights",
            w.len()
        )));
    }
    let mut out = PackedBatch {
        rows: Vec::with_capacity(n * TRAIN_ROW),
        ..PackedBatch::default()
    };
    for i in 0..n {
        let q = &batch.queries[i];
        let t = batch.targets[i];
        let w = batch.weights.as_ref().map_or(1.0, |w| w[i]);
        match check_record(q, &t, w, max_target) {
            Err(Dropped::NonFinite) => {
                out.dropped_nonfinite += 1;
                continue;
            }
            Err(Dropped::Absurd) => {
                out.dropped_absurd += 1;
                continue;
            }
            Ok(()) => {}
        }
        out.rows.extend_from_slice(&raw_inputs(q));
        out.rows.extend_from_slice(&reflectance_factor(q));
        out.rows.extend_from_slice(&t);
        out.rows.push(w);
        out.len += 1;
    }
    Ok(out)
}

/// Packs inference queries (non-finite fields are sanitised, see [`raw_inputs`]), in parallel
/// and eight at a time ([`raw_inputs_group`]): converted one at a time, the spherical
/// coordinates took 5 % of inference's thread time (`perf`), about 1 % in groups.
pub fn pack_queries(queries: &[CacheQuery]) -> Vec<f32> {
    const G: usize = SPHERICAL_GROUP;
    let mut rows = vec![0f32; queries.len() * QUERY_ROW];
    rows.par_chunks_mut(QUERY_ROW * G)
        .zip(queries.par_chunks(G))
        .with_min_len(1024 / G)
        .for_each(|(rows, qs)| {
            match <&[CacheQuery; G]>::try_from(qs) {
                Ok(group) => raw_inputs_group(group, rows, QUERY_ROW),
                Err(_) => {
                    for (row, q) in rows.chunks_exact_mut(QUERY_ROW).zip(qs) {
                        row[..RAW_INPUT_DIMS].copy_from_slice(&raw_inputs(q));
                    }
                }
            }
            for (row, q) in rows.chunks_exact_mut(QUERY_ROW).zip(qs) {
                row[RAW_INPUT_DIMS..].copy_from_slice(&reflectance_factor(q));
            }
        });
    rows
}
