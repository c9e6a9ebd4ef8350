//! The fused CPU training step: encode → MLP forward → loss → MLP backward per cache-resident
//! tile (parallel over tiles), then the hash-grid gradient scatter and sparse Adam + EMA per
//! level (parallel over levels), then dense Adam + EMA of the MLP.

use std::time::{Duration, Instant};

use burn::tensor::f16;
use rayon::prelude::*;

use std::cell::RefCell;

use super::grid::{BinScratch, scatter_binned, scatter_level, split_levels};
use super::mlp::{MlpGrad, OUT_PAD, PreparedMlp, TILE, TileScratch, backward_tile, forward_tile};
use super::optim::{RECORD, StepConstants, dense_step, sparse_step};
use crate::batch::{FACTOR_AT, TARGET_AT, TRAIN_ROW, WEIGHT_AT};
use crate::config::OutputActivation;
use crate::loss::sample_loss;
use crate::model::ModelLayout;
use crate::profile::TrainClock;

thread_local! {
    /// Each thread's buffers for the binned gradient scatter, kept between steps (fresh
    /// megabyte-sized buffers would page-fault on every step).
    static SCRATCH: RefCell<BinScratch> = RefCell::default();
}

/// Mutable training state of one parameter group.
#[derive(Debug)]
pub struct GroupState<'a> {
    /// Weights.
    pub w: &'a mut [f32],
    /// Adam first moment.
    pub m: &'a mut [f32],
    /// Adam second moment.
    pub v: &'a mut [f32],
    /// Raw (not bias-corrected) EMA.
    pub ema: &'a mut [f32],
}

/// Hash-table state: the per-entry records (see [`super::optim`]) and optionally the weights
/// in half precision.
#[derive(Debug)]
pub struct GridState<'a> {
    /// Records `[w | m | v | q]` per entry (`q`: the EMA gap, see [`super::optim`]).
    pub records: &'a mut [f32],
    /// The weights rounded to half precision (`F` per entry, equal to
    /// [`super::optim::half_weights`] of the records): when present, the forward pass reads
    /// them instead of the records, and the update keeps them equal.
    pub half: Option<&'a mut [f16]>,
}

/// Groups of tiles whose losses and gradients phase A sums separately (then in order): a fixed
/// number, so the sums do not depend on the thread count.
const REDUCTION_GROUPS: usize = 16;

/// One tile of phase A: its packed rows, and its slice of each level's gradient columns.
type TileIo<'a, 'b> = (&'a [f32], Vec<&'b mut [f32]>);

/// Loss settings of a step.
#[derive(Clone, Copy, Debug)]
pub struct LossSettings {
    /// Output mapping.
    pub activation: OutputActivation,
    /// ε of the relative loss.
    pub epsilon: f32,
    /// The relative residual beyond which the loss is linear.
    pub max_relative_error: f32,
}

