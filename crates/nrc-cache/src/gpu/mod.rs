//! The wgpu path: the fused training step and inference as CubeCL kernels ([`fused`], the
//! `nrc-gpu` crate, behind [`crate::ops::NrcFusedOps`]: the default), and the custom-ops path
//! kept as the measured baseline, whose hash-grid encoding is WGSL from `shaders/`
//! ([`hashgrid`], behind [`crate::hash_grid_op::HashGridOps`]) and whose MLP is burn's matmuls.
//!
//! # How a hand-written WGSL kernel runs on burn 0.22.1 tensors (the mechanism)
//!
//! burn 0.22 has no backend type parameter on tensors: a `Tensor<D>` holds a
//! `DispatchTensor`, an enum over the enabled backends, and its `Device` says which one runs
//! it. Every CubeCL runtime (wgpu, CUDA, ROCm, CubeCL-CPU) is the one backend type
//! `burn_cubecl::CubeBackend` (`burn::backend::Cube`, wrapped in `Fusion` only with the
//! `fusion` feature, which this workspace does not enable); Flex is `burn::backend::Flex`.
//! A custom op therefore takes four pieces:
//!
//! 1. **An extension trait** declared with `#[burn::backend::backend_extension(Cube, Flex,
//!    Autodiff)]` (burn feature `extension`). The macro generates `impl Trait for Dispatch`
//!    that routes each call to the backend of its routing (first float) tensor; `Autodiff`
//!    routes autodiff tensors to a hand-written `impl<B: Trait, C: CheckpointStrategy> Trait
//!    for Autodiff<B, C>`. Callers go through `Tensor::into_dispatch` /
//!    `Tensor::from_dispatch`. Ordinary (non-tensor) arguments must be `Clone + Send + Sync +
//!    'static`.
//! 2. **The wgpu implementation** on `CubeBackend`, whose float primitive is
//!    `burn_cubecl::tensor::CubeTensor { client, handle, meta, device, dtype, .. }`. The
//!    `handle` is the tensor's GPU buffer (a slice of a pooled wgpu buffer);
//!    `handle.clone().binding()` turns it into a kernel binding. Outputs are allocated with
//!    `client.empty(bytes)` and wrapped with `CubeTensor::new_contiguous`, or made with
//!    `CubeBackend::float_zeros` when a kernel accumulates into them. Small parameter blocks
//!    go in one more buffer made with `client.create_from_slice`.
//! 3. **The kernel text.** With burn feature `template`, `burn::backend::wgpu` exports
//!    `KernelSource` (three methods: `source() -> SourceTemplate` with `{{ name }}`
//!    placeholders filled by `register`, `id() -> KernelId` that keys the pipeline cache and
//!    must include every template parameter, and `lang() -> "wgsl"`) and `SourceKernel`,
//!    which wraps it into a `CubeKernel` whose precompiled source skips CubeCL's compiler.
//!    `client.launch(Box::new(SourceKernel::new(kernel, cube_dim)), CubeCount::Static(x, y,
//!    z), KernelArguments::new().with_buffers(vec![..]))` enqueues it lazily on the tensor's
//!    stream. Buffers bind to `@group(0) @binding(i)` in the order given; the pipeline
//!    layout is derived from the shader (so every binding must be used), the entry point is
//!    `main`, and workgroup memory is *not* zero-initialised. Every binding must be declared
//!    `var<storage, read_write>`, inputs included: CubeCL's memory pool packs many tensors
//!    into one wgpu buffer, and wgpu rejects a dispatch that uses one buffer both read-only
//!    and read-write ("conflicting usages"), so a `read` declaration fails as soon as an input
//!    and an output share a pool page. The cubecl wgpu runtime picks
//!    the WGSL compiler unless a SPIR-V build (`vulkan` feature) is chosen, where a WGSL
//!    template is refused at launch: this crate does not enable `vulkan`.
//! 4. **The backward pass**: in the `Autodiff<B, C>` impl, a zero-sized struct implementing
//!    `burn::backend::autodiff::ops::Backward<B, N>` whose `backward` reads the output
//!    gradient (`grads.consume::<B>(&ops.node)`) and registers input gradients computed by
//!    the backend's own kernels (`grads.register::<B>(id, g)`), prepared with
//!    `Struct.prepare::<C>([tensor.node()]).compute_bound().stateful()`; this is how
//!    burn-autodiff itself does `embedding`, the closest relative of a hash-grid lookup.
//!
//! Device selection: `Device::wgpu_options().init()` returns an error instead of panicking
//! when no adapter exists; [`wgpu_device`] wraps that once per process, and
//! [`adapters`] tells a hardware GPU from a software rasteriser (lavapipe, llvmpipe).

