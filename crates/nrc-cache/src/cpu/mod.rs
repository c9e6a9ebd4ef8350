//! CPU kernels behind the Flex custom ops: small dense products (f32, and bfloat16 pairs), the
//! fused MLP tile, the hash-grid batch passes, Adam/EMA, and the fused training step and
//! inference built from them. Parallel over batch tiles (or hash-grid levels) with rayon.

pub mod bf16;
pub mod gemm;
pub mod grid;
pub mod huge;
pub mod infer;
pub mod mlp;
pub mod optim;
pub mod train;

/// Encodes the packed rows `rows` (`row_len` floats each, the raw inputs first) into a tile's
/// network inputs `x` (`k_in` per sample): the per-sample encodings, then the hash grid level
/// by level from `table` (see [`grid::encode_tile`]). Returns the time spent in the hash grid.
pub fn encode_rows(
    layout: &crate::model::ModelLayout,
    levels: &[crate::encoding::hash_grid::FastLevel],
    table: grid::Table,
    rows: &[f32],
    row_len: usize,
    x: &mut [f32],
    k_in: usize,
) -> std::time::Duration {
    let m = rows.len() / row_len;
    layout
        .encoding
        .forward_rows_without_grid(rows, row_len, x, k_in);
    let t_grid = std::time::Instant::now();
    if let Some((hg, part)) = layout.encoding.grid() {
        let at = part.in_offset;
        grid::encode_tile(
            hg,
            levels,
            table,
            m,
            |i| {
                let p = &rows[i * row_len + at..];
                [p[0], p[1], p[2]]
            },
            x,
            k_in,
            part.out_offset,
        );
    }
    t_grid.elapsed()
}
