//! The optimizer's wrappers. The weight EMA: its bias-corrected average equals the closed form
//! `ê_t = Σ_{i≤t} (1 − α) α^(t−i) w_i / (1 − α^t)` of the weights after each step. The learning
//! rate's decay (`ExponentialDecay`, as tiny-cuda-nn's): its factor, its effect on training, and
//! its restart when the scene changes.

use burn::tensor::f16;
use nrc_cache::config::{AdamParams, LrDecay, NestedEncoding, OptimizerConfig};
use nrc_cache::cpu::optim::{
    StepConstants, decay_pow, dense_step, ema_gap_from_raw, ema_raw_from_gap, materialize_dense,
    materialize_grid, pack_records, rebase_ema_gap, sparse_step, unpack_records,
};
use nrc_cache::state::tensor_vec;
use nrc_cache::{
    Cache, CacheConfig, CacheDevice, CacheQuery, ComputePath, RadianceCache, SceneBox,
    TrainingBatch,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Closed form in f64 of the bias-corrected EMA of `history[0..t]` (weights after steps 1..t).
fn closed_form(alpha: f64, history: &[Vec<f32>]) -> Vec<f64> {
    let t = history.len() as i32;
    let norm = 1.0 - alpha.powi(t);
    (0..history[0].len())
        .map(|j| {
            history
                .iter()
                .enumerate()
                .map(|(i, w)| (1.0 - alpha) * alpha.powi(t - 1 - i as i32) * f64::from(w[j]))
                .sum::<f64>()
                / norm
        })
        .collect()
}

fn adam() -> AdamParams {
    AdamParams {
        learning_rate: 1e-2,
        beta1: 0.9,
        beta2: 0.99,
        epsilon: 1e-15,
        l2_reg: 0.0,
    }
}

#[test]
fn lazy_sparse_and_dense_ema_match_the_closed_form_on_a_toy_sequence() {
    let alpha = 0.9f32; // a short memory makes early steps matter
    let (entries, f) = (40, 2);
    let mut r = Pcg64Mcg::seed_from_u64(1);
    let w0: Vec<f32> = (0..entries * f)
        .map(|_| r.random_range(-1.0..1.0))
        .collect();
    let zeros = vec![0f32; w0.len()];
    // The raw EMA starts at zero; the records hold it as a gap to the weights, based at step 0.
    let mut records = pack_records(f, &w0, &zeros, &zeros, &zeros);
    ema_gap_from_raw(f, &mut records);
    let mut base = 0;
    let mut grad = zeros.clone();
    let mut dw = w0.clone();
    let (mut dm, mut dv, mut de) = (zeros.clone(), zeros.clone(), zeros.clone());
    let (mut history, mut dense_history) = (Vec::new(), Vec::new());
    for step in 1..=25u32 {
        // Rebase every seventh step (the cache does it every `ema_rebase_interval` steps).
        if step % 7 == 0 {
            rebase_ema_gap(alpha, step - 1 - base, f, &mut records);
            base = step - 1;
        }
        let c = StepConstants::new(adam(), Some(alpha), step, base);
        // Sparse: each entry is referenced with probability 1/3; some entries never.
        let mut touched = vec![0u64; entries.div_ceil(64)];
        for en in 0..entries {
            if en % 7 != 0 && r.random_range(0..3) == 0 {
                touched[en / 64] |= 1 << (en % 64);
                for k in 0..f {
                    grad[en * f + k] = r.random_range(-1.0..1.0);
                }
            }
        }
        sparse_step(&c, f, &mut touched, &mut records, &mut grad, None);
        assert!(
            grad.iter().all(|g| *g == 0.0),
            "the step consumes the gradient"
        );
        history.push(unpack_records(f, &records)[0].clone());
        // Dense on the side.
        let g: Vec<f32> = (0..dw.len()).map(|_| r.random_range(-1.0..1.0)).collect();
        dense_step(&c, &mut dw, &mut dm, &mut dv, &mut de, &g);
        dense_history.push(dw.clone());

        let expect = closed_form(f64::from(alpha), &history);
        let mut got = vec![0f32; w0.len()];
        materialize_grid(Some(alpha), step, Some(base), f, &records, &mut got);
        for (j, (a, b)) in got.iter().zip(&expect).enumerate() {
            assert!(
                (f64::from(*a) - b).abs() < 1e-5 * (1.0 + b.abs()),
                "step {step} entry {j}: {a} vs closed form {b}"
            );
        }
        let expect = closed_form(f64::from(alpha), &dense_history);
        let mut got = vec![0f32; dw.len()];
        materialize_dense(alpha, step, &dw, &de, &mut got);
        for (a, b) in got.iter().zip(&expect) {
            assert!(
                (f64::from(*a) - b).abs() < 1e-5 * (1.0 + b.abs()),
                "dense step {step}: {a} vs {b}"
            );
        }
    }
    // Untouched entries never moved, and their average is exactly their weight.
    let w = unpack_records(f, &records)[0].clone();
    for en in (0..entries).step_by(7) {
        assert_eq!(w[en * f], w0[en * f]);
    }
    // A rebase, and a round trip through the raw EMA (what a snapshot stores), move the
    // materialised average by rounding only.
    let mut before = vec![0f32; w.len()];
    materialize_grid(Some(alpha), 25, Some(base), f, &records, &mut before);
    let mut rebased = records.clone();
    rebase_ema_gap(alpha, 25 - base, f, &mut rebased);
    let mut round_trip = records.clone();
    ema_raw_from_gap(alpha, 25 - base, f, &mut round_trip);
    ema_gap_from_raw(f, &mut round_trip);
    for (what, r) in [("rebased", &rebased), ("raw and back", &round_trip)] {
        let mut after = vec![0f32; w.len()];
        materialize_grid(Some(alpha), 25, Some(25), f, r, &mut after);
        for (j, (a, b)) in after.iter().zip(&before).enumerate() {
            assert!(
                (a - b).abs() <= 4.0 * f32::EPSILON * b.abs().max(1.0),
                "{what} {j}: {a} vs {b}"
            );
        }
    }
}

fn batch(n: usize, seed: u64) -> TrainingBatch {
    let mut r = Pcg64Mcg::seed_from_u64(seed);
    let queries: Vec<CacheQuery> = (0..n)
        .map(|_| CacheQuery {
            position: [r.random(), r.random(), r.random()],
            direction: [0.0, 0.0, 1.0],
            normal: [0.0, 1.0, 0.0],
            roughness: 0.5,
            diffuse: [0.5; 3],
            specular: [0.0; 3],
        })
        .collect();
    let targets = queries
        .iter()
        .map(|q| [q.position[0], 0.5, q.position[2]])
        .collect();
    TrainingBatch {
        queries,
        targets,
        weights: None,
    }
}

/// The hash-grid preset with a 2^12 table, the average read in f32 (the average itself, not
/// its half-precision rounding, tested on its own below) and EMA decay `alpha`.
fn small_config(alpha: f32) -> CacheConfig {
    let mut config = CacheConfig::hash_grid_preset();
    if let Some(NestedEncoding::HashGrid {
        log2_hashmap_size,
        inference_precision,
        ..
    }) = config.encoding.nested.first_mut()
    {
        *log2_hashmap_size = 12;
        *inference_precision = nrc_cache::encoding::hash_grid::TablePrecision::F32;
    }
    if let nrc_cache::config::OptimizerConfig::EMA { decay, .. } = &mut config.optimizer {
        *decay = alpha;
    }
    config
}

fn cache_on(config: &CacheConfig, path: ComputePath) -> RadianceCache {
    RadianceCache::with_path(config.clone(), SceneBox::default(), CacheDevice::Cpu, path).unwrap()
}

/// The cache's inference weights are the closed-form average of its weight history, on the
/// fused path (the table's EMA as a gap, see `nrc_cache::cpu::optim`) and on the tensor path
/// (dense EMA): with decay 0.8 over 12 steps, and with decay 0.5 over 100 steps, where the fused
/// path rebases the gap every 40 steps; also after a snapshot-style round trip of the state
/// halfway (the raw EMA and back).
#[test]
fn cache_inference_weights_are_the_closed_form_average() {
    for (alpha, steps) in [(0.8f32, 12u64), (0.5, 100)] {
        let config = small_config(alpha);
        assert_eq!(nrc_cache::cpu::optim::ema_rebase_interval(0.5), 40);
        for path in [ComputePath::Fused, ComputePath::Unfused] {
            let mut cache = cache_on(&config, path);
            let (mut grid_hist, mut mlp_hist) = (Vec::new(), Vec::new());
            for step in 0..steps {
                // Small batches leave most fine-level entries unreferenced in most steps.
                cache.train(&batch(16, step), 1).unwrap();
                let (g, m) = cache.weights();
                grid_hist.push(g);
                mlp_hist.push(m);
                if step == steps / 2 {
                    let _ = cache.host_state();
                }
            }
            let (g, m) = cache.inference_weights();
            for (got, hist, what) in [
                (tensor_vec(g), &grid_hist, "table"),
                (tensor_vec(m), &mlp_hist, "mlp"),
            ] {
                let expect = closed_form(f64::from(alpha), hist);
                for (j, (a, b)) in got.iter().zip(&expect).enumerate() {
                    assert!(
                        (f64::from(*a) - b).abs() < 1e-5 * (1.0 + b.abs()),
                        "decay {alpha}, {path} {what} {j}: {a} vs {b}"
                    );
                }
            }
        }
    }
}

/// Follow mode: while it is on, inference reads the training weights; leaving it restarts the
/// average at them, so that afterwards the inference weights are the average of the weights
/// from that step on, started at the weights (`e = (1 − α^t0)·w_t0`, then the EMA's
/// recursion), on the fused path (the table's EMA as a gap, rebased every 40 steps at decay 0.5:
/// a rebase falls after the restart) and on the tensor path. A cache that never follows
/// keeps the closed-form average (the negative control: the restarted average is not it).
#[test]
fn following_reads_the_weights_and_leaving_restarts_the_average_at_them() {
    for (alpha, steps, follow_from, follow_to) in [(0.8f32, 16u64, 5u64, 9u64), (0.5, 44, 30, 38)] {
        let config = small_config(alpha);
        for path in [ComputePath::Fused, ComputePath::Unfused] {
            let mut cache = cache_on(&config, path);
            let (mut grid_hist, mut mlp_hist) = (Vec::new(), Vec::new());
            for step in 0..steps {
                if step == follow_from {
                    cache.set_follow(true);
                    assert!(cache.follows());
                }
                if step == follow_to {
                    cache.set_follow(false);
                }
                cache.train(&batch(16, step), 1).unwrap();
                let (g, m) = cache.weights();
                if cache.follows() {
                    let (gi, mi) = cache.inference_weights();
                    assert_eq!(
                        tensor_vec(gi),
                        g,
                        "{path}: following, the table is the weights"
                    );
                    assert_eq!(
                        tensor_vec(mi),
                        m,
                        "{path}: following, the MLP is the weights"
                    );
                }
                grid_hist.push(g);
                mlp_hist.push(m);
            }
            let (g, m) = cache.inference_weights();
            for (got, hist, what) in [
                (tensor_vec(g), &grid_hist, "table"),
                (tensor_vec(m), &mlp_hist, "mlp"),
            ] {
                // The average restarted after step `follow_to` (the weights of that step, hist
                // index follow_to − 1) and run on.
                let a = f64::from(alpha);
                let t0 = follow_to as usize;
                let mut e: Vec<f64> = hist[t0 - 1]
                    .iter()
                    .map(|w| (1.0 - a.powi(t0 as i32)) * f64::from(*w))
                    .collect();
                for w in &hist[t0..] {
                    for (e, w) in e.iter_mut().zip(w) {
                        *e = a * *e + (1.0 - a) * f64::from(*w);
                    }
                }
                let norm = 1.0 - a.powi(hist.len() as i32);
                let never = closed_form(a, hist);
                let (mut worst, mut apart) = (0.0f64, 0.0f64);
                for ((got, e), n) in got.iter().zip(&e).zip(&never) {
                    let expect = e / norm;
                    worst = worst.max((f64::from(*got) - expect).abs() / (1.0 + expect.abs()));
                    apart = apart.max((expect - n).abs() / (1.0 + n.abs()));
                }
                assert!(
                    worst < 1e-5,
                    "decay {alpha}, {path} {what}: off by {worst:e}"
                );
                assert!(
                    apart > (10.0 * worst).max(1e-5),
                    "decay {alpha}, {path} {what}: the restarted average ({worst:e} off) is not told \
                     from the never restarted one ({apart:e} apart)"
                );
            }
        }
    }
}

/// A snapshot saved while the cache follows its weights answers as the cache does: the loaded
/// cache's inference weights (its average) are the saved cache's weights.
#[test]
fn a_snapshot_saved_while_following_answers_as_the_cache_does() {
    let mut cache = cache_on(&small_config(0.99), ComputePath::Fused);
    for step in 0..6 {
        cache.train(&batch(64, step), 1).unwrap();
    }
    cache.set_follow(true);
    for step in 6..9 {
        cache.train(&batch(64, step), 1).unwrap();
    }
    let (grid, mlp) = cache.weights();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("following.nrc");
    cache.save(&path).unwrap();
    assert!(cache.follows(), "saving does not end follow mode");
    let loaded = RadianceCache::load(&path, CacheDevice::Cpu).unwrap();
    let (g, m) = loaded.inference_weights();
    for (got, want, what) in [(tensor_vec(g), grid, "table"), (tensor_vec(m), mlp, "mlp")] {
        let worst = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs() / (1.0 + b.abs()))
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-5,
            "{what}: the loaded average is {worst:e} off the weights"
        );
    }
    // The negative control: a cache that does not follow saves an average that is not its
    // weights (what the loaded cache would answer without the restart).
    let mut plain = cache_on(&small_config(0.99), ComputePath::Fused);
    for step in 0..9 {
        plain.train(&batch(64, step), 1).unwrap();
    }
    let (_, mlp) = plain.weights();
    plain.save(&path).unwrap();
    let (_, m) = RadianceCache::load(&path, CacheDevice::Cpu)
        .unwrap()
        .inference_weights();
    let apart = tensor_vec(m)
        .iter()
        .zip(&mlp)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(
        apart > 1e-4,
        "the average is the weights anyway ({apart:e})"
    );
}

