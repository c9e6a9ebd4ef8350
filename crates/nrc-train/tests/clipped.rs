//! The light the loss bound clips, returned to its bins (`nrc_train::clipped`): a cache trained
//! through the bound settles at its targets' mean where rare bright targets carry the light,
//! and below it when the clipped light is lost (the negative control); a bin without rare
//! targets is left alone; targets the cache drops are not touched; a glossy surface's clipped
//! light is not spread over its bin.

use nrc_cache::config::{LossConfig, LossType, ReturnClipped};
use nrc_cache::{CacheQuery, TrainingBatch};
use nrc_train::clipped::ClippedLight;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn loss() -> LossConfig {
    LossConfig {
        otype: LossType::RelativeL2Luminance,
        epsilon: 0.01,
        max_target: 1e8,
        max_relative_error: 16.0,
        return_clipped: None,
    }
}

/// Three strips of the floor (`x` in thirds, one bin each on a 3³ grid): true radiance 1, 2
/// and 3. Targets are 1-spp-like estimates (exponential noise); in the second and third
/// strips one record in 200 is a firefly of 100 × the radiance times its noise, so those
/// strips' target means are 1.495 × the radiance and a fifth of it comes in fireflies.
const FIREFLY: f64 = 0.005;
const FIREFLY_SCALE: f64 = 100.0;

fn strip(x: f32) -> usize {
    ((x * 3.0) as usize).min(2)
}

fn target_mean(s: usize) -> f64 {
    let truth = (s + 1) as f64;
    if s == 0 {
        truth
    } else {
        truth * (1.0 - FIREFLY + FIREFLY * FIREFLY_SCALE)
    }
}

fn frame(r: &mut Pcg64Mcg, n: usize) -> TrainingBatch {
    let mut batch = TrainingBatch::default();
    for _ in 0..n {
        let (x, z) = (r.random::<f32>(), r.random::<f32>());
        let s = strip(x);
        let noise = -(1.0 - r.random::<f64>()).ln();
        let scale = if s > 0 && r.random::<f64>() < FIREFLY {
            FIREFLY_SCALE
        } else {
            1.0
        };
        batch.queries.push(CacheQuery {
            position: [x, 0.5, z],
            normal: [0.0, 1.0, 0.0],
            direction: [0.0, 1.0, 0.0],
            ..Default::default()
        });
        batch
            .targets
            .push([((s + 1) as f64 * scale * noise) as f32; 3]);
    }
    batch
}

/// A cache of one value per strip trained through the bound: each frame its records'
/// targets pass through `light` (if any), then the loss's bound at the prediction clips what
/// is still beyond it (Huber's gradient is the clipped residual's), and the value moves a
/// tenth of the way to the mean of what is left. Returns the values after `frames` frames
/// divided by the strips' target means.
fn settle(mut light: Option<ClippedLight>, frames: usize) -> [f64; 3] {
    let loss = loss();
    let k = f64::from(loss.max_relative_error);
    let eps = f64::from(loss.epsilon);
    let mut r = Pcg64Mcg::seed_from_u64(7);
    let mut y = [1.0f64; 3];
    for _ in 0..frames {
        let mut batch = frame(&mut r, 3000);
        let predictions: Vec<[f32; 3]> = batch
            .queries
            .iter()
            .map(|q| [y[strip(q.position[0])] as f32; 3])
            .collect();
        if let Some(l) = &mut light {
            l.apply(&mut batch, &predictions, &loss);
        }
        let mut sum = [0.0f64; 3];
        let mut n = [0usize; 3];
        for (q, t) in batch.queries.iter().zip(&batch.targets) {
            let s = strip(q.position[0]);
            let bound = y[s] + k * (y[s] * y[s] + eps).sqrt();
            sum[s] += f64::from(t[0]).min(bound);
            n[s] += 1;
        }
        for s in 0..3 {
            y[s] += 0.1 * (sum[s] / n[s] as f64 - y[s]);
        }
    }
    std::array::from_fn(|s| y[s] / target_mean(s))
}

fn spec(max_gain: f32) -> ReturnClipped {
    ReturnClipped {
        grid: 3,
        frames: 64.0,
        max_gain,
        min_roughness: 0.7,
    }
}

#[test]
fn a_cache_trained_through_the_bound_settles_at_its_targets_mean_when_the_clipped_light_returns() {
    let returned = settle(Some(ClippedLight::new(&spec(2.0))), 400);
    // The negative control: the bound alone (as without `return_clipped`).
    let lost = settle(None, 400);
    println!("settled / target mean: returned {returned:.3?}, lost {lost:.3?}");
    for s in 1..3 {
        assert!(
            (returned[s] - 1.0).abs() < 0.05,
            "strip {s} with fireflies: the cache settles at {:.3} of its targets' mean with the clipped light returned",
            returned[s]
        );
        assert!(
            lost[s] < 0.9,
            "negative control: strip {s} settles at {:.3} of its targets' mean without the return, expected the bound's bias (< 0.9)",
            lost[s]
        );
    }
    // Without fireflies nothing is clipped: the first strip's targets are left at their mean
    // (exponential noise beyond 17 × the mean: e⁻¹⁷), with or without the return.
    assert!((returned[0] - 1.0).abs() < 0.02 && (lost[0] - 1.0).abs() < 0.02);
}

