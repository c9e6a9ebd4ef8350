//! Throughput benchmark: training samples/s and inference queries/s for both presets at batch
//! 2^14 and 2^16 per device, the fused-vs-unfused ratios, and where the fused step's time goes.
//! Run it with `cargo run --release -p nrc-cache --example bench` (or `nrc bench cache`).

use std::time::{Duration, Instant};

use burn::tensor::{Device, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::cpu::train::PHASE_NANOS;
use crate::model::ModelLayout;
use crate::{CacheConfig, CacheDevice, CacheQuery, ComputePath, RadianceCache, SceneBox, TrainingBatch};

/// What to measure.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Devices to run on (wgpu is skipped with a message when no adapter exists).
    pub devices: Vec<CacheDevice>,
    /// Batch sizes.
    pub batches: Vec<usize>,
    /// Minimum measured time per figure.
    pub min_time: Duration,
    /// Also measure the unfused and custom-op paths and the MLP alone (slow).
    pub compare_paths: bool,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self { devices: vec![CacheDevice::Cpu, CacheDevice::Wgpu], batches: vec![1 << 14, 1 << 16], min_time: Duration::from_secs(2), compare_paths: true }
    }
}

/// One measured figure.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchFigure {
    /// Preset name.
    pub preset: String,
    /// Device.
    pub device: CacheDevice,
    /// Computation path.
    pub path: ComputePath,
    /// Batch size.
    pub batch: usize,
    /// Training samples per second (steps included), if measured.
    pub train_per_s: Option<f64>,
    /// Inference queries per second, if measured.
    pub infer_per_s: Option<f64>,
}

/// Random but plausible training data (the learning test's kind of field).
pub fn synthetic_batch(n: usize, seed: u64) -> TrainingBatch {
    let mut r = Pcg64Mcg::seed_from_u64(seed);
    let queries: Vec<CacheQuery> = (0..n)
        .map(|_| CacheQuery {
            position: [r.random(), r.random(), r.random()],
            direction: [r.random_range(-1.0..1.0), r.random_range(-1.0..1.0), r.random_range(-1.0..1.0)],
            normal: [r.random_range(-1.0..1.0), r.random_range(-1.0..1.0), r.random_range(-1.0..1.0)],
            roughness: r.random_range(0.0..1.0),
            diffuse: [r.random_range(0.0..0.9), r.random_range(0.0..0.9), r.random_range(0.0..0.9)],
            specular: [0.04; 3],
        })
        .collect();
    let targets = queries.iter().map(|q| [0.5 + q.position[0], 0.5 + q.position[1] * q.position[2], 1.0 - 0.5 * q.position[2]]).collect();
    TrainingBatch { queries, targets, weights: None }
}

/// Runs `f` (doing `work` units per call) until `min_time` has passed; units per second.
fn rate(min_time: Duration, work: usize, mut f: impl FnMut()) -> f64 {
    f(); // warm-up
    let start = Instant::now();
    let mut calls = 0usize;
    while calls == 0 || start.elapsed() < min_time {
        f();
        calls += 1;
    }
    (calls * work) as f64 / start.elapsed().as_secs_f64()
}

/// MACs per sample of one training step's MLP (forward, weight gradients, input gradients
/// of every layer but the first, hash-grid columns of the first) as the fused kernels run it.
pub fn mlp_macs_per_sample(layout: &ModelLayout) -> (usize, usize) {
    let pad8 = |n: usize| n.div_ceil(8) * 8;
    let last = layout.layers.len() - 1;
    let fwd: usize = layout.layers.iter().enumerate().map(|(l, s)| s.inputs * if l == last { pad8(s.outputs) } else { s.outputs }).sum();
    let grid_cols = layout.encoding.grid().map_or(0, |(g, _)| pad8(g.output_dims()));
    let bwd_x: usize = layout.layers.iter().enumerate().skip(1).map(|(l, s)| s.outputs.max(if l == last { 3 } else { 0 }) * s.inputs).sum::<usize>() + 64 * grid_cols;
    (fwd, fwd + bwd_x)
}

