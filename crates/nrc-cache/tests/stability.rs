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

/// The packing's `atan2` (a polynomial, for speed) agrees with the C library's within 4e-7 rad
/// over every octant, the axes, signed zeros (0 for atan2(±0, ±0)) and magnitudes from 1e-30 to 1e30; spherical
/// coordinates stay in [0, 1] with φ < 1, and match the f64 `acos`/`atan2` of the normalised
/// vector within 2e-7.
#[test]
fn packing_atan2_matches_the_library() {
    use nrc_cache::record::{atan2, spherical};
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let mut pairs: Vec<(f32, f32)> = (0..200_000)
        .map(|_| {
            let scale = 10f32.powf(rng.random_range(-30.0..30.0));
            (
                rng.random_range(-1.0f32..1.0) * scale,
                rng.random_range(-1.0f32..1.0) * scale,
            )
        })
        .collect();
    for y in [0.0f32, -0.0, 1.0, -1.0, 1e-30, 3.0] {
        for x in [0.0f32, -0.0, 1.0, -1.0, 1e-30, 3.0] {
            pairs.push((y, x));
        }
    }
    let mut worst = 0f32;
    for &(y, x) in &pairs {
        let (got, want) = (atan2(y, x), y.atan2(x));
        if y == 0.0 && x == 0.0 {
            // Undefined; ours is 0 (spherical coordinates never ask: zero vectors map to +z).
            assert_eq!(got, 0.0);
            continue;
        }
        // atan2(±0, −x) is ±π in the library; both give the same φ after wrapping.
        let err = if y == 0.0 && x < 0.0 {
            (got.abs() - want.abs()).abs()
        } else {
            (got - want).abs()
        };
        worst = worst.max(err);
        assert!(err <= 4e-7, "atan2({y}, {x}) = {got}, library {want}");
    }
    println!("worst atan2 error {worst:e} rad");
    for _ in 0..100_000 {
        let v: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0f32..1.0));
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if len < 1e-3 {
            continue;
        }
        let (t, p) = spherical(v);
        assert!(
            (0.0..=1.0).contains(&t) && (0.0..1.0).contains(&p),
            "{v:?}: ({t}, {p})"
        );
        // References in f64 (acos of a rounded f32 cosine loses digits near the poles).
        let [x, y, z] = v.map(f64::from);
        let want_t = (z / (x * x + y * y + z * z).sqrt()).acos() / std::f64::consts::PI;
        let want_p = (y.atan2(x) / std::f64::consts::TAU).rem_euclid(1.0);
        let dp = (f64::from(p) - want_p).abs();
        let dp = dp.min(1.0 - dp);
        assert!(
            (f64::from(t) - want_t).abs() <= 2e-7 && dp <= 2e-7,
            "{v:?}: ({t}, {p}) vs ({want_t}, {want_p})"
        );
    }
}

/// The inference packing converts eight queries' directions and normals at once
/// (`spherical_lanes`, vectorised by the compiler): the rows are the same bits as converting one
/// query at a time, for random, axis-aligned, signed-zero, tiny, huge, infinite and NaN vectors,
/// with a batch that is not a multiple of eight (the remainder takes the per-query path).
#[test]
fn grouped_query_packing_matches_one_query_at_a_time() {
    use nrc_cache::batch::{QUERY_ROW, pack_queries};
    use nrc_cache::record::{RAW_INPUT_DIMS, raw_inputs, spherical, spherical_lanes};
    let mut rng = Pcg64Mcg::seed_from_u64(23);
    let special = [
        [0.0, 0.0, 0.0],
        [-0.0, -0.0, -0.0],
        [0.0, 0.0, -1.0],
        [-1.0, 0.0, 0.0],
        [-1.0, -0.0, 0.0],
        [0.0, -1.0, 0.0],
        [1e-20, 0.0, 0.0],
        [1e-16, -1e-16, 1e-16],
        [1e20, 1e20, -1e20],
        [3e38, 3e38, 0.0],
        [f32::INFINITY, 0.0, 0.0],
        [f32::NAN, 1.0, 0.0],
        [1.0, 1.0, 1.0],
        [-1.0, 1.0, -1.0],
    ];
    let mut vectors: Vec<[f32; 3]> = special.to_vec();
    vectors.extend((0..4000).map(|_| {
        let scale = 10f32.powi(rng.random_range(-8..8));
        std::array::from_fn(|_| scale * rng.random_range(-1.0f32..1.0))
    }));
    for group in vectors.chunks_exact(16) {
        let lanes = spherical_lanes::<16>(group.try_into().expect("16 vectors"));
        for (v, got) in group.iter().zip(lanes) {
            let (t, p) = spherical(*v);
            assert_eq!(
                [got[0].to_bits(), got[1].to_bits()],
                [t.to_bits(), p.to_bits()],
                "{v:?}: {got:?} vs ({t}, {p})"
            );
        }
    }
    let queries: Vec<CacheQuery> = vectors
        .chunks_exact(2)
        .take(1003)
        .enumerate()
        .map(|(i, pair)| CacheQuery {
            position: [0.1 * (i % 10) as f32, 0.5, 2.0],
            direction: pair[0],
            normal: pair[1],
            roughness: 0.3,
            diffuse: [0.5, 0.4, 0.3],
            specular: [0.04; 3],
        })
        .collect();
    assert_eq!(queries.len() % 8, 3, "a remainder outside the groups");
    let rows = pack_queries(&queries);
    for (i, (row, q)) in rows.chunks_exact(QUERY_ROW).zip(&queries).enumerate() {
        let want = raw_inputs(q);
        for (j, (a, b)) in row[..RAW_INPUT_DIMS].iter().zip(&want).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "query {i}, input {j}: {a} vs {b}");
        }
    }
}
