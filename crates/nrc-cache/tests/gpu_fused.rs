//! The fused step's CubeCL kernels (the `nrc-gpu` crate, on wgpu: lavapipe in CI) against the
//! fused CPU path, from the same initialisation: the gradients of the tile pass and the scatter
//! (both atomic paths, batches of 1, 63, 65 and 4097 rows, both presets, 1 and 5 hidden
//! layers, a batch whose every sample hits the same table entries, every scratch buffer
//! poisoned with NaN), 50 training steps loss by loss, inference, the sparse update (untouched
//! entries keep their bits; the lazy EMA equals a dense one, inference reads it bias-corrected),
//! queued steps (losses read later) against waited ones, and the dispatches per step.
//! Skipped with a message where no adapter exists (CI refuses the skip).
//!
//! Tolerances: the GPU sums in f32 in another order than the CPU (whose loss is f64), so
//! gradients agree to a relative L2 error of 1e-4 (measured: below 1e-6 on lavapipe) and
//! losses over 50 Adam steps to 2 % (Adam divides by √v, which amplifies rounding where a
//! gradient is near zero).

use nrc_cache::config::{MlpPrecision, NestedEncoding};
use nrc_cache::encoding::hash_grid::TablePrecision;
use nrc_cache::gpu::fused::force_atomics;
use nrc_cache::{
    CacheConfig, CacheDevice, CacheQuery, ComputePath, RadianceCache, SceneBox, TrainingBatch,
};
use nrc_gpu::Atomics;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use std::sync::Mutex;

/// The tests share process-wide switches (forced atomics, poison): one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

fn wgpu_or_skip(test: &str) -> bool {
    match nrc_cache::gpu::wgpu_device() {
        Ok(_) => true,
        Err(e) => {
            nrc_scene::testing::skipped(test, &e.to_string());
            false
        }
    }
}

/// A preset with f32 tables and products (the precisions both paths share), `hidden` hidden
/// layers and a 2^14-entry table.
fn f32_config(mut c: CacheConfig, hidden: u32) -> CacheConfig {
    for n in &mut c.encoding.nested {
        if let NestedEncoding::HashGrid {
            log2_hashmap_size,
            inference_precision,
            training_precision,
            ..
        } = n
        {
            *log2_hashmap_size = 14;
            *inference_precision = TablePrecision::F32;
            *training_precision = TablePrecision::F32;
        }
    }
    c.network.precision = MlpPrecision::F32;
    c.network.n_hidden_layers = hidden;
    c
}

