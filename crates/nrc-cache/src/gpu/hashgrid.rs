//! Hash-grid encoding on wgpu: launches `shaders/hashgrid_forward.wgsl` and
//! `shaders/hashgrid_backward.wgsl` on the buffers of burn `CubeTensor`s (see the module doc of
//! [`crate::gpu`] for the mechanism). One thread per (level, sample).

use burn::backend::ops::FloatTensorOps;
use burn::backend::wgpu::{
    CubeBackend, CubeTensor, KernelSource, SourceKernel, SourceTemplate, into_contiguous,
};
use burn::cubecl::prelude::KernelId;
use burn::cubecl::server::KernelArguments;
use burn::cubecl::{CubeCount, CubeDim};
use burn::tensor::{DType, FloatDType, Shape};

use crate::encoding::hash_grid::HashGrid;

/// Threads per workgroup of both kernels.
const WORKGROUP: u32 = 256;
/// Most workgroups one dispatch dimension may hold (WebGPU's default limit).
const MAX_GROUPS_PER_DIM: u32 = 65_535;

const COMMON: &str = include_str!("../../../../shaders/hashgrid_common.wgsl");
const FORWARD: &str = include_str!("../../../../shaders/hashgrid_forward.wgsl");
const BACKWARD: &str = include_str!("../../../../shaders/hashgrid_backward.wgsl");

/// One level of the grid as the kernels read it (see `shaders/hashgrid_common.wgsl`).
#[derive(Clone, Copy, Debug, PartialEq)]
struct GpuLevel {
    /// s_l = base_resolution · per_level_scale^l − 1, the very f32 the CPU path uses.
    scale: f32,
    /// r_l = ceil(s_l) + 1.
    resolution: u32,
    /// Table entries of this level: min(T, r_l³ rounded up to a multiple of 8).
    entries: u32,
    /// Index (in floats, not entries) of this level's first parameter in the level-major table.
    offset: u32,
    /// Whether the level hashes (r_l³ > T) rather than indexing densely.
    hashed: bool,
}