/// The AVX2 sparse update (four entries of two features at once) gives the same bits as the
/// portable loop: weights, moments, EMA gaps, zeroed gradients, cleared bitmap and
/// the half-precision copy of the weights (each updated entry's weights rounded as
/// `half_weights` rounds them, clamped to ±65504; the other entries' halves untouched), with
/// non-finite gradients, an L2 term and weights beyond the half range in the mix, with and
/// without the EMA.
#[test]
fn avx2_sparse_step_matches_the_portable_loop() {
    use nrc_cache::cpu::optim::{RECORD, half_weights, sparse_step_portable};
    if !nrc_cache::cpu::gemm::has_avx2_fma() || !nrc_cache::cpu::grid::has_f16c() {
        nrc_scene::testing::skipped(
            "avx2_sparse_step_matches_the_portable_loop",
            "this CPU has no AVX2/FMA/F16C, so only the portable loop exists",
        );
        return;
    }
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let (entries, f) = (1001usize, 2usize);
    let adam = AdamParams {
        learning_rate: 1e-2,
        beta1: 0.9,
        beta2: 0.99,
        epsilon: 1e-15,
        l2_reg: 1e-3,
    };
    for ema in [Some(0.99f32), None] {
        let step = 57;
        let c = StepConstants::new(adam, ema, step, step - 40);
        let records: Vec<f32> = (0..entries * RECORD * f)
            .map(|i| match i % 8 {
                4 | 5 => rng.random_range(0.0..2.0),                 // v ≥ 0
                0 | 1 if i % 13 == 0 => rng.random_range(-1e5..1e5), // beyond ±65504 too
                _ => rng.random_range(-3.0..3.0),
            })
            .collect();
        // A stale half copy, so that an entry left alone is seen to keep its halves.
        let half: Vec<f16> = (0..entries * f)
            .map(|_| f16::from_f32(rng.random_range(-1.0..1.0)))
            .collect();
        let grad: Vec<f32> = (0..entries * f)
            .map(|i| match i % 97 {
                3 => f32::NAN,
                5 => f32::INFINITY,
                7 => 0.0,
                _ => rng.random_range(-5.0..5.0),
            })
            .collect();
        let mut touched = vec![0u64; entries.div_ceil(64)];
        for e in 0..entries {
            if rng.random::<f32>() < 0.3 {
                touched[e / 64] |= 1 << (e % 64);
            }
        }
        let run = |avx: bool, with_half: bool| {
            let (mut r, mut g, mut t, mut h) =
                (records.clone(), grad.clone(), touched.clone(), half.clone());
            let hs = with_half.then_some(&mut h[..]);
            if avx {
                sparse_step(&c, f, &mut t, &mut r, &mut g, hs);
            } else {
                sparse_step_portable::<2>(&c, &mut t, &mut r, &mut g, hs);
            }
            (r, g, t, h)
        };
        let (a, b) = (run(true, true), run(false, true));
        let without = run(true, false);
        assert_eq!(without.0, a.0, "the half copy changes the update");
        assert_eq!(without.3, half, "no half copy given, none written");
        let rounded = half_weights(f, &a.0);
        for e in 0..entries {
            let hit = touched[e / 64] >> (e % 64) & 1 == 1;
            let want = if hit { &rounded } else { &half };
            let span = e * f..(e + 1) * f;
            let got = a.3[span.clone()].iter().zip(&b.3[span.clone()]);
            for ((x, portable), w) in got.zip(&want[span]) {
                assert_eq!(
                    x.to_bits(),
                    w.to_bits(),
                    "ema {ema:?}: entry {e} (touched {hit}): half {x} vs {w}"
                );
                assert_eq!(
                    x.to_bits(),
                    portable.to_bits(),
                    "entry {e}: AVX2 vs portable"
                );
            }
        }
        assert!(rounded.iter().all(|h| h.is_finite()), "halves clamp");
        assert_ne!(a.0, records, "the step changed nothing");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (i, (x, y)) in a.0.iter().zip(&b.0).enumerate() {
            assert_eq!(
                x.to_bits(),
                y.to_bits(),
                "ema {ema:?}: record float {i}: {x} vs {y}"
            );
        }
        assert_eq!(bits(&a.1), bits(&b.1), "gradients");
        assert_eq!(a.2, b.2, "bitmap");
        assert!(a.2.iter().all(|w| *w == 0));
    }
}

