//! Run files: a whole run described by one JSON document, as tiny-cuda-nn describes a model.
//! `nrc train --run run.json [flags]` (and `render`, `compare`): every field of the object is
//! the subcommand's flag of the same name (`snake_case` or `kebab-case`), so the run file's
//! schema is the command's help; flags given on the command line override the file's.
//!
//! ```json
//! { "scene": "scenes/cornell-box.gltf", "camera_path": "scenes/orbit.json",
//!   "producer": "mix:pt-sl=0.5,sppc=0.5", "pass": "cache-first", "frames": 200,
//!   "records": 16384, "config": { "encoding": { "otype": "HashGrid", ... }, ... } }
//! ```
//!
//! Values: strings and numbers as on the command line, `true` for a switch (`false` or `null`:
//! left out), three numbers `[x, y, z]` for a vector, a list for a comma-separated list, and
//! for `config` an inline cache configuration object as well as a preset name or file. Paths
//! are relative to the working directory, as on the command line.

use std::ffi::OsString;
use std::path::Path;

use anyhow::{Context, Result, bail};

/// The command line with the run file named by `--run FILE` or `--run=FILE` (after the
/// subcommand) expanded into flags, placed before the command line's own. A field whose flag
/// the command line also gives is left out, so the command line overrides it (list flags such
/// as `--methods` included, which would otherwise add up). `command` is the program's command
/// line (its subcommands' flags are the fields a run file may hold).
pub fn expand(args: Vec<OsString>, command: &clap::Command) -> Result<Vec<OsString>> {
    let file = args.iter().enumerate().find_map(|(i, a)| {
        let a = a.to_str()?;
        if a == "--run" {
            Some(args.get(i + 1).cloned())
        } else {
            a.strip_prefix("--run=").map(|f| Some(OsString::from(f)))
        }
    });
    let Some(file) = file else {
        return Ok(args);
    };
    let Some(file) = file else {
        bail!("--run needs a run file");
    };
    let Some(sub) = args.get(1).and_then(|s| s.to_str()) else {
        bail!("--run needs a subcommand before it");
    };
    // Flags the command line gives itself (`--flag` or `--flag=value`).
    let given: Vec<&str> = args[2..]
        .iter()
        .filter_map(|a| a.to_str()?.strip_prefix("--"))
        .map(|a| a.split_once('=').map_or(a, |(flag, _)| flag))
        .collect();
    let flags = flags_of(Path::new(&file), command, sub, &given)?;
    let mut out = args[..2].to_vec();
    out.extend(flags);
    out.extend(args[2..].iter().cloned());
    Ok(out)
}

/// The run file's fields as flags of subcommand `sub`, but for the flags in `given`.
fn flags_of(
    path: &Path,
    command: &clap::Command,
    sub: &str,
    given: &[&str],
) -> Result<Vec<OsString>> {
    let what = || format!("run file {}", path.display());
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", what()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not JSON", what()))?;
    let Some(sub_cmd) = command.find_subcommand(sub) else {
        bail!("{}: unknown subcommand `{sub}`", what());
    };
    fields_to_flags(&value, sub_cmd, &what(), given)
}

/// The fields of the JSON object `value` as flags of the command `sub_cmd` (the run file's
/// conversion: see the module documentation), but for the flags in `given`; `what` names the
/// object in errors (the run file, or the keyword arguments of a Python call).
pub fn fields_to_flags(
    value: &serde_json::Value,
    sub_cmd: &clap::Command,
    what: &str,
    given: &[&str],
) -> Result<Vec<OsString>> {
    let what = || what.to_string();
    let sub = sub_cmd.get_name();
    let Some(fields) = value.as_object() else {
        bail!("{}: expected an object of flags", what());
    };
    let known: Vec<String> = sub_cmd
        .get_arguments()
        .filter_map(|a| a.get_long().map(str::to_string))
        .collect();
    let mut flags = Vec::new();
    for (key, v) in fields {
        let flag = key.replace('_', "-");
        if flag == "run" || !known.contains(&flag) {
            bail!(
                "{}: unknown field `{key}` (the fields are the flags of `nrc {sub}`: see `nrc {sub} --help`)",
                what()
            );
        }
        if given.contains(&flag.as_str()) {
            continue;
        }
        let text = match v {
            serde_json::Value::Null | serde_json::Value::Bool(false) => continue,
            serde_json::Value::Bool(true) => None,
            serde_json::Value::String(s) => Some(s.clone()),
            serde_json::Value::Number(n) => Some(n.to_string()),
            serde_json::Value::Array(items) => {
                let parts: Option<Vec<String>> = items
                    .iter()
                    .map(|x| match x {
                        serde_json::Value::String(s) => Some(s.clone()),
                        serde_json::Value::Number(n) => Some(n.to_string()),
                        _ => None,
                    })
                    .collect();
                let Some(parts) = parts else {
                    bail!("{}: field `{key}`: a list holds strings or numbers", what());
                };
                Some(parts.join(","))
            }
            serde_json::Value::Object(_) if flag == "config" => Some(v.to_string()),
            serde_json::Value::Object(_) => {
                bail!("{}: field `{key}` cannot be an object", what())
            }
        };
        flags.push(OsString::from(format!("--{flag}")));
        flags.extend(text.map(OsString::from));
    }
    Ok(flags)
}

