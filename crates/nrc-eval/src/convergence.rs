//! Frames to equal error: the protocol of Table 1 of the DDGI-resampling paper (Majercik et
//! al., §5: "the number of frames each method needs to reach the error of our first frame").
//! Each method renders consecutive frames of a static view from one state (its history and
//! probes carry over, its cache keeps training), the frames are averaged progressively, and
//! the error of the running mean after each frame gives a curve; a method's cost to reach a
//! target error is the first frame count whose running mean is at or below it, and the timed
//! milliseconds of those frames.
//!
//! A method whose mean is still above the target after the frames it was given is either
//! still converging (its error still falls as a power of the frame count: the count is
//! extrapolated along the power law fitted to the second half of its curve, and marked so) or
//! has settled on its bias (the fitted exponent is above [`PLATEAU_SLOPE`]: "not reached").

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::metrics::{ErrorMetrics, Metric};
use crate::sweep::{SweepPoint, SweepSeries};

/// A fitted log-log slope above this (error falling slower than frames^-0.2) counts as a
/// plateau: no extrapolation.
pub const PLATEAU_SLOPE: f64 = -0.2;

/// The running mean after `frames` frames.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConvergencePoint {
    pub frames: u32,
    /// Timed milliseconds of these frames, summed.
    pub time_ms: f64,
    pub metrics: ErrorMetrics,
}

/// One method's curve, one point per frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConvergenceSeries {
    pub method: String,
    pub points: Vec<ConvergencePoint>,
    /// Milliseconds of the untimed warm-up before the first frame (a stateful method's
    /// history, probes or trained cache); zero for stateless methods.
    #[serde(default)]
    pub warm_up_ms: f64,
}

impl ConvergenceSeries {
    /// The curve as error against accumulated time, for the error-against-time plot.
    pub fn as_sweep(&self) -> SweepSeries {
        SweepSeries {
            method: self.method.clone(),
            points: self
                .points
                .iter()
                .map(|p| SweepPoint {
                    time_ms: p.time_ms,
                    samples_per_pixel: p.frames as f64,
                    metrics: p.metrics,
                })
                .collect(),
        }
    }

    /// Mean timed milliseconds per frame.
    pub fn frame_ms(&self) -> Option<f64> {
        self.points
            .last()
            .map(|p| p.time_ms / p.frames.max(1) as f64)
    }

    /// The first point at or below `target` in `metric`.
    pub fn first_at_or_below(&self, metric: Metric, target: f64) -> Option<ConvergencePoint> {
        self.points
            .iter()
            .find(|p| metric.of(&p.metrics).is_some_and(|e| e <= target))
            .copied()
    }

    /// Least-squares slope of log error against log frames over the second half of the curve
    /// (at least 4 points), `None` with fewer.
    pub fn tail_slope(&self, metric: Metric) -> Option<f64> {
        let tail: Vec<(f64, f64)> = self.points[self.points.len() / 2..]
            .iter()
            .filter_map(|p| {
                let e = metric.of(&p.metrics)?;
                (e > 0.0 && e.is_finite()).then(|| ((p.frames as f64).ln(), e.ln()))
            })
            .collect();
        if tail.len() < 4 {
            return None;
        }
        let n = tail.len() as f64;
        let (mx, my) = (
            tail.iter().map(|p| p.0).sum::<f64>() / n,
            tail.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let sxx: f64 = tail.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = tail.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        (sxx > 0.0).then(|| sxy / sxx)
    }
}

/// How many frames a method needs to reach the target.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FramesToReach {
    /// Measured: the running mean of this many frames is at or below the target.
    Reached { frames: u32, time_ms: f64 },
    /// Still above the target at the last frame, still falling with log-log `slope`: the
    /// power law's frame count, at the measured mean time per frame.
    Extrapolated {
        frames: f64,
        time_ms: f64,
        slope: f64,
    },
    /// Still above the target and no longer falling (its bias), or too few frames to fit.
    NotReached,
}

impl FramesToReach {
    /// Milliseconds to reach the target, measured or extrapolated.
    pub fn time_ms(self) -> Option<f64> {
        match self {
            FramesToReach::Reached { time_ms, .. }
            | FramesToReach::Extrapolated { time_ms, .. } => Some(time_ms),
            FramesToReach::NotReached => None,
        }
    }
}

/// One method's row.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FramesToErrorRow {
    pub method: String,
    pub reach: FramesToReach,
    /// Frames rendered, and the error of their mean.
    pub frames_run: u32,
    pub last_error: f64,
    pub frame_ms: f64,
    /// This method's time to the target over the target method's (> 1: slower).
    pub time_ratio: Option<f64>,
    /// Its warm-up's milliseconds.
    #[serde(default)]
    pub warm_up_ms: f64,
    /// The same ratio with each method charged its warm-up (the target's too).
    #[serde(default)]
    pub time_ratio_with_warm_up: Option<f64>,
}

/// Frames and milliseconds each method needs to reach the error of `target_method`'s first frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FramesToErrorTable {
    pub metric: Metric,
    pub target_method: String,
    pub target_error: f64,
    pub rows: Vec<FramesToErrorRow>,
}

/// The error of `target_method`'s first frame in `metric`.
pub fn first_frame_error(
    series: &[ConvergenceSeries],
    metric: Metric,
    target_method: &str,
) -> Result<f64> {
    let s = series
        .iter()
        .find(|s| s.method == target_method)
        .ok_or_else(|| EvalError::InvalidParameter {
            name: "target method",
            reason: format!("no frames of method '{target_method}'"),
        })?;
    s.points
        .first()
        .and_then(|p| metric.of(&p.metrics))
        .filter(|e| e.is_finite() && *e > 0.0)
        .ok_or_else(|| {
            EvalError::NotEnoughData(format!(
                "method '{target_method}' has no positive finite {} at its first frame",
                metric.label()
            ))
        })
}

