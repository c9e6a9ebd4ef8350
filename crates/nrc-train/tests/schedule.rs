//! The online loop's control (`nrc_train::schedule`): the change score is ≈ N(0, 1) on a
//! stationary stream whatever the cache's persistent bias and the targets' fireflies, and
//! jumps when the radiance moves; the detector calls that jump a change and nothing else; the
//! training budget spends less on a settled cache, more after a change, and follows the cost.

use nrc_cache::{CacheQuery, TrainingBatch};
use nrc_train::schedule::{
    ChangeDetector, ChangeMonitor, MAX_BUDGET_RECORDS, MIN_BUDGET_RECORDS, Phase,
    RECOVERY_MAX_FRAMES, RECOVERY_MIN_FRAMES, SETTLED_SHARE, TrainBudget, WARM_UP_FRAMES,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A frame of `n` records on the floor of the unit box (positions uniform, normal +y): the
/// true radiance is `1 + x` (`+ shift` on the half `x > 0.5` after a change), each target a
/// 1-spp-like estimate of it (exponential noise, and one record in 500 a firefly 20 × the
/// mean); the cache predicts the true radiance of the scene before the change times a
/// persistent bias that varies over the floor (0.6 … 1.4).
fn frame(r: &mut Pcg64Mcg, n: usize, shift: f32) -> (TrainingBatch, Vec<[f32; 3]>) {
    let mut batch = TrainingBatch::default();
    let mut predictions = Vec::with_capacity(n);
    for _ in 0..n {
        let (x, z) = (r.random::<f32>(), r.random::<f32>());
        let truth = 1.0 + x + if x > 0.5 { shift } else { 0.0 };
        let noise = -(1.0 - r.random::<f32>()).ln();
        let target = if r.random::<f32>() < 0.002 {
            20.0 * truth * noise
        } else {
            truth * noise
        };
        batch.queries.push(CacheQuery {
            position: [x, 0.0, z],
            normal: [0.0, 1.0, 0.0],
            direction: [0.0, 1.0, 0.0],
            ..Default::default()
        });
        batch.targets.push([target; 3]);
        let bias = 1.0 + 0.4 * (6.0 * z).sin();
        predictions.push([(1.0 + x) * bias; 3]);
    }
    (batch, predictions)
}

#[test]
fn the_change_score_is_calm_on_a_stationary_stream_and_jumps_when_the_radiance_moves() {
    let mut r = Pcg64Mcg::seed_from_u64(5);
    let mut monitor = ChangeMonitor::default();
    let mut still = Vec::new();
    for _ in 0..200 {
        let (b, p) = frame(&mut r, 4096, 0.0);
        still.push(monitor.score(&b, &p).z);
    }
    // After the history fills: mean ≈ 0, spread ≈ 1 (heavy tails make it a little smaller).
    let calm = &still[10..];
    let mean = calm.iter().sum::<f32>() / calm.len() as f32;
    let sd = (calm.iter().map(|z| (z - mean).powi(2)).sum::<f32>() / calm.len() as f32).sqrt();
    assert!(
        mean.abs() < 0.5 && sd < 2.0,
        "stationary score: mean {mean}, sd {sd}"
    );
    // A burst in one place (every record of two cells 10 × as bright this frame, as when a
    // caustic is found by many paths at once): two bins move a lot, which a change is not.
    let (mut b, p) = frame(&mut r, 4096, 0.0);
    for (q, t) in b.queries.iter().zip(b.targets.iter_mut()) {
        if q.position[0] < 0.125 && q.position[2] < 0.25 {
            *t = [t[0] * 10.0; 3];
        }
    }
    let z = monitor.score(&b, &p).z;
    assert!(z < 8.0, "a burst in two bins scores {z}");
    // The radiance of half the floor doubles (a light moved towards it).
    let (b, p) = frame(&mut r, 4096, 1.5);
    let z = monitor.score(&b, &p).z;
    assert!(z > 10.0, "score after the change: {z}");

    // Negative control: compared with zero instead of with its history, the residual of the
    // biased cache scores far above N(0, 1) on the very same stationary stream — the bias the
    // history cancels.
    let (b, p) = frame(&mut r, 4096, 0.0);
    let mut first = ChangeMonitor::default();
    let zeros: Vec<[f32; 3]> = b.targets.iter().map(|_| [0.0; 3]).collect();
    // A history of residuals that are exactly zero: the score is then the residual against 0.
    let zero = TrainingBatch {
        queries: b.queries.clone(),
        targets: zeros.clone(),
        weights: None,
    };
    first.score(&zero, &zeros);
    let against_zero = first.score(&b, &p).z;
    assert!(
        against_zero > 10.0,
        "the biased cache against zero scores {against_zero}: the negative control is calm"
    );
}

#[test]
fn the_detector_calls_a_jump_a_change_and_the_noise_nothing() {
    let mut r = Pcg64Mcg::seed_from_u64(9);
    let mut d = ChangeDetector::default();
    let normal = |r: &mut Pcg64Mcg| {
        // Box–Muller.
        let (u, v) = (1.0 - r.random::<f32>(), r.random::<f32>());
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    };
    // A level that drifts down (a cache still learning) with N(0, 1) noise: never a change.
    for k in 0..2000 {
        let z = 3.0 + 20.0 * (-(k as f32) / 100.0).exp() + normal(&mut r);
        let phase = d.observe(z);
        assert_ne!(
            phase,
            Phase::Changed,
            "frame {k}: noise taken for a change (z {z})"
        );
        if k as u32 > WARM_UP_FRAMES {
            assert!(d.settled(), "frame {k}: {phase:?}");
        }
    }
    // A jump: a change at once, a recovery while the score stays high, then watching again.
    assert_eq!(d.observe(60.0), Phase::Changed);
    assert!(d.recovering() && !d.settled());
    assert_eq!(d.observe(40.0 + normal(&mut r)), Phase::Confirmed);
    for _ in 0..4 {
        assert_eq!(d.observe(40.0 + normal(&mut r)), Phase::Recovering);
    }
    assert_eq!(d.observe(3.0), Phase::Recovered);
    assert!(!d.recovering());
    assert_eq!(d.observe(3.0), Phase::Watching);
    // A score that never comes back ends the recovery after RECOVERY_MAX_FRAMES frames.
    for _ in 0..WARM_UP_FRAMES + 2 {
        d.observe(3.0 + normal(&mut r));
    }
    assert_eq!(d.observe(80.0), Phase::Changed);
    assert_eq!(d.observe(80.0), Phase::Confirmed);
    let mut frames = 1;
    while d.observe(80.0) == Phase::Recovering {
        frames += 1;
        assert!(frames < RECOVERY_MAX_FRAMES, "the recovery does not end");
    }
    assert_eq!(frames + 1, RECOVERY_MAX_FRAMES);
    // A one-frame outlier (a burst of caustic paths): a change, never confirmed; the recovery
    // lasts its shortest (after the level, left at 80 by the recovery above, has settled).
    for _ in 0..100 {
        d.observe(3.0 + normal(&mut r));
    }
    assert_eq!(d.observe(60.0), Phase::Changed);
    let after: Vec<Phase> = (0..RECOVERY_MIN_FRAMES)
        .map(|_| d.observe(3.0 + normal(&mut r)))
        .collect();
    assert!(
        !after.contains(&Phase::Confirmed) && after.last() == Some(&Phase::Recovered),
        "an outlier's recovery: {after:?}"
    );
    // Non-finite scores change nothing.
    assert_eq!(d.observe(f32::NAN), Phase::Watching);
}

#[test]
fn the_budget_spends_less_when_settled_more_after_a_change_and_follows_the_cost() {
    // A frame costs 1 ms plus 1 µs a record to produce, and 0.5 ms plus 2 µs a record and step
    // to train: 10 ms hold (10 − 1.5)/0.003 ≈ 2,830 records at one step.
    let cost = |records: usize, steps: u32, f: f64| {
        let n = records as f64;
        (
            f * (1.0 + 0.001 * n),
            f * (0.5 + 0.002 * n * f64::from(steps)),
        )
    };
    let mut b = TrainBudget::new(10.0, 4096);
    assert_eq!(b.plan(1, false).records, 4096, "before any measurement");
    // The first frame pays for allocations (100 ms): not measured.
    b.observe(4096, 1, 50.0, 50.0);
    assert_eq!(b.plan(1, false).records, 4096);
    let frames = |b: &mut TrainBudget, n: usize, settled: bool, f: f64| {
        for _ in 0..n {
            let r = b.plan(1, settled).records;
            let (p, t) = cost(r, 1, f);
            b.observe(r, 1, p, t);
        }
    };
    frames(&mut b, 40, false, 1.0);
    let warm = b.plan(1, false);
    let recovering = b.plan(2, false);
    // A settled cache: within a frame the records at most halve, then they follow the fit.
    let first_settled = b.plan(1, true).records;
    assert!(
        first_settled as f64 >= 0.49 * warm.records as f64,
        "{first_settled} records after {warm:?}"
    );
    frames(&mut b, 10, true, 1.0);
    let settled = b.plan(1, true);
    assert!((2700..=2900).contains(&warm.records), "{warm:?}");
    let (p, t) = cost(warm.records, 1, 1.0);
    assert!(
        p + t <= 10.0 && p + t > 9.5,
        "planned frame costs {}",
        p + t
    );
    assert_eq!(warm.spend_ms, 10.0);
    assert_eq!(settled.spend_ms, 10.0 * SETTLED_SHARE);
    // Half the budget less the fixed 1.5 ms: (5 − 1.5)/0.003 ≈ 1,170 records.
    assert!(
        (1100..=1250).contains(&settled.records),
        "settled: {settled:?}"
    );
    // Two steps: (10 − 1.5)/0.005 = 1,700.
    assert!(
        (1600..=1800).contains(&recovering.records),
        "two steps: {recovering:?}"
    );
    // The cost doubles: the records follow within a few frames.
    frames(&mut b, 30, false, 2.0);
    let dear = b.plan(1, false).records;
    assert!(
        (950..=1200).contains(&dear),
        "after the cost doubled: {dear}"
    );
    // Noisy costs plan below the quiet costs' records (two deviations of margin).
    let mut noisy = TrainBudget::new(10.0, 4096);
    for k in 0..20 {
        frames(&mut noisy, 1, false, 0.7);
        frames(&mut noisy, 1, false, 1.3 + 0.0 * k as f64);
    }
    assert!(noisy.plan(1, false).records < warm.records);
    // Bounds.
    let mut cheap = TrainBudget::new(1e6, 10);
    assert_eq!(cheap.plan(1, false).records, MIN_BUDGET_RECORDS.max(10));
    for _ in 0..12 {
        frames(&mut cheap, 1, false, 0.0);
    }
    assert_eq!(cheap.plan(1, false).records, MAX_BUDGET_RECORDS);
    let mut dear = TrainBudget::new(0.001, 4096);
    for _ in 0..12 {
        frames(&mut dear, 1, true, 1.0);
    }
    assert_eq!(dear.plan(1, true).records, MIN_BUDGET_RECORDS);
}
