//! The training state as device tensors, and its host (plain `Vec`) form for snapshots.

use burn::backend::Dispatch;
use burn::tensor::{Device, Tensor, TensorData};

use crate::ops::TrainState;

/// All training state on the device (see [`TrainState`] for the fields' meaning).
///
/// With `packed = Some(F)` (the fused CPU path) `grid` holds the table's per-entry records
/// `[w | m | v | ema]` ([`crate::cpu::optim::RECORD`]·F floats per entry) and `grid_m`,
/// `grid_v`, `grid_ema` are empty; otherwise the four are separate arrays.
#[derive(Clone, Debug)]
pub struct TensorState {
    /// Features per table entry when the table is stored as records.
    pub packed: Option<usize>,
    /// Hash table weights (or records).
    pub grid: Tensor<1>,
    /// Adam first moment of the table.
    pub grid_m: Tensor<1>,
    /// Adam second moment of the table.
    pub grid_v: Tensor<1>,
    /// Raw EMA of the table.
    pub grid_ema: Tensor<1>,
    /// Half-precision copy of the table's weights for the fused training forward (built by the
    /// first fused step that needs it; empty until then and on the other paths).
    pub grid_half: Tensor<1>,
    /// MLP weights.
    pub mlp: Tensor<1>,
    /// Adam first moment of the MLP.
    pub mlp_m: Tensor<1>,
    /// Adam second moment of the MLP.
    pub mlp_v: Tensor<1>,
    /// Raw EMA of the MLP.
    pub mlp_ema: Tensor<1>,
}

/// The training state on the host, with the raw EMA of every weight at the step count.
#[derive(Clone, Debug, PartialEq)]
pub struct HostState {
    /// Hash table weights `[entry][feature]`.
    pub grid: Vec<f32>,
    /// Adam first moment of the table.
    pub grid_m: Vec<f32>,
    /// Adam second moment of the table.
    pub grid_v: Vec<f32>,
    /// Raw EMA of the table.
    pub grid_ema: Vec<f32>,
    /// MLP weights.
    pub mlp: Vec<f32>,
    /// Adam first moment of the MLP.
    pub mlp_m: Vec<f32>,
    /// Adam second moment of the MLP.
    pub mlp_v: Vec<f32>,
    /// Raw EMA of the MLP.
    pub mlp_ema: Vec<f32>,
}

/// A float vector on `device`.
pub fn vec_tensor(values: Vec<f32>, device: &Device) -> Tensor<1> {
    let n = values.len();
    Tensor::from_data(TensorData::new(values, [n]), device)
}

/// A float vector's values on the host.
pub fn tensor_vec(t: Tensor<1>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32 tensor")
}

impl TensorState {
    /// Uploads a host state. `packed = Some(F)` stores the table as records (the fused path),
    /// the raw EMA in the records' last field (the fused step wants its EMA gap: see
    /// [`crate::ops::EmaConversion`]).
    pub fn from_host(h: HostState, packed: Option<usize>, device: &Device) -> Self {
        let (grid, grid_m, grid_v, grid_ema) = match packed {
            Some(f) => (
                crate::cpu::optim::pack_records(f, &h.grid, &h.grid_m, &h.grid_v, &h.grid_ema),
                Vec::new(),
                Vec::new(),
                Vec::new(),
            ),
            None => (h.grid, h.grid_m, h.grid_v, h.grid_ema),
        };
        Self {
            packed,
            grid: vec_tensor(grid, device),
            grid_m: vec_tensor(grid_m, device),
            grid_v: vec_tensor(grid_v, device),
            grid_ema: vec_tensor(grid_ema, device),
            grid_half: vec_tensor(Vec::new(), device),
            mlp: vec_tensor(h.mlp, device),
            mlp_m: vec_tensor(h.mlp_m, device),
            mlp_v: vec_tensor(h.mlp_v, device),
            mlp_ema: vec_tensor(h.mlp_ema, device),
        }
    }

    /// Downloads the state (on the fused path, the caller has turned the EMA gap into the raw
    /// EMA).
    pub fn to_host(&self) -> HostState {
        let (grid, grid_m, grid_v, grid_ema) = match self.packed {
            Some(f) => {
                let [w, m, v, e] =
                    crate::cpu::optim::unpack_records(f, &tensor_vec(self.grid.clone()));
                (w, m, v, e)
            }
            None => (
                tensor_vec(self.grid.clone()),
                tensor_vec(self.grid_m.clone()),
                tensor_vec(self.grid_v.clone()),
                tensor_vec(self.grid_ema.clone()),
            ),
        };
        HostState {
            grid,
            grid_m,
            grid_v,
            grid_ema,
            mlp: tensor_vec(self.mlp.clone()),
            mlp_m: tensor_vec(self.mlp_m.clone()),
            mlp_v: tensor_vec(self.mlp_v.clone()),
            mlp_ema: tensor_vec(self.mlp_ema.clone()),
        }
    }

    /// Hands the tensors to the dispatch layer (for the fused custom ops).
    pub fn into_dispatch(self) -> TrainState<Dispatch> {
        TrainState {
            grid: self.grid.into_dispatch(),
            grid_m: self.grid_m.into_dispatch(),
            grid_v: self.grid_v.into_dispatch(),
            grid_ema: self.grid_ema.into_dispatch(),
            grid_half: self.grid_half.into_dispatch(),
            mlp: self.mlp.into_dispatch(),
            mlp_m: self.mlp_m.into_dispatch(),
            mlp_v: self.mlp_v.into_dispatch(),
            mlp_ema: self.mlp_ema.into_dispatch(),
        }
    }

    /// Takes the tensors back from the dispatch layer.
    pub fn from_dispatch(s: TrainState<Dispatch>, packed: Option<usize>) -> Self {
        Self {
            packed,
            grid: Tensor::from_dispatch(s.grid),
            grid_m: Tensor::from_dispatch(s.grid_m),
            grid_v: Tensor::from_dispatch(s.grid_v),
            grid_ema: Tensor::from_dispatch(s.grid_ema),
            grid_half: Tensor::from_dispatch(s.grid_half),
            mlp: Tensor::from_dispatch(s.mlp),
            mlp_m: Tensor::from_dispatch(s.mlp_m),
            mlp_v: Tensor::from_dispatch(s.mlp_v),
            mlp_ema: Tensor::from_dispatch(s.mlp_ema),
        }
    }
}