/// The materialised average of a two-feature table (four entries per AVX2 register where the
/// CPU has it) gives the same bits as the formula `(w + α^(t−b)·q) / (1 − α^t)` entry by entry,
/// with the gap's base at the step itself, one step back and a rebase interval back, and as
/// `e / (1 − α^t)` from the raw EMA; with a length that is not a multiple of four.
#[test]
fn materialised_grid_matches_the_formula_bit_for_bit() {
    let mut r = Pcg64Mcg::seed_from_u64(21);
    let (f, entries, step, alpha) = (2usize, 1003usize, 5000u32, 0.99f32);
    let value = |r: &mut Pcg64Mcg| -> Vec<f32> {
        (0..entries * f)
            .map(|_| r.random_range(-2.0..2.0))
            .collect()
    };
    let (w, m, v, q) = (value(&mut r), value(&mut r), value(&mut r), value(&mut r));
    let records = pack_records(f, &w, &m, &v, &q);
    let interval = nrc_cache::cpu::optim::ema_rebase_interval(alpha);
    for base in [Some(step), Some(step - 1), Some(step - interval), None] {
        let mut got = vec![0f32; entries * f];
        materialize_grid(Some(alpha), step, base, f, &records, &mut got);
        let inv = 1.0 / (1.0 - decay_pow(alpha, step));
        for (i, g) in got.iter().enumerate() {
            // Without a base, the records hold the raw EMA.
            let want = match base {
                Some(b) => (w[i] + decay_pow(alpha, step - b) * q[i]) * inv,
                None => q[i] * inv,
            };
            assert_eq!(
                g.to_bits(),
                want.to_bits(),
                "base {base:?}, value {i}: {g} vs {want}"
            );
        }
    }
}

