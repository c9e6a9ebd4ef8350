//! Studies split into jobs: a comparison (`nrc compare`) written as a plan of independent jobs
//! that any scheduler can run (`nrc job`, a Ray driver, a Slurm job array), then merged into
//! the report the single process would have written (`nrc compare --merge`).
//!
//! **Plan** (`DIR/plan.json`): the comparison's command line (run files expanded), the working
//! directory it was planned in (its relative paths are relative to it), the machine (CPU model,
//! cores, threads: equal-time frames are comparable only within one kind), a content
//! key (SHA-256 over the format, the command line and the scene's content), and the jobs:
//! - *reference chunks*: samples `first..end` of every pixel of the reference. A pixel's
//!   sample `s` depends only on the seed, the pixel and `s` ([`nrc_render::render_moments`]),
//!   so the chunks' moments merge ([`Moments::merge`]) into the mean and variance of a single
//!   render of all the samples, up to the order of the float sums;
//! - *runs*: run `r` of method `i`, built, prepared, warmed up and restarted as the single
//!   process does for each run ([`crate::compare::run_frame`]), its frame rendered within the
//!   budget.
//!
//! **Results** (`DIR/jobs/NNNN.safetensors`, one file per job, written atomically: a killed job
//! leaves none): the chunk's moments (f64) or the run's image (f32), with JSON metadata (the
//! plan's key, the job, what it measured, its wall time and machine) under the key
//! `nrc_study`. A result is refused at merge when it belongs to another plan or job, or does
//! not parse; missing results are listed, never merged into a partial report.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail, ensure};
use nrc_render::Moments;
use nrc_render::passes::PhaseTimes;
use nrc_scene::Image;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::budget::Frame;
use crate::compare::StoredRuns;

/// Format tag of plans and results. 2: a run's frame carries its rays and phase times, and
/// the DDGI passes' defaults changed (probe rays sized to the frame, history cap 5), so a
/// plan of the first format does not mix with this build's results. 3: the DDGI passes'
/// default probe counts follow the frame (updated in turn) and young probes average their
/// first updates. 4: `wsrestir-gi` and `wsrestir-gi-biased` split their gathered light over
/// two camera rays by default (`split=2`), so a plan naming them meant another estimator.
pub const FORMAT: &str = "nrc-study/4";
/// The plan's file name in a study folder.
pub const PLAN_FILE: &str = "plan.json";
const METADATA_KEY: &str = "nrc_study";

/// Where a job ran or a plan was made.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Machine {
    /// The CPU model (`/proc/cpuinfo`'s model name, or the architecture).
    pub cpu: String,
    /// Logical cores available to the process.
    pub cores: usize,
    /// Worker threads the job rendered with (its rayon pool's; a plan records the planner's).
    pub threads: usize,
}

impl Machine {
    /// This machine.
    pub fn this() -> Self {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|t| {
                t.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split_once(':'))
                    .map(|(_, v)| v.trim().to_string())
            })
            .unwrap_or_else(|| std::env::consts::ARCH.to_string());
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        Self {
            cpu,
            cores,
            threads: rayon::current_num_threads(),
        }
    }

    /// The kind of machine times are comparable on: the CPU model, core count and threads
    /// (an equal-time frame on one thread holds half the passes of one on two).
    pub fn describe(&self) -> String {
        format!(
            "{} × {} cores, {} thread(s)",
            self.cpu, self.cores, self.threads
        )
    }
}

/// One job of a plan.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Job {
    pub id: usize,
    #[serde(flatten)]
    pub kind: JobKind,
    /// The result file, relative to the study folder.
    pub output: String,
}

/// What a job computes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum JobKind {
    /// Samples `first..end` of every pixel of the reference.
    ReferenceChunk { first: u32, end: u32 },
    /// Run `run` of the method at `method` in the comparison's list (`name` as listed).
    Run {
        method: usize,
        name: String,
        run: u32,
    },
}

/// The reference the chunks make.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferencePlan {
    pub spp: u32,
    pub chunks: u32,
}

