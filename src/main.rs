//! `nrc`: the neural radiance cache command line (the commands live in the library, `lib.rs`).
//! Every failure is reported as one `error: ...` line and a non-zero exit status.

use clap::Parser;

fn main() -> std::process::ExitCode {
    // Before anything else: a CPU without the build's SIMD level gets a line, not SIGILL.
    if let Err(e) = nrc_scene::cpu::check() {
        eprintln!("error: {e}");
        return std::process::ExitCode::FAILURE;
    }
    let args = match nrc::expand(std::env::args_os().collect()) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {}", nrc::one_line(&e));
            return std::process::ExitCode::FAILURE;
        }
    };
    // The documented-commands test checks that a command parses, without running it.
    let parse_only = std::env::var_os("NRC_PARSE_ONLY").is_some();
    let result = match nrc::merge_dir(&args) {
        Some(_) if parse_only => return std::process::ExitCode::SUCCESS,
        Some(dir) => nrc::merge(&dir),
        None => {
            let cli = nrc::Cli::parse_from(&args);
            if parse_only {
                return std::process::ExitCode::SUCCESS;
            }
            nrc::run(cli, &args)
        }
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", nrc::one_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}
