//! The hash-grid encoding as a burn custom op with an explicit backward pass, on every backend
//! the cache runs on: WGSL kernels on wgpu ([`crate::gpu::hashgrid`]), the rayon kernels of
//! [`crate::cpu::grid`] on Flex, and a hand-written autodiff node on top of both.
//!
//! The op is differentiable w.r.t. the table only: positions are inputs, never trained, so
//! their gradient is not computed. How burn routes the call is described in [`crate::gpu`].

use std::borrow::Cow;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::wgpu::CubeBackend;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Flex, backend_extension};
use burn::tensor::{DType, Tensor, TensorData};

use crate::encoding::hash_grid::HashGrid;

/// Backends that run the hash-grid encoding as one custom op.
#[backend_extension(Cube, Flex, Autodiff)]
pub trait HashGridOps: Backend {
    /// `positions` [n, 3] in [0,1]³, `table` [entries·F] level-major → encoding [n, L·F].
    fn hash_grid_forward(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self>;

    /// Gradient w.r.t. the table [entries·F] of a loss whose gradient w.r.t. the encoding is
    /// `grad_encoded` [n, L·F].
    fn hash_grid_backward(
        positions: FloatTensor<Self>,
        grad_encoded: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self>;
}

/// The hash-grid encoding of `positions` ([n, 3]) with `table` ([entries·F]) as one custom op:
/// returns [n, L·F]; on an autodiff device the table receives its gradient.
pub fn hash_grid(grid: &HashGrid, table: Tensor<1>, positions: Tensor<2>) -> Tensor<2> {
    Tensor::from_dispatch(Dispatch::hash_grid_forward(
        positions.into_dispatch(),
        table.into_dispatch(),
        grid.clone(),
    ))
}

impl HashGridOps for CubeBackend {
    fn hash_grid_forward(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        crate::gpu::hashgrid::forward(positions, table, &grid)
    }

    fn hash_grid_backward(
        positions: FloatTensor<Self>,
        grad_encoded: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        crate::gpu::hashgrid::backward(positions, grad_encoded, &grid)
    }
}

/// The f32 values of a Flex tensor, borrowed when it is contiguous.
fn flex_values(tensor: &FlexTensor) -> Cow<'_, [f32]> {
    assert_eq!(
        tensor.dtype(),
        DType::F32,
        "hash grid on Flex: tensors must be f32"
    );
    match tensor.as_slice::<f32>() {
        Some(values) => Cow::Borrowed(values),
        None => Cow::Owned(
            tensor
                .to_contiguous()
                .into_data()
                .try_into_vec::<f32>()
                .expect("f32 data"),
        ),
    }
}

fn flex_tensor(values: Vec<f32>, shape: [usize; 2]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

impl HashGridOps for Flex {
    fn hash_grid_forward(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        let p = flex_values(&positions);
        let table = flex_values(&table);
        assert_eq!(
            table.len(),
            grid.param_count(),
            "hash grid on Flex: table size"
        );
        let n = p.len() / 3;
        let mut out = vec![0f32; n * grid.output_dims()];
        crate::cpu::grid::forward(&grid, &table, &p, &mut out);
        flex_tensor(out, [n, grid.output_dims()])
    }

    fn hash_grid_backward(
        positions: FloatTensor<Self>,
        grad_encoded: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        let p = flex_values(&positions);
        let d = flex_values(&grad_encoded);
        assert_eq!(
            d.len(),
            p.len() / 3 * grid.output_dims(),
            "hash grid on Flex: gradient of the encoding must be [n, L·F]"
        );
        let mut grad = vec![0f32; grid.param_count()];
        crate::cpu::grid::backward_table(&grid, &p, &d, &mut grad);
        FlexTensor::from_data(TensorData::new(grad, [grid.param_count()]))
    }
}

/// The autodiff node: forward runs the inner backend's kernel; backward hands the output
/// gradient to the inner backend's scatter kernel (as burn-autodiff does for `embedding`).
impl<B: HashGridOps, C: CheckpointStrategy> HashGridOps for Autodiff<B, C> {
    fn hash_grid_forward(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct HashGridBackward;

        impl<B: HashGridOps> Backward<B, 1> for HashGridBackward {
            type State = (FloatTensor<B>, HashGrid);

            fn backward(
                self,
                ops: Ops<Self::State, 1>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let (positions, grid) = ops.state;
                unary::<B, _>(ops.parents, ops.node, grads, |grad| {
                    B::hash_grid_backward(positions, grad, grid)
                });
            }
        }

        let positions = positions.into_primitive();
        match HashGridBackward
            .prepare::<C>([table.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let output =
                    B::hash_grid_forward(positions.clone(), table.into_primitive(), grid.clone());
                prep.finish((positions, grid), output)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::hash_grid_forward(
                positions,
                table.into_primitive(),
                grid,
            )),
        }
    }

    fn hash_grid_backward(
        positions: FloatTensor<Self>,
        grad_encoded: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        // The scatter itself is not differentiated (no second-order training).
        let grad = B::hash_grid_backward(
            positions.into_primitive(),
            grad_encoded.into_primitive(),
            grid,
        );
        <Self as AutodiffBackend>::from_inner(grad)
    }
}