/// The half-precision inference table (AVX2/F16C where the CPU has it, eight values per
/// conversion) holds each f32 value of the materialised table rounded to the nearest half,
/// bit for bit: values from 1e-9 (below the smallest half subnormal) to 1e6 (beyond the largest
/// half, clamped to ±65504, never infinite), an EMA gap based 2000 steps back, a
/// length that is not a multiple of four; with and without the EMA.
#[test]
fn half_table_is_the_f32_table_rounded_to_nearest() {
    use burn::tensor::f16;
    use nrc_cache::cpu::optim::materialize_grid_into;
    let mut r = Pcg64Mcg::seed_from_u64(22);
    let (f, entries, step) = (2usize, 1003usize, 5000u32);
    let value = |r: &mut Pcg64Mcg| -> Vec<f32> {
        (0..entries * f)
            .map(|_| {
                let sign = if r.random::<bool>() { 1.0 } else { -1.0 };
                sign * 10f32.powf(r.random_range(-9.0..6.0))
            })
            .collect()
    };
    let (w, m, v, q) = (value(&mut r), value(&mut r), value(&mut r), value(&mut r));
    let records = pack_records(f, &w, &m, &v, &q);
    let base = step - 2000;
    for alpha in [Some(0.99f32), None] {
        let mut full = vec![0f32; entries * f];
        materialize_grid(alpha, step, Some(base), f, &records, &mut full);
        let mut halves = vec![std::mem::MaybeUninit::<f16>::uninit(); entries * f];
        materialize_grid_into(alpha, step, Some(base), f, &records, &mut halves);
        let (mut clamped, mut subnormal) = (0, 0);
        for (i, (h, x)) in halves.iter().zip(&full).enumerate() {
            // SAFETY: `materialize_grid_into` writes every element.
            let h = unsafe { h.assume_init() };
            let want = f16::from_f32(x.clamp(-65504.0, 65504.0));
            assert!(h.is_finite(), "value {i}: {x} became {h}");
            assert_eq!(
                h.to_bits(),
                want.to_bits(),
                "value {i}: {x} gave {h}, not {want}"
            );
            clamped += usize::from(x.abs() > 65504.0);
            subnormal += usize::from(h.to_bits() & 0x7c00 == 0 && h.to_bits() & 0x03ff != 0);
        }
        // The data exercise both ends of the half range.
        assert!(
            clamped > 10 && subnormal > 10,
            "{clamped} clamped, {subnormal} subnormal"
        );
    }
}

