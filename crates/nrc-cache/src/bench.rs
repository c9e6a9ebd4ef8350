//! Throughput benchmark: training samples/s and inference queries/s for both presets at batch
//! 2^14 and 2^16 per device, the fused-vs-unfused ratios, and where the fused step's time goes.
//! Run it with `nrc bench cache` (`cargo run --release -- bench cache --help`).

use std::time::{Duration, Instant};

use burn::tensor::{Device, Tensor, TensorData, f16};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::model::ModelLayout;
use crate::profile::{InferProfile, TrainProfile};
use crate::{
    CacheConfig, CacheDevice, CacheQuery, ComputePath, RadianceCache, SceneBox, TrainingBatch,
};

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
    /// Configurations to measure, by name; empty: the two presets.
    pub configs: Vec<(String, CacheConfig)>,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            devices: vec![CacheDevice::Cpu, CacheDevice::Wgpu],
            batches: vec![1 << 14, 1 << 16],
            min_time: Duration::from_secs(2),
            compare_paths: true,
            configs: Vec::new(),
        }
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
            direction: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
            ],
            normal: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
            ],
            roughness: r.random_range(0.0..1.0),
            diffuse: [
                r.random_range(0.0..0.9),
                r.random_range(0.0..0.9),
                r.random_range(0.0..0.9),
            ],
            specular: [0.04; 3],
        })
        .collect();
    let targets = queries
        .iter()
        .map(|q| {
            [
                0.5 + q.position[0],
                0.5 + q.position[1] * q.position[2],
                1.0 - 0.5 * q.position[2],
            ]
        })
        .collect();
    TrainingBatch {
        queries,
        targets,
        weights: None,
    }
}

/// CPU time (user + system) this process has used, from `/proc/self/stat` (Linux; 10 ms
/// resolution), or None elsewhere.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are the 12th and 13th.
    let rest = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// A throughput measured over wall-clock time, with the process's CPU time over the same span.
#[derive(Clone, Copy, Debug)]
struct Rate {
    /// Units per wall-clock second.
    per_s: f64,
    /// Units per CPU-second of this process, times the thread count: the rate had the cores
    /// been ours alone (other processes on a shared machine inflate wall time).
    per_cpu_s: Option<f64>,
}

/// Runs `f` (doing `work` units per call) until `min_time` has passed.
fn rate(min_time: Duration, work: usize, mut f: impl FnMut()) -> Rate {
    f(); // warm-up
    let cpu0 = process_cpu_seconds();
    let start = Instant::now();
    let mut calls = 0usize;
    while calls == 0 || start.elapsed() < min_time {
        f();
        calls += 1;
    }
    let wall = start.elapsed().as_secs_f64();
    let units = (calls * work) as f64;
    let per_cpu_s = match (cpu0, process_cpu_seconds()) {
        (Some(a), Some(b)) if b > a => Some(units / (b - a) * rayon::current_num_threads() as f64),
        _ => None,
    };
    Rate {
        per_s: units / wall,
        per_cpu_s,
    }
}

fn show(r: Rate) -> String {
    match r.per_cpu_s {
        Some(c) => format!("{:>10.0} ({:>10.0} per core-share)", r.per_s, c),
        None => format!("{:>10.0}", r.per_s),
    }
}

/// MACs per sample of one training step's MLP (forward, weight gradients, input gradients
/// of every layer but the first, hash-grid columns of the first) as the fused kernels run it.
pub fn mlp_macs_per_sample(layout: &ModelLayout) -> (usize, usize) {
    let pad8 = |n: usize| n.div_ceil(8) * 8;
    let last = layout.layers.len() - 1;
    let fwd: usize = layout
        .layers
        .iter()
        .enumerate()
        .map(|(l, s)| {
            s.inputs
                * if l == last {
                    pad8(s.outputs)
                } else {
                    s.outputs
                }
        })
        .sum();
    let grid_cols = layout
        .encoding
        .grid()
        .map_or(0, |(g, _)| pad8(g.output_dims()));
    let bwd_x: usize = layout
        .layers
        .iter()
        .enumerate()
        .skip(1)
        .map(|(l, s)| s.outputs.max(if l == last { 3 } else { 0 }) * s.inputs)
        .sum::<usize>()
        + 64 * grid_cols;
    (fwd, fwd + bwd_x)
}