/// Phase A of a step, parallel over tiles: forward, loss and backward of every tile, the hash
/// grid read from `table`. Returns the summed loss, the MLP weight gradients, and
/// ∂L/∂(hash-grid columns) level-major, `[L][n][F]`.
fn forward_backward(
    layout: &ModelLayout,
    table: super::grid::Table,
    mlp_w: &[f32],
    rows: &[f32],
    loss: LossSettings,
    clock: &TrainClock,
) -> (f64, MlpGrad, Vec<f32>) {
    let n = rows.len() / TRAIN_ROW;
    let prepared = PreparedMlp::new(&layout.layers, mlp_w, layout.mlp_precision);
    let k_in = prepared.inputs();
    let hidden = prepared.hidden();
    let (grid_col, grid_dims) = layout
        .encoding
        .grid()
        .map_or((0, 0), |(g, p)| (p.out_offset, g.output_dims()));
    let scale = 1.0 / (3.0 * n as f32);
    let fast = layout
        .encoding
        .grid()
        .map(|(g, _)| g.fast_levels())
        .unwrap_or_default();
    let features = layout.encoding.grid().map_or(1, |(g, _)| g.features());
    // ∂L/∂(grid columns), level-major (`[level][sample][feature]`, what the per-level scatter
    // reads), handed to the tiles as one slice per level.
    let mut dxg = vec![0f32; n * grid_dims];
    let tiles = n.div_ceil(TILE);
    let mut tile_outs: Vec<Vec<&mut [f32]>> = (0..tiles).map(|_| Vec::new()).collect();
    if grid_dims > 0 {
        for level in dxg.chunks_mut(n * features) {
            for (t, part) in level.chunks_mut(TILE * features).enumerate() {
                tile_outs[t].push(part);
            }
        }
    }
    // Tiles are summed in a fixed number of groups of consecutive tiles, each group in tile
    // order and the groups in group order, so the loss and the MLP gradients are the same bits
    // whatever the thread count. (A rayon fold summed one accumulator per work split, and the
    // splits follow work stealing: two runs of one seed trained slightly different networks.)
    let tiles_in: Vec<TileIo> = rows.chunks(TILE * TRAIN_ROW).zip(tile_outs).collect();
    let per_group = tiles.div_ceil(REDUCTION_GROUPS).max(1);
    let mut groups: Vec<Vec<TileIo>> = Vec::new();
    let mut tiles_in = tiles_in.into_iter().peekable();
    while tiles_in.peek().is_some() {
        groups.push(tiles_in.by_ref().take(per_group).collect());
    }
    let partial: Vec<(f64, MlpGrad)> = groups
        .into_par_iter()
        .map_init(
            // Scratch only: every tile overwrites what it reads, so its history is irrelevant.
            || TileScratch::new(k_in, hidden),
            |s, group| {
                let mut loss_acc = 0f64;
                let mut grad = MlpGrad::zeros(&prepared);
                for (rows_t, mut outs) in group {
                    let m = rows_t.len() / TRAIN_ROW;
                    let t_encode = Instant::now();
                    super::encode_rows(layout, &fast, table, rows_t, TRAIN_ROW, &mut s.x, k_in);
                    clock.encode.since(t_encode);
                    let t_mlp = Instant::now();
                    forward_tile(&prepared, m, s);
                    for i in 0..m {
                        let row = &rows_t[i * TRAIN_ROW..(i + 1) * TRAIN_ROW];
                        let o = &s.out[i * OUT_PAD..i * OUT_PAD + 3];
                        let (l, g) = sample_loss(
                            loss.activation,
                            [o[0], o[1], o[2]],
                            [row[FACTOR_AT], row[FACTOR_AT + 1], row[FACTOR_AT + 2]],
                            [row[TARGET_AT], row[TARGET_AT + 1], row[TARGET_AT + 2]],
                            row[WEIGHT_AT],
                            loss.epsilon,
                            loss.max_relative_error,
                            scale,
                        );
                        loss_acc += l;
                        let d = &mut s.dout[i * OUT_PAD..(i + 1) * OUT_PAD];
                        d[..3].copy_from_slice(&g);
                        d[3..].fill(0.0);
                    }
                    // Each row's gradient columns straight into their levels (a pass over the
                    // whole batch in phase C cost 40–70 ns a sample more).
                    let mut to_levels = |i: usize, row: &[f32]| {
                        // (Element by element: `copy_from_slice` of two floats calls `memmove`.)
                        for (out, g) in outs.iter_mut().zip(row.chunks_exact(features)) {
                            for (o, v) in out[i * features..(i + 1) * features].iter_mut().zip(g) {
                                *o = *v;
                            }
                        }
                    };
                    let dx = (grid_dims > 0).then_some((grid_col, grid_dims, &mut to_levels as _));
                    backward_tile(&prepared, m, s, &mut grad, dx);
                    clock.mlp.since(t_mlp);
                }
                (loss_acc, grad)
            },
        )
        .collect();
    let mut partial = partial.into_iter();
    let (mut loss_sum, mut mgrad) = partial
        .next()
        .unwrap_or_else(|| (0.0, MlpGrad::zeros(&prepared)));
    for (l, g) in partial {
        loss_sum += l;
        mgrad.add(&g);
    }
    (loss_sum, mgrad, dxg)
}

/// Loss and gradients of the fused step without an update (what the step feeds to Adam):
/// mean loss, ∂L/∂table (dense), ∂L/∂MLP weights.
pub fn gradients(
    layout: &ModelLayout,
    grid_w: &[f32],
    mlp_w: &[f32],
    rows: &[f32],
    loss: LossSettings,
) -> (f64, Vec<f32>, Vec<f32>) {
    let n = rows.len() / TRAIN_ROW;
    let f = layout.encoding.grid().map_or(1, |(g, _)| g.features());
    let table = super::grid::Table::F32(grid_w, f);
    let clock = TrainClock::default();
    let (loss_sum, mgrad, dxg) = forward_backward(layout, table, mlp_w, rows, loss, &clock);
    let mut mlp = vec![0f32; mlp_w.len()];
    mgrad.write_flat(&layout.layers, &mut mlp);
    let mut grid = vec![0f32; grid_w.len()];
    if let Some((hg, part)) = layout.encoding.grid() {
        let f = hg.features();
        let levels = split_levels(hg, f, &mut grid[..]);
        levels.into_par_iter().enumerate().for_each(|(l, g)| {
            scatter_level(
                hg,
                l,
                n,
                |i| {
                    let r = &rows[i * TRAIN_ROW + part.in_offset..];
                    [r[0], r[1], r[2]]
                },
                |i| &dxg[(l * n + i) * f..(l * n + i + 1) * f],
                g,
                None,
            );
        });
    }
    (loss_sum / (3.0 * n as f64), grid, mlp)
}