/// The fused step gives the same bits whatever the thread count and however rayon splits the
/// work: three steps of 8 192 samples on one thread and on three, then every weight and every
/// EMA weight compared bit for bit. (Phase A once summed the MLP gradients per work split, so
/// two runs of one seed trained slightly different networks.)
#[test]
fn fused_training_is_the_same_whatever_the_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut config = CacheConfig::hash_grid_preset();
            if let Some(NestedEncoding::HashGrid {
                log2_hashmap_size, ..
            }) = config.encoding.nested.first_mut()
            {
                *log2_hashmap_size = 14;
            }
            let mut cache = RadianceCache::with_path(
                config,
                SceneBox::default(),
                CacheDevice::Cpu,
                ComputePath::Fused,
            )
            .unwrap();
            let mut losses = Vec::new();
            for step in 0..3 {
                losses.push(cache.train(&batch(8192, 40 + step), 1).unwrap().loss);
            }
            let (g, m) = cache.weights();
            let (eg, em) = cache.inference_weights();
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            (
                losses,
                bits(&g),
                bits(&m),
                bits(&tensor_vec(eg)),
                bits(&tensor_vec(em)),
            )
        })
    };
    let one = run(1);
    for threads in [2, 3] {
        assert!(run(threads) == one, "{threads} threads differ from one");
    }
}