/// The machine's memory limits as the cache meets them: streaming copy bandwidth (read +
/// write) and independent random 64-byte reads per second over a 256 MiB buffer, all threads.
pub fn memory_limits() -> (f64, f64) {
    use rayon::prelude::*;
    let n = 64 << 20;
    let a = vec![1.0f32; n];
    let mut b = vec![0.0f32; n];
    let mut copy = 0f64;
    let mut random = 0f64;
    for _ in 0..2 {
        let t = Instant::now();
        b.par_chunks_mut(1 << 16)
            .zip(a.par_chunks(1 << 16))
            .for_each(|(x, y)| x.copy_from_slice(y));
        copy = copy.max((2 * n * 4) as f64 / t.elapsed().as_secs_f64());
        let lines = n / 16;
        let threads = rayon::current_num_threads();
        let per = 2_000_000;
        let t = Instant::now();
        let s: f32 = (0..threads)
            .into_par_iter()
            .map(|k| {
                let mut x = 12345u64 + k as u64;
                let mut s = 0.0;
                for _ in 0..per {
                    x = x
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    s += a[((x >> 33) as usize % lines) * 16];
                }
                s
            })
            .sum();
        std::hint::black_box(s);
        random = random.max((threads * per) as f64 / t.elapsed().as_secs_f64());
    }
    std::hint::black_box(&b);
    (copy, random)
}

/// The hash-grid encoding kernel alone, on one thread, over the hash-grid preset's grid
/// (tables in huge pages): ns per query for the plain table (2 floats per entry), the
/// half-precision table (2 halves per entry; both are inference tables) and the training
/// records (8 floats per entry), with random positions (the table's lines come from memory)
/// and with every query at one position (all lines in L1: the arithmetic alone), for the
/// dispatching kernel and the portable loop. Returns
/// `[f32 table, f16 table, records][random, one position][kernel, portable]`.
pub fn hash_grid_kernel(min_time: Duration) -> [[[f64; 2]; 2]; 3] {
    use crate::cpu::grid::{Table, encode_tile, encode_tile_portable};
    let layout = ModelLayout::new(&CacheConfig::hash_grid_preset());
    let Some((grid, _)) = layout.encoding.grid() else {
        return [[[f64::NAN; 2]; 2]; 3];
    };
    let levels = grid.fast_levels();
    let d = grid.output_dims();
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let n = 1 << 14;
    let tile = 128;
    let mut out = vec![0f32; tile * d];
    let mut figures = [[[0f64; 2]; 2]; 3];
    for (si, stride) in [2usize, 2, 8].into_iter().enumerate() {
        let mut table = crate::cpu::huge::huge_vec(grid.total_entries * stride, 0f32);
        table
            .iter_mut()
            .for_each(|v| *v = rng.random_range(-1.0..1.0));
        let halves: Vec<f16> = if si == 1 {
            let mut h = crate::cpu::huge::huge_vec(table.len(), f16::ZERO);
            h.iter_mut()
                .zip(&table)
                .for_each(|(h, v)| *h = f16::from_f32(*v));
            table = Vec::new();
            h
        } else {
            Vec::new()
        };
        let view = if si == 1 {
            Table::F16(&halves)
        } else {
            Table::F32(&table, stride)
        };
        for (pi, one_position) in [false, true].into_iter().enumerate() {
            let pos: Vec<f32> = (0..3 * n)
                .map(|i| {
                    if one_position {
                        [0.37, 0.52, 0.71][i % 3]
                    } else {
                        rng.random()
                    }
                })
                .collect();
            for (ki, portable) in [false, true].into_iter().enumerate() {
                let r = rate(min_time / 8, n, || {
                    for chunk in pos.chunks(3 * tile) {
                        let p = |i: usize| [chunk[3 * i], chunk[3 * i + 1], chunk[3 * i + 2]];
                        let m = chunk.len() / 3;
                        if portable {
                            encode_tile_portable(&levels, 2, view, m, p, &mut out, d, 0);
                        } else {
                            encode_tile(grid, &levels, view, m, p, &mut out, d, 0);
                        }
                    }
                    std::hint::black_box(&out);
                });
                figures[si][pi][ki] = 1e9 / r.per_s;
            }
        }
    }
    figures
}