/// Runs the benchmark, printing a table as it goes; returns the figures.
pub fn run(options: &BenchOptions) -> Vec<BenchFigure> {
    let presets = [("hashgrid", CacheConfig::hash_grid_preset()), ("trianglewave", CacheConfig::triangle_wave_preset())];
    let mut figures = Vec::new();
    println!("nrc-cache benchmark (threads: {}, AVX2+FMA kernels: {})", rayon::current_num_threads(), crate::cpu::gemm::has_avx2_fma());
    for &device in &options.devices {
        if device == CacheDevice::Wgpu {
            match crate::gpu::wgpu_device() {
                Ok(_) => {
                    let names: Vec<String> = crate::gpu::adapters().iter().map(|a| format!("{} ({:?}, {:?})", a.name, a.device_type, a.backend)).collect();
                    println!("wgpu adapters: {}", names.join("; "));
                }
                Err(e) => {
                    println!("wgpu: skipped ({e})");
                    continue;
                }
            }
        }
        for (name, config) in &presets {
            let layout = ModelLayout::new(config);
            let (fwd, train_macs) = mlp_macs_per_sample(&layout);
            println!("\n== {name} on {device}: {} parameters, MLP {fwd} MACs/sample forward, {} training", layout.param_count(), fwd + train_macs);
            for &batch_size in &options.batches {
                let mut cache = match RadianceCache::with_path(config.clone(), SceneBox::default(), device, device.default_path()) {
                    Ok(c) => c,
                    Err(e) => {
                        println!("  skipped: {e}");
                        continue;
                    }
                };
                let batch = synthetic_batch(batch_size, 1);
                let steps = if device == CacheDevice::Cpu { 4 } else { 2 };
                for p in &PHASE_NANOS {
                    p.store(0, std::sync::atomic::Ordering::Relaxed);
                }
                let t0 = Instant::now();
                let train = rate(options.min_time, batch_size * steps as usize, || {
                    cache.train(&batch, steps).expect("training");
                });
                let wall = t0.elapsed().as_secs_f64();
                let t_mat = Instant::now();
                let _ = cache.inference_weights();
                let materialise = t_mat.elapsed();
                let infer = rate(options.min_time, batch_size, || {
                    std::hint::black_box(cache.infer(&batch.queries));
                });
                println!(
                    "  batch {batch_size:>6} [{}]: train {:>10.0} samples/s ({:.1} GFLOP/s in the MLP), infer {:>10.0} queries/s; EMA materialisation {:.1} ms",
                    device.default_path(),
                    train,
                    train * (fwd + train_macs) as f64 * 2.0 / 1e9,
                    infer,
                    materialise.as_secs_f64() * 1e3
                );
                if device == CacheDevice::Cpu {
                    let phases: Vec<f64> = PHASE_NANOS.iter().map(|p| p.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9).collect();
                    println!(
                        "    time per phase (thread-seconds / wall {:.2} s): pack+upload {:.2}, encode {:.2}, MLP+loss {:.2}, grid scatter+Adam+EMA {:.2}, MLP Adam {:.3}",
                        wall, phases[4], phases[0], phases[1], phases[2], phases[3]
                    );
                }
                figures.push(BenchFigure { preset: name.to_string(), device, path: device.default_path(), batch: batch_size, train_per_s: Some(train), infer_per_s: Some(infer) });
            }
            if options.compare_paths {
                figures.extend(compare(name, config, device, options));
            }
        }
    }
    figures
}

/// The same step and inference along the other paths (batch 2^14), and the MLP alone.
fn compare(name: &str, config: &CacheConfig, device: CacheDevice, options: &BenchOptions) -> Vec<BenchFigure> {
    let mut out = Vec::new();
    let n = 1 << 14;
    let batch = synthetic_batch(n, 2);
    let short = options.min_time / 2;
    let paths: &[ComputePath] = if device == CacheDevice::Cpu { &[ComputePath::Fused, ComputePath::CustomOps, ComputePath::Unfused] } else { &[ComputePath::CustomOps, ComputePath::Unfused] };
    let mut base: Option<(f64, f64)> = None;
    for &path in paths {
        let Ok(mut cache) = RadianceCache::with_path(config.clone(), SceneBox::default(), device, path) else { continue };
        let train = rate(short, n, || {
            cache.train(&batch, 1).expect("training");
        });
        let infer = rate(short, n, || {
            std::hint::black_box(cache.infer(&batch.queries));
        });
        let (bt, bi) = *base.get_or_insert((train, infer));
        println!("  path {path:<10} batch {n}: train {train:>10.0} samples/s, infer {infer:>10.0} queries/s  (fastest path is {:.1}× / {:.1}× this)", bt / train, bi / infer);
        out.push(BenchFigure { preset: name.to_string(), device, path, batch: n, train_per_s: Some(train), infer_per_s: Some(infer) });
    }
    if let Ok(d) = device.burn_device() {
        mlp_alone(config, &d, n, short);
    }
    out
}

/// The MLP alone, forward + backward through burn autodiff: the fused op (where the backend has
/// one) against the matmul + ReLU ops it replaces.
fn mlp_alone(config: &CacheConfig, device: &Device, n: usize, min_time: Duration) {
    let layout = ModelLayout::new(config);
    let (_, mlp) = layout.init_params(3);
    let k = layout.encoding.padded_dims;
    let mut r = Pcg64Mcg::seed_from_u64(4);
    let x: Vec<f32> = (0..n * k).map(|_| r.random_range(0.0..1.0)).collect();
    let ad = device.clone().autodiff();
    let layers = std::sync::Arc::new(layout.layers.clone());
    let flex = matches!(device.clone().inner().as_dispatch(), burn::backend::DispatchDevice::Flex(_));
    let mut results = Vec::new();
    for fused in [true, false] {
        if fused && !flex {
            continue;
        }
        let w = Tensor::<1>::from_data(TensorData::new(mlp.clone(), [mlp.len()]), &ad);
        let xt = Tensor::<2>::from_data(TensorData::new(x.clone(), [n, k]), &ad);
        let per_s = rate(min_time, n, || {
            let w = w.clone().require_grad();
            let o = if fused { crate::ops::mlp(w.clone(), xt.clone(), &layers) } else { crate::tensor_path::mlp_tensor(w.clone(), xt.clone(), &layers) };
            let grads = o.sum().backward();
            std::hint::black_box(w.grad(&grads).expect("gradient").into_data());
        });
        results.push(per_s);
        println!("  MLP alone, forward + backward, {}: {per_s:>10.0} samples/s", if fused { "fused op" } else { "burn matmul + relu" });
    }
    if results.len() == 2 {
        println!("  MLP fused / unfused: {:.1}×", results[0] / results[1]);
    }
}