/// tiny-cuda-nn's rule: the factor is multiplied by the base at steps `start`, `start +
/// interval`, … up to `end` (its `step()` counted from 0 before each step).
#[test]
fn the_factor_is_the_staircase_of_tiny_cuda_nn() {
    let d = LrDecay {
        start: 400,
        interval: 800,
        base: 0.5,
        end: 2000,
    };
    // The same rule, stepped as tiny-cuda-nn steps it.
    let mut factor = 1.0f32;
    for k in 0..5000u32 {
        if k >= d.start && (k - d.start) % d.interval == 0 && k <= d.end {
            factor *= d.base;
        }
        assert_eq!(d.factor(k), factor, "step {k}");
    }
    assert_eq!(d.factor(399), 1.0);
    assert_eq!(d.factor(400), 0.5);
    assert_eq!(d.factor(1199), 0.5);
    assert_eq!(d.factor(1200), 0.25);
    assert_eq!(d.floor(), 0.125);
    assert_eq!(d.factor(u32::MAX), 0.125);
    // A decay that never ends, one step apart: no overflow at the last step.
    let endless = LrDecay {
        start: 0,
        interval: 1,
        base: 0.5,
        end: u32::MAX,
    };
    assert_eq!(endless.floor(), 0.0);
    assert_eq!(endless.factor(3), 0.0625);
}

