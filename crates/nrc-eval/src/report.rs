//! The comparison report: one row per method (time per frame, samples, MSE, relMSE, MAPE, FLIP,
//! bias², variance), optional temporal statistics, sweeps and time-to-error tables; written as
//! `report.md` (a table a person reads at a glance, the best value of each error column in bold)
//! and `report.json` (the same data, serde).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::atomic::atomic_write;
use crate::bias_variance::BiasVariance;
use crate::concentration::ErrorConcentration;
use crate::convergence::{ConvergenceSeries, FramesToErrorTable, FramesToReach};
use crate::error::{EvalError, Result};
use crate::metrics::{ErrorMetrics, MAPE_EPSILON, REL_MSE_EPSILON};
use crate::sweep::{SweepSeries, TimeToErrorTable, TimeToReach};
use crate::temporal::TemporalStats;

/// One method's results.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReportRow {
    pub method: String,
    /// Mean wall time per frame, milliseconds.
    pub time_per_frame_ms: f64,
    /// Samples per pixel per frame (or the method's budget unit).
    pub samples_per_pixel: f64,
    #[serde(flatten)]
    pub metrics: ErrorMetrics,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bias_variance: Option<BiasVariance>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temporal: Option<TemporalStats>,
    /// Where the error sits (mean over runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub concentration: Option<ErrorConcentration>,
    /// What a pass cost (mean over runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cost: Option<PassCost>,
}

/// What one pass of a method (one estimate at its stated samples per pixel) cost, as means
/// over runs: where a resampling frame's time goes, against a path-traced sample's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PassCost {
    /// Wall time per pass, ms (a frame's wall time over its passes).
    pub ms_per_pass: f64,
    /// Rays per pixel per pass, closest-hit and shadow.
    pub rays_per_pixel: f64,
    /// Milliseconds per pass in each phase the pass times (empty where it times none).
    pub phases: Vec<(String, f64)>,
}

/// Whether `method` names the path tracer at a fixed sample count (`pt-4spp`): the unit of
/// the cost table.
fn is_path_tracer(method: &str) -> bool {
    method
        .strip_prefix("pt-")
        .and_then(|s| s.strip_suffix("spp"))
        .is_some_and(|n| n.parse::<u32>().is_ok())
}

/// A whole comparison.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub title: String,
    #[serde(default)]
    pub scene: Option<String>,
    pub width: usize,
    pub height: usize,
    /// How the reference was made, e.g. "path tracer, 4096 spp".
    #[serde(default)]
    pub reference: Option<String>,
    /// ε of relMSE used for the rows.
    pub rel_mse_epsilon: f64,
    /// ε of MAPE used for the rows.
    pub mape_epsilon: f64,
    #[serde(default)]
    pub notes: Vec<String>,
    pub rows: Vec<ReportRow>,
    #[serde(default)]
    pub sweeps: Vec<SweepSeries>,
    #[serde(default)]
    pub time_to_error: Vec<TimeToErrorTable>,
    /// Progressive frames of each method (running-mean error after each frame).
    #[serde(default)]
    pub convergence: Vec<ConvergenceSeries>,
    #[serde(default)]
    pub frames_to_error: Vec<FramesToErrorTable>,
}

impl Report {
    /// An empty report with the default metric settings.
    pub fn new(title: impl Into<String>, width: usize, height: usize) -> Self {
        Self {
            title: title.into(),
            scene: None,
            width,
            height,
            reference: None,
            rel_mse_epsilon: REL_MSE_EPSILON,
            mape_epsilon: MAPE_EPSILON,
            notes: Vec::new(),
            rows: Vec::new(),
            sweeps: Vec::new(),
            time_to_error: Vec::new(),
            convergence: Vec::new(),
            frames_to_error: Vec::new(),
        }
    }