/// `plan.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub format: String,
    /// SHA-256 (hex) of the format, the command line and the scene's content.
    pub key: String,
    /// The `nrc compare` command line after `compare` (run files expanded, the plan's own
    /// flags removed).
    pub args: Vec<String>,
    /// The working directory the plan was made in: relative paths in `args` are relative to it.
    pub cwd: PathBuf,
    /// The machine it was planned on.
    pub machine: Machine,
    /// The reference's chunks, where the reference is not given or stored already.
    pub reference: Option<ReferencePlan>,
    pub jobs: Vec<Job>,
}

/// The content key of a plan.
pub fn plan_key(args: &[String], scene_content: &str) -> String {
    let mut h = Sha256::new();
    h.update(FORMAT.as_bytes());
    for a in args {
        h.update([0]);
        h.update(a.as_bytes());
    }
    h.update([1]);
    h.update(scene_content.as_bytes());
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// Splits `spp` samples into `chunks` ranges of nearly equal size (at least one sample each).
pub fn chunk_ranges(spp: u32, chunks: u32) -> Vec<(u32, u32)> {
    let chunks = chunks.clamp(1, spp.max(1));
    (0..chunks)
        .map(|k| {
            let a = (u64::from(spp) * u64::from(k) / u64::from(chunks)) as u32;
            let b = (u64::from(spp) * u64::from(k + 1) / u64::from(chunks)) as u32;
            (a, b)
        })
        .collect()
}

/// The jobs of a plan: the `reference` chunks (if any), then one job per method and run.
pub fn jobs_for(reference: Option<&ReferencePlan>, methods: &[String], runs: u32) -> Vec<Job> {
    let mut jobs = Vec::new();
    let mut push = |kind: JobKind| {
        let id = jobs.len();
        jobs.push(Job {
            id,
            kind,
            output: format!("jobs/{id:04}.safetensors"),
        });
    };
    if let Some(r) = reference {
        for (first, end) in chunk_ranges(r.spp, r.chunks) {
            push(JobKind::ReferenceChunk { first, end });
        }
    }
    for (method, name) in methods.iter().enumerate() {
        for run in 0..runs {
            push(JobKind::Run {
                method,
                name: name.clone(),
                run,
            });
        }
    }
    jobs
}

impl Plan {
    /// Checks the plan against what its command line plans (`methods`, `runs`) and the scene
    /// it names now (`scene_content`): the key, and the job list (so that no edited job can
    /// write outside `jobs/` or make a wrong reference).
    pub fn check(&self, scene_content: &str, methods: &[String], runs: u32) -> Result<()> {
        ensure!(
            plan_key(&self.args, scene_content) == self.key,
            "the study's scene or settings changed since it was planned (its key no longer matches): run jobs and the merge from {} with the files it was planned with",
            self.cwd.display()
        );
        if let Some(r) = &self.reference {
            ensure!(
                r.chunks >= 1 && r.chunks <= r.spp.max(1),
                "the plan's reference has {} chunks for {} samples",
                r.chunks,
                r.spp
            );
        }
        ensure!(
            self.jobs == jobs_for(self.reference.as_ref(), methods, runs),
            "the plan's job list is not the one its settings give (edited?): plan the study again"
        );
        Ok(())
    }

    /// A plan of `reference` chunks (if any) and one run job per method and run.
    pub fn new(
        args: Vec<String>,
        scene_content: &str,
        reference: Option<ReferencePlan>,
        methods: &[String],
        runs: u32,
    ) -> Result<Self> {
        let key = plan_key(&args, scene_content);
        let jobs = jobs_for(reference.as_ref(), methods, runs);
        Ok(Self {
            format: FORMAT.into(),
            key,
            args,
            cwd: std::env::current_dir().context("the working directory")?,
            machine: Machine::this(),
            reference,
            jobs,
        })
    }

    /// Writes `DIR/plan.json` (atomically) and creates `DIR/jobs`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir.join("jobs"))
            .with_context(|| format!("cannot create the study folder {}", dir.display()))?;
        let json = serde_json::to_string_pretty(self).expect("a plan serialises");
        nrc_scene::image::write_atomic(&dir.join(PLAN_FILE), json.as_bytes())?;
        Ok(())
    }

    /// Reads `DIR/plan.json`.
    pub fn read(dir: &Path) -> Result<Self> {
        let path = dir.join(PLAN_FILE);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("cannot read the study plan {}", path.display()))?;
        let plan: Plan = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a study plan", path.display()))?;
        ensure!(
            plan.format == FORMAT,
            "{} has format {}, this program reads {FORMAT}",
            path.display(),
            plan.format
        );
        Ok(plan)
    }

    /// Job `k`.
    pub fn job(&self, k: usize) -> Result<&Job> {
        self.jobs.get(k).with_context(|| {
            format!(
                "no job {k}: the plan has {} (0 to {})",
                self.jobs.len(),
                self.jobs.len().saturating_sub(1)
            )
        })
    }
}

