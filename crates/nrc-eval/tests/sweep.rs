//! "Time to reach the error of X" on power-law sweeps, where log-log interpolation is exact.

use nrc_eval::metrics::{ErrorMetrics, Metric};
use nrc_eval::sweep::{error_at_time, time_to_error_table};
use nrc_eval::{SweepPoint, SweepSeries, TimeToReach, time_to_reach};

/// A sweep whose relMSE (and MSE) is `c · t^(−slope)` at the given times.
fn power_law(method: &str, c: f64, slope: f64, times: &[f64]) -> SweepSeries {
    SweepSeries {
        method: method.to_string(),
        points: times
            .iter()
            .map(|&t| {
                let e = c * t.powf(-slope);
                SweepPoint {
                    time_ms: t,
                    samples_per_pixel: t,
                    metrics: ErrorMetrics {
                        mse: e,
                        rel_mse: e,
                        mape: e.sqrt(),
                        flip: None,
                    },
                }
            })
            .collect(),
    }
}

fn near(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9 * b.abs().max(1.0)
}

#[test]
fn interpolates_exactly_on_power_laws() {
    let a = power_law("a", 2.0, 1.0, &[1.0, 4.0, 16.0, 64.0]);
    let b = power_law("b", 0.5, 1.0, &[2.0, 8.0, 32.0]);
    let c = power_law("c", 1.0, 0.5, &[1.0, 10.0, 100.0, 1000.0]);
    // a's error at 8 ms (between its 4 and 16 ms budgets) is 2/8.
    assert!(near(error_at_time(&a, Metric::RelMse, 8.0).unwrap(), 0.25));
    assert_eq!(error_at_time(&a, Metric::RelMse, 100.0), None);
    // b reaches 0.125 at 0.5/t = 0.125 → 4 ms; c at t^(-1/2) = 0.125 → 64 ms.
    match time_to_reach(&b, Metric::RelMse, 0.125).unwrap() {
        TimeToReach::Interpolated(t) => assert!(near(t, 4.0), "{t}"),
        other => panic!("{other:?}"),
    }
    match time_to_reach(&c, Metric::RelMse, 0.125).unwrap() {
        TimeToReach::Interpolated(t) => assert!(near(t, 64.0), "{t}"),
        other => panic!("{other:?}"),
    }
    // FLIP was not measured.
    assert!(time_to_reach(&a, Metric::Flip, 0.1).is_err());
}

#[test]
fn bounds_when_target_is_outside_the_sweep() {
    let a = power_law("a", 2.0, 1.0, &[1.0, 4.0, 16.0]);
    assert_eq!(
        time_to_reach(&a, Metric::Mse, 5.0).unwrap(),
        TimeToReach::AtMost(1.0)
    );
    assert_eq!(
        time_to_reach(&a, Metric::Mse, 0.01).unwrap(),
        TimeToReach::NotReached
    );
    assert!(time_to_reach(&a, Metric::Mse, 0.0).is_err());
    // Points come in any order.
    let mut shuffled = a.clone();
    shuffled.points.reverse();
    assert_eq!(
        time_to_reach(&shuffled, Metric::Mse, 1.0).unwrap(),
        time_to_reach(&a, Metric::Mse, 1.0).unwrap()
    );
}

#[test]
fn time_to_error_table_gives_speedups() {
    let series = vec![
        power_law("pt", 2.0, 1.0, &[1.0, 4.0, 16.0, 64.0]),
        power_law("nrc", 0.5, 1.0, &[2.0, 8.0, 32.0]),
    ];
    let table = time_to_error_table(&series, Metric::RelMse, "pt", 16.0).unwrap();
    assert!(near(table.target_error, 0.125));
    assert!(near(table.rows[0].time.time_ms().unwrap(), 16.0));
    assert!(near(table.rows[0].speedup.unwrap(), 1.0));
    assert!(near(table.rows[1].time.time_ms().unwrap(), 4.0));
    assert!(near(table.rows[1].speedup.unwrap(), 4.0));
    assert!(time_to_error_table(&series, Metric::RelMse, "missing", 16.0).is_err());
    assert!(time_to_error_table(&series, Metric::RelMse, "pt", 1000.0).is_err());
}