/// When `s` reaches `target` in `metric` (see the module's notes on extrapolation).
pub fn frames_to_reach(s: &ConvergenceSeries, metric: Metric, target: f64) -> FramesToReach {
    if let Some(p) = s.first_at_or_below(metric, target) {
        return FramesToReach::Reached {
            frames: p.frames,
            time_ms: p.time_ms,
        };
    }
    let (Some(last), Some(slope), Some(frame_ms)) =
        (s.points.last(), s.tail_slope(metric), s.frame_ms())
    else {
        return FramesToReach::NotReached;
    };
    let Some(e) = metric.of(&last.metrics) else {
        return FramesToReach::NotReached;
    };
    if slope > PLATEAU_SLOPE {
        return FramesToReach::NotReached;
    }
    let frames = last.frames as f64 * (target / e).powf(1.0 / slope);
    FramesToReach::Extrapolated {
        frames,
        time_ms: frames * frame_ms,
        slope,
    }
}

/// The table over `series` for the error of `target_method`'s first frame.
pub fn frames_to_error_table(
    series: &[ConvergenceSeries],
    metric: Metric,
    target_method: &str,
) -> Result<FramesToErrorTable> {
    let target_error = first_frame_error(series, metric, target_method)?;
    let reach: Vec<FramesToReach> = series
        .iter()
        .map(|s| frames_to_reach(s, metric, target_error))
        .collect();
    let target = series
        .iter()
        .zip(&reach)
        .find(|(s, _)| s.method == target_method);
    let target_ms = target.and_then(|(_, r)| r.time_ms());
    let target_warm_ms = target.and_then(|(s, r)| r.time_ms().map(|t| t + s.warm_up_ms));
    let rows = series
        .iter()
        .zip(reach)
        .map(|(s, reach)| FramesToErrorRow {
            method: s.method.clone(),
            reach,
            frames_run: s.points.last().map_or(0, |p| p.frames),
            last_error: s
                .points
                .last()
                .and_then(|p| metric.of(&p.metrics))
                .unwrap_or(f64::NAN),
            frame_ms: s.frame_ms().unwrap_or(f64::NAN),
            time_ratio: reach.time_ms().zip(target_ms).map(|(t, t0)| t / t0),
            warm_up_ms: s.warm_up_ms,
            time_ratio_with_warm_up: reach
                .time_ms()
                .zip(target_warm_ms)
                .map(|(t, t0)| (t + s.warm_up_ms) / t0),
        })
        .collect();
    Ok(FramesToErrorTable {
        metric,
        target_method: target_method.to_string(),
        target_error,
        rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A curve whose MAPE is `a · frames^slope + floor`.
    fn series(
        name: &str,
        frames: u32,
        a: f64,
        slope: f64,
        floor: f64,
        ms: f64,
    ) -> ConvergenceSeries {
        ConvergenceSeries {
            method: name.into(),
            points: (1..=frames)
                .map(|n| ConvergencePoint {
                    frames: n,
                    time_ms: n as f64 * ms,
                    metrics: ErrorMetrics {
                        mse: 0.0,
                        rel_mse: 0.0,
                        mape: a * (n as f64).powf(slope) + floor,
                        flip: None,
                    },
                })
                .collect(),
            warm_up_ms: 0.0,
        }
    }

    #[test]
    fn reached_extrapolated_and_plateaued_curves() {
        let s = [
            series("fast", 4, 0.1, -0.5, 0.0, 10.0),
            // Reaches 0.1 at frame 16 (0.4/√16 = 0.1).
            series("pt", 64, 0.4, -0.5, 0.0, 1.0),
            // Needs (1.6/0.1)² = 256 frames; run for 64.
            series("slow", 64, 1.6, -0.5, 0.0, 2.0),
            // Settles at 0.2 > 0.1.
            series("biased", 64, 0.0001, -0.5, 0.2, 1.0),
        ];
        let t = frames_to_error_table(&s, Metric::Mape, "fast").unwrap();
        assert!((t.target_error - 0.1).abs() < 1e-12);
        assert_eq!(
            t.rows[0].reach,
            FramesToReach::Reached {
                frames: 1,
                time_ms: 10.0
            }
        );
        assert_eq!(
            t.rows[1].reach,
            FramesToReach::Reached {
                frames: 16,
                time_ms: 16.0
            }
        );
        assert!((t.rows[1].time_ratio.unwrap() - 1.6).abs() < 1e-12);
        // Charged their warm-ups (the target 90 ms, pt none): (16 + 0) / (10 + 90).
        let mut warm = s.clone();
        warm[0].warm_up_ms = 90.0;
        let tw = frames_to_error_table(&warm, Metric::Mape, "fast").unwrap();
        assert!((tw.rows[1].time_ratio_with_warm_up.unwrap() - 0.16).abs() < 1e-12);
        assert!((tw.rows[0].time_ratio_with_warm_up.unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(tw.rows[1].time_ratio, t.rows[1].time_ratio);
        match t.rows[2].reach {
            FramesToReach::Extrapolated {
                frames,
                time_ms,
                slope,
            } => {
                assert!((slope + 0.5).abs() < 1e-9, "slope {slope}");
                assert!((frames - 256.0).abs() < 1e-6, "frames {frames}");
                assert!((time_ms - 512.0).abs() < 1e-6);
            }
            r => panic!("expected an extrapolation, got {r:?}"),
        }
        assert_eq!(t.rows[3].reach, FramesToReach::NotReached);
        assert!(frames_to_error_table(&s, Metric::Mape, "missing").is_err());
    }
}