/// What a result file says of itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResultMeta {
    pub format: String,
    pub plan_key: String,
    pub job: usize,
    #[serde(flatten)]
    pub kind: JobKind,
    /// Wall time of the job, seconds (set-up included).
    pub seconds: f64,
    pub machine: Machine,
    /// A chunk: samples merged and those that were NaN or infinite.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub invalid_samples: Option<u64>,
    /// A run: the frame (its method's name as built, what the budget gave).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameMeta>,
}

/// A run's frame, but its image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameMeta {
    pub method: String,
    pub passes: u32,
    pub samples_per_pixel: u64,
    pub elapsed_ns: u64,
    pub longest_pass_ns: u64,
    pub invalid_samples: u64,
    pub warm_frames: Option<u32>,
    /// Rays traced and phase times, summed over the passes.
    pub rays: u64,
    pub phases: PhaseTimes,
}

/// What a job produced.
pub enum JobOutput {
    Chunk(Moments),
    Run { name: String, frame: Frame },
}

/// Writes job `job`'s result into the study folder `dir`, atomically.
pub fn write_result(
    dir: &Path,
    plan: &Plan,
    job: &Job,
    output: &JobOutput,
    seconds: f64,
) -> Result<PathBuf> {
    let mut meta = ResultMeta {
        format: FORMAT.into(),
        plan_key: plan.key.clone(),
        job: job.id,
        kind: job.kind.clone(),
        seconds,
        machine: Machine::this(),
        samples: None,
        invalid_samples: None,
        frame: None,
    };
    let (tensors, shape): (Vec<(&str, Vec<u8>, Dtype)>, Vec<usize>) = match output {
        JobOutput::Chunk(m) => {
            meta.samples = Some(m.count);
            meta.invalid_samples = Some(m.invalid_samples);
            let bytes = |v: &[[f64; 3]]| -> Vec<u8> {
                v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect()
            };
            (
                vec![
                    ("mean", bytes(&m.mean), Dtype::F64),
                    ("m2", bytes(&m.m2), Dtype::F64),
                ],
                vec![m.height as usize, m.width as usize, 3],
            )
        }
        JobOutput::Run { name, frame } => {
            meta.frame = Some(FrameMeta {
                method: name.clone(),
                passes: frame.passes,
                samples_per_pixel: frame.samples_per_pixel,
                elapsed_ns: frame.elapsed.as_nanos() as u64,
                longest_pass_ns: frame.longest_pass.as_nanos() as u64,
                invalid_samples: frame.invalid_samples,
                warm_frames: frame.warm_frames,
                rays: frame.rays,
                phases: frame.phases,
            });
            let bytes: Vec<u8> = frame
                .image
                .data
                .iter()
                .flat_map(|p| p.to_array())
                .flat_map(|x| x.to_le_bytes())
                .collect();
            (
                vec![("image", bytes, Dtype::F32)],
                vec![frame.image.height, frame.image.width, 3],
            )
        }
    };
    let path = dir.join(&job.output);
    let mut views = Vec::new();
    for (name, bytes, dtype) in &tensors {
        views.push((
            name.to_string(),
            TensorView::new(*dtype, shape.clone(), bytes)
                .map_err(|e| anyhow::anyhow!("cannot encode {name}: {e}"))?,
        ));
    }
    let metadata = HashMap::from([(
        METADATA_KEY.to_string(),
        serde_json::to_string(&meta).expect("metadata serialises"),
    )]);
    let data = safetensors::tensor::serialize(views, Some(metadata))
        .map_err(|e| anyhow::anyhow!("cannot encode the result of job {}: {e}", job.id))?;
    nrc_scene::image::write_atomic(&path, &data)?;
    Ok(path)
}

