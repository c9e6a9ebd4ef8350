//! `nrc`: the neural radiance cache command line.
//!
//! Subcommands: `render` (the reference path tracer), `info` (what a scene holds) and
//! `bench` (measured throughput). Every failure is reported as one `error: ...` line and a
//! non-zero exit status.

mod args;
mod bench;
mod info;
mod render;
mod scene_args;

use clap::{Parser, Subcommand};

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
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(a) => render::run(&a),
        Command::Info(a) => info::run(&a),
        Command::Bench(b) => bench::run(&b),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line: the error and its causes, outermost first.
            eprintln!("error: {}", format!("{e:#}").replace('\n', " "));
            std::process::ExitCode::FAILURE
        }
    }
}