/// The hash-grid preset with a 2^12 table and the decay `d` (start, interval, base, end).
fn decay_config(d: (u32, u32, f32, u32)) -> CacheConfig {
    let mut json: serde_json::Value =
        serde_json::from_str(&CacheConfig::hash_grid_preset().to_json()).unwrap();
    let decay = json.pointer_mut("/optimizer/nested").unwrap();
    assert_eq!(decay["otype"], "ExponentialDecay", "the preset decays");
    decay["decay_start"] = d.0.into();
    decay["decay_interval"] = d.1.into();
    decay["decay_base"] = d.2.into();
    decay["decay_end"] = d.3.into();
    let mut c = CacheConfig::from_json_str(&json.to_string()).unwrap();
    if let Some(NestedEncoding::HashGrid {
        log2_hashmap_size, ..
    }) = c.encoding.nested.first_mut()
    {
        *log2_hashmap_size = 12;
    }
    c
}

/// `config` without its decay: EMA over Adam.
fn undecayed(config: &CacheConfig) -> CacheConfig {
    let mut c = config.clone();
    let OptimizerConfig::EMA { nested, .. } = &mut c.optimizer else {
        panic!("EMA at the top");
    };
    let OptimizerConfig::ExponentialDecay { nested: adam, .. } = nested.as_ref().clone() else {
        panic!("the decay under the EMA");
    };
    *nested = adam;
    assert!(c.optimizer.lr_decay().is_none());
    c
}