fn presets(hidden: u32) -> [(&'static str, CacheConfig); 2] {
    [
        (
            "hashgrid",
            f32_config(CacheConfig::hash_grid_preset(), hidden),
        ),
        (
            "trianglewave",
            f32_config(CacheConfig::triangle_wave_preset(), hidden),
        ),
    ]
}

fn unit(r: &mut Pcg64Mcg) -> [f32; 3] {
    loop {
        let v: [f32; 3] = [
            r.random_range(-1.0..1.0),
            r.random_range(-1.0..1.0),
            r.random_range(-1.0..1.0),
        ];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 0.1 && l <= 1.0 {
            return v.map(|x| x / l);
        }
    }
}

/// `n` random records (a fresh seed per call); with `one_point`, every sample at the same
/// position (so each level's eight entries receive every sample's gradient).
fn batch(n: usize, seed: u64, one_point: bool) -> TrainingBatch {
    let mut r = Pcg64Mcg::seed_from_u64(seed);
    let fixed: [f32; 3] = [r.random(), r.random(), r.random()];
    let queries: Vec<CacheQuery> = (0..n)
        .map(|_| CacheQuery {
            position: if one_point {
                fixed
            } else {
                [r.random(), r.random(), r.random()]
            },
            direction: unit(&mut r),
            normal: unit(&mut r),
            roughness: r.random_range(0.05..1.0),
            diffuse: [r.random(), r.random(), r.random()],
            specular: [r.random_range(0.0..0.2); 3],
        })
        .collect();
    let targets = queries
        .iter()
        .map(|_| {
            let base: f32 = r.random_range(-3.0f32..1.5).exp();
            [
                base * r.random_range(0.5..1.5),
                base,
                base * r.random_range(0.5..1.5),
            ]
        })
        .collect();
    let weights = Some((0..n).map(|_| r.random_range(0.25..2.0)).collect());
    TrainingBatch {
        queries,
        targets,
        weights,
    }
}

fn cache(config: &CacheConfig, device: CacheDevice) -> RadianceCache {
    RadianceCache::with_path(
        config.clone(),
        SceneBox::default(),
        device,
        ComputePath::Fused,
    )
    .unwrap()
}

/// ‖a − b‖ / ‖b‖ (0 when both are zero).
fn relative_l2(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    let (mut d, mut n) = (0f64, 0f64);
    for (x, y) in a.iter().zip(b) {
        d += (f64::from(*x) - f64::from(*y)).powi(2);
        n += f64::from(*y).powi(2);
    }
    if n == 0.0 { d.sqrt() } else { (d / n).sqrt() }
}

fn atomics_to_test() -> Vec<Atomics> {
    let device = nrc_cache::gpu::wgpu_device().expect("checked");
    let client = nrc_cache::gpu::fused::client(&device).expect("a CubeCL device");
    match Atomics::best(&client) {
        Atomics::Native => vec![Atomics::CompareSwap, Atomics::Native],
        Atomics::CompareSwap => {
            println!("this adapter has no native f32 atomics: the compare-and-swap path only");
            vec![Atomics::CompareSwap]
        }
    }
}

#[test]
fn fused_gpu_gradients_equal_the_cpu_kernels() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !wgpu_or_skip("fused_gpu_gradients_equal_the_cpu_kernels") {
        return;
    }
    nrc_gpu::set_poison(true);
    let mut seed = 1000u64;
    let mut worst = 0f64;
    for atomics in atomics_to_test() {
        force_atomics(Some(atomics));
        for hidden in [1, 5] {
            for (name, config) in presets(hidden) {
                let mut gpu = cache(&config, CacheDevice::Wgpu);
                let mut cpu = cache(&config, CacheDevice::Cpu);
                for (n, one_point, cap) in [
                    (1, false, None),
                    (63, false, None),
                    (65, false, None),
                    (4097, false, None),
                    // Three cubes: each sums many tiles into its partials.
                    (4097, false, Some(3)),
                    (300, true, None),
                ] {
                    seed += 1;
                    nrc_gpu::set_cube_cap(cap);
                    let b = batch(n, seed, one_point);
                    let what = format!(
                        "{name}, {hidden} hidden, {n} rows{}{}, {atomics:?}",
                        if one_point { " at one point" } else { "" },
                        if cap.is_some() { " on 3 cubes" } else { "" }
                    );
                    let (lg, gg, mg) = gpu.gradients(&b).unwrap();
                    let (lc, gc, mc) = cpu.gradients(&b).unwrap();
                    assert!(
                        (lg - lc).abs() <= 1e-5 * lc.abs(),
                        "{what}: loss {lg} vs {lc}"
                    );
                    let em = relative_l2(&mg, &mc);
                    assert!(em <= 1e-4, "{what}: MLP gradient off by {em:e}");
                    let eg = relative_l2(&gg, &gc);
                    assert!(eg <= 1e-4, "{what}: table gradient off by {eg:e}");
                    assert!(
                        gg.iter().chain(&mg).all(|v| v.is_finite()),
                        "{what}: a gradient is not finite (an unwritten value?)"
                    );
                    if !gc.is_empty() {
                        assert!(
                            gc.iter().any(|v| *v != 0.0),
                            "{what}: the CPU's table gradient is zero: the test checks nothing"
                        );
                    }
                    worst = worst.max(em).max(eg);
                }
            }
        }
    }
    force_atomics(None);
    nrc_gpu::set_cube_cap(None);
    nrc_gpu::set_poison(false);
    println!("largest relative L2 gradient error: {worst:e}");
}