    /// The report as Markdown.
    pub fn to_markdown(&self) -> String {
        let mut md = String::new();
        let _ = writeln!(md, "# {}\n", self.title);
        let mut facts = Vec::new();
        if let Some(s) = &self.scene {
            facts.push(format!("scene `{s}`"));
        }
        facts.push(format!("{}×{} pixels", self.width, self.height));
        if let Some(r) = &self.reference {
            facts.push(format!("reference: {r}"));
        }
        let _ = writeln!(md, "{}.\n", facts.join(", "));

        if !self.rows.is_empty() {
            self.rows_table(&mut md);
        }
        if self.rows.iter().any(|r| r.concentration.is_some()) {
            self.concentration_table(&mut md);
        }
        if self.rows.iter().any(|r| r.cost.is_some()) {
            self.cost_table(&mut md);
        }
        if self.rows.iter().any(|r| r.temporal.is_some()) {
            self.temporal_table(&mut md);
        }
        for t in &self.time_to_error {
            time_to_error_markdown(t, &mut md);
        }
        for t in &self.frames_to_error {
            frames_to_error_markdown(t, &mut md);
        }
        if !self.sweeps.is_empty() {
            self.sweep_table(&mut md);
        }
        let _ = writeln!(
            md,
            "Errors per colour channel, averaged over pixels: MSE (x−y)², relMSE (x−y)²/(y²+{}), MAPE |x−y|/(y+{}); \
             FLIP is mean HDR-FLIP (ACES exposures from the reference). bias² is corrected for the noise of the mean of R renders; \
             variance is that of one render. Best value per column in **bold**.",
            self.rel_mse_epsilon, self.mape_epsilon
        );
        for n in &self.notes {
            let _ = writeln!(md, "\n{n}");
        }
        md
    }

    fn rows_table(&self, md: &mut String) {
        let bv = |r: &ReportRow, f: fn(&BiasVariance) -> f64| r.bias_variance.as_ref().map(f);
        let columns: [(&str, Vec<Option<f64>>, bool); 6] = [
            (
                "MSE",
                self.rows.iter().map(|r| Some(r.metrics.mse)).collect(),
                false,
            ),
            (
                "relMSE",
                self.rows.iter().map(|r| Some(r.metrics.rel_mse)).collect(),
                false,
            ),
            (
                "MAPE",
                self.rows.iter().map(|r| Some(r.metrics.mape)).collect(),
                false,
            ),
            (
                "FLIP",
                self.rows.iter().map(|r| r.metrics.flip).collect(),
                false,
            ),
            (
                "bias²",
                self.rows.iter().map(|r| bv(r, |b| b.bias_sq)).collect(),
                true,
            ),
            (
                "variance",
                self.rows.iter().map(|r| bv(r, |b| b.variance)).collect(),
                false,
            ),
        ];
        let _ = write!(md, "| method | time/frame (ms) | spp |");
        for (name, _, _) in &columns {
            let _ = write!(md, " {name} |");
        }
        let _ = write!(md, "\n|---|---:|---:|");
        for _ in &columns {
            let _ = write!(md, "---:|");
        }
        md.push('\n');
        // The best of a column is its smallest value (for bias², the one closest to zero).
        let best: Vec<Option<f64>> = columns
            .iter()
            .map(|(_, v, by_abs)| {
                v.iter()
                    .flatten()
                    .map(|&x| if *by_abs { x.abs() } else { x })
                    .fold(None, |m: Option<f64>, x| Some(m.map_or(x, |m| m.min(x))))
            })
            .collect();
        for (i, r) in self.rows.iter().enumerate() {
            let _ = write!(
                md,
                "| {} | {} | {} |",
                r.method,
                fmt_num(r.time_per_frame_ms),
                fmt_num(r.samples_per_pixel)
            );
            for ((_, v, by_abs), b) in columns.iter().zip(&best) {
                let cell = match v[i] {
                    None => "–".to_string(),
                    Some(x) => {
                        let key = if *by_abs { x.abs() } else { x };
                        if self.rows.len() > 1 && Some(key) == *b {
                            format!("**{}**", fmt_num(x))
                        } else {
                            fmt_num(x)
                        }
                    }
                };
                let _ = write!(md, " {cell} |");
            }
            md.push('\n');
        }
        md.push('\n');
    }

