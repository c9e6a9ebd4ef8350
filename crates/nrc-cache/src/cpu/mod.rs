//! CPU kernels behind the Flex custom ops: small dense products, the fused MLP tile, the
//! hash-grid batch passes, Adam/EMA, and the fused training step and inference built from them.
//! Parallel over batch tiles (or hash-grid levels) with rayon.

pub mod gemm;
pub mod grid;
pub mod huge;
pub mod infer;
pub mod mlp;
pub mod optim;
pub mod train;