#[cfg(test)]
mod tests {
    use clap::{CommandFactory, Parser};
    use rand::SeedableRng;

    use crate::options::{RadianceCacheArgs, SceneArgs};

    /// A command line with a `train` subcommand holding the shared option groups and flags of
    /// every kind (the program's own is in the binary crate, above this one).
    #[derive(Parser, Debug)]
    struct Cli {
        #[command(subcommand)]
        command: Command,
    }

    #[derive(clap::Subcommand, Debug)]
    enum Command {
        Train(Box<Train>),
        Info,
    }

    #[derive(clap::Args, Debug)]
    struct Train {
        #[arg(long)]
        run: Option<std::path::PathBuf>,
        #[command(flatten)]
        scene: SceneArgs,
        #[arg(long, default_value = "pt-sl")]
        producer: nrc_train::ProducerSpec,
        #[arg(long, default_value_t = 64)]
        frames: u32,
        #[arg(long, default_value_t = 256)]
        width: u32,
        #[arg(long, default_value_t = 256)]
        height: u32,
        #[arg(long)]
        no_nee: bool,
        #[arg(long)]
        pass: Option<nrc_render::PassSpec>,
        #[arg(long, default_value_t = 0.0)]
        from_terminations: f32,
        #[arg(long)]
        camera_path: Option<std::path::PathBuf>,
        #[command(flatten)]
        cache: RadianceCacheArgs,
    }

    /// A run file of `train` with every kind of value: strings, numbers, a switch, null, an
    /// inline cache configuration (the shipped hash-grid preset).
    fn run_file() -> String {
        format!(
            r#"{{
  "scene": "scenes/cornell-box.gltf", "producer": "mix:pt-sl=0.5,sppc=0.5",
  "frames": 200, "records": 16384, "width": 128, "height": 96, "no_nee": true,
  "pass": null, "from_terminations": 0.25, "camera_path": "orbit.json",
  "config": {}
}}"#,
            include_str!("../../../models/nrc-hashgrid.json")
        )
    }

    /// Mutation test of run files (issue 21): the run file above mutated by the seeded mutator
    /// of `nrc_scene::testing`; expanding it and parsing the command line (and its inline
    /// configuration) gives a command or an error, never a panic or a hang.
    #[test]
    fn mutated_run_files_expand_or_fail_cleanly() {
        let dir = tempfile::tempdir().unwrap();
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(21);
        let mut tally = nrc_scene::testing::Tally::default();
        let limits = (std::time::Duration::from_secs(20), usize::MAX);
        // The unmutated file parses (its configuration too, or the test would test nothing).
        let parse = |path: std::path::PathBuf| {
            move || {
                let args = vec!["nrc".into(), "train".into(), "--run".into(), path.into()];
                let args = super::expand(args, &Cli::command()).ok()?;
                match Cli::try_parse_from(args).ok()?.command {
                    Command::Train(t) => Some(t.cache.config().is_ok()),
                    Command::Info => Some(false),
                }
            }
        };
        let seed = dir.path().join("run.json");
        let text = run_file();
        std::fs::write(&seed, &text).unwrap();
        assert_eq!(parse(seed)(), Some(true), "the seed run file parses");
        for case in 0..400 {
            let mutated = nrc_scene::testing::mutate(text.as_bytes(), true, &mut rng);
            let path = dir.path().join(format!("run-{case}.json"));
            std::fs::write(&path, &mutated).unwrap();
            let label = format!("{case}-run.json");
            // A parsed run whose inline configuration is refused counts as a clean error.
            let load = parse(path);
            tally.case("run file", &label, &mutated, limits, move || {
                load().filter(|ok| *ok)
            });
        }
        println!("{}", tally.summary());
        tally.assert_clean();
        let (_, loaded, refused) = tally.kinds["run file"];
        assert!(
            loaded > 0 && refused > 0,
            "{loaded} parsed, {refused} refused"
        );
    }
}