    fn concentration_table(&self, md: &mut String) {
        let _ = writeln!(
            md,
            "## Where the error is
"
        );
        let _ = writeln!(
            md,
            "| method | MSE | share in the worst 1 % of pixels | share in pixels seeing an emitter | 99.9th percentile of pixel squared error |\n|---|---:|---:|---:|---:|"
        );
        let pct = |x: f64| format!("{:.0} %", 100.0 * x);
        for r in &self.rows {
            let Some(c) = &r.concentration else { continue };
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} |",
                r.method,
                fmt_num(r.metrics.mse),
                pct(c.top_percent),
                c.emitters.map_or("–".to_string(), pct),
                fmt_num(c.p999)
            );
        }
        let _ = writeln!(
            md,
            "\nShares of each run's summed squared error (per pixel, the mean over channels), averaged over runs; \
             the pixels seeing an emitter are those a 4×4 grid of rays per pixel finds on one, and their 8 neighbours: \
             their anti-aliasing noise only more camera samples lower.\n"
        );
    }

    fn cost_table(&self, md: &mut String) {
        let _ = writeln!(md, "## Where the time goes\n");
        // A path-traced sample's time, from the first path-tracer row.
        let sample_ms = self
            .rows
            .iter()
            .find(|r| {
                is_path_tracer(&r.method) && r.samples_per_pixel > 0.0 && r.time_per_frame_ms > 0.0
            })
            .map(|r| (r.method.clone(), r.time_per_frame_ms / r.samples_per_pixel));
        let _ = writeln!(
            md,
            "| method | ms per pass | path-traced samples per pass | rays per pixel per pass | phases (ms per pass) |\n|---|---:|---:|---:|---|"
        );
        for r in &self.rows {
            let Some(c) = &r.cost else { continue };
            let in_samples = sample_ms.as_ref().map_or("–".to_string(), |(_, ms)| {
                format!("{:.2}", c.ms_per_pass / ms)
            });
            let phases: Vec<String> = c
                .phases
                .iter()
                .filter(|(_, ms)| *ms >= 0.05)
                .map(|(n, ms)| format!("{n} {ms:.1}"))
                .collect();
            let named: f64 = c.phases.iter().map(|(_, ms)| ms).sum();
            let phases = if phases.is_empty() {
                "–".to_string()
            } else {
                format!("{}; rest {:.1}", phases.join(", "), c.ms_per_pass - named)
            };
            let _ = writeln!(
                md,
                "| {} | {} | {in_samples} | {:.1} | {phases} |",
                r.method,
                fmt_num(c.ms_per_pass),
                c.rays_per_pixel
            );
        }
        let unit = sample_ms.map_or(
            "no path tracer at fixed samples was compared, so no unit".to_string(),
            |(m, ms)| format!("one sample of `{m}`, {} ms", fmt_num(ms)),
        );
        let _ = writeln!(
            md,
            "\nA pass is one estimate at the method's stated samples per pixel; its time is the frame's wall time over its \
             passes (a trained cache's training included), its rays those the pass traced (closest-hit and shadow; the \
             training records' not included). The rest is the time outside the named phases (for the path tracer and the \
             passes that name none, their whole trace; for the others a cache's training, the outline's extra \
             camera rays, the frame's averaging). Path-traced samples per pass: against {unit}.\n"
        );
    }

    fn temporal_table(&self, md: &mut String) {
        let _ = writeln!(md, "## Temporal stability\n");
        let _ = writeln!(
            md,
            "| method | frames | mean abs. change | abs. error E | abs. error change E′ |\n|---|---:|---:|---:|---:|"
        );
        for r in &self.rows {
            if let Some(t) = &r.temporal {
                let opt = |v: Option<f64>| v.map_or("–".to_string(), fmt_num);
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | {} | {} |",
                    r.method,
                    t.frames,
                    fmt_num(t.mean_abs_change),
                    opt(t.mean_abs_error),
                    opt(t.mean_abs_error_change)
                );
            }
        }
        md.push('\n');
    }

    fn sweep_table(&self, md: &mut String) {
        let _ = writeln!(md, "## Sweep: error against time\n");
        let _ = writeln!(
            md,
            "| method | time/frame (ms) | spp | MSE | relMSE | MAPE | FLIP |\n|---|---:|---:|---:|---:|---:|---:|"
        );
        for s in &self.sweeps {
            for p in &s.points {
                let m = &p.metrics;
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | {} | {} | {} | {} |",
                    s.method,
                    fmt_num(p.time_ms),
                    fmt_num(p.samples_per_pixel),
                    fmt_num(m.mse),
                    fmt_num(m.rel_mse),
                    fmt_num(m.mape),
                    m.flip.map_or("–".to_string(), fmt_num)
                );
            }
        }
        md.push('\n');
    }
}