/// Training with the decay takes exactly the steps of training without it whose learning rate
/// is set by hand to the decayed one before each step, on the fused path and the tensor path;
/// restarted (as the online loop restarts it at a confirmed change), the rate is the full one again and
/// decays anew. The negative control: the undecayed cache left at the full rate ends elsewhere.
#[test]
fn a_decayed_cache_trains_as_one_whose_rate_is_set_by_hand() {
    let decayed_config = decay_config((3, 2, 0.5, 7));
    let d = decayed_config.optimizer.lr_decay().unwrap();
    for path in [ComputePath::Fused, ComputePath::Unfused] {
        let mut decayed = cache_on(&decayed_config, path);
        let mut by_hand = cache_on(&undecayed(&decayed_config), path);
        let mut full = cache_on(&undecayed(&decayed_config), path);
        let lr = decayed.learning_rate();
        let (mut k, mut rates) = (0u32, Vec::new());
        for step in 0..16u64 {
            if step == 10 {
                decayed.restart_learning_rate();
                k = 0;
            }
            let expect = lr * d.factor(k);
            assert_eq!(
                decayed.current_learning_rate(),
                expect,
                "{path} step {step}"
            );
            rates.push(expect);
            by_hand.set_learning_rate(expect).unwrap();
            let b = batch(64, step);
            decayed.train(&b, 1).unwrap();
            by_hand.train(&b, 1).unwrap();
            full.train(&b, 1).unwrap();
            k += 1;
        }
        // The rate fell to the floor, and came back after the restart.
        assert_eq!(rates[9], lr * d.floor());
        assert_eq!(rates[10], lr);
        assert!(rates[15] < lr);
        assert_eq!(decayed.weights(), by_hand.weights(), "{path}");
        assert_ne!(decayed.weights(), full.weights(), "{path}");
    }
    let decayed = cache_on(&decayed_config, ComputePath::Fused);
    // The description says what the rate is and will be.
    let text = decayed.describe();
    assert!(
        text.contains("× 0.5 every 2 steps from step 3 to 7"),
        "{text}"
    );
}

/// A change confirmed by the online loop ([`Cache::confirm_change`]) restarts the neural
/// cache's decay; a change called and not yet confirmed ([`Cache::begin_recovery`]) does not.
#[test]
fn a_change_restarts_the_decay() {
    let c = decay_config((0, 1, 0.5, 4));
    let mut cache = Cache::Neural(Box::new(cache_on(&c, ComputePath::Fused)));
    for step in 0..6 {
        cache.train(&batch(32, step), 1).unwrap();
    }
    let n = cache.neural().unwrap();
    assert_eq!(
        n.current_learning_rate(),
        n.learning_rate() * 0.5f32.powi(5)
    );
    cache.begin_recovery();
    let n = cache.neural().unwrap();
    assert_eq!(
        n.current_learning_rate(),
        n.learning_rate() * 0.5f32.powi(5),
        "a change not yet confirmed restarted the decay"
    );
    cache.confirm_change();
    let n = cache.neural().unwrap();
    assert_eq!(n.current_learning_rate(), n.learning_rate() * 0.5);
}

/// The step a restarted decay counts from survives a snapshot and a change of compute path:
/// the loaded (and the moved) cache takes the rate the saved one would take. The negative
/// control: the same cache without the restart is at another rate, so a lost restart shows.
#[test]
fn a_restarted_decay_survives_a_snapshot_and_a_path_change() {
    let c = decay_config((0, 1, 0.5, 6));
    let trained = |restart: bool| {
        let mut cache = Cache::Neural(Box::new(cache_on(&c, ComputePath::Fused)));
        for step in 0..5 {
            cache.train(&batch(32, step), 1).unwrap();
        }
        if restart {
            cache.confirm_change();
        }
        cache.train(&batch(32, 5), 1).unwrap();
        cache
    };
    let mut restarted = trained(true);
    let rate = restarted.neural().unwrap().current_learning_rate();
    let plain = trained(false).neural().unwrap().current_learning_rate();
    assert_ne!(rate, plain, "the restart changed nothing to test");
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("c.nrc");
    restarted.neural_mut().unwrap().save(&file).unwrap();
    let loaded = RadianceCache::load(&file, CacheDevice::Cpu).unwrap();
    assert_eq!(
        loaded.current_learning_rate(),
        rate,
        "the loaded cache lost the restart"
    );
    let moved = restarted.neural_mut().unwrap();
    moved.set_path(ComputePath::CustomOps).unwrap();
    assert_eq!(
        moved.current_learning_rate(),
        rate,
        "the path change lost the restart"
    );
}
