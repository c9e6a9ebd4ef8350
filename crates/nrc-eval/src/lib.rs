//! Estimator evaluation for the neural radiance cache: how far a rendering method is from the
//! reference, how much of that is bias and how much noise, how stable it is over time, and how
//! fast it gets there.
//!
//! - [`metrics`]: MSE, relMSE, MAPE; [`hdr_flip`](mod@hdr_flip) (with the LDR core in [`flip`]): HDR-FLIP,
//!   checked against NVIDIA's published tool on the fixtures in `tests/fixtures/flip`;
//! - [`bias_variance`](mod@bias_variance): bias² and variance from R independent renders;
//! - [`concentration`](mod@concentration): where the error sits (the worst 1 % of pixels, the
//!   pixels that see an emitter);
//! - [`temporal`]: frame-to-frame change and the error measures |E|, |E′|;
//! - [`sweep`]: error against time, "time to reach the error of X";
//! - [`convergence`]: frames to equal error (progressive frames of one state, the
//!   DDGI-resampling paper's Table 1);
//! - [`report`], [`plot`], [`png_output`]: `report.md` / `report.json`, error-against-time
//!   plots (PNG and SVG), false-colour error images; every file written atomically ([`atomic`]).
//!
//! Examples: `synthetic_report` runs the whole pipeline on synthetic renders;
//! `flip_bench` times HDR-FLIP and the other metrics (`cargo run --release -p nrc-eval
//! --example flip_bench -- 1280 720 3`).
//!
//! Images are plain row-major `[[f32; 3]]` linear-RGB slices wrapped in an [`ImageView`], so any
//! image type plugs in:
//!
//! ```
//! use nrc_eval::{ImageView, metrics::{mse, rel_mse, REL_MSE_EPSILON}};
//! let reference = vec![[1.0f32; 3]; 4];
//! let render = vec![[1.5f32; 3]; 4];
//! let r = ImageView::new("reference", 2, 2, &reference)?;
//! let x = ImageView::new("render", 2, 2, &render)?;
//! assert_eq!(mse(&x, &r)?, 0.25);
//! assert!((rel_mse(&x, &r, REL_MSE_EPSILON)? - 0.25 / 1.01).abs() < 1e-12);
//! # Ok::<(), nrc_eval::EvalError>(())
//! ```

pub mod atomic;
pub mod bias_variance;
pub mod concentration;
pub mod convergence;
pub mod error;
pub mod flip;
mod flip_color;
pub mod hdr_flip;
pub mod image;
pub mod metrics;
pub mod plot;
pub mod png_output;
pub mod report;
pub mod sweep;
pub mod temporal;

pub use bias_variance::{BiasVariance, BiasVarianceAccumulator, bias_variance};
pub use concentration::{ErrorConcentration, concentration, mean_concentration};
pub use error::{EvalError, Result};
pub use hdr_flip::{HdrFlipParams, HdrFlipResult, ToneMapper, hdr_flip};
pub use image::{ImageView, RgbImage, ScalarImage};
pub use metrics::{ErrorMetrics, Metric, MetricOptions, compute_metrics};
pub use report::{PassCost, Report, ReportRow, write_report};
pub use sweep::{SweepPoint, SweepSeries, TimeToReach, time_to_reach};
pub use temporal::{TemporalAccumulator, TemporalStats, TrackedLuminance, temporal_stats};