fn time_to_error_markdown(t: &TimeToErrorTable, md: &mut String) {
    let _ = writeln!(
        md,
        "## Time to reach the {} of {} at {} ms ({})\n",
        t.metric.label(),
        t.baseline,
        fmt_num(t.baseline_time_ms),
        fmt_num(t.target_error)
    );
    let _ = writeln!(md, "| method | time (ms) | speed-up |\n|---|---:|---:|");
    for r in &t.rows {
        let time = match r.time {
            TimeToReach::Interpolated(v) => fmt_num(v),
            TimeToReach::AtMost(v) => format!("≤ {}", fmt_num(v)),
            TimeToReach::NotReached => "not reached".to_string(),
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} |",
            r.method,
            time,
            r.speedup.map_or("–".to_string(), |s| format!("{:.2}×", s))
        );
    }
    md.push('\n');
}

fn frames_to_error_markdown(t: &FramesToErrorTable, md: &mut String) {
    let _ = writeln!(
        md,
        "## Frames to reach the {} of {}'s first frame ({})\n",
        t.metric.label(),
        t.target_method,
        fmt_num(t.target_error)
    );
    let _ = writeln!(
        md,
        "| method | frames | time (ms) | × {}'s time | warm-up (ms) | × with warm-ups | ms per frame | frames run | {} of their mean |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        t.target_method,
        t.metric.label()
    );
    for r in &t.rows {
        let (frames, time) = match r.reach {
            FramesToReach::Reached { frames, time_ms } => (frames.to_string(), fmt_num(time_ms)),
            FramesToReach::Extrapolated {
                frames,
                time_ms,
                slope,
            } => (
                format!(
                    "≈ {} (extrapolated, slope {slope:.2})",
                    fmt_num(frames.round())
                ),
                format!("≈ {}", fmt_num(time_ms)),
            ),
            FramesToReach::NotReached => ("not reached".into(), "–".into()),
        };
        let _ = writeln!(
            md,
            "| {} | {frames} | {time} | {} | {} | {} | {} | {} | {} |",
            r.method,
            r.time_ratio
                .map_or("–".to_string(), |x| format!("{}×", fmt_num(x))),
            fmt_num(r.warm_up_ms),
            r.time_ratio_with_warm_up
                .map_or("–".to_string(), |x| format!("{}×", fmt_num(x))),
            fmt_num(r.frame_ms),
            r.frames_run,
            fmt_num(r.last_error)
        );
    }
    let _ = writeln!(
        md,
        "\nEach method renders consecutive frames of the static view from one state after its untimed warm-up, averaged \
         progressively; \"frames\" is the first count whose mean is at or below the target, \"time\" their timed milliseconds. \
         A method still above the target is extrapolated along the power law of its curve's second half when that still \
         falls faster than frames^{}, else \"not reached\" (its bias). \"Warm-up\" is the untimed start of the method's state \
         (its history, probes or online-trained cache); \"× with warm-ups\" charges every method its own, the target's too.\n",
        crate::convergence::PLATEAU_SLOPE
    );
}

/// Four significant digits; scientific notation outside [1e-3, 1e5).
pub fn fmt_num(v: f64) -> String {
    if !v.is_finite() {
        return v.to_string();
    }
    if v == 0.0 {
        return "0".to_string();
    }
    let a = v.abs();
    if (1e-3..1e5).contains(&a) {
        let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
        format!("{v:.decimals$}")
    } else {
        format!("{v:.3e}")
    }
}

/// Paths of a written report.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReportFiles {
    pub markdown: PathBuf,
    pub json: PathBuf,
}

/// Writes `report.md` and `report.json` into `dir` (created if missing), each atomically.
pub fn write_report(dir: &Path, report: &Report) -> Result<ReportFiles> {
    std::fs::create_dir_all(dir).map_err(|source| EvalError::Io {
        action: "creating directory",
        path: dir.to_path_buf(),
        source,
    })?;
    let files = ReportFiles {
        markdown: dir.join("report.md"),
        json: dir.join("report.json"),
    };
    let json = serde_json::to_string_pretty(report).map_err(|source| EvalError::Json {
        path: files.json.clone(),
        source,
    })?;
    atomic_write(&files.json, json.as_bytes())?;
    atomic_write(&files.markdown, report.to_markdown().as_bytes())?;
    Ok(files)
}

/// Reads a `report.json` written by [`write_report`].
pub fn read_report_json(path: &Path) -> Result<Report> {
    let text = std::fs::read_to_string(path).map_err(|source| EvalError::Io {
        action: "reading",
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| EvalError::Json {
        path: path.to_path_buf(),
        source,
    })
}
