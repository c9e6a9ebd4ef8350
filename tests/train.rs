//! End to end: `nrc train` writes statistics, frames and a snapshot; `nrc render --cache`
//! renders from the snapshot deterministically; bad input is a clear error.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn nrc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nrc"))
        .args(args)
        .output()
        .expect("nrc runs")
}

fn cornell() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box.gltf")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Failed cleanly: non-zero status, no panic, an `error: ...` line naming `needle`.
fn assert_error(out: &Output, needle: &str) {
    let err = text(&out.stderr);
    assert!(!out.status.success(), "succeeded: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(
        err.lines()
            .any(|l| l.starts_with("error: ") && l.contains(needle)),
        "{err}"
    );
}

#[test]
fn train_then_render_from_the_snapshot() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let scene = cornell();
    let out = nrc(&[
        "train",
        "--scene",
        scene.to_str().unwrap(),
        "--frames",
        "3",
        "--width",
        "32",
        "--height",
        "24",
        "--records",
        "2048",
        "--batch",
        "1024",
        "--snapshot",
        &p("c.nrc"),
        "--stats",
        &p("stats.csv"),
        "--frames-out",
        &p("frames"),
        "--every",
        "2",
        "--producer",
        "mix:pt-sl=0.5,sppc=0.5",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("trained 3 frames"),
        "{}",
        text(&out.stdout)
    );
    // Frames 0 and 2 (every 2nd, and the last).
    let mut frames: Vec<String> = std::fs::read_dir(dir.path().join("frames"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    frames.sort();
    assert_eq!(frames, ["frame-00000.exr", "frame-00002.exr"]);
    let csv = std::fs::read_to_string(p("stats.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 4, "{csv}");
    assert!(rows[0].starts_with("frame,produce_ms,train_ms,infer_ms,records,used,dropped"));
    let lr_column = rows[0].split(',').position(|c| c == "learning_rate");
    for row in &rows[1..] {
        let cols: Vec<&str> = row.split(',').collect();
        let (records, used): (usize, usize) = (cols[4].parse().unwrap(), cols[5].parse().unwrap());
        assert!(records > 0 && used == records, "{row}");
        assert!(cols[9].parse::<f32>().unwrap().is_finite());
        // The preset's rate: its decay starts at step 400.
        let lr: f32 = cols[lr_column.expect("a learning_rate column")]
            .parse()
            .unwrap();
        assert_eq!(lr, 1e-2, "{row}");
    }

    // Two renders from the snapshot are identical; a different seed differs.
    let render = |out: &str, seed: &str| {
        let o = nrc(&[
            "render",
            "--scene",
            scene.to_str().unwrap(),
            "--cache",
            &p("c.nrc"),
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "2",
            "--seed",
            seed,
            "--out",
            &p(out),
        ]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        std::fs::read(p(out)).unwrap()
    };
    let a = render("a.exr", "3");
    assert_eq!(a, render("b.exr", "3"));
    assert_ne!(a, render("c.exr", "4"));

    // A truncated snapshot is an error naming the file, not a panic.
    let bytes = std::fs::read(p("c.nrc")).unwrap();
    std::fs::write(p("t.nrc"), &bytes[..bytes.len() / 2]).unwrap();
    let o = nrc(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--cache",
        &p("t.nrc"),
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        &p("t.exr"),
    ]);
    assert_error(&o, "t.nrc");

    // The snapshot knows its scene: rendering another scene with it is refused (it once
    // rendered silently), unless explicitly allowed.
    let ajar = cornell().with_file_name("ajar.gltf");
    let (snapshot, other_out) = (p("c.nrc"), p("other.exr"));
    let other = |extra: &[&str]| {
        let mut a = vec![
            "render",
            "--scene",
            ajar.to_str().unwrap(),
            "--cache",
            &snapshot,
            "--width",
            "8",
            "--height",
            "8",
            "--spp",
            "1",
            "--out",
            &other_out,
        ];
        a.extend_from_slice(extra);
        nrc(&a)
    };
    assert_error(&other(&[]), "another scene");
    let o = other(&["--allow-other-scene"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("warning:"), "{}", text(&o.stderr));
}

/// The spatial-hash cache end to end: `nrc train --cache-kind hash` writes its snapshot, `nrc
/// render --cache` reads it (the kind told by the file) with the same render twice, and refuses
/// it on another scene; a bad kind is a clear error.
#[test]
fn the_hash_cache_trains_saves_and_renders() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let scene = cornell();
    let scene = scene.to_str().unwrap();
    let out = nrc(&[
        "train",
        "--scene",
        scene,
        "--cache-kind",
        "hash",
        "--frames",
        "8",
        "--width",
        "32",
        "--height",
        "32",
        "--records",
        "2048",
        "--snapshot",
        &p("h.nrc"),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("hash cache:"),
        "{}",
        text(&out.stderr)
    );
    let render = |name: &str| {
        nrc(&[
            "render",
            "--scene",
            scene,
            "--cache",
            &p("h.nrc"),
            "--termination",
            "first",
            "--spp",
            "2",
            "--width",
            "24",
            "--height",
            "16",
            "--out",
            &p(name),
        ])
    };
    let (a, b) = (render("a.exr"), render("b.exr"));
    assert!(
        a.status.success() && b.status.success(),
        "{}",
        text(&a.stderr)
    );
    let image = std::fs::read(p("a.exr")).unwrap();
    assert_eq!(
        image,
        std::fs::read(p("b.exr")).unwrap(),
        "the same render twice"
    );
    let ajar = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/ajar.gltf");
    let other = nrc(&[
        "render",
        "--scene",
        ajar.to_str().unwrap(),
        "--cache",
        &p("h.nrc"),
        "--spp",
        "1",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        &p("c.exr"),
    ]);
    assert_error(&other, "another scene");
    let bad = nrc(&[
        "train",
        "--scene",
        scene,
        "--cache-kind",
        "tree",
        "--frames",
        "1",
    ]);
    assert!(!bad.status.success() && text(&bad.stderr).contains("unknown cache kind"));
}

#[test]
fn bad_training_options_are_clear_errors() {
    let scene = cornell();
    let s = scene.to_str().unwrap();
    for (args, needle) in [
        (vec!["--producer", "ptx"], "unknown producer"),
        (vec!["--producer", "mix:pt=0"], "positive"),
        (vec!["--termination", "spread:-1"], "positive number"),
        (vec!["--frames", "0"], "--frames"),
        (vec!["--from-terminations", "2"], "--from-terminations"),
        (vec!["--resolution", "0"], "--resolution"),
        (vec!["--config", "/nonexistent.json"], "nonexistent"),
        (vec!["--sppc-alpha", "1.5"], "alpha"),
        (
            vec!["--lt-surface-balance", "0.8", "--lt-camera-balance", "0.5"],
            "at most 1",
        ),
        (vec!["--pass", "cache-last"], "unknown termination"),
        (vec!["--pass", "nope"], "unknown pass"),
        (vec!["--env", "/nonexistent/sky.hdr"], "nonexistent"),
        (vec!["--env", "/nonexistent/sky.png"], "nonexistent"),
        (vec!["--background=-1"], "--background"),
        (vec!["--emitter-samples", "300"], "--emitter-samples"),
    ] {
        let mut all = vec!["train", "--scene", s, "--width", "8", "--height", "8"];
        all.extend(args.iter());
        assert_error(&nrc(&all), needle);
    }
}

/// `--emitter-samples` reaches the online loop's render: the Cornell box's frame changes (its
/// light's outline gets the extra rays), and the same settings give the same bits.
#[test]
fn emitter_samples_reach_the_online_frames() {
    let dir = tempfile::tempdir().unwrap();
    let scene = cornell();
    let frame = |name: &str, k: &str| {
        let out = dir.path().join(name);
        let o = nrc(&[
            "train",
            "--scene",
            scene.to_str().unwrap(),
            "--frames",
            "1",
            "--width",
            "24",
            "--height",
            "24",
            "--records",
            "1024",
            "--batch",
            "1024",
            "--emitter-samples",
            k,
            "--frames-out",
            out.to_str().unwrap(),
            "--every",
            "1",
        ]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        std::fs::read(out.join("frame-00000.exr")).unwrap()
    };
    let plain = frame("plain", "0");
    let aa = frame("aa", "8");
    assert_ne!(plain, aa, "the extra rays changed nothing");
    assert_eq!(aa, frame("aa2", "8"));
}

/// `--pass` chooses the inference pass of `nrc train` and `nrc render`; a pass that ends paths
/// in a cache needs one.
#[test]
fn passes_are_chosen_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let scene = cornell();
    let s = scene.to_str().unwrap();
    let small = ["--width", "8", "--height", "8"];
    let (stats, x, y) = (p("s.json"), p("x.exr"), p("y.exr"));
    for pass in ["cache-first", "cache-bth:8-nonee", "pt"] {
        let mut a = vec!["train", "--scene", s, "--frames", "2", "--records", "512"];
        a.extend(small);
        a.extend(["--pass", pass, "--stats", &stats]);
        let o = nrc(&a);
        assert!(o.status.success(), "{pass}: {}", text(&o.stderr));
    }
    let mut a = vec!["render", "--scene", s, "--pass", "cache-first", "--out", &x];
    a.extend(small);
    assert_error(&nrc(&a), "--cache");
    let mut a = vec!["render", "--scene", s, "--pass", "pt-nonee", "--out", &y];
    a.extend(small);
    let o = nrc(&a);
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// A run file describes the whole run (its fields are the flags); flags override it; a field
/// that is no flag, or a file that is not JSON, is one clear error.
#[test]
fn run_files_describe_a_run_and_flags_override_them() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let config: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("models/nrc-hashgrid.json"),
        )
        .unwrap(),
    )
    .unwrap();
    let run = serde_json::json!({
        "scene": cornell(),
        "frames": 3,
        "width": 8,
        "height": 8,
        "records": 512,
        "pass": "cache-first",
        "config": config,
        "stats": p("stats.json"),
    });
    std::fs::write(p("run.json"), run.to_string()).unwrap();
    let frames = |extra: &[&str]| {
        let mut a = vec!["train", "--run", &p("run.json")]
            .into_iter()
            .map(String::from)
            .collect::<Vec<_>>();
        a.extend(extra.iter().map(|s| s.to_string()));
        let o = Command::new(env!("CARGO_BIN_EXE_nrc"))
            .args(&a)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        let stats: Vec<serde_json::Value> =
            serde_json::from_str(&std::fs::read_to_string(p("stats.json")).unwrap()).unwrap();
        (stats.len(), text(&o.stdout))
    };
    let (n, out) = frames(&[]);
    assert_eq!(n, 3);
    assert!(out.contains("512 records/frame"), "{out}");
    let (n, out) = frames(&["--frames", "2", "--records", "256"]);
    assert_eq!(n, 2);
    assert!(out.contains("256 records/frame"), "{out}");

    std::fs::write(p("bad.json"), r#"{"frame": 3}"#).unwrap();
    assert_error(
        &nrc(&["train", "--run", &p("bad.json")]),
        "unknown field `frame`",
    );
    std::fs::write(p("bad.json"), r#"{"frames": 3"#).unwrap();
    assert_error(&nrc(&["train", "--run", &p("bad.json")]), "not JSON");
}

/// The kajiya scene has no emitter: lit only by the background (the trivial environment),
/// every producer trains on it, light-path ones included (their paths start at the
/// environment), with non-zero targets; with nothing lighting it, light-path producers refuse.
#[test]
fn every_producer_trains_on_the_environment_lit_kajiya_scene() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes/kajiya-roughness-scale/scene.gltf");
    if !scene.exists() {
        nrc_scene::testing::skipped(
            "every_producer_trains_on_the_environment_lit_kajiya_scene",
            &format!("{} is absent", scene.display()),
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let stats = dir.path().join("stats.json");
    let s = scene.to_str().unwrap();
    let train = |producer: &str, lit: bool| {
        let mut a = vec!["train", "--scene", s, "--producer", producer];
        if lit {
            a.extend(["--background", "1"]);
        }
        a.extend([
            "--width",
            "8",
            "--height",
            "8",
            "--frames",
            "2",
            "--records",
            "512",
            "--stats",
            stats.to_str().unwrap(),
        ]);
        nrc(&a)
    };
    for producer in ["bt", "lt", "sppc"] {
        assert_error(&train(producer, false), "nothing lights it");
    }
    for producer in ["pt-sl", "bt", "lt", "sppc"] {
        let o = train(producer, true);
        assert!(o.status.success(), "{producer}: {}", text(&o.stderr));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
        let frames = json.as_array().expect("per-frame statistics");
        let mean = frames.last().unwrap()["target_mean"].as_f64();
        assert!(
            mean.is_some_and(|m| m > 0.0),
            "{producer}: targets {mean:?} in {}",
            frames.last().unwrap()
        );
    }
}

/// `nrc train` on `cornell-box-jump` (the lamp jumps at frame 30) reports the change it
/// detected and confirmed; on the still Cornell box, the negative control, it reports none.
#[test]
fn a_jump_in_the_scene_is_reported_as_a_confirmed_change() {
    let run = |scene: &Path| {
        let o = nrc(&[
            "train",
            "--scene",
            scene.to_str().unwrap(),
            "--frames",
            "60",
            "--width",
            "32",
            "--height",
            "32",
        ]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
    };
    let jump = run(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box-jump.gltf"));
    let line = jump
        .lines()
        .find(|l| l.contains("change(s) in the scene detected"))
        .unwrap_or_else(|| panic!("no change reported: {jump}"));
    let count = |word: &str| -> usize {
        let before = line.split(word).next().unwrap();
        let n = before.split_whitespace().last().unwrap();
        n.parse().unwrap_or_else(|_| panic!("{line}"))
    };
    assert!(
        count("change(s)") >= 1 && count("confirmed") >= 1,
        "the lamp's jump is not a confirmed change: {line}"
    );
    let still = run(&cornell());
    assert!(
        !still.contains("change(s) in the scene detected"),
        "a change reported on a still scene: {still}"
    );
}
