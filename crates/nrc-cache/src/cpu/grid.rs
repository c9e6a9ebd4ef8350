//! Hash-grid passes over a whole batch (the Flex implementation of the encoding custom op).
//!
//! The backward scatter runs one task per level: levels own disjoint parts of the table, so the
//! gradient needs neither atomics nor per-thread copies.

use rayon::prelude::*;

use crate::encoding::hash_grid::HashGrid;

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
    out.par_chunks_mut(d * 256).zip(positions.par_chunks(3 * 256)).for_each(|(o, p)| {
        for (oi, pi) in o.chunks_mut(d).zip(p.chunks(3)) {
            grid.forward_one(table, [pi[0], pi[1], pi[2]], oi);
        }
    });
}

/// Gradient of the table for `dout` (`[N][L·F]`), written into `grad` (zeroed first).
pub fn backward_table(grid: &HashGrid, positions: &[f32], dout: &[f32], grad: &mut [f32]) {
    let f = grid.features();
    grad.fill(0.0);
    let levels = split_levels(grid, f, grad);
    levels.into_par_iter().enumerate().for_each(|(l, g)| {
        scatter_level(grid, l, positions.len() / 3, |i| [positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]], |i| &dout[i * grid.output_dims() + l * f..i * grid.output_dims() + (l + 1) * f], g, None);
    });
}

/// Gradient of the positions for `dout`: `[N][3]`.
pub fn backward_positions(grid: &HashGrid, table: &[f32], positions: &[f32], dout: &[f32]) -> Vec<f32> {
    let d = grid.output_dims();
    let mut out = vec![0f32; positions.len()];
    out.par_chunks_mut(3).zip(positions.par_chunks(3)).zip(dout.par_chunks(d)).for_each(|((o, p), g)| {
        o.copy_from_slice(&grid.backward_input_one(table, [p[0], p[1], p[2]], g));
    });
    out
}

/// Scatters level `l`'s gradient of `n` samples into that level's table gradient `grad`
/// (level-local entries), marking referenced entries in `touched` when given.
#[inline]
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
    let level = grid.levels[l];
    let offset = level.offset as u32;
    for i in 0..n {
        let c = grid.corners(&level, position(i));
        let d = dout(i);
        for k in 0..8 {
            let e = (c.index[k] - offset) as usize;
            let w = c.weight[k];
            for j in 0..f {
                grad[e * f + j] += w * d[j];
            }
            if let Some(t) = touched.as_deref_mut() {
                t[e / 64] |= 1u64 << (e % 64);
            }
        }
    }
}