/// Job `job`'s result in `dir`, checked against the plan: `Ok(None)` when there is none yet,
/// an error when it is corrupt or belongs to another plan or job.
pub fn read_result(dir: &Path, plan: &Plan, job: &Job) -> Result<Option<(ResultMeta, JobOutput)>> {
    let path = dir.join(&job.output);
    let bytes = match std::fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let bad =
        |why: String| anyhow::anyhow!("the result of job {} ({}) {why}", job.id, path.display());
    let (_, header) =
        SafeTensors::read_metadata(&bytes).map_err(|e| bad(format!("is corrupt: {e}")))?;
    let text = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get(METADATA_KEY))
        .ok_or_else(|| bad("is not a study result".into()))?;
    let meta: ResultMeta =
        serde_json::from_str(text).map_err(|e| bad(format!("has bad metadata: {e}")))?;
    if meta.plan_key != plan.key {
        let short = |k: &str| k.chars().take(12).collect::<String>();
        return Err(bad(format!(
            "belongs to another plan (key {}…, this plan {}…)",
            short(&meta.plan_key),
            short(&plan.key)
        )));
    }
    if meta.job != job.id || meta.kind != job.kind {
        return Err(bad(format!("is the result of job {} instead", meta.job)));
    }
    let tensors = SafeTensors::deserialize(&bytes).map_err(|e| bad(format!("is corrupt: {e}")))?;
    let read = |name: &str, dtype: Dtype| -> Result<(Vec<u8>, Vec<usize>)> {
        let t = tensors
            .tensor(name)
            .map_err(|e| bad(format!("lacks the tensor {name}: {e}")))?;
        if t.dtype() != dtype || t.shape().len() != 3 || t.shape()[2] != 3 {
            return Err(bad(format!("has a malformed tensor {name}")));
        }
        Ok((t.data().to_vec(), t.shape().to_vec()))
    };
    let output = match &job.kind {
        JobKind::ReferenceChunk { first, end } => {
            let (mean, shape) = read("mean", Dtype::F64)?;
            let (m2, shape2) = read("m2", Dtype::F64)?;
            ensure!(
                shape == shape2,
                "{}",
                bad("has tensors of two shapes".into())
            );
            let triples = |b: &[u8]| -> Vec<[f64; 3]> {
                b.chunks_exact(24)
                    .map(|c| {
                        std::array::from_fn(|k| {
                            f64::from_le_bytes(c[8 * k..8 * k + 8].try_into().expect("8 bytes"))
                        })
                    })
                    .collect()
            };
            let count = meta.samples.unwrap_or(0);
            let want = u64::from(end.saturating_sub(*first));
            ensure!(
                count == want,
                "{}",
                bad(format!("holds {count} samples, the job {want}"))
            );
            ensure!(
                shape[0] * shape[1] * 24 == mean.len(),
                "{}",
                bad("has tensors of the wrong size".into())
            );
            JobOutput::Chunk(Moments {
                width: shape[1] as u32,
                height: shape[0] as u32,
                count,
                mean: triples(&mean),
                m2: triples(&m2),
                invalid_samples: meta.invalid_samples.unwrap_or(0),
            })
        }
        JobKind::Run { .. } => {
            let (data, shape) = read("image", Dtype::F32)?;
            ensure!(
                shape[0] * shape[1] * 12 == data.len(),
                "{}",
                bad("has an image of the wrong size".into())
            );
            let f = meta
                .frame
                .clone()
                .ok_or_else(|| bad("lacks its frame's measurements".into()))?;
            let pixels = data
                .chunks_exact(12)
                .map(|c| {
                    glam::Vec3::from_array(std::array::from_fn(|k| {
                        f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().expect("4 bytes"))
                    }))
                })
                .collect();
            let image = Image::from_data(shape[1], shape[0], pixels)
                .ok_or_else(|| bad("has a malformed image".into()))?;
            JobOutput::Run {
                name: f.method.clone(),
                frame: Frame {
                    image,
                    passes: f.passes,
                    samples_per_pixel: f.samples_per_pixel,
                    elapsed: Duration::from_nanos(f.elapsed_ns),
                    longest_pass: Duration::from_nanos(f.longest_pass_ns),
                    invalid_samples: f.invalid_samples,
                    warm_frames: f.warm_frames,
                    rays: f.rays,
                    phases: f.phases,
                },
            }
        }
    };
    Ok(Some((meta, output)))
}

