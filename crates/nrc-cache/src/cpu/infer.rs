//! Fused CPU inference: encode and run the MLP per cache-resident tile, parallel over tiles.

use std::time::Instant;

use rayon::prelude::*;

use super::grid::Table;
use super::mlp::{OUT_PAD, PreparedMlp, TILE, TileScratch, forward_tile};
use crate::batch::{FACTOR_AT, QUERY_ROW};
use crate::loss::activate;
use crate::model::ModelLayout;
use crate::profile::InferClock;

/// Radiance of the packed query rows (`n · QUERY_ROW` floats) into `out` (`n · 3`), with the
/// hash table `grid` and MLP weights `mlp` (the bias-corrected EMA weights for inference); the
/// phases' times are added to `clock`.
pub fn infer(
    layout: &ModelLayout,
    grid: Table,
    mlp: &[f32],
    rows: &[f32],
    out: &mut [f32],
    clock: &InferClock,
) {
    let t_kernel = Instant::now();
    let prepared = PreparedMlp::new(&layout.layers, mlp, layout.mlp_precision);
    let network_out = network_outputs(layout, &prepared, grid, rows, clock);
    out.par_chunks_mut(3)
        .zip(network_out.par_chunks(3))
        .zip(rows.par_chunks(QUERY_ROW))
        .for_each(|((o, y), r)| {
            for c in 0..3 {
                o[c] = activate(layout.output_activation, y[c]).0 * r[FACTOR_AT + c];
            }
        });
    clock.kernel.since(t_kernel);
}

/// The raw network outputs (before the output activation and reflectance factor), `[n][3]`.
pub fn network_outputs(
    layout: &ModelLayout,
    prepared: &PreparedMlp,
    grid: Table,
    rows: &[f32],
    clock: &InferClock,
) -> Vec<f32> {
    let n = rows.len() / QUERY_ROW;
    let k_in = prepared.inputs();
    let mut out = vec![0f32; n * 3];
    let fast = layout
        .encoding
        .grid()
        .map(|(g, _)| g.fast_levels())
        .unwrap_or_default();
    out.par_chunks_mut(TILE * 3)
        .zip(rows.par_chunks(TILE * QUERY_ROW))
        .for_each_init(
            || TileScratch::new(k_in, prepared.hidden()),
            |s, (o, r)| {
                let m = r.len() / QUERY_ROW;
                let t_encode = Instant::now();
                let grid_time =
                    super::encode_rows(layout, &fast, grid, r, QUERY_ROW, &mut s.x, k_in);
                clock.hash_grid.add(grid_time);
                clock.encode.since(t_encode);
                let t_mlp = Instant::now();
                forward_tile(prepared, m, s);
                clock.mlp.since(t_mlp);
                for i in 0..m {
                    o[i * 3..i * 3 + 3].copy_from_slice(&s.out[i * OUT_PAD..i * OUT_PAD + 3]);
                }
            },
        );
    out
}