#[test]
fn fifty_fused_gpu_steps_follow_the_cpu_and_infer_alike() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !wgpu_or_skip("fifty_fused_gpu_steps_follow_the_cpu_and_infer_alike") {
        return;
    }
    nrc_gpu::set_poison(true);
    // The preset's own table precisions too: f16 reads in the forward and inference, where the
    // adapter has f16 arithmetic (lavapipe has).
    let mut half = presets(3)[0].1.clone();
    for n in &mut half.encoding.nested {
        if let NestedEncoding::HashGrid {
            inference_precision,
            training_precision,
            ..
        } = n
        {
            *inference_precision = TablePrecision::F16;
            *training_precision = TablePrecision::F16;
        }
    }
    let mut configs = presets(3).to_vec();
    configs.push(("hashgrid with f16 tables", half));
    for (name, config) in configs {
        let mut gpu = cache(&config, CacheDevice::Wgpu);
        let description = gpu.describe();
        // An adapter without `shader-f16` (wgpu's GL backend where no Vulkan driver is
        // installed) reads the tables in f32: the CPU then reads them in f32 too, or the two
        // would train different models (per-step losses measured 1.6 % apart at the median,
        // 7.6 % at worst, with f16 on the CPU alone).
        let cpu_config = if description.contains("table read in f32 by the training forward") {
            let mut c = config.clone();
            for n in &mut c.encoding.nested {
                if let NestedEncoding::HashGrid {
                    inference_precision,
                    training_precision,
                    ..
                } = n
                {
                    *inference_precision = TablePrecision::F32;
                    *training_precision = TablePrecision::F32;
                }
            }
            c
        } else {
            config.clone()
        };
        let mut cpu = cache(&cpu_config, CacheDevice::Cpu);
        assert!(
            description.contains("fused CubeCL kernels"),
            "{name}: {description}"
        );
        if name.contains("f16") {
            println!("{name}: {}", description.lines().last().unwrap_or(""));
        }
        let probe = batch(500, 77, false).queries;
        let (a, b) = (gpu.infer(&probe), cpu.infer(&probe));
        for (x, y) in a.iter().zip(&b) {
            for c in 0..3 {
                assert!(
                    (x[c] - y[c]).abs() <= 1e-4 * (1e-3 + y[c].abs()),
                    "{name}: initial answers {x:?} vs {y:?}"
                );
            }
        }
        let mut losses = Vec::new();
        for step in 0..50 {
            let b = batch(1024, 5000 + step, false);
            // Two calls of 2 and 3 steps now and then: runs of steps, and the EMA gap's
            // conversions between them.
            let (lg, lc) = if step % 10 == 9 {
                let (g, c) = (gpu.train(&b, 2).unwrap(), cpu.train(&b, 2).unwrap());
                (g.first_loss, c.first_loss)
            } else {
                let (g, c) = (gpu.train(&b, 1).unwrap(), cpu.train(&b, 1).unwrap());
                (g.loss, c.loss)
            };
            assert!(
                (lg - lc).abs() <= 0.02 * lc.abs(),
                "{name}: step {step}: loss {lg} on the GPU, {lc} on the CPU"
            );
            losses.push(lg);
        }
        assert!(
            losses[45..].iter().sum::<f32>() < 0.8 * losses[..5].iter().sum::<f32>(),
            "{name}: the GPU's training does not lower the loss: {losses:?}"
        );
        // Inference from the GPU's weights equals the CPU's from the same weights.
        let (grid, mlp) = gpu.inference_weights_host();
        let mut same = cache(&config, CacheDevice::Cpu);
        same.set_weights(grid, mlp).unwrap();
        let (a, b) = (gpu.infer(&probe), same.infer(&probe));
        let mut worst = 0f32;
        for (x, y) in a.iter().zip(&b) {
            for c in 0..3 {
                let e = (x[c] - y[c]).abs() / (1e-3 + y[c].abs());
                worst = worst.max(e);
            }
        }
        assert!(
            worst <= 1e-4,
            "{name}: inference differs by {worst:e} (relative)"
        );
        // And the two caches' answers after 50 steps each stay close.
        let c = cpu.infer(&probe);
        let rel: f32 = a
            .iter()
            .zip(&c)
            .map(|(x, y)| {
                (0..3)
                    .map(|k| (x[k] - y[k]).abs() / (1e-2 + y[k].abs()))
                    .sum::<f32>()
            })
            .sum::<f32>()
            / (3 * a.len()) as f32;
        assert!(
            rel <= 0.05,
            "{name}: the caches trained on the GPU and the CPU answer {rel} apart"
        );
        println!(
            "{name}: losses {:?} … {:?}; GPU vs CPU answers {rel:.2e} apart",
            &losses[..3],
            &losses[47..]
        );
    }
    nrc_gpu::set_poison(false);
}