#[test]
fn targets_within_the_bound_keep_their_value_without_clipped_light_and_non_finite_ones_are_left_alone()
 {
    let mut light = ClippedLight::new(&spec(100.0));
    let q = CacheQuery {
        position: [0.1, 0.5, 0.5],
        normal: [0.0, 1.0, 0.0],
        ..Default::default()
    };
    let mut batch = TrainingBatch {
        queries: vec![q; 3],
        targets: vec![[0.5, 1.0, 2.0], [f32::NAN, 1.0, 1.0], [f32::INFINITY; 3]],
        weights: None,
    };
    let before = batch.targets.clone();
    let stats = light.apply(&mut batch, &[[1.0; 3]; 3], &loss());
    assert_eq!(stats.clamped, 0);
    assert_eq!(batch.targets[0], before[0]);
    assert!(batch.targets[1][0].is_nan() && batch.targets[1][1] == 1.0);
    assert_eq!(batch.targets[2], before[2]);

    // A target 100 × the prediction in the same bin is clamped at the bound (1 + 16 · √1.01),
    // and the bin's gain (1 + clipped / kept, the cap of 100 not reached) then scales every
    // target of the bin. An absurd target (above `max_target`) and a record of negative weight
    // are left alone and not counted.
    let mut batch = TrainingBatch {
        queries: vec![q; 4],
        targets: vec![[100.0; 3], [1.0; 3], [1e12; 3], [50.0; 3]],
        weights: Some(vec![1.0, 1.0, 1.0, -1.0]),
    };
    let stats = light.apply(&mut batch, &[[1.0; 3]; 4], &loss());
    assert_eq!(stats.clamped, 1);
    let bound = 1.0 + 16.0 * 1.01f64.sqrt();
    // The bin remembers the first frame's kept luminance (0.5·0.2126 + 0.7152 + 2·0.0722) at
    // 63/64, then adds this frame's.
    let kept = (0.5 * 0.2126 + 0.7152 + 2.0 * 0.0722) * (63.0 / 64.0) + bound + 1.0;
    let gain = 1.0 + (100.0 - bound) / kept;
    assert!(gain > 5.0 && gain < 100.0, "{gain}");
    let got = f64::from(batch.targets[1][0]);
    assert!(
        (got - gain).abs() < 1e-4 * gain,
        "gain {got}, expected {gain}"
    );
    let firefly = f64::from(batch.targets[0][0]);
    assert!(
        (firefly - bound * gain).abs() < 1e-4 * bound * gain,
        "{firefly}"
    );
    assert_eq!(
        batch.targets[2], [1e12; 3],
        "the absurd target is the cache's to drop"
    );
    assert_eq!(
        batch.targets[3], [50.0; 3],
        "the negative weight's record is the cache's to drop"
    );
    assert!((f64::from(stats.gain) - (2.0 * gain + 2.0) / 4.0).abs() < 1e-4 * gain);
}

#[test]
fn a_glossy_surfaces_clipped_light_is_clamped_but_not_spread_over_its_bin() {
    // One bin: 100 diffuse records at the prediction (luminance 1) and one firefly of 1,000 on
    // a surface with a specular part, glossy (roughness 0.2) or rough (0.8).
    let diffuse = CacheQuery {
        position: [0.1, 0.5, 0.5],
        normal: [0.0, 1.0, 0.0],
        roughness: 1.0,
        diffuse: [0.5; 3],
        ..Default::default()
    };
    let bound = 1.0 + 16.0 * 1.01f64.sqrt();
    let share = (1000.0 - bound) / (100.0 + bound);
    for (roughness, expected) in [(0.2, 1.0), (0.8, 1.0 + share)] {
        let mut queries = vec![diffuse; 100];
        queries.push(CacheQuery {
            roughness,
            specular: [0.04; 3],
            ..diffuse
        });
        let mut targets = vec![[1.0f32; 3]; 100];
        targets.push([1000.0; 3]);
        let mut batch = TrainingBatch {
            queries,
            targets,
            weights: None,
        };
        let mut light = ClippedLight::new(&spec(100.0));
        let stats = light.apply(&mut batch, &[[1.0; 3]; 101], &loss());
        assert_eq!(stats.clamped, 1, "roughness {roughness}");
        let gain = f64::from(batch.targets[0][0]);
        assert!(
            (gain - expected).abs() < 1e-4 * expected,
            "roughness {roughness}: the diffuse records' gain {gain}, expected {expected}"
        );
        // The firefly itself: at the bound, times the gain where it took part.
        let own = if roughness < 0.7 { 1.0 } else { expected };
        assert!(
            (f64::from(batch.targets[100][0]) - bound * own).abs() < 1e-3 * bound * own,
            "roughness {roughness}: {:?}",
            batch.targets[100]
        );
    }
}
