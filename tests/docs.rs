//! Every command in the fenced blocks of RESULTS.md and BENCHMARKS.md runs as written:
//! `nrc` commands parse (with `SCENE`/`PASS` placeholders filled by a shipped scene and a
//! pass, and `$M` by the block's own `M=`), their `--scene` files exist (or are under
//! `../shared/`), `cargo test` commands name a test target of their package, and scripts
//! exist.

use std::path::Path;
use std::process::Command;

/// The shell commands of the fenced blocks of `text`, continuation lines joined,
/// comments and `M=` definitions applied.
fn commands(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for block in text.split("```").skip(1).step_by(2) {
        let body = block.split_once('\n').map_or("", |(_, b)| b);
        let body = body.replace("\\\n", " ");
        let mut m = None;
        for line in body.lines() {
            let line = line.split(" #").next().unwrap_or("").trim();
            if let Some(v) = line.strip_prefix("M=") {
                m = Some(v.to_string());
                continue;
            }
            let mut line = line.to_string();
            if let Some(v) = &m {
                line = line.replace("$M", v);
            }
            out.push(line);
        }
    }
    out
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn check(command: &str) -> Result<bool, String> {
    let words: Vec<String> = command
        .replace("SCENE", "cornell-box")
        .replace("PASS", "restir-di")
        .replace(['[', ']'], "")
        .replace("spread|first", "spread")
        .split_whitespace()
        .map(String::from)
        .collect();
    let Some(first) = words.first() else {
        return Ok(false);
    };
    let nrc_args = match first.as_str() {
        "nrc" | "target/release/nrc" => Some(&words[1..]),
        "cargo" if words[1] == "run" => {
            let dash = words
                .iter()
                .position(|w| w == "--")
                .ok_or("cargo run without --")?;
            Some(&words[dash + 1..])
        }
        _ => None,
    };
    if let Some(args) = nrc_args {
        let out = Command::new(env!("CARGO_BIN_EXE_nrc"))
            .args(args)
            .env("NRC_PARSE_ONLY", "1")
            .current_dir(root())
            .output()
            .map_err(|e| e.to_string())?;
        if !out.status.success() {
            return Err(String::from_utf8_lossy(&out.stderr).into_owned());
        }
        for pair in args.windows(2).filter(|p| p[0] == "--scene") {
            let scene = Path::new(&pair[1]);
            if !scene.starts_with("../shared") && !root().join(scene).exists() {
                return Err(format!("no scene {}", scene.display()));
            }
        }
        return Ok(true);
    }
    if first == "cargo" && words[1] == "test" {
        let target = words
            .windows(2)
            .find(|p| p[0] == "--test")
            .map(|p| p[1].clone());
        let package = words
            .windows(2)
            .find(|p| p[0] == "-p")
            .map(|p| p[1].clone());
        if !words.iter().any(|w| w == "--workspace") && package.is_none() {
            return Err("neither --workspace nor -p: the test is looked for in nrc alone".into());
        }
        if let Some(t) = target {
            let dirs: Vec<std::path::PathBuf> = match package {
                Some(p) => vec![root().join("crates").join(p).join("tests")],
                None => std::fs::read_dir(root().join("crates"))
                    .map_err(|e| e.to_string())?
                    .map(|d| d.unwrap().path().join("tests"))
                    .chain([root().join("tests")])
                    .collect(),
            };
            if !dirs.iter().any(|d| d.join(format!("{t}.rs")).exists()) {
                return Err(format!("no test target {t}"));
            }
        }
        return Ok(true);
    }
    let script = words
        .iter()
        .find(|w| w.starts_with("scripts/"))
        .filter(|_| {
            matches!(first.as_str(), "python3" | "bash")
                || first.starts_with("scripts/")
                || first.starts_with("venv/")
        });
    if let Some(s) = script {
        if !root().join(s).exists() {
            return Err(format!("no script {s}"));
        }
        return Ok(true);
    }
    Ok(false)
}

#[test]
fn every_documented_command_runs_as_written() {
    let mut checked = 0;
    let mut failures = Vec::new();
    for doc in ["RESULTS.md", "BENCHMARKS.md"] {
        let text = std::fs::read_to_string(root().join(doc)).unwrap();
        for c in commands(&text) {
            match check(&c) {
                Ok(true) => checked += 1,
                Ok(false) => {}
                Err(e) => failures.push(format!("{doc}: `{c}`: {e}")),
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
    assert!(checked >= 20, "only {checked} commands found");
    // The check can fail: a flag that does not exist, a test target of another package.
    assert!(check("nrc render --scene scenes/cornell-box.gltf --no-such-flag").is_err());
    assert!(check("cargo test --release --test online long").is_err());
    assert!(check("nrc render --scene scenes/none.gltf --spp 1 --out x.exr").is_err());
}

/// The README's claim that files depend only on files below them: `scripts/import-cycles.py`
/// finds no file-level import cycle in any crate (it exits 1 and names the files otherwise).
#[test]
fn no_file_level_import_cycles() {
    let out = match Command::new("python3")
        .arg(root().join("scripts/import-cycles.py"))
        .output()
    {
        Ok(out) => out,
        Err(e) => {
            nrc_scene::testing::skipped("no_file_level_import_cycles", &format!("python3: {e}"));
            return;
        }
    };
    assert!(
        out.status.success(),
        "import cycles: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    // Control: a crate whose two files name each other is reported.
    let dir = tempfile::tempdir().expect("temporary directory");
    let src = dir.path().join("src");
    std::fs::create_dir(&src).expect("src");
    std::fs::write(src.join("lib.rs"), "mod a;\nmod b;\n").expect("lib.rs");
    std::fs::write(src.join("a.rs"), "use crate::b::B;\npub struct A;\n").expect("a.rs");
    std::fs::write(src.join("b.rs"), "use super::a::A;\npub struct B;\n").expect("b.rs");
    let control = Command::new("python3")
        .arg(root().join("scripts/import-cycles.py"))
        .arg(dir.path())
        .output()
        .expect("python3 ran above");
    let text = String::from_utf8_lossy(&control.stdout);
    assert!(
        control.status.code() == Some(1) && text.contains("a, b"),
        "the cycle a <-> b is not reported: {:?} {text}{}",
        control.status,
        String::from_utf8_lossy(&control.stderr)
    );
}