#[test]
fn fused_gpu_sparse_update_keeps_untouched_entries_and_a_dense_ema() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !wgpu_or_skip("fused_gpu_sparse_update_keeps_untouched_entries_and_a_dense_ema") {
        return;
    }
    let config = presets(2)[0].1.clone();
    let mut gpu = cache(&config, CacheDevice::Wgpu);
    let alpha = config.optimizer.resolve().1.expect("the preset has an EMA");
    let before = gpu.host_state();
    // Every sample in a small corner of the box: most entries of the fine levels untouched.
    let mut b = batch(200, 31, false);
    for q in &mut b.queries {
        q.position = q.position.map(|p| 0.1 * p);
    }
    let (grid_dims, touched) = {
        let layout = gpu.layout();
        let (hg, _) = layout.encoding.grid().expect("a hash grid");
        let mut touched = vec![false; hg.total_entries];
        for q in &b.queries {
            for level in &hg.levels {
                for e in hg.corners(level, q.position).index {
                    touched[e as usize] = true;
                }
            }
        }
        (hg.features(), touched)
    };
    let f = grid_dims;
    let mut dense_ema = before.grid_ema.clone();
    let steps = 30;
    for _ in 0..steps {
        gpu.train(&b, 1).unwrap();
        let (w, _) = gpu.weights();
        for (e, w) in dense_ema.iter_mut().zip(&w) {
            *e = alpha * *e + (1.0 - alpha) * w;
        }
    }
    let after = gpu.host_state();
    let mut untouched = 0;
    for (e, t) in touched.iter().enumerate() {
        let r = e * f..(e + 1) * f;
        if *t {
            continue;
        }
        untouched += 1;
        for (name, x, y) in [
            ("weight", &before.grid, &after.grid),
            ("first moment", &before.grid_m, &after.grid_m),
            ("second moment", &before.grid_v, &after.grid_v),
        ] {
            for (a, b) in x[r.clone()].iter().zip(&y[r.clone()]) {
                assert_eq!(
                    a.to_bits(),
                    b.to_bits(),
                    "untouched entry {e}: its {name} moved"
                );
            }
        }
    }
    assert!(
        untouched > touched.len() / 2,
        "only {untouched} of {} entries untouched",
        touched.len()
    );
    assert!(
        touched
            .iter()
            .enumerate()
            .any(|(e, t)| *t && before.grid[e * f] != after.grid[e * f]),
        "no touched entry moved: the test checks nothing"
    );
    let err = relative_l2(&after.grid_ema, &dense_ema);
    assert!(
        err <= 1e-5,
        "the lazy EMA differs from a dense one by {err:e}"
    );
    // Inference reads the bias-corrected average, e_t / (1 − α^t) (the weights, t = 30 steps).
    let (table, _) = gpu.inference_weights_host();
    let inv = 1.0 / (1.0 - alpha.powi(steps));
    let corrected: Vec<f32> = dense_ema.iter().map(|e| e * inv).collect();
    let err = relative_l2(&table, &corrected);
    assert!(
        err <= 1e-5,
        "the inference table differs from the corrected EMA by {err:e}"
    );
}

#[test]
fn listed_and_dense_table_updates_agree_over_runs_of_steps() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !wgpu_or_skip("listed_and_dense_table_updates_agree_over_runs_of_steps") {
        return;
    }
    let config = presets(2)[0].1.clone();
    let mut states = Vec::new();
    for list in [true, false] {
        nrc_gpu::set_table_list(Some(list));
        let mut gpu = cache(&config, CacheDevice::Wgpu);
        for call in 0..5 {
            // Runs of 3 steps: the list's counters alternate within a run.
            gpu.train(&batch(700, 40 + call, false), 3).unwrap();
        }
        states.push(gpu.host_state());
    }
    nrc_gpu::set_table_list(None);
    let (a, b) = (&states[0], &states[1]);
    for (name, x, y) in [
        ("weights", &a.grid, &b.grid),
        ("first moments", &a.grid_m, &b.grid_m),
        ("second moments", &a.grid_v, &b.grid_v),
        ("EMA", &a.grid_ema, &b.grid_ema),
    ] {
        let err = relative_l2(x, y);
        assert!(
            err <= 1e-5,
            "the table's {name} differ by {err:e}, listed against dense"
        );
    }
    assert!(
        a.grid_v.iter().any(|v| *v > 0.0),
        "no table entry was updated: the test checks nothing"
    );
}

