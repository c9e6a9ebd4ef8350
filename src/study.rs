//! Studies split into jobs (`nrc compare --plan DIR`, `nrc job DIR K`, `nrc compare --merge
//! DIR`): the command-line side of [`nrc_harness::study`], which says what a plan, a job and a
//! result are.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail, ensure};
use nrc_harness::budget::Budget;
use nrc_harness::compare::{Progress as Step, compare_runs, ready_method, run_frame};
use nrc_harness::progress::{Progress, Unit};
use nrc_harness::reference;
use nrc_harness::study::{
    self, JobKind, JobOutput, Plan, ReferencePlan, StoredFrames, read_all, read_result,
    write_result,
};

use crate::compare::{CompareArgs, comparison, print_report, reference_request, validate};

/// Arguments of `nrc job`.
#[derive(clap::Args, Debug)]
pub struct JobArgs {
    /// The study folder (`nrc compare --plan DIR`).
    pub dir: PathBuf,

    /// The job to run (0 … jobs − 1, as `plan.json` lists them).
    #[arg(required_unless_present = "all")]
    pub job: Option<usize>,

    /// Run every job without a result, in order (reference chunks first).
    #[arg(long, conflicts_with = "job")]
    pub all: bool,

    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// The flags a plan does not record: its own, and the worker threads (each job's runner
/// chooses its own).
const NOT_RECORDED: [&str; 3] = ["--plan", "--chunks", "--threads"];

/// The comparison's command line after `compare`, without the flags a plan does not record.
fn recorded_args(argv: &[OsString]) -> Result<Vec<String>> {
    let words: Vec<String> = argv
        .iter()
        .skip(2)
        .map(|a| {
            a.to_str()
                .map(str::to_string)
                .context("the command line is not UTF-8")
        })
        .collect::<Result<_>>()?;
    let mut out = Vec::new();
    let mut skip_value = false;
    for w in words {
        if skip_value {
            skip_value = false;
            continue;
        }
        if NOT_RECORDED.contains(&w.as_str()) {
            skip_value = true;
            continue;
        }
        if NOT_RECORDED.iter().any(|f| w.starts_with(&format!("{f}="))) {
            continue;
        }
        out.push(w);
    }
    Ok(out)
}

/// `nrc compare --plan DIR`: writes the plan.
pub fn plan(args: &CompareArgs, argv: &[OsString], dir: &Path) -> Result<()> {
    validate(args)?;
    ensure!(
        args.chunks >= 1,
        "--chunks must be at least 1, got {}",
        args.chunks
    );
    let scene = args.scene.load()?;
    let content = reference::scene_content_hash(&args.scene.scene)?;
    let reference = args.reference.is_none().then_some(ReferencePlan {
        spp: args.reference_spp,
        chunks: args.chunks.min(args.reference_spp.max(1)),
    });
    let names: Vec<String> = args.methods().iter().map(|m| m.to_string()).collect();
    let plan = Plan::new(recorded_args(argv)?, &content, reference, &names, args.runs)?;
    plan.write(dir)?;
    let chunks = plan
        .jobs
        .iter()
        .filter(|j| matches!(j.kind, JobKind::ReferenceChunk { .. }))
        .count();
    println!(
        "planned {} jobs ({chunks} reference chunks, {} methods × {} runs) of {} ({} triangles) in {}: run `nrc job {} K` for K in 0..{} (or --all) from {}, then `nrc compare --merge {}`",
        plan.jobs.len(),
        names.len(),
        args.runs,
        args.scene.scene.display(),
        scene.triangle_count(),
        dir.join(study::PLAN_FILE).display(),
        dir.display(),
        plan.jobs.len(),
        plan.cwd.display(),
        dir.display()
    );
    Ok(())
}

/// The comparison a plan records, parsed as `nrc compare` parses it, and the plan checked
/// against it and the scene as it is now ([`Plan::check`]).
fn planned_args(plan: &Plan) -> Result<CompareArgs> {
    let mut argv: Vec<OsString> = vec!["nrc".into(), "compare".into()];
    argv.extend(plan.args.iter().map(OsString::from));
    let args = match crate::try_parse(&argv)
        .context("the plan's command line does not parse with this program")?
        .command
    {
        crate::Command::Compare(a) => *a,
        _ => bail!("the plan's command line is not a comparison"),
    };
    let content = reference::scene_content_hash(&args.scene.scene).with_context(|| {
        format!(
            "the study's scene (run jobs and the merge from the folder it was planned in, {}, or a copy of it)",
            plan.cwd.display()
        )
    })?;
    let names: Vec<String> = args.methods().iter().map(|m| m.to_string()).collect();
    plan.check(&content, &names, args.runs)?;
    Ok(args)
}

/// The plan's scene, loaded (relative paths are the plan's working directory's).
fn planned_scene(args: &CompareArgs, plan: &Plan) -> Result<nrc_scene::Scene> {
    args.scene.load().with_context(|| {
        format!(
            "the study's scene (run jobs and the merge from the folder it was planned in, {}, or a copy of it)",
            plan.cwd.display()
        )
    })
}

/// `nrc job DIR K` (or `--all`).
pub fn job(a: &JobArgs) -> Result<()> {
    let plan = Plan::read(&a.dir)?;
    let args = planned_args(&plan)?;
    let budget = validate(&args)?;
    let ids: Vec<usize> = match a.job {
        Some(k) => vec![plan.job(k)?.id],
        None => (0..plan.jobs.len()).collect(),
    };
    let pool = nrc_harness::options::thread_pool(a.threads)?;
    let scene = planned_scene(&args, &plan)?;
    pool.install(|| -> Result<()> {
        for k in ids {
            let job = plan.job(k)?;
            if let Ok(Some(_)) = read_result(&a.dir, &plan, job) {
                eprintln!("job {k}: its result exists ({}): skipped", job.output);
                continue;
            }
            let (output, seconds) = study::timed(|| run_job(&args, budget, &scene, &job.kind))?;
            let path = write_result(&a.dir, &plan, job, &output, seconds)?;
            let what = match (&job.kind, &output) {
                (JobKind::ReferenceChunk { first, end }, _) => {
                    format!("reference samples {first}..{end}")
                }
                (JobKind::Run { run, .. }, JobOutput::Run { name, .. }) => {
                    format!("run {run} of {name}")
                }
                _ => String::new(),
            };
            println!("job {k} ({what}): {seconds:.2} s, {}", path.display());
        }
        Ok(())
    })
}

fn run_job(
    args: &CompareArgs,
    budget: Budget,
    scene: &nrc_scene::Scene,
    kind: &JobKind,
) -> Result<JobOutput> {
    match kind {
        JobKind::ReferenceChunk { first, end } => {
            let req = reference_request(args, scene);
            let (moments, _) = nrc_render::render_moments(
                scene,
                &scene.camera,
                &req.estimator(),
                (req.width, req.height),
                req.seed,
                *first..*end,
                &|_| {},
            );
            Ok(JobOutput::Chunk(moments))
        }
        JobKind::Run { method, run, .. } => {
            let c = comparison(args, budget, scene, false)?;
            let spec = c
                .methods
                .get(*method)
                .with_context(|| format!("the plan has no method {method}"))?;
            let mut m = ready_method(&c, scene, spec)?;
            let frame = run_frame(&c, scene, m.as_mut(), *run)?;
            Ok(JobOutput::Run {
                name: m.name().to_string(),
                frame,
            })
        }
    }
}

/// `nrc compare --merge DIR`.
pub fn merge(dir: &Path) -> Result<()> {
    let plan = Plan::read(dir)?;
    let args = planned_args(&plan)?;
    let budget = validate(&args)?;
    let results = read_all(dir, &plan)?;
    if matches!(budget, Budget::Time(_)) && !args.allow_mixed_machines {
        let mut kinds: Vec<String> = results
            .iter()
            .filter(|(m, _)| matches!(m.kind, JobKind::Run { .. }))
            .map(|(m, _)| m.machine.describe())
            .collect();
        kinds.sort();
        kinds.dedup();
        ensure!(
            kinds.len() <= 1,
            "the runs were timed on {} kinds of machine ({}): their equal-time frames are not comparable (run every job with the same --threads on one kind of machine, or plan with --allow-mixed-machines)",
            kinds.len(),
            kinds.join("; ")
        );
    }
    let scene = planned_scene(&args, &plan)?;
    let c = comparison(&args, budget, &scene, false)?;
    std::fs::create_dir_all(&c.out)
        .with_context(|| format!("cannot create output folder {}", c.out.display()))?;
    let req = reference_request(&args, &scene);
    let reference = match (&args.reference, &plan.reference) {
        (Some(path), _) => {
            let r = reference::load_given(path, args.width, args.height)?;
            reference::check_given(&r, &req)?;
            r
        }
        (None, _) => reference::obtain_from(&req, &args.cache.dir(), false, &|| {
            study::merged_reference(&results)
                .context("the study's reference chunks do not merge (another image size?)")
        })?,
    };
    eprintln!(
        "reference: {} {}",
        if reference.reused {
            "reused"
        } else {
            "merged from the study's chunks into"
        },
        reference.location.display()
    );
    let stored = StoredFrames::new(&results);
    let progress = Progress::new(
        c.methods.len() as u64 * u64::from(c.runs),
        Unit::Frames,
        "merge",
    );
    let (report, markdown) = compare_runs(&c, &scene, &reference, Some(&stored), &|p| match p {
        Step::Method(name) => progress.set_message(name),
        Step::Frame => progress.inc(1),
    })?;
    progress.finish();
    print_report(&report, &markdown, &c.out);
    Ok(())
}