impl GpuLevel {
    fn all(grid: &HashGrid) -> Vec<GpuLevel> {
        let features = grid.features();
        grid.levels
            .iter()
            .map(|level| GpuLevel {
                scale: level.scale,
                resolution: level.resolution,
                entries: level.entries,
                offset: (level.offset * features) as u32,
                hashed: !level.dense,
            })
            .collect()
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Pass {
    Forward,
    Backward,
}

/// The WGSL source of one pass, specialised to the feature count (a compile-time constant, so
/// the per-feature loops unroll and the accumulators live in registers).
#[derive(Debug)]
struct HashGridKernel {
    pass: Pass,
    features: u32,
}

impl KernelSource for HashGridKernel {
    fn source(&self) -> SourceTemplate {
        let main = match self.pass {
            Pass::Forward => FORWARD,
            Pass::Backward => BACKWARD,
        };
        SourceTemplate::new(main)
            .add_template(COMMON)
            .register("features", self.features.to_string())
            .register("workgroup_size", WORKGROUP.to_string())
    }

    fn id(&self) -> KernelId {
        KernelId::new::<Self>().info((self.pass, self.features, WORKGROUP))
    }

    fn lang(&self) -> &'static str {
        "wgsl"
    }
}

/// The `info` buffer both kernels read: sample count, level count, then five words per level.
fn info_words(samples: usize, levels: &[GpuLevel]) -> Vec<u32> {
    let mut info = Vec::with_capacity(2 + 5 * levels.len());
    info.push(samples as u32);
    info.push(levels.len() as u32);
    for level in levels {
        info.extend([
            level.scale.to_bits(),
            level.resolution,
            level.entries,
            level.offset,
            u32::from(level.hashed),
        ]);
    }
    info
}

/// Workgroups for `threads` threads, folded into two dimensions past the per-dimension limit.
fn cube_count(threads: usize) -> CubeCount {
    let groups = threads.div_ceil(WORKGROUP as usize) as u32;
    let x = groups.clamp(1, MAX_GROUPS_PER_DIM);
    CubeCount::Static(x, groups.div_ceil(x).max(1), 1)
}

fn check_inputs(positions: &CubeTensor, grid: &HashGrid) -> usize {
    let features = grid.features();
    assert_eq!(
        positions.dtype,
        DType::F32,
        "hash grid on wgpu: positions must be f32"
    );
    let shape = positions.meta.shape();
    assert!(
        shape.num_dims() == 2 && shape[1] == 3,
        "hash grid on wgpu: positions must be [n, 3], got {shape:?}"
    );
    assert!(
        (1..=8).contains(&features),
        "hash grid on wgpu: 1 to 8 features per level, got {features}"
    );
    let samples = shape[0];
    // Every index the kernels form (sample · L · F + …, level offsets) is a u32.
    assert!(
        (samples as u64) * (grid.output_dims() as u64) < u64::from(u32::MAX)
            && (grid.param_count() as u64) < u64::from(u32::MAX),
        "hash grid on wgpu: {samples} samples or {} parameters too many for 32-bit indexing",
        grid.param_count()
    );
    samples
}

/// Encodes `positions` ([n, 3], in [0, 1]³) with the table `params` ([Σ entries · F], level
/// major): returns [n, L·F] with column l·F + f holding feature f of level l, as
/// [`HashGrid::forward_one`] does on the CPU.
pub fn forward(positions: CubeTensor, params: CubeTensor, grid: &HashGrid) -> CubeTensor {
    let samples = check_inputs(&positions, grid);
    let (levels, features) = (GpuLevel::all(grid), grid.features());
    assert_eq!(
        params.meta.shape().num_elements(),
        grid.param_count(),
        "hash grid on wgpu: parameter table size"
    );
    assert_eq!(
        params.dtype,
        DType::F32,
        "hash grid on wgpu: parameters must be f32"
    );
    let positions = into_contiguous(positions);
    let params = into_contiguous(params);
    let client = positions.client.clone();

    let out_shape = Shape::new([samples, levels.len() * features]);
    let out_handle = client.empty(out_shape.num_elements() * size_of::<f32>());
    let encoded = CubeTensor::new_contiguous(
        client.clone(),
        positions.device.clone(),
        out_shape,
        out_handle,
        DType::F32,
    );
    if samples == 0 || levels.is_empty() {
        return encoded;
    }
    launch(
        Pass::Forward,
        features,
        samples,
        &levels,
        [&positions, &params, &encoded],
    );
    encoded
}

/// Gradient of the loss w.r.t. the table, given its gradient w.r.t. the encoding
/// (`grad_encoded`, [n, L·F]): a zeroed [n_params] tensor into which every sample scatters
/// weight · gradient at its eight corners per level with emulated float atomics, as
/// [`HashGrid::backward_params_one`] does on the CPU.
pub fn backward(positions: CubeTensor, grad_encoded: CubeTensor, grid: &HashGrid) -> CubeTensor {
    let samples = check_inputs(&positions, grid);
    let (levels, features) = (GpuLevel::all(grid), grid.features());
    let n_params = grid.param_count();
    assert_eq!(
        grad_encoded.dtype,
        DType::F32,
        "hash grid on wgpu: gradient must be f32"
    );
    assert_eq!(
        grad_encoded.meta.shape().num_elements(),
        samples * levels.len() * features,
        "hash grid on wgpu: gradient of the encoding must be [n, L·F]"
    );
    let positions = into_contiguous(positions);
    let grad_encoded = into_contiguous(grad_encoded);
    let grad_params =
        CubeBackend::float_zeros(Shape::new([n_params]), &positions.device, FloatDType::F32);
    if samples == 0 || levels.is_empty() {
        return grad_params;
    }
    launch(
        Pass::Backward,
        features,
        samples,
        &levels,
        [&positions, &grad_encoded, &grad_params],
    );
    grad_params
}

/// Launches `pass` over `samples` × `levels` threads on the kernel's first three bindings
/// (`tensors`, in the shader's order) and the `info` buffer built here.
fn launch(
    pass: Pass,
    features: usize,
    samples: usize,
    levels: &[GpuLevel],
    tensors: [&CubeTensor; 3],
) {
    let client = &tensors[0].client;
    let info = client.create_from_slice(bytemuck::cast_slice(&info_words(samples, levels)));
    let kernel = HashGridKernel {
        pass,
        features: features as u32,
    };
    let mut buffers: Vec<_> = tensors.iter().map(|t| t.handle.clone().binding()).collect();
    buffers.push(info.binding());
    client.launch(
        Box::new(SourceKernel::new(kernel, CubeDim::new_1d(WORKGROUP))),
        cube_count(samples * levels.len()),
        KernelArguments::new().with_buffers(buffers),
    );
}
