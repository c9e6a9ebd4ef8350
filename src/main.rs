//! `nrc`: the neural radiance cache command line.
//!
//! Subcommands: `render` (the reference path tracer, or rendering from a cache snapshot),
//! `train` (the online loop), `compare` (methods against a reference), `reference`, `info`
//! and `bench` (measured throughput). Every failure is reported as one `error: ...` line and a
//! non-zero exit status.

mod bench;
mod compare;
mod info;
mod reference;
mod render;
mod train;

use clap::{CommandFactory, Parser, Subcommand};

/// Neural radiance cache trainer and reference renderer.
#[derive(Parser, Debug)]
#[command(name = "nrc", version, about, long_about = None)]
struct Cli {
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
}

fn main() -> std::process::ExitCode {
    let args = match nrc_harness::run_file::expand(std::env::args_os().collect(), &Cli::command()) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            return std::process::ExitCode::FAILURE;
        }
    };
    let cli = Cli::parse_from(args);
    // The documented-commands test checks that a command parses, without running it.
    if std::env::var_os("NRC_PARSE_ONLY").is_some() {
        return std::process::ExitCode::SUCCESS;
    }
    let result = match cli.command {
        Command::Render(a) => render::run(&a),
        Command::Info(a) => info::run(&a),
        Command::Bench(b) => bench::run(&b),
        Command::Reference(a) => reference::run(&a),
        Command::Compare(a) => compare::run(&a),
        Command::Train(a) => train::run(&a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes, outermost first, on one line. A cause whose text the message
/// already contains (errors that print their source themselves) is not repeated.
fn one_line(e: &anyhow::Error) -> String {
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
