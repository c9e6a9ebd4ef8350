//! Hard inputs: extreme, zero, NaN and infinite targets, zero reflectance, degenerate normals.
//! No weight or output may become non-finite, the loss stays finite, bad samples are counted.

use nrc_cache::config::NestedEncoding;
use nrc_cache::{
    CacheConfig, CacheDevice, CacheQuery, ComputePath, RadianceCache, SceneBox, TrainingBatch,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn small(mut c: CacheConfig) -> CacheConfig {
    if let Some(NestedEncoding::HashGrid {
        log2_hashmap_size, ..
    }) = c.encoding.nested.first_mut()
    {
        *log2_hashmap_size = 15;
    }
    c
}

/// A batch mixing every hard case; returns it with the expected (non-finite, absurd) drop counts.
fn hard_batch(seed: u64) -> (TrainingBatch, usize, usize) {
    let mut r = Pcg64Mcg::seed_from_u64(seed);
    let mut queries = Vec::new();
    let mut targets = Vec::new();
    let mut weights = Vec::new();
    let (mut nonfinite, mut absurd) = (0, 0);
    for i in 0..2000 {
        let mut q = CacheQuery {
            position: [r.random(), r.random(), r.random()],
            direction: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
            ],
            normal: [0.0, 0.0, 1.0],
            roughness: r.random_range(0.0..1.0),
            diffuse: [0.5, 0.4, 0.3],
            specular: [0.04; 3],
        };
        // Targets spanning 1e-6 .. 1e6.
        let mut t = [10f32.powf(r.random_range(-6.0..6.0)); 3];
        let mut w = 1.0;
        match i % 10 {
            0 => t = [0.0; 3],
            1 => {
                q.diffuse = [0.0; 3];
                q.specular = [0.0; 3];
            }
            2 => q.normal = [0.0; 3],
            3 => q.direction = [0.0, 0.0, 0.0],
            4 => {
                t[1] = f32::NAN;
                nonfinite += 1;
            }
            5 => {
                t[0] = f32::INFINITY;
                nonfinite += 1;
            }
            6 => {
                q.position[2] = f32::NAN;
                nonfinite += 1;
            }
            7 => {
                t[2] = -1.0;
                absurd += 1;
            }
            8 => {
                t = [1e12; 3];
                absurd += 1;
            }
            _ => {
                q.normal = [1e-30, 0.0, 0.0];
                w = if i % 20 == 9 { 0.0 } else { 3.0 };
            }
        }
        queries.push(q);
        targets.push(t);
        weights.push(w);
    }
    (
        TrainingBatch {
            queries,
            targets,
            weights: Some(weights),
        },
        nonfinite,
        absurd,
    )
}

fn check(config: CacheConfig, path: ComputePath) {
    let mut cache =
        RadianceCache::with_path(config, SceneBox::default(), CacheDevice::Cpu, path).unwrap();
    for round in 0..4 {
        let (batch, nonfinite, absurd) = hard_batch(round);
        let stats = cache.train(&batch, 5).unwrap();
        assert_eq!(stats.dropped_nonfinite, nonfinite, "{path}");
        assert_eq!(stats.dropped_absurd, absurd, "{path}");
        assert_eq!(stats.used, batch.queries.len() - nonfinite - absurd);
        assert!(
            stats.loss.is_finite() && stats.first_loss.is_finite(),
            "{path}: loss {stats:?}"
        );
        let out = cache.infer(&batch.queries);
        for (i, o) in out.iter().enumerate() {
            assert!(
                o.iter().all(|v| v.is_finite() && *v >= 0.0),
                "{path}: output {i} = {o:?}"
            );
        }
    }
    let host = cache.host_state();
    for (name, v) in [
        ("grid", &host.grid),
        ("grid_m", &host.grid_m),
        ("grid_v", &host.grid_v),
        ("grid_ema", &host.grid_ema),
        ("mlp", &host.mlp),
        ("mlp_m", &host.mlp_m),
        ("mlp_v", &host.mlp_v),
        ("mlp_ema", &host.mlp_ema),
    ] {
        assert!(v.iter().all(|x| x.is_finite()), "{path}: non-finite {name}");
    }
    // A batch with nothing usable takes no step.
    let (mut batch, ..) = hard_batch(9);
    batch.targets.iter_mut().for_each(|t| *t = [f32::NAN; 3]);
    let before = cache.step_count();
    let stats = cache.train(&batch, 3).unwrap();
    assert_eq!(
        (stats.used, stats.steps, cache.step_count()),
        (0, 0, before)
    );
    // Mismatched lengths are an error, not a panic.
    batch.targets.pop();
    assert!(cache.train(&batch, 1).is_err());
}

#[test]
fn hard_cases_fused_cpu_step() {
    check(small(CacheConfig::hash_grid_preset()), ComputePath::Fused);
    check(CacheConfig::triangle_wave_preset(), ComputePath::Fused);
}

#[test]
fn hard_cases_tensor_paths() {
    check(
        small(CacheConfig::hash_grid_preset()),
        ComputePath::CustomOps,
    );
    check(CacheConfig::triangle_wave_preset(), ComputePath::Unfused);
}