/// Every result of the plan, read and checked: an error listing the missing jobs (or naming
/// the first bad result).
pub fn read_all(dir: &Path, plan: &Plan) -> Result<Vec<(ResultMeta, JobOutput)>> {
    let mut out = Vec::with_capacity(plan.jobs.len());
    let mut missing = Vec::new();
    for job in &plan.jobs {
        match read_result(dir, plan, job)? {
            Some(r) => out.push(r),
            None => missing.push(job.id),
        }
    }
    if !missing.is_empty() {
        bail!(
            "{} of {} jobs have no result yet (jobs {}): run them (`nrc job {} K`) before merging",
            missing.len(),
            plan.jobs.len(),
            list(&missing),
            dir.display()
        );
    }
    Ok(out)
}

/// `0-3, 7, 9-10`.
fn list(ids: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut i = 0;
    while i < ids.len() {
        let mut j = i;
        while j + 1 < ids.len() && ids[j + 1] == ids[j] + 1 {
            j += 1;
        }
        parts.push(if i == j {
            ids[i].to_string()
        } else {
            format!("{}-{}", ids[i], ids[j])
        });
        i = j + 1;
    }
    parts.join(", ")
}

/// The reference chunks' moments merged, and the seconds they took in all.
pub fn merged_reference(results: &[(ResultMeta, JobOutput)]) -> Option<(Moments, f64)> {
    let mut merged: Option<Moments> = None;
    let mut seconds = 0.0;
    for (meta, out) in results {
        if let JobOutput::Chunk(m) = out {
            seconds += meta.seconds;
            match &mut merged {
                None => merged = Some(m.clone()),
                Some(acc) => acc.merge(m).ok()?,
            }
        }
    }
    merged.map(|m| (m, seconds))
}

/// The run frames of a study's results, as the comparison loop reads them.
pub struct StoredFrames<'a> {
    results: &'a [(ResultMeta, JobOutput)],
}

impl<'a> StoredFrames<'a> {
    pub fn new(results: &'a [(ResultMeta, JobOutput)]) -> Self {
        Self { results }
    }

    fn find(&self, method: usize, run: u32) -> Result<(&str, &Frame)> {
        self.results
            .iter()
            .find_map(|(meta, out)| match (&meta.kind, out) {
                (
                    JobKind::Run {
                        method: m, run: r, ..
                    },
                    JobOutput::Run { name, frame },
                ) if *m == method && *r == run => Some((name.as_str(), frame)),
                _ => None,
            })
            .with_context(|| format!("the study has no run {run} of method {method}"))
    }
}

impl StoredRuns for StoredFrames<'_> {
    fn name(&self, method: usize) -> Result<String> {
        Ok(self.find(method, 0)?.0.to_string())
    }

    fn frame(&self, method: usize, run: u32) -> Result<Frame> {
        Ok(self.find(method, run)?.1.clone())
    }
}

/// Times a job.
pub fn timed<T>(f: impl FnOnce() -> Result<T>) -> Result<(T, f64)> {
    let start = Instant::now();
    let out = f()?;
    Ok((out, start.elapsed().as_secs_f64()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_cover_the_samples_once() {
        for (spp, chunks) in [(16, 1), (16, 3), (7, 7), (5, 9), (1000, 64)] {
            let r = chunk_ranges(spp, chunks);
            assert_eq!(r.first().unwrap().0, 0);
            assert_eq!(r.last().unwrap().1, spp);
            assert!(r.windows(2).all(|w| w[0].1 == w[1].0));
            assert!(r.iter().all(|(a, b)| b > a));
        }
    }

    #[test]
    fn lists_ranges() {
        assert_eq!(list(&[0, 1, 2, 3, 7, 9, 10]), "0-3, 7, 9-10");
        assert_eq!(list(&[4]), "4");
    }
}