/// One optimisation step over the packed rows (`n · TRAIN_ROW` floats, `n ≥ 1`); returns the
/// mean loss over samples and channels (before the update).
pub fn train_step(
    layout: &ModelLayout,
    grid: Option<GridState<'_>>,
    mlp: GroupState<'_>,
    rows: &[f32],
    c: &StepConstants,
    loss: LossSettings,
    clock: &TrainClock,
) -> f64 {
    let n = rows.len() / TRAIN_ROW;
    let grid_part = layout.encoding.grid();
    let grid_in = grid_part.map_or(0, |(_, p)| p.in_offset);
    let stride = grid_part.map_or(1, |(g, _)| g.features() * super::optim::RECORD);
    let table = match &grid {
        Some(GridState { half: Some(h), .. }) => super::grid::Table::F16(h),
        Some(g) => super::grid::Table::F32(g.records, stride),
        None => super::grid::Table::F32(&[], stride),
    };
    let (loss_sum, mgrad, dxg) = forward_backward(layout, table, mlp.w, rows, loss, clock);

    // Phase C: hash-grid scatter + sparse Adam/EMA, one task per level.
    let t_grid = Instant::now();
    if let (Some(g), Some((hg, _))) = (grid, grid_part) {
        let f = hg.features();
        let GridState { records, half } = g;
        let rs = split_levels(hg, f * RECORD, records);
        let hs: Vec<Option<&mut [f16]>> = match half {
            Some(h) => split_levels(hg, f, h).into_iter().map(Some).collect(),
            None => (0..hg.levels.len()).map(|_| None).collect(),
        };
        // Positions one axis per array, padded to whole groups of eight.
        let padded = n.next_multiple_of(8);
        let mut xyz = vec![0f32; 3 * padded];
        for (axis, out) in xyz.chunks_mut(padded).enumerate() {
            for (i, o) in out[..n].iter_mut().enumerate() {
                *o = rows[i * TRAIN_ROW + grid_in + axis];
            }
        }
        let xyz = [&xyz[..padded], &xyz[padded..2 * padded], &xyz[2 * padded..]];
        let dxg = &dxg;
        let level_step = |l: usize, rec: &mut [f32], mut hl: Option<&mut [f16]>| {
            SCRATCH.with_borrow_mut(|scratch| {
                let t_scatter = Instant::now();
                let mut adam = Duration::ZERO;
                let per_bin = |first: usize, gr: &mut [f32], touched: &mut [u64]| {
                    let t_adam = Instant::now();
                    let len = gr.len() / f;
                    let rec = &mut rec[first * f * RECORD..(first + len) * f * RECORD];
                    let half = hl
                        .as_deref_mut()
                        .map(|h| &mut h[first * f..(first + len) * f]);
                    sparse_step(c, f, touched, rec, gr, half);
                    adam += t_adam.elapsed();
                };
                let dout = &dxg[l * n * f..(l + 1) * n * f];
                match f {
                    1 => scatter_binned::<1>(hg, l, xyz, dout, scratch, per_bin),
                    2 => scatter_binned::<2>(hg, l, xyz, dout, scratch, per_bin),
                    4 => scatter_binned::<4>(hg, l, xyz, dout, scratch, per_bin),
                    8 => scatter_binned::<8>(hg, l, xyz, dout, scratch, per_bin),
                    _ => panic!("unsupported features per level {f}"),
                }
                clock
                    .grid_scatter
                    .add(t_scatter.elapsed().saturating_sub(adam));
                clock.grid_adam.add(adam);
            });
        };
        // Largest levels first (longest-processing-time order): the tasks left when a thread
        // runs out of work are the small coarse levels, so the threads finish together.
        let mut tasks: Vec<_> = rs.into_iter().zip(hs).enumerate().collect();
        tasks.sort_by_key(|(l, _)| std::cmp::Reverse(hg.levels[*l].entries));
        let level_step = &level_step;
        rayon::scope_fifo(|s| {
            for (l, (rec, hl)) in tasks {
                s.spawn_fifo(move |_| level_step(l, rec, hl));
            }
        });
    }

    clock.grid_wall.since(t_grid);
    // Phase D: dense Adam + EMA of the MLP.
    let t_adam = Instant::now();
    let mut flat = vec![0f32; mlp.w.len()];
    mgrad.write_flat(&layout.layers, &mut flat);
    dense_step(c, mlp.w, mlp.m, mlp.v, mlp.ema, &flat);
    clock.mlp_adam.since(t_adam);

    loss_sum / (3.0 * n as f64)
}