#[test]
fn queued_gpu_steps_give_what_waited_ones_give() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !wgpu_or_skip("queued_gpu_steps_give_what_waited_ones_give") {
        return;
    }
    let config = presets(3)[0].1.clone();
    let (mut queued, mut waited) = (
        cache(&config, CacheDevice::Wgpu),
        cache(&config, CacheDevice::Wgpu),
    );
    let probe = batch(300, 91, false).queries;
    for step in 0..4 {
        let b = batch(2048, 700 + step, false);
        // Queued: inference is asked before the losses are read, and must see the new steps
        // (the scatter's float atomics add in any order: equal to rounding, not to the bit).
        let before = queued.infer(&probe);
        let pending = queued.train_submit(&b, 2).unwrap();
        let early = queued.infer(&probe);
        let q = pending.wait();
        let w = waited.train(&b, 2).unwrap();
        let late = waited.infer(&probe);
        assert_eq!((q.steps, q.used), (w.steps, w.used), "step {step}");
        for (x, y) in [(q.first_loss, w.first_loss), (q.loss, w.loss)] {
            assert!(
                (x - y).abs() <= 1e-4 * y.abs(),
                "step {step}: losses {x} queued, {y} waited"
            );
        }
        let (mut moved, mut apart) = (0f32, 0f32);
        for ((a, b), c) in early.iter().zip(&late).zip(&before) {
            for k in 0..3 {
                apart = apart.max((a[k] - b[k]).abs() / (1e-3 + b[k].abs()));
                moved = moved.max((a[k] - c[k]).abs() / (1e-3 + c[k].abs()));
            }
        }
        assert!(
            apart <= 1e-3,
            "step {step}: queued and waited answers {apart:e} apart"
        );
        assert!(
            moved > 100.0 * apart.max(1e-6),
            "step {step}: the answers after queued steps did not move ({moved:e}): inference ran before them?"
        );
    }
}

#[test]
fn fused_gpu_step_takes_four_dispatches() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !wgpu_or_skip("fused_gpu_step_takes_four_dispatches") {
        return;
    }
    let mut configs = presets(3).to_vec();
    configs.push((
        "hashgrid with an f16 MLP",
        half_mlp(presets(3)[0].1.clone()),
    ));
    for (name, config) in configs {
        let per_step = if name.starts_with("hashgrid") { 4 } else { 2 };
        // The f16 MLP's copy is made once a call.
        let per_call = u64::from(name.contains("f16"));
        let mut gpu = cache(&config, CacheDevice::Wgpu);
        let b = batch(256, 3, false);
        gpu.train(&b, 1).unwrap();
        let mut counts = Vec::new();
        for steps in [1u32, 6] {
            let start = nrc_gpu::dispatches();
            gpu.train(&b, steps).unwrap();
            counts.push(nrc_gpu::dispatches() - start);
        }
        assert_eq!(
            counts[1] - counts[0],
            5 * per_step,
            "{name}: dispatches per step (1 step: {}, 6 steps: {})",
            counts[0],
            counts[1]
        );
        assert!(
            counts[0] <= per_step + per_call,
            "{name}: a one-step call took {} dispatches",
            counts[0]
        );
        assert!(per_step <= 8, "the issue's bound");
    }
}

/// Where the kernels compile to SPIR-V (the cargo feature `vulkan` on a Vulkan adapter), the
/// custom-ops baseline, whose hash-grid kernels are WGSL source, is refused with an error that
/// says why; on WGSL it is made. The triangle-wave preset has no hash grid and is made on both.
#[test]
fn the_custom_ops_baseline_is_refused_only_where_kernels_compile_to_spirv() {
    let _guard = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !wgpu_or_skip("the_custom_ops_baseline_is_refused_only_where_kernels_compile_to_spirv") {
        return;
    }
    let device = CacheDevice::Wgpu.burn_device().unwrap();
    let spirv = nrc_cache::gpu::fused::compiles_spirv(&device);
    // lavapipe and the GPUs seen so far have what CubeCL's SPIR-V compiler needs.
    assert_eq!(spirv, cfg!(feature = "vulkan"), "SPIR-V {spirv}");
    let [(_, grid), (_, wave)] = presets(1);
    let make = |c: &CacheConfig| {
        RadianceCache::with_path(
            c.clone(),
            SceneBox::default(),
            CacheDevice::Wgpu,
            ComputePath::CustomOps,
        )
    };
    match make(&grid) {
        Ok(_) => assert!(!spirv, "the custom-ops hash grid was made on SPIR-V"),
        Err(e) => {
            assert!(spirv, "refused on WGSL: {e}");
            assert!(e.to_string().contains("SPIR-V"), "{e}");
        }
    }
    assert!(make(&wave).is_ok());
}

