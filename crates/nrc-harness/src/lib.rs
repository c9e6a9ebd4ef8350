//! # nrc-harness: the evaluation harness
//!
//! Everything `nrc compare`, `nrc reference` and `nrc bench` do besides parsing arguments and
//! printing:
//!
//! - [`methods`]: the method registry, one [`MethodSpec`] (pass × radiance source ×
//!   producers), building each method's state;
//! - [`bench`]: the path tracer's benchmark (`nrc bench trace`);
//! - [`budget`]: the [`Method`] trait, budgets (equal samples, equal time) and the frame loop;
//! - [`compare`]: the comparison loop (errors, bias and variance, sweeps, the report, the
//!   images) and the `runs.json` schema ([`compare::RunsFile`]);
//! - [`options`]: the option groups every command shares (scene and camera, depth, the cache
//!   model and its training), deriving clap's `Args`;
//! - [`progress`]: progress of long runs (a bar on a terminal, a line every few seconds in
//!   logs);
//! - [`reference`]: the reference store (references cached by the content of their scene and
//!   settings, with their variance);
//!
//! - [`run`]: a run of the online loop (camera paths, the frame loop and its outputs, the
//!   statistics file, the snapshot's scene check).
//! - [`run_file`]: run files (a run's flags as one JSON document, `--run FILE`);
//! - [`sequence`]: comparisons over animated sequences (per-frame references, |E| and |E′|).
//!
//! The CLI (`src/` of the workspace root) parses arguments into these types and prints.

pub mod bench;
pub mod budget;
pub mod compare;
pub mod error;
pub mod methods;
pub mod options;
pub mod progress;
pub mod reference;
pub mod run;
pub mod run_file;
pub mod sequence;
pub mod study;

pub use budget::{Budget, Estimate, Frame, FrameRequest, Method, render_frame};
pub use methods::{CacheMethodSettings, MethodList, MethodSpec};