/// Runs the benchmark, printing a table as it goes; returns the figures.
pub fn run(options: &BenchOptions) -> Vec<BenchFigure> {
    let presets = if options.configs.is_empty() {
        vec![
            ("hashgrid".to_string(), CacheConfig::hash_grid_preset()),
            (
                "trianglewave".to_string(),
                CacheConfig::triangle_wave_preset(),
            ),
        ]
    } else {
        options.configs.clone()
    };
    let mut figures = Vec::new();
    println!(
        "nrc-cache benchmark (threads: {}, AVX2+FMA kernels: {}, MLP kernel: {:?})",
        rayon::current_num_threads(),
        crate::cpu::gemm::has_avx2_fma(),
        crate::cpu::gemm::Kernel::best()
    );
    let (copy, random) = memory_limits();
    println!(
        "memory: streaming copy {:.1} GB/s (read + write), random 64-byte reads {:.0} M/s",
        copy / 1e9,
        random / 1e6
    );
    let k = hash_grid_kernel(options.min_time);
    for (si, what) in [
        "f32 table (inference)",
        "f16 table (inference)",
        "training records",
    ]
    .into_iter()
    .enumerate()
    {
        println!(
            "hash-grid encode, one thread, {what}: {:.0} ns/query with random positions, {:.0} at one position (kernel); portable loop {:.0} / {:.0}",
            k[si][0][0], k[si][1][0], k[si][0][1], k[si][1][1]
        );
    }
    for &device in &options.devices {
        if device == CacheDevice::Wgpu {
            match crate::gpu::wgpu_device() {
                Ok(_) => {
                    for line in crate::gpu::describe_adapters() {
                        println!("wgpu adapter: {line}");
                    }
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
            println!(
                "\n== {name} on {device}: {} parameters, MLP {fwd} MACs/sample forward, {} training",
                layout.param_count(),
                fwd + train_macs
            );
            for &batch_size in &options.batches {
                let mut cache = match RadianceCache::with_path(
                    config.clone(),
                    SceneBox::default(),
                    device,
                    device.default_path(),
                ) {
                    Ok(c) => c,
                    Err(e) => {
                        println!("  skipped: {e}");
                        continue;
                    }
                };
                let batch = synthetic_batch(batch_size, 1);
                let steps = if device == CacheDevice::Cpu { 4 } else { 2 };
                let mut trained = TrainProfile::default();
                let t0 = Instant::now();
                let train = rate(options.min_time, batch_size * steps as usize, || {
                    trained += cache.train(&batch, steps).expect("training").profile;
                });
                let wall = t0.elapsed().as_secs_f64();
                let t_mat = Instant::now();
                let _ = cache.inference_weights();
                let materialise = t_mat.elapsed();
                let mut inferred = InferProfile::default();
                let mut infer_calls = 0usize;
                let infer = rate(options.min_time, batch_size, || {
                    let (answers, profile) = cache.infer_profiled(&batch.queries);
                    std::hint::black_box(answers);
                    inferred += profile;
                    infer_calls += 1;
                });
                println!(
                    "  batch {batch_size:>6} [{}]: train {} samples/s, infer {} queries/s; EMA materialisation {:.1} ms",
                    device.default_path(),
                    show(train),
                    show(infer),
                    materialise.as_secs_f64() * 1e3
                );
                if device == CacheDevice::Wgpu {
                    // Kernel launches of the fused step, counted (the bound: 8).
                    let count = |steps: u32, cache: &mut RadianceCache| {
                        let start = nrc_gpu::dispatches();
                        cache.train(&batch, steps).expect("training");
                        nrc_gpu::dispatches() - start
                    };
                    let (one, five) = (count(1, &mut cache), count(5, &mut cache));
                    println!(
                        "    dispatches: {} a training step ({one} for a call of one step, {five} for five), 1 an inference call",
                        (five - one) / 4
                    );
                }
                if device == CacheDevice::Cpu {
                    // Calls and sums both include the rate's warm-up call.
                    let ns = |d: Duration| {
                        d.as_nanos() as f64 / (infer_calls * batch_size).max(1) as f64
                    };
                    println!(
                        "    inference per query: encode {:.0} ns (hash grid {:.0} ns) + MLP {:.0} ns thread-time; kernel {:.0} ns wall of {:.0} ns per call (rest: packing and copies)",
                        ns(inferred.encode),
                        ns(inferred.hash_grid),
                        ns(inferred.mlp),
                        ns(inferred.kernel),
                        ns(inferred.call)
                    );
                    let samples = train.per_s * wall;
                    let per_sample = |t: Duration| t.as_secs_f64() / samples * 1e9;
                    println!(
                        "    thread-time per sample: encode {:.0} ns, MLP+loss {:.0} ns ({:.1} GFLOP/s per thread), grid scatter {:.0} ns + sparse Adam/EMA {:.0} ns (phase wall {:.0} ns), MLP Adam {:.1} ns, packing {:.1} ns",
                        per_sample(trained.encode),
                        per_sample(trained.mlp),
                        2.0 * (fwd + train_macs) as f64 / per_sample(trained.mlp),
                        per_sample(trained.grid_scatter),
                        per_sample(trained.grid_adam),
                        per_sample(trained.grid_wall),
                        per_sample(trained.mlp_adam),
                        per_sample(trained.packing),
                    );
                }
                figures.push(BenchFigure {
                    preset: name.to_string(),
                    device,
                    path: device.default_path(),
                    batch: batch_size,
                    train_per_s: Some(train.per_s),
                    infer_per_s: Some(infer.per_s),
                });
            }
            if options.compare_paths {
                figures.extend(compare(name, config, device, options));
            }
        }
    }
    figures
}

/// The same step and inference along the other paths (batch 2^14), and the MLP alone.
fn compare(
    name: &str,
    config: &CacheConfig,
    device: CacheDevice,
    options: &BenchOptions,
) -> Vec<BenchFigure> {
    let mut out = Vec::new();
    let short = options.min_time / 2;
    let paths = [
        ComputePath::Fused,
        ComputePath::CustomOps,
        ComputePath::Unfused,
    ];
    // On the CPU at 2^14 only; on wgpu also at the larger batches asked for (without the
    // unfused path there, which takes seconds a step on a software adapter).
    let sizes: Vec<usize> = if device == CacheDevice::Cpu {
        vec![1 << 14]
    } else {
        let mut v = options.batches.clone();
        v.sort_unstable();
        v.dedup();
        v
    };
    // On wgpu the fused path also with the half-precision MLP (`"precision": "f16"`), beside
    // the configuration's own.
    let mut half = config.clone();
    half.network.precision = crate::config::MlpPrecision::F16;
    let mut variants: Vec<(String, &CacheConfig, ComputePath)> = Vec::new();
    for path in paths {
        variants.push((path.to_string(), config, path));
        if path == ComputePath::Fused
            && device == CacheDevice::Wgpu
            && config.network.precision != crate::config::MlpPrecision::F16
        {
            variants.push(("fused f16".into(), &half, path));
        }
    }
    for &n in &sizes {
        let batch = synthetic_batch(n, 2);
        let mut base: Option<(Rate, Rate)> = None;
        for (label, config, path) in &variants {
            let (label, path) = (label.as_str(), *path);
            if device == CacheDevice::Wgpu && path == ComputePath::Unfused && n > 1 << 14 {
                continue;
            }
            let mut cache = match RadianceCache::with_path(
                (*config).clone(),
                SceneBox::default(),
                device,
                path,
            ) {
                Ok(c) => c,
                Err(e) => {
                    println!("  path {label:<10} batch {n}: skipped ({e})");
                    continue;
                }
            };
            if label == "fused f16" && cache.mlp_arithmetic() != "f16" {
                println!("  path {label:<10} batch {n}: skipped (the adapter has no shader-f16)");
                continue;
            }
            let train = rate(short, n, || {
                cache.train(&batch, 1).expect("training");
            });
            let infer = rate(short, n, || {
                std::hint::black_box(cache.infer(&batch.queries));
            });
            let (bt, bi) = *base.get_or_insert((train, infer));
            let ratio = |a: Rate, b: Rate| match (a.per_cpu_s, b.per_cpu_s) {
                (Some(x), Some(y)) => x / y,
                _ => a.per_s / b.per_s,
            };
            println!(
                "  path {label:<10} batch {n}: train {} samples/s, infer {} queries/s  (first path / this: {:.1}× train, {:.1}× infer)",
                show(train),
                show(infer),
                ratio(bt, train),
                ratio(bi, infer)
            );
            out.push(BenchFigure {
                preset: if label == "fused f16" {
                    format!("{name}, f16 MLP")
                } else {
                    name.to_string()
                },
                device,
                path,
                batch: n,
                train_per_s: Some(train.per_s),
                infer_per_s: Some(infer.per_s),
            });
        }
    }
    if let Ok(d) = device.burn_device() {
        mlp_alone(config, &d, 1 << 14, short);
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
    let flex = matches!(
        device.clone().inner().as_dispatch(),
        burn::backend::DispatchDevice::Flex(_)
    );
    let mut results = Vec::new();
    for fused in [true, false] {
        if fused && !flex {
            continue;
        }
        let w = Tensor::<1>::from_data(TensorData::new(mlp.clone(), [mlp.len()]), &ad);
        let xt = Tensor::<2>::from_data(TensorData::new(x.clone(), [n, k]), &ad);
        let per_s = rate(min_time, n, || {
            let w = w.clone().require_grad();
            let o = if fused {
                crate::ops::mlp(w.clone(), xt.clone(), &layers)
            } else {
                crate::tensor_path::mlp_tensor(w.clone(), xt.clone(), &layers)
            };
            let grads = o.sum().backward();
            std::hint::black_box(w.grad(&grads).expect("gradient").into_data());
        });
        results.push(per_s.per_cpu_s.unwrap_or(per_s.per_s));
        println!(
            "  MLP alone, forward + backward, {}: {} samples/s",
            if fused {
                "fused op"
            } else {
                "burn matmul + relu"
            },
            show(per_s)
        );
    }
    if results.len() == 2 {
        println!("  MLP fused / unfused: {:.1}×", results[0] / results[1]);
    }
}
