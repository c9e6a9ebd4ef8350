//! `nrc`: the neural radiance cache command line, as a library (the `nrc` program and the
//! Python module `nrc` both run its commands).
//!
//! Subcommands: `render` (the reference path tracer, or rendering from a cache snapshot),
//! `train` (the online loop), `compare` (methods against a reference), `reference`, `info`,
//! `export` (a snapshot as portable weights), `bench` (measured throughput) and `view` (the
//! online loop live in a window). Every failure
//! is an error whose [`one_line`] is the program's `error: ...` line.

mod bench;
mod compare;
mod export;
mod info;
mod reference;
pub mod render;
mod study;
pub mod train;
pub mod view;

use std::ffi::OsString;

use clap::{CommandFactory, Parser, Subcommand};

/// Neural radiance cache trainer and reference renderer.
#[derive(Parser, Debug)]
#[command(name = "nrc", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a scene with the unbiased reference path tracer and write an EXR.
    Render(render::RenderArgs),
    /// Print what a scene holds: triangles, materials, lights, bounds and camera.
    Info(info::InfoArgs),
    /// Measure throughput.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Render (or find in the cache) a reference image with its per-pixel variance.
    Reference(reference::ReferenceArgs),
    /// Compare rendering methods against a reference: errors, bias and variance, equal-time
    /// and equal-sample studies, report, plots and images.
    Compare(Box<compare::CompareArgs>),
    /// Train a neural radiance cache online on a scene: per frame produce training records,
    /// train, and render with paths ending in the cache; statistics, frames and a snapshot.
    Train(Box<train::TrainArgs>),
    /// Export a neural cache snapshot as portable weights (safetensors) and a
    /// tiny-cuda-nn–style JSON description of the encoding and network (docs/export.md).
    Export(export::ExportArgs),
    /// Watch the online loop live in a window: the cache learning, fly controls, the passes,
    /// debug views and plots (`--headless` for pictures without a display).
    View(Box<view::ViewArgs>),
    /// Run jobs of a study planned by `nrc compare --plan DIR` (a job whose result exists is
    /// skipped).
    Job(study::JobArgs),
}

/// The command line (program name first) with a run file (`--run FILE`) expanded into flags.
pub fn expand(args: Vec<OsString>) -> anyhow::Result<Vec<OsString>> {
    nrc_harness::run_file::expand(args, &Cli::command())
}

/// Runs a parsed command; `argv` is the command line it was parsed from (run files expanded),
/// which a study's plan records.
pub fn run(cli: Cli, argv: &[OsString]) -> anyhow::Result<()> {
    match cli.command {
        Command::Render(a) => render::run(&a),
        Command::Info(a) => info::run(&a),
        Command::Bench(b) => bench::run(&b),
        Command::Reference(a) => reference::run(&a),
        Command::Compare(a) => match &a.plan {
            Some(dir) => study::plan(&a, argv, dir),
            None => compare::run(&a),
        },
        Command::Train(a) => train::run(&a),
        Command::Export(a) => export::run(&a),
        Command::Job(a) => study::job(&a),
        Command::View(a) => view::run(&a),
    }
}

/// The study folder of `nrc compare --merge DIR` (the flag alone: the settings are the plan's,
/// so clap's required flags of `compare` do not apply), if that is the command line.
pub fn merge_dir(argv: &[OsString]) -> Option<std::path::PathBuf> {
    let words: Vec<&str> = argv
        .iter()
        .skip(1)
        .map(|a| a.to_str())
        .collect::<Option<_>>()?;
    match words.as_slice() {
        ["compare", "--merge", dir] => Some(dir.into()),
        ["compare", flag] => flag.strip_prefix("--merge=").map(Into::into),
        _ => None,
    }
}

/// `nrc compare --merge DIR`.
pub fn merge(dir: &std::path::Path) -> anyhow::Result<()> {
    study::merge(dir)
}

/// The first line of clap's message for a malformed command line, without its `error: `
/// (the program's one error line, and the Python module's exception text).
pub fn clap_message(e: &clap::Error) -> String {
    let text = e.render().to_string();
    text.lines()
        .map(|l| l.trim_start_matches("error: ").trim())
        .find(|l| !l.is_empty())
        .unwrap_or("malformed command line")
        .to_string()
}

/// Parses a command line (program name first, run files expanded), returning clap's message
/// as the error's first line instead of exiting.
fn try_parse(args: &[OsString]) -> anyhow::Result<Cli> {
    Cli::try_parse_from(args).map_err(|e| anyhow::anyhow!(clap_message(&e)))
}

/// Expands, parses and runs a command line (program name first) as the program would, but
/// returns every failure, a malformed command line included (with clap's message), instead of
/// exiting.
pub fn run_args(args: Vec<OsString>) -> anyhow::Result<()> {
    let args = expand(args)?;
    if let Some(dir) = merge_dir(&args) {
        return merge(&dir);
    }
    // Help and version are printed, as the program prints them, not errors.
    if let Err(e) = Cli::try_parse_from(&args)
        && matches!(
            e.kind(),
            clap::error::ErrorKind::DisplayHelp | clap::error::ErrorKind::DisplayVersion
        )
    {
        print!("{}", e.render());
        return Ok(());
    }
    let cli = try_parse(&args)?;
    run(cli, &args)
}

/// The error and its causes, outermost first, on one line. A cause whose text the message
/// already contains (errors that print their source themselves) is not repeated.
pub fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line.replace('\n', " ")
}