pub mod fused;
pub mod hashgrid;

use std::sync::OnceLock;

use burn::backend::wgpu::wgpu;
use burn::tensor::Device;

/// The wgpu device, initialised once per process; `Err` names why there is none (no adapter).
///
/// burn refuses to initialise the same wgpu runtime twice, so the first outcome is kept.
pub fn wgpu_device() -> Result<Device, String> {
    static DEVICE: OnceLock<Result<Device, String>> = OnceLock::new();
    DEVICE
        .get_or_init(|| {
            Device::wgpu_options()
                .init()
                .map_err(|err| format!("no usable wgpu adapter: {err}"))
        })
        .clone()
}

/// The adapters wgpu can see: name, device type and graphics API of each.
///
/// A `wgpu::DeviceType::Cpu` adapter is a software rasteriser (mesa lavapipe/llvmpipe): it
/// runs the kernels correctly but is no faster than the CPU backend.
pub fn adapters() -> Vec<wgpu::AdapterInfo> {
    let instance = wgpu::Instance::default();
    burn::cubecl::future::block_on(instance.enumerate_adapters(wgpu::Backends::all()))
        .iter()
        .map(wgpu::Adapter::get_info)
        .collect()
}

/// One line per adapter wgpu can see, with what the fused kernels care about: the graphics API
/// and driver, the shader features (f16, subgroups and their sizes, float atomics, 64-bit
/// integers, timestamp queries, cooperative matrices and their shapes) and the limits
/// (workgroup memory, invocations per workgroup, storage binding and buffer sizes).
pub fn describe_adapters() -> Vec<String> {
    let instance = wgpu::Instance::default();
    let adapters =
        burn::cubecl::future::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
    adapters.iter().map(describe).collect()
}

fn describe(adapter: &wgpu::Adapter) -> String {
    use wgpu::Features as F;
    let info = adapter.get_info();
    let features = adapter.features();
    let limits = adapter.limits();
    let named = [
        (F::SHADER_F16, "shader-f16"),
        (F::SUBGROUP, "subgroup"),
        (F::SHADER_FLOAT32_ATOMIC, "f32-atomics"),
        (F::SHADER_INT64, "int64"),
        (F::TIMESTAMP_QUERY, "timestamp-query"),
        (F::EXPERIMENTAL_COOPERATIVE_MATRIX, "cooperative-matrix"),
    ];
    let has: Vec<&str> = named
        .iter()
        .filter(|(f, _)| features.contains(*f))
        .map(|(_, n)| *n)
        .collect();
    let lacks: Vec<&str> = named
        .iter()
        .filter(|(f, _)| !features.contains(*f))
        .map(|(_, n)| *n)
        .collect();
    let shapes: Vec<String> = if features.contains(F::EXPERIMENTAL_COOPERATIVE_MATRIX) {
        adapter
            .cooperative_matrix_properties()
            .iter()
            .map(|p| {
                format!(
                    "{}x{}x{} {:?}->{:?}",
                    p.m_size, p.n_size, p.k_size, p.ab_type, p.cr_type
                )
            })
            .collect()
    } else {
        Vec::new()
    };
    format!(
        "{} ({:?}, {:?}, driver {} {}); features: {}; lacks: {}; subgroup size {}..{}; \
         workgroup memory {} B, {} invocations per workgroup, storage binding {} MiB, buffer {} MiB{}",
        info.name,
        info.device_type,
        info.backend,
        info.driver,
        info.driver_info,
        if has.is_empty() {
            "none".into()
        } else {
            has.join(", ")
        },
        if lacks.is_empty() {
            "nothing".into()
        } else {
            lacks.join(", ")
        },
        info.subgroup_min_size,
        info.subgroup_max_size,
        limits.max_compute_workgroup_storage_size,
        limits.max_compute_invocations_per_workgroup,
        limits.max_storage_buffer_binding_size >> 20,
        limits.max_buffer_size >> 20,
        if shapes.is_empty() {
            String::new()
        } else {
            format!("; cooperative-matrix shapes: {}", shapes.join(", "))
        }
    )
}
