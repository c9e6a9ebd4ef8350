//! Speed against error: each method run at increasing budgets gives a series of (time, error)
//! points; from these, "how long does method M need to reach the error of X" is read off by
//! interpolating in log-log space (errors of Monte Carlo estimators fall as a power of time, so
//! they are straight lines there), as in Table 1 of the DDGI-resampling paper.

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::metrics::{ErrorMetrics, Metric};

/// One budget of one method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepPoint {
    /// Wall time per frame, milliseconds.
    pub time_ms: f64,
    /// Samples per pixel (or the method's budget unit).
    pub samples_per_pixel: f64,
    pub metrics: ErrorMetrics,
}

/// A method's sweep over budgets.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepSeries {
    pub method: String,
    pub points: Vec<SweepPoint>,
}

impl SweepSeries {
    /// `(time_ms, error)` of `metric`, sorted by time, keeping points with positive finite values.
    pub fn curve(&self, metric: Metric) -> Vec<(f64, f64)> {
        let mut c: Vec<(f64, f64)> = self
            .points
            .iter()
            .filter_map(|p| metric.of(&p.metrics).map(|e| (p.time_ms, e)))
            .filter(|&(t, e)| t.is_finite() && e.is_finite() && t > 0.0 && e > 0.0)
            .collect();
        c.sort_by(|a, b| a.0.total_cmp(&b.0));
        c
    }
}

/// When a method reaches a target error.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", content = "time_ms", rename_all = "snake_case")]
pub enum TimeToReach {
    /// Interpolated (log-log) between the two budgets whose errors straddle the target.
    Interpolated(f64),
    /// Already at or below the target at the smallest budget: at most this time.
    AtMost(f64),
    /// Still above the target at the largest budget measured.
    NotReached,
}

impl TimeToReach {
    /// The time, when known or bounded.
    pub fn time_ms(self) -> Option<f64> {
        match self {
            TimeToReach::Interpolated(t) | TimeToReach::AtMost(t) => Some(t),
            TimeToReach::NotReached => None,
        }
    }
}

/// Time at which `series` first reaches `target` in `metric` (first crossing in time order).
pub fn time_to_reach(series: &SweepSeries, metric: Metric, target: f64) -> Result<TimeToReach> {
    if !(target.is_finite() && target > 0.0) {
        return Err(EvalError::InvalidParameter {
            name: "target error",
            reason: format!("must be finite and > 0, got {target}"),
        });
    }
    let c = series.curve(metric);
    let Some(&(t0, e0)) = c.first() else {
        return Err(EvalError::NotEnoughData(format!(
            "method '{}' has no {} values",
            series.method,
            metric.label()
        )));
    };
    if e0 <= target {
        return Ok(TimeToReach::AtMost(t0));
    }
    for w in c.windows(2) {
        let ((ta, ea), (tb, eb)) = (w[0], w[1]);
        if ea > target && eb <= target {
            let s = (target.ln() - ea.ln()) / (eb.ln() - ea.ln());
            return Ok(TimeToReach::Interpolated(
                (ta.ln() + s * (tb.ln() - ta.ln())).exp(),
            ));
        }
    }
    Ok(TimeToReach::NotReached)
}

/// Error of `series` at `time_ms`, interpolated in log-log between the neighbouring budgets;
/// `None` outside the measured time range.
pub fn error_at_time(series: &SweepSeries, metric: Metric, time_ms: f64) -> Option<f64> {
    let c = series.curve(metric);
    if time_ms <= 0.0 || !time_ms.is_finite() {
        return None;
    }
    c.windows(2)
        .find(|w| w[0].0 <= time_ms && time_ms <= w[1].0)
        .map(|w| {
            let ((ta, ea), (tb, eb)) = (w[0], w[1]);
            if tb == ta {
                return ea.min(eb);
            }
            let s = (time_ms.ln() - ta.ln()) / (tb.ln() - ta.ln());
            (ea.ln() + s * (eb.ln() - ea.ln())).exp()
        })
        .or_else(|| c.iter().find(|p| p.0 == time_ms).map(|p| p.1))
}

/// One row of a time-to-error table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimeToErrorRow {
    pub method: String,
    pub time: TimeToReach,
    /// `baseline time / this method's time` (> 1: faster than the baseline).
    pub speedup: Option<f64>,
}

/// "Time to reach the error of X": the error of `baseline` at `baseline_time_ms` is the target;
/// each series' time to reach it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimeToErrorTable {
    pub metric: Metric,
    pub baseline: String,
    pub baseline_time_ms: f64,
    pub target_error: f64,
    pub rows: Vec<TimeToErrorRow>,
}

/// Builds a [`TimeToErrorTable`] over `series` for the error `baseline` has at `baseline_time_ms`.
pub fn time_to_error_table(
    series: &[SweepSeries],
    metric: Metric,
    baseline: &str,
    baseline_time_ms: f64,
) -> Result<TimeToErrorTable> {
    let base = series
        .iter()
        .find(|s| s.method == baseline)
        .ok_or_else(|| EvalError::InvalidParameter {
            name: "baseline",
            reason: format!("no sweep for method '{baseline}'"),
        })?;
    let target_error = error_at_time(base, metric, baseline_time_ms).ok_or_else(|| {
        EvalError::InvalidParameter {
            name: "baseline time",
            reason: format!("{baseline_time_ms} ms is outside the times measured for '{baseline}'"),
        }
    })?;
    let rows = series
        .iter()
        .map(|s| {
            let time = time_to_reach(s, metric, target_error)?;
            let speedup = match time {
                TimeToReach::Interpolated(t) => Some(baseline_time_ms / t),
                _ => None,
            };
            Ok(TimeToErrorRow {
                method: s.method.clone(),
                time,
                speedup,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(TimeToErrorTable {
        metric,
        baseline: baseline.to_string(),
        baseline_time_ms,
        target_error,
        rows,
    })
}