/// `config` with `"precision": "f16"` (the fused wgpu path's half-precision MLP).
fn half_mlp(mut config: CacheConfig) -> CacheConfig {
    config.network.precision = MlpPrecision::F16;
    config
}

/// Whether the adapter computes in f16 (else the f16 MLP falls back to f32, and says so).
fn gpu_has_f16() -> bool {
    let device = nrc_cache::gpu::wgpu_device().expect("checked");
    let client = nrc_cache::gpu::fused::client(&device).expect("a CubeCL device");
    nrc_gpu::supports_f16(&client)
}

/// The half-precision MLP (`"precision": "f16"`: weights from an f16 copy, activations in f16,
/// f32 sums, an f32 backward) against the f32 kernels. Its gradients equal the CPU's f32
/// gradients of the same f16-rounded weights to within what rounding the activations to half
/// precision (11 significant bits) moves them, and differ by far more than the f32 GPU path's
/// from the same weights (the control: the activations are really rounded). The bound, 10 %,
/// is wide because the relative loss's gradient at a residual `r` moves by `δy / norm`: rows
/// predicted close to their targets see theirs move by up to 1e-3 / r (measured on lavapipe:
/// 3.5 % at worst, 1e-4 to 2 % typically, against 1e-6 for the f32 kernels). 50 training steps
/// follow the CPU's f32 training: loss by loss for 10 steps (then the two runs' rounding sets
/// them apart as any two trainings on random targets: 20 % by step 27), and the last 10 steps'
/// mean within 20 %; inference equals the CPU's from the same weights within half precision;
/// the description line says what runs.
#[test]
fn an_f16_mlp_follows_the_f32_kernels_within_half_precision() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let test = "an_f16_mlp_follows_the_f32_kernels_within_half_precision";
    if !wgpu_or_skip(test) {
        return;
    }
    if !gpu_has_f16() {
        let gpu = cache(&half_mlp(presets(1)[0].1.clone()), CacheDevice::Wgpu);
        assert!(gpu.describe().contains("f32 MLP"), "{}", gpu.describe());
        nrc_scene::testing::skipped(test, "the adapter has no shader-f16");
        return;
    }
    nrc_gpu::set_poison(true);
    let mut seed = 9000u64;
    let (mut worst_half, mut worst_f32) = (0f64, 0f64);
    for hidden in [1, 5] {
        for (name, config) in presets(hidden) {
            let mut gpu = cache(&half_mlp(config.clone()), CacheDevice::Wgpu);
            let description = gpu.describe();
            assert!(description.contains("f16 MLP"), "{name}: {description}");
            assert!(
                description.contains("f16 products on the fused wgpu path"),
                "{name}: {description}"
            );
            assert_eq!(gpu.mlp_arithmetic(), "f16");
            // Half-size activations: at least as many rows a tile as the f32 MLP's.
            let rows = |d: &str| -> usize {
                d.split(" rows a tile")
                    .next()
                    .and_then(|s| s.rsplit(' ').next())
                    .and_then(|n| n.parse().ok())
                    .unwrap_or_else(|| panic!("no rows a tile in {d}"))
            };
            let (r16, r32) = (
                rows(&description),
                rows(&cache(&config, CacheDevice::Wgpu).describe()),
            );
            println!("{name}, {hidden} hidden: {r16} rows a tile with the f16 MLP, {r32} with f32");
            assert!(
                r16 >= r32,
                "{name}: {r16} rows a tile with f16, {r32} with f32"
            );
            // Inference weights before any step: the weights themselves, the MLP rounded to f16.
            let (grid, mlp16) = gpu.inference_weights_host();
            let mut gpu32 = cache(&config, CacheDevice::Wgpu);
            gpu32.set_weights(grid.clone(), mlp16.clone()).unwrap();
            let mut cpu = cache(&config, CacheDevice::Cpu);
            cpu.set_weights(grid, mlp16).unwrap();
            for n in [1, 65, 4097] {
                seed += 1;
                let b = batch(n, seed, false);
                let what = format!("{name}, {hidden} hidden, {n} rows");
                let (lh, gh, mh) = gpu.gradients(&b).unwrap();
                let (l32, g32, m32) = gpu32.gradients(&b).unwrap();
                let (lc, gc, mc) = cpu.gradients(&b).unwrap();
                assert!(
                    (lh - lc).abs() <= 2e-3 * lc.abs(),
                    "{what}: loss {lh} (f16 MLP) vs {lc}"
                );
                assert!(
                    (l32 - lc).abs() <= 1e-5 * lc.abs(),
                    "{what}: loss {l32} (f32) vs {lc}"
                );
                let e_half = relative_l2(&mh, &mc).max(relative_l2(&gh, &gc));
                let e_f32 = relative_l2(&m32, &mc).max(relative_l2(&g32, &gc));
                assert!(
                    gh.iter().chain(&mh).all(|v| v.is_finite()),
                    "{what}: a gradient is not finite"
                );
                assert!(
                    e_half <= 0.1,
                    "{what}: the f16 MLP's gradients are {e_half:e} off"
                );
                assert!(
                    e_half > 10.0 * e_f32.max(1e-7),
                    "{what}: the f16 MLP's gradients ({e_half:e} off) are as close as the f32 \
                     path's ({e_f32:e}): were the activations rounded?"
                );
                worst_half = worst_half.max(e_half);
                worst_f32 = worst_f32.max(e_f32);
            }
        }
    }
    println!("largest relative L2 gradient error: f16 MLP {worst_half:e}, f32 MLP {worst_f32:e}");
    // Training: 50 steps of the f16 MLP on the GPU against the f32 CPU path from the same
    // initialisation.
    let config = presets(3)[0].1.clone();
    let mut gpu = cache(&half_mlp(config.clone()), CacheDevice::Wgpu);
    let mut cpu = cache(&config, CacheDevice::Cpu);
    let mut worst_step = 0f32;
    let (mut losses, mut cpu_losses) = (Vec::new(), Vec::new());
    for step in 0..50 {
        let b = batch(1024, 7000 + step, false);
        let (lg, lc) = (
            gpu.train(&b, 1).unwrap().loss,
            cpu.train(&b, 1).unwrap().loss,
        );
        if step < 10 {
            worst_step = worst_step.max((lg - lc).abs() / lc.abs());
        }
        losses.push(lg);
        cpu_losses.push(lc);
    }
    let tail = |l: &[f32]| l[40..].iter().sum::<f32>() / 10.0;
    let (tail_half, tail_cpu) = (tail(&losses), tail(&cpu_losses));
    println!(
        "f16 MLP: largest relative loss difference to the f32 CPU over the first 10 steps \
         {worst_step:e}; mean loss of steps 40-49 {tail_half} against {tail_cpu}"
    );
    assert!(
        worst_step <= 0.02,
        "the f16 MLP's losses leave the f32 path's by {worst_step} in 10 steps"
    );
    assert!(
        (tail_half - tail_cpu).abs() <= 0.2 * tail_cpu,
        "the f16 MLP's last losses average {tail_half}, the f32 path's {tail_cpu}"
    );
    assert!(
        losses[45..].iter().sum::<f32>() < 0.8 * losses[..5].iter().sum::<f32>(),
        "the f16 MLP does not lower the loss: {losses:?}"
    );
    // Inference from the trained weights (the EMA, rounded to f16) against the CPU's f32
    // inference from the same rounded weights.
    let (grid, mlp16) = gpu.inference_weights_host();
    let mut same = cache(&config, CacheDevice::Cpu);
    same.set_weights(grid, mlp16).unwrap();
    let probe = batch(500, 78, false).queries;
    let (a, b) = (gpu.infer(&probe), same.infer(&probe));
    let mut worst = 0f32;
    for (x, y) in a.iter().zip(&b) {
        for c in 0..3 {
            worst = worst.max((x[c] - y[c]).abs() / (1e-3 + y[c].abs()));
        }
    }
    println!("f16 MLP: inference within {worst:e} (relative) of the f32 CPU's");
    assert!(worst <= 5e-3, "f16 MLP inference differs by {worst:e}");
    assert!(
        worst > 0.0,
        "f16 inference equals f32's to the bit: was it f16?"
    );
    nrc_gpu::set_poison(false);
}
