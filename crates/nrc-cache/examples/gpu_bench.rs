//! Benchmark of the wgpu kernels against the unfused burn ops they replace, on whatever wgpu
//! adapter exists (the adapter is printed: a software rasteriser such as lavapipe says nothing
//! about a GPU).
//!
//! ```text
//! cargo run --release -p nrc-cache --example gpu_bench [-- ITERATIONS]
//! ```
//!
//! For batches of 2^14 and 2^16 samples it times, in samples per second:
//! * the fused MLP (`ops::mlp`, WGSL with a tile's activations in workgroup memory) against the
//!   matmul + ReLU chain (`tensor_path::mlp_tensor`), forward alone and forward + backward;
//! * the hash-grid custom op (`hash_grid_op::hash_grid`, WGSL with atomic scatter) against the
//!   gather-based tensor-op encoding (`encoding::hash_grid_tensor`), forward + backward,
//!   with the hash-grid preset's grid (16 levels × 2 features, T = 2^19).

use std::sync::Arc;
use std::time::Instant;

use burn::tensor::{Device, Distribution, Tensor};
use nrc_cache::CacheConfig;
use nrc_cache::encoding::hash_grid::HashGrid;
use nrc_cache::model::{LayerShape, ModelLayout};

/// Seconds per call of `f`, after two warm-up calls (kernel compilation), each call followed by
/// a device synchronisation so that the time is the kernels' and not their enqueueing.
fn time(device: &Device, iterations: usize, mut f: impl FnMut()) -> f64 {
    let mut call = || {
        f();
        device.sync().expect("device synchronisation");
    };
    call();
    call();
    let start = Instant::now();
    for _ in 0..iterations {
        call();
    }
    start.elapsed().as_secs_f64() / iterations as f64
}

fn mlp_case(device: &Device, layers: &Arc<Vec<LayerShape>>, batch: usize, iterations: usize) {
    let inputs = layers[0].inputs;
    let count = layers.last().map_or(0, |l| l.offset + l.len());
    let w = Tensor::<1>::random([count], Distribution::Uniform(-0.2, 0.2), device);
    let x = Tensor::<2>::random([batch, inputs], Distribution::Uniform(-1.0, 1.0), device);
    let fused = time(device, iterations, || {
        drop(nrc_cache::ops::mlp(w.clone(), x.clone(), layers))
    });
    let unfused = time(device, iterations, || {
        drop(nrc_cache::tensor_path::mlp_tensor(
            w.clone(),
            x.clone(),
            layers,
        ))
    });

    let ad = device.clone().autodiff();
    let train = |fused: bool| {
        let w = Tensor::<1>::from_data(w.to_data(), &ad).require_grad();
        let x = Tensor::<2>::from_data(x.to_data(), &ad);
        let layers = layers.clone();
        move || {
            let out = if fused {
                nrc_cache::ops::mlp(w.clone(), x.clone(), &layers)
            } else {
                nrc_cache::tensor_path::mlp_tensor(w.clone(), x.clone(), &layers)
            };
            let grads = out.sum().backward();
            drop(w.grad(&grads).expect("weight gradient"));
        }
    };
    let fused_train = time(device, iterations, train(true));
    let unfused_train = time(device, iterations, train(false));
    let rate = |s: f64| batch as f64 / s;
    println!(
        "MLP {inputs}→{}×64→3, batch {batch}: forward fused {:.3e}/s, unfused {:.3e}/s (×{:.2}); \
         forward+backward fused {:.3e}/s, unfused {:.3e}/s (×{:.2})",
        layers.len() - 1,
        rate(fused),
        rate(unfused),
        unfused / fused,
        rate(fused_train),
        rate(unfused_train),
        unfused_train / fused_train,
    );
}

fn grid_case(device: &Device, grid: &HashGrid, batch: usize, iterations: usize) {
    let ad = device.clone().autodiff();
    let table = Tensor::<1>::random(
        [grid.param_count()],
        Distribution::Uniform(-1e-4, 1e-4),
        &ad,
    )
    .require_grad();
    let p = Tensor::<2>::random([batch, 3], Distribution::Uniform(0.0, 1.0), &ad);
    let run = |op: bool| {
        let (table, p, grid) = (table.clone(), p.clone(), grid.clone());
        move || {
            let e = if op {
                nrc_cache::hash_grid_op::hash_grid(&grid, table.clone(), p.clone())
            } else {
                nrc_cache::encoding::hash_grid_tensor(&grid, table.clone(), p.clone())
            };
            let grads = e.sum().backward();
            drop(table.grad(&grads).expect("table gradient"));
        }
    };
    let custom = time(device, iterations, run(true));
    let reference = time(device, iterations, run(false));
    println!(
        "hash grid {}×{} (T=2^{}), batch {batch}, forward+backward: custom op {:.3e}/s, tensor ops {:.3e}/s (×{:.2})",
        grid.levels.len(),
        grid.features(),
        grid.params.log2_hashmap_size,
        batch as f64 / custom,
        batch as f64 / reference,
        reference / custom
    );
}

fn main() {
    let iterations = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let device = match nrc_cache::gpu::wgpu_device() {
        Ok(device) => device,
        Err(why) => {
            eprintln!("no wgpu device: {why}");
            std::process::exit(1);
        }
    };
    for info in nrc_cache::gpu::adapters() {
        println!(
            "wgpu adapter: {} ({:?}, {:?}, driver {})",
            info.name, info.device_type, info.backend, info.driver_info
        );
    }
    let presets = [
        CacheConfig::hash_grid_preset(),
        CacheConfig::triangle_wave_preset(),
    ];
    for batch in [1 << 14, 1 << 16] {
        for config in &presets {
            let layout = ModelLayout::new(config);
            mlp_case(&device, &Arc::new(layout.layers.clone()), batch, iterations);
        }
        let layout = ModelLayout::new(&presets[0]);
        let (grid, _) = layout
            .encoding
            .grid()
            .expect("the hash-grid preset has a grid");
        grid_case(&device, grid, batch, iterations);
    }
}
