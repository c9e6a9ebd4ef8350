//! End-to-end tests of `nrc reference` and `nrc compare` on the shipped Cornell box at tiny
//! resolutions: the report files exist and parse, the path tracer's error falls as its sample
//! count rises (by the expected factor, within a statistical bound), equal-time frames meet
//! their budget within the stated tolerance, references are cached and reused, and corrupt or
//! mismatched references end with one clear error line.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

// `runs.json` is read with the schema the harness writes it with.
use nrc_harness::compare::RunsFile;
use nrc_scene::Image;

fn nrc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nrc"))
        .args(args)
        .output()
        .expect("nrc runs")
}

fn cornell() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box.gltf")
        .to_str()
        .unwrap()
        .to_string()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn assert_ok(out: &Output) {
    assert!(
        out.status.success(),
        "failed: {}\n{}",
        text(&out.stderr),
        text(&out.stdout)
    );
}

/// The command failed cleanly: non-zero status, exactly one `error:` line on stderr naming
/// every `needle`, no panic.
fn assert_clean_error(out: &Output, needles: &[&str]) {
    let err = text(&out.stderr);
    assert!(!out.status.success(), "succeeded; stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one error line, got: {err}");
    assert!(lines[0].starts_with("error: "), "not an error line: {err}");
    for n in needles {
        assert!(
            lines[0].contains(n),
            "error line does not name `{n}`: {err}"
        );
    }
}

/// The one cache entry folder in `cache`.
fn entries(cache: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

/// Mean and standard error of the mean.
fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

fn is_png(path: &Path) -> bool {
    std::fs::read(path)
        .map(|b| b.len() > 8 && &b[1..4] == b"PNG")
        .unwrap_or(false)
}

fn read_runs(dir: &Path) -> RunsFile {
    serde_json::from_str(&std::fs::read_to_string(dir.join("runs.json")).unwrap()).unwrap()
}

/// Equal samples: every output exists and parses, and the path tracer's MSE falls with spp.
///
/// E[MSE_k] = S/k + V, where S is the image-averaged variance of one path, k the spp and V the
/// reference's own noise (the mean of its variance of the mean, stored with it). So
/// S₁ = MSE₁ − V and S₁₆ = 16 (MSE₁₆ − V) estimate the same S: MSE₁/MSE₁₆ ≈ 16. Each MSE is
/// the mean over independent runs, with its standard error from their spread; the difference
/// of the two estimates of S over its standard error is about N(0, 1) and is required to be
/// within 4. (Over base seeds 1–12 the ratio came out between 10.8 and 21.2, |z| ≤ 1.7.) Fixed seeds
/// make the test deterministic.
#[test]
fn equal_spp_report_and_error_falls_with_spp() {
    // Runs per method: the errors of one tiny render are dominated by a few pixels on the
    // light's edge, so they are averaged over runs (and their spread gives the bounds).
    const RUNS: u32 = 16;
    let dir = tempfile::tempdir().unwrap();
    let (cache, out) = (dir.path().join("cache"), dir.path().join("out"));
    let o = nrc(&[
        "compare",
        "--scene",
        &cornell(),
        "--methods",
        "pt-1spp,pt-4spp,pt-16spp",
        "--equal-spp",
        "1",
        "--width",
        "32",
        "--height",
        "32",
        "--runs",
        &RUNS.to_string(),
        "--reference-spp",
        "256",
        "--sweep",
        "--sweep-steps",
        "3",
        "--cache-dir",
        cache.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_ok(&o);
    assert!(
        text(&o.stdout).contains("| pt-16spp |"),
        "report printed: {}",
        text(&o.stdout)
    );

    // Report files.
    let report = nrc_eval::report::read_report_json(&out.join("report.json")).unwrap();
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        md.contains("| method | time/frame (ms) | spp | MSE |"),
        "{md}"
    );
    let names: Vec<&str> = report.rows.iter().map(|r| r.method.as_str()).collect();
    assert_eq!(names, ["pt-1spp", "pt-4spp", "pt-16spp"]);
    assert_eq!((report.width, report.height), (32, 32));
    for (row, spp) in report.rows.iter().zip([1.0, 4.0, 16.0]) {
        assert_eq!(row.samples_per_pixel, spp);
        assert!(row.time_per_frame_ms > 0.0);
        assert!(
            row.metrics.flip.is_some_and(|f| f > 0.0 && f < 1.0),
            "{row:?}"
        );
        let bv = row.bias_variance.expect("bias and variance from the runs");
        assert_eq!(bv.renders, RUNS as usize);
        assert!(bv.variance > 0.0);
    }
    // Sweep: doubling passes, and the time-to-error table against the first method.
    assert_eq!(report.sweeps.len(), 3);
    for (s, spp) in report.sweeps.iter().zip([1.0, 4.0, 16.0]) {
        let spps: Vec<f64> = s.points.iter().map(|p| p.samples_per_pixel).collect();
        assert_eq!(spps, [spp, 2.0 * spp, 4.0 * spp], "{}", s.method);
    }
    assert_eq!(report.time_to_error.len(), 1);
    assert_eq!(report.time_to_error[0].baseline, "pt-1spp");
    assert_eq!(report.time_to_error[0].rows.len(), 3);
    let runs = read_runs(&out);
    assert_eq!(runs.mode, "equal-spp");
    assert_eq!(runs.runs.len(), 3 * (RUNS as usize + 2));

    // Images.
    for f in ["error-vs-time.png", "reference.png"] {
        assert!(is_png(&out.join(f)), "{f}");
    }
    let svg = std::fs::read_to_string(out.join("error-vs-time.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("pt-16spp"));
    for m in ["pt-1spp", "pt-4spp", "pt-16spp"] {
        for suffix in [".png", "-relmse.png", "-flip.png"] {
            assert!(is_png(&out.join(format!("{m}{suffix}"))), "{m}{suffix}");
        }
    }
    let no_temporaries = std::fs::read_dir(&out)
        .unwrap()
        .all(|e| !e.unwrap().file_name().to_string_lossy().starts_with('.'));
    assert!(no_temporaries);

    // The MSE falls as spp rises, by the expected factor.
    let entry = &entries(&cache)[0];
    let reference = Image::read_exr(&entry.join("mean.exr")).unwrap();
    let ref_var = Image::read_exr(&entry.join("variance.exr")).unwrap();
    // runs.json holds each run's errors; run 0's are those of the image written.
    let x1 = Image::read_exr(&out.join("pt-1spp.exr")).unwrap();
    let e1 = x1
        .data
        .iter()
        .zip(&reference.data)
        .map(|(a, b)| (*a - *b).length_squared() as f64)
        .sum::<f64>()
        / (3 * x1.data.len()) as f64;
    let run0 = runs
        .runs
        .iter()
        .find(|r| r.method == "pt-1spp" && r.run == Some(0))
        .unwrap();
    assert!(
        (run0.metrics.mse - e1).abs() <= 1e-5 * e1,
        "{} vs {e1}",
        run0.metrics.mse
    );
    let per_run = |m: &str| -> Vec<f64> {
        runs.runs
            .iter()
            .filter(|r| r.method == m && r.run.is_some())
            .map(|r| r.metrics.mse)
            .collect()
    };
    let ((m1, se1), (m4, _), (m16, se16)) = (
        mean_se(&per_run("pt-1spp")),
        mean_se(&per_run("pt-4spp")),
        mean_se(&per_run("pt-16spp")),
    );
    for (row, m) in report.rows.iter().zip([m1, m4, m16]) {
        assert!(
            (row.metrics.mse - m).abs() <= 1e-12 * m,
            "report rows hold the means over runs"
        );
    }
    eprintln!(
        "MSE: 1 spp {m1:.5} ± {se1:.5}, 4 spp {m4:.5}, 16 spp {m16:.6} ± {se16:.6}; ratio {:.2}",
        m1 / m16
    );
    assert!(m1 > m4 && m4 > m16, "MSE {m1}, {m4}, {m16}");
    // A clear margin: the drop from 1 to 16 spp is over 3 standard errors (p < 0.0014 if
    // the MSE did not fall).
    assert!(
        m1 - m16 > 3.0 * se1.hypot(se16),
        "{m1} ± {se1} vs {m16} ± {se16}"
    );
    // The expected ratio: S from 1 spp and from 16 spp agree, |z| < 4.
    let v = ref_var
        .data
        .iter()
        .map(|p| p.element_sum() as f64)
        .sum::<f64>()
        / (3 * ref_var.data.len()) as f64;
    let (s1, s16) = (m1 - v, 16.0 * (m16 - v));
    let z = (s1 - s16) / se1.hypot(16.0 * se16);
    eprintln!(
        "path variance S: from 1 spp {s1:.4}, from 16 spp {s16:.4}, reference noise {v:.2e}, z {z:.2}"
    );
    assert!(
        z.abs() < 4.0,
        "path variance from 1 spp {s1} ± {se1}, from 16 spp {s16} ± {}: z = {z}",
        16.0 * se16
    );
}

/// Equal time: each frame ends within its longest pass of the budget (the stated tolerance),
/// holds whole passes, and the sweep doubles the budget.
#[test]
fn equal_time_frames_meet_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    let (cache, out) = (dir.path().join("cache"), dir.path().join("out"));
    let o = nrc(&[
        "compare",
        "--scene",
        &cornell(),
        "--methods",
        "pt-1spp,pt-4spp-nonee",
        "--equal-time",
        "40",
        "--width",
        "24",
        "--height",
        "24",
        "--runs",
        "2",
        "--reference-spp",
        "64",
        "--sweep",
        "--sweep-steps",
        "2",
        "--no-flip",
        "--cache-dir",
        cache.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_ok(&o);
    let runs = read_runs(&out);
    assert_eq!(runs.mode, "equal-time");
    assert_eq!(runs.runs.len(), 2 * (2 + 1));
    for r in &runs.runs {
        let budget = r.budget_ms.unwrap();
        let expected = if r.sweep_step == Some(1) { 80.0 } else { 40.0 };
        assert_eq!(budget, expected);
        let spp = if r.method == "pt-1spp" { 1 } else { 4 };
        assert_eq!(r.samples_per_pixel, r.passes as u64 * spp);
        // The tolerance; 0.5 ms covers the final averaging of the passes, after the last check.
        assert!(
            (r.time_ms - budget).abs() <= r.longest_pass_ms + 0.5,
            "{} took {} ms for a {} ms budget; longest pass {} ms",
            r.method,
            r.time_ms,
            budget,
            r.longest_pass_ms
        );
        assert!(r.metrics.flip.is_none());
    }
    let report = nrc_eval::report::read_report_json(&out.join("report.json")).unwrap();
    assert_eq!(report.rows.len(), 2);
    assert!(
        report
            .rows
            .iter()
            .all(|r| r.metrics.flip.is_none() && r.bias_variance.is_some())
    );
    assert_eq!(report.sweeps.len(), 2);
    assert!(is_png(&out.join("error-vs-time.png")));
}

/// A reference is rendered once and then reused; another spp, or other scene content, gets
/// its own entry.
#[test]
fn references_are_cached_by_content_and_settings() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    // A copy of the scene whose buffer can be changed.
    let scene_dir = dir.path().join("scene");
    std::fs::create_dir(&scene_dir).unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    for f in ["cornell-box.gltf", "cornell-box.bin"] {
        std::fs::copy(root.join(f), scene_dir.join(f)).unwrap();
    }
    let scene = scene_dir.join("cornell-box.gltf");
    let reference = |spp: &str| {
        let o = nrc(&[
            "reference",
            "--scene",
            scene.to_str().unwrap(),
            "--spp",
            spp,
            "--width",
            "16",
            "--height",
            "12",
            "--cache-dir",
            cache.to_str().unwrap(),
        ]);
        assert_ok(&o);
        text(&o.stdout)
    };
    assert!(reference("32").starts_with("rendered reference"));
    assert_eq!(entries(&cache).len(), 1);
    let mtime = std::fs::metadata(entries(&cache)[0].join("mean.exr"))
        .unwrap()
        .modified()
        .unwrap();
    assert!(reference("32").starts_with("reused reference"));
    assert_eq!(
        std::fs::metadata(entries(&cache)[0].join("mean.exr"))
            .unwrap()
            .modified()
            .unwrap(),
        mtime
    );
    let stored = Image::read_exr(&entries(&cache)[0].join("mean.exr")).unwrap();
    assert_eq!((stored.width, stored.height), (16, 12));

    assert!(reference("16").starts_with("rendered reference"));
    assert_eq!(entries(&cache).len(), 2);
    // Extra bytes after the buffer's data: the scene loads the same, but its content differs.
    let mut bin = std::fs::read(scene_dir.join("cornell-box.bin")).unwrap();
    bin.push(0);
    std::fs::write(scene_dir.join("cornell-box.bin"), bin).unwrap();
    assert!(reference("32").starts_with("rendered reference"));
    assert_eq!(entries(&cache).len(), 3);
}

/// Corrupt cache entries, references of the wrong size and bad arguments end with one clear
/// error line.
#[test]
fn bad_references_and_arguments_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let out = dir.path().join("out");
    let (c, o) = (cache.to_str().unwrap(), out.to_str().unwrap());
    let scene = cornell();
    assert_ok(&nrc(&[
        "reference",
        "--scene",
        &scene,
        "--spp",
        "8",
        "--width",
        "16",
        "--height",
        "16",
        "--cache-dir",
        c,
    ]));
    let entry = entries(&cache)[0].clone();
    let entry_s = entry.to_str().unwrap();

    // A reference of another size.
    let compare = |extra: &[&str]| {
        let mut args = vec![
            "compare",
            "--scene",
            &scene,
            "--methods",
            "pt-1spp",
            "--equal-spp",
            "1",
            "--no-flip",
            "--out",
            o,
            "--cache-dir",
            c,
        ];
        args.extend_from_slice(extra);
        nrc(&args)
    };
    assert_clean_error(
        &compare(&["--width", "20", "--height", "16", "--reference", entry_s]),
        &["is 16x16 pixels", "renders 20x16"],
    );
    // The right size works, from the folder and from its bare EXR.
    assert_ok(&compare(&[
        "--width",
        "16",
        "--height",
        "16",
        "--reference",
        entry_s,
    ]));
    // Another scene's reference of the same size is refused; so is one from another camera.
    let glossy = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/glossy.gltf");
    let mut other = vec!["compare", "--scene", glossy.to_str().unwrap()];
    other.extend_from_slice(&[
        "--methods",
        "pt-1spp",
        "--equal-spp",
        "1",
        "--no-flip",
        "--out",
        o,
        "--cache-dir",
        c,
        "--width",
        "16",
        "--height",
        "16",
        "--reference",
        entry_s,
    ]);
    assert_clean_error(
        &nrc(&other),
        &["rendered from another scene", "glossy.gltf"],
    );
    assert_clean_error(
        &compare(&[
            "--width",
            "16",
            "--height",
            "16",
            "--reference",
            entry_s,
            "--camera-pos",
            "0.3,0.3,-0.9",
        ]),
        &["other settings", "camera"],
    );
    let mean = entry.join("mean.exr");
    assert_ok(&compare(&[
        "--width",
        "16",
        "--height",
        "16",
        "--reference",
        mean.to_str().unwrap(),
    ]));

    // A corrupt EXR in the cache: `reference` and `compare` both refuse it.
    std::fs::write(&mean, b"not an EXR file").unwrap();
    let again = nrc(&[
        "reference",
        "--scene",
        &scene,
        "--spp",
        "8",
        "--width",
        "16",
        "--height",
        "16",
        "--cache-dir",
        c,
    ]);
    assert_clean_error(&again, &["corrupt", "mean.exr", "delete"]);
    assert_clean_error(
        &compare(&["--width", "16", "--height", "16", "--reference-spp", "8"]),
        &["corrupt", "mean.exr"],
    );
    // `--force` renders it again.
    let forced = nrc(&[
        "reference",
        "--scene",
        &scene,
        "--spp",
        "8",
        "--width",
        "16",
        "--height",
        "16",
        "--cache-dir",
        c,
        "--force",
    ]);
    assert_ok(&forced);
    assert!(text(&forced.stdout).starts_with("rendered reference"));
    // Settings that disagree with the stored image.
    let meta = entry.join("reference.json");
    let json = std::fs::read_to_string(&meta)
        .unwrap()
        .replace("\"width\": 16", "\"width\": 17");
    std::fs::write(&meta, json).unwrap();
    assert_clean_error(
        &compare(&["--width", "16", "--height", "16", "--reference-spp", "8"]),
        &["is 16x16, but its settings say 17x16"],
    );
    std::fs::write(&meta, "{").unwrap();
    assert_clean_error(
        &compare(&["--width", "16", "--height", "16", "--reference-spp", "8"]),
        &["reference.json", "corrupt"],
    );

    // Bad arguments.
    // (A method name is parsed by clap, whose messages add a usage hint.)
    let unknown = compare(&["--methods", "pt-1spp,foo"]);
    assert!(!unknown.status.success() && !text(&unknown.stderr).contains("panicked"));
    assert!(
        text(&unknown.stderr).contains("unknown method `foo`"),
        "{}",
        text(&unknown.stderr)
    );
    assert_clean_error(
        &nrc(&[
            "compare",
            "--scene",
            &scene,
            "--methods",
            "pt-1spp",
            "--equal-time",
            "0",
            "--out",
            o,
        ]),
        &["--equal-time"],
    );
    assert_clean_error(
        &compare(&["--methods", "pt-1spp,pt-1spp"]),
        &["listed twice"],
    );
    assert_clean_error(
        &nrc(&[
            "reference",
            "--scene",
            &scene,
            "--spp",
            "1",
            "--cache-dir",
            c,
        ]),
        &["at least 2 samples"],
    );
}

/// `--exclude-emitters` zeroes the error of the pixels that see the light (and their
/// neighbours), which at 1 spp carry most of the path tracer's MSE, and says so in the report.
#[test]
fn excluding_emitters_removes_their_error() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let scene = cornell();
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec![
            "compare",
            "--scene",
            &scene,
            "--methods",
            "pt-1spp",
            "--equal-spp",
            "1",
            "--width",
            "32",
            "--height",
            "32",
            "--runs",
            "4",
            "--reference-spp",
            "64",
            "--no-flip",
            "--cache-dir",
            cache.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = nrc(&args);
        assert_ok(&o);
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        let mse = report["rows"][0]["mse"].as_f64().unwrap();
        (mse, std::fs::read_to_string(out.join("report.md")).unwrap())
    };
    let (all, _) = run("all", &[]);
    let (masked, md) = run("masked", &["--exclude-emitters"]);
    assert!(
        masked < 0.5 * all,
        "MSE {masked} with the emitters excluded, {all} without"
    );
    assert!(md.contains("see an emitter"), "{md}");
}

/// `--diagnostics`: each method's per-pixel MSE, bias² and variance over its runs (their image
/// means are the report's figures) and a resampling pass's reservoir statistics after its last
/// frame; a single run, which has no variance, is a clear error.
#[test]
fn diagnostics_write_each_pixels_bias_and_variance_and_the_reservoirs() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let out = dir.path().join("diag");
    let scene = cornell();
    let args = |runs: &'static str| {
        vec![
            "compare".to_string(),
            "--scene".into(),
            scene.clone(),
            "--methods".into(),
            "pt-1spp,restir-di".into(),
            "--equal-spp".into(),
            "1".into(),
            "--width".into(),
            "32".into(),
            "--height".into(),
            "32".into(),
            "--runs".into(),
            runs.into(),
            "--reference-spp".into(),
            "64".into(),
            "--no-flip".into(),
            "--diagnostics".into(),
            "--cache-dir".into(),
            cache.to_str().unwrap().into(),
            "--out".into(),
            out.to_str().unwrap().into(),
        ]
    };
    fn argv(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }
    assert_clean_error(&nrc(&argv(&args("1"))), &["--diagnostics", "--runs"]);
    assert_ok(&nrc(&argv(&args("4"))));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    for (k, method) in ["pt-1spp", "restir-di"].iter().enumerate() {
        let errors = Image::read_exr(&out.join(format!("{method}-errors.exr"))).unwrap();
        let n = errors.data.len() as f64;
        let mean = |c: usize| errors.data.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let bv = &report["rows"][k]["bias_variance"];
        let (bias, var) = (
            bv["bias_sq"].as_f64().unwrap(),
            bv["variance"].as_f64().unwrap(),
        );
        assert!(var > 0.0, "{method}: no variance");
        for (c, want) in [(0, bias + var), (1, bias), (2, var)] {
            assert!(
                (mean(c) - want).abs() <= 1e-4 * var,
                "{method}: channel {c} averages {} where the report says {want}",
                mean(c)
            );
        }
    }
    assert!(
        !out.join("pt-1spp-view-reservoir-m.exr").exists(),
        "the path tracer has no reservoirs"
    );
    // ReSTIR DI's final reservoirs merge its neighbours' and the previous frame's: M > 1 on
    // average, and the contributions of lit pixels are positive and finite.
    let m = Image::read_exr(&out.join("restir-di-view-reservoir-m.exr")).unwrap();
    let mean_m = m.data.iter().map(|p| p.x as f64).sum::<f64>() / m.data.len() as f64;
    assert!(mean_m > 1.0, "mean M {mean_m}");
    let w = Image::read_exr(&out.join("restir-di-view-reservoir-contribution.exr")).unwrap();
    assert!(w.data.iter().all(|p| p.x.is_finite() && p.x >= 0.0));
    assert!(w.data.iter().filter(|p| p.x > 0.0).count() > w.data.len() / 2);
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("Diagnostics: METHOD-errors.exr"), "{md}");
}

/// A run file names the comparison; a list flag given on the command line replaces the file's
/// list (it does not add to it), and `--run=FILE` reads the file as `--run FILE` does.
#[test]
fn run_files_describe_a_comparison_and_list_flags_override_them() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let run = serde_json::json!({
        "scene": cornell(),
        "methods": ["pt-1spp", "pt-1spp-nonee"],
        "equal_spp": 1,
        "width": 8,
        "height": 8,
        "reference_spp": 4,
        "no_flip": true,
        "cache_dir": p("cache"),
        "out": p("out"),
    });
    std::fs::write(p("run.json"), run.to_string()).unwrap();
    let methods = |args: &[&str]| {
        assert_ok(&nrc(args));
        let mut m: Vec<String> = read_runs(&dir.path().join("out"))
            .runs
            .into_iter()
            .map(|r| r.method)
            .collect();
        m.sort();
        m
    };
    let file = format!("--run={}", p("run.json"));
    assert_eq!(methods(&["compare", &file]), ["pt-1spp", "pt-1spp-nonee"]);
    assert_eq!(
        methods(&["compare", "--run", &p("run.json"), "--methods", "pt-2spp"]),
        ["pt-2spp"]
    );
}

/// `--converge` (the DDGI-resampling paper's Table 1 protocol): progressive frames from one
/// state. `pt-1spp` averaged over k frames is `pt-{k}spp`, so it reaches the MAPE of
/// `pt-16spp`'s first frame after about 16 frames (the bound allows for the noise of both
/// MAPEs at 32²: 8 to 40 frames), and, listed after its target, stops at twice that; the
/// target reaches its own error in one frame. A target that is not a listed method is one
/// clear error.
#[test]
fn converge_counts_frames_to_the_targets_first_frame_error() {
    let dir = tempfile::tempdir().unwrap();
    let (cache, out) = (dir.path().join("cache"), dir.path().join("out"));
    let args = |target: &str| {
        vec![
            "compare".to_string(),
            "--scene".into(),
            cornell(),
            "--methods".into(),
            "pt-16spp,pt-1spp".into(),
            "--equal-spp".into(),
            "1".into(),
            "--width".into(),
            "32".into(),
            "--height".into(),
            "32".into(),
            "--reference-spp".into(),
            "512".into(),
            "--no-flip".into(),
            "--converge".into(),
            "200".into(),
            "--converge-target".into(),
            target.into(),
            "--cache-dir".into(),
            cache.to_str().unwrap().into(),
            "--out".into(),
            out.to_str().unwrap().into(),
        ]
    };
    let run = |a: Vec<String>| nrc(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let o = run(args("pt-16spp"));
    assert_ok(&o);
    let report = nrc_eval::report::read_report_json(&out.join("report.json")).unwrap();
    let t = &report.frames_to_error[0];
    assert_eq!(t.target_method, "pt-16spp");
    assert_eq!(t.target_error, report.convergence[0].points[0].metrics.mape);
    use nrc_eval::convergence::FramesToReach;
    assert!(
        matches!(t.rows[0].reach, FramesToReach::Reached { frames: 1, .. }),
        "{:?}",
        t.rows[0]
    );
    let FramesToReach::Reached { frames, time_ms } = t.rows[1].reach else {
        panic!("pt-1spp did not reach pt-16spp's error: {:?}", t.rows[1]);
    };
    assert!((8..=40).contains(&frames), "pt-1spp needed {frames} frames");
    assert_eq!(t.rows[1].frames_run, 2 * frames);
    assert!(time_ms > 0.0 && t.rows[1].time_ratio.is_some());
    // The running mean's error falls: the last point is below the first.
    let c = &report.convergence[1].points;
    assert!(c.last().unwrap().metrics.mape < c[0].metrics.mape);
    assert!(is_png(&out.join("frames-to-error.png")));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        md.contains("## Frames to reach the MAPE of pt-16spp's first frame"),
        "{md}"
    );

    assert_clean_error(&run(args("pt-4spp")), &["--converge-target", "pt-4spp"]);
}

/// A trained cache's comparison kept small: 3 training frames, a coarse model, 24 × 24 pixels, a
/// 16-spp reference.
const SMALL_RUN: [&str; 13] = [
    "--train-frames",
    "3",
    "--records",
    "1024",
    "--resolution",
    "64",
    "--width",
    "24",
    "--height",
    "24",
    "--reference-spp",
    "16",
    "--no-flip",
];

/// Every stateful method's first timed frame of every run sees a history warmed by as many
/// frames as `--train-frames`, at the comparison's size: the resampling passes that read no
/// cache (their untimed warm-up per run) and those that read one (their pass rendered every
/// training frame). Before this was checked, run 0 of the cache-reading ones started cold: an
/// untimed 16 × 16 start-up frame after training replaced their history.
#[test]
fn stateful_methods_start_every_run_warm() {
    let dir = tempfile::tempdir().unwrap();
    let (cache, out) = (dir.path().join("cache"), dir.path().join("out"));
    let scene = cornell();
    let args = [
        &[
            "compare",
            "--scene",
            &scene,
            "--methods",
            "pt-1spp,restir-di,restir-gi-nrc,nrc-restir,nrc-pt-sl",
            "--equal-spp",
            "1",
            "--runs",
            "2",
            "--cache-dir",
            cache.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ][..],
        &SMALL_RUN[..],
    ]
    .concat();
    let o = nrc(&args);
    assert_ok(&o);
    let runs = read_runs(&out).runs;
    for method in ["restir-di", "restir-gi-nrc", "nrc-restir"] {
        for r in 0..2 {
            let rec = runs
                .iter()
                .find(|x| x.method == method && x.run == Some(r))
                .unwrap_or_else(|| panic!("{method} run {r} in runs.json"));
            assert!(
                rec.warm_frames.is_some_and(|w| w >= 3),
                "{method} run {r}: first timed frame after {:?} warm frames",
                rec.warm_frames
            );
        }
    }
    // Stateless methods report none.
    for rec in runs
        .iter()
        .filter(|x| x.method == "pt-1spp" || x.method == "nrc-pt-sl")
    {
        assert_eq!(rec.warm_frames, None, "{}", rec.method);
    }
}

/// `--interleave` renders each run's methods back to back, after restarting them all, and
/// renders the same frames as method by method: every run's errors agree to the bit, stateful
/// methods and a trained cache included, while the runs differ from each other (so agreement
/// is not of constant images), and the report says how the runs were rendered.
#[test]
fn interleaved_runs_render_the_same_frames_as_method_by_method() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let scene = cornell();
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "compare",
            "--scene",
            &scene,
            "--methods",
            "pt-1spp,restir-gi,nrc-restir",
            "--equal-spp",
            "2",
            "--runs",
            "3",
            "--camera-offsets",
            "sobol",
        ];
        args.extend_from_slice(&SMALL_RUN);
        let cache = cache.to_str().unwrap().to_string();
        let out = out.to_str().unwrap().to_string();
        args.push("--cache-dir");
        args.push(&cache);
        args.push("--out");
        args.push(&out);
        args.extend_from_slice(extra);
        let o = nrc(&args);
        assert_ok(&o);
    };
    let (plain, interleaved) = (dir.path().join("plain"), dir.path().join("interleaved"));
    run(&plain, &[]);
    run(&interleaved, &["--interleave"]);
    let (a, b) = (read_runs(&plain).runs, read_runs(&interleaved).runs);
    assert_eq!(a.len(), 9);
    assert_eq!(b.len(), 9);
    for x in &a {
        let y = b
            .iter()
            .find(|y| y.method == x.method && y.run == x.run)
            .unwrap_or_else(|| panic!("{} run {:?} interleaved", x.method, x.run));
        assert_eq!(
            (x.seed, x.passes, x.warm_frames),
            (y.seed, y.passes, y.warm_frames)
        );
        assert_eq!(
            x.metrics.mse.to_bits(),
            y.metrics.mse.to_bits(),
            "{} run {:?}: {} method by method, {} interleaved",
            x.method,
            x.run,
            x.metrics.mse,
            y.metrics.mse
        );
    }
    // The control: each method's runs are distinct estimates.
    for m in ["pt-1spp", "restir-gi", "nrc-restir"] {
        let mut mses: Vec<u64> = a
            .iter()
            .filter(|x| x.method == m)
            .map(|x| x.metrics.mse.to_bits())
            .collect();
        mses.sort_unstable();
        mses.dedup();
        assert_eq!(mses.len(), 3, "{m}: runs with equal errors");
    }
    let report = std::fs::read_to_string(interleaved.join("report.md")).unwrap();
    assert!(report.contains("Runs interleaved"), "{report}");
    let report = std::fs::read_to_string(plain.join("report.md")).unwrap();
    assert!(!report.contains("Runs interleaved"), "{report}");
}

/// `--cache-kind hash` makes the cache methods train the spatial-hash cache: `nrc-pt-sl` runs
/// (and is reported) as `hash-pt-sl`, and renders what `hash-pt-sl` renders; without it the
/// same name is the network.
#[test]
fn cache_kind_switches_the_cache_methods_to_the_hash_cache() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("store").to_str().unwrap().to_string();
    let scene = cornell();
    // (method, MSE) of each row of a comparison of `methods` with `extra` flags.
    let run = |name: &str, methods: &str, extra: &[&str]| {
        let out = dir.path().join(name).to_str().unwrap().to_string();
        let mut args = vec![
            "compare",
            "--scene",
            &scene,
            "--methods",
            methods,
            "--equal-spp",
            "1",
            "--width",
            "16",
            "--height",
            "16",
            "--reference-spp",
            "4",
            "--train-frames",
            "2",
            "--runs",
            "1",
            "--no-flip",
            "--out",
            &out,
            "--cache-dir",
            &store,
        ];
        args.extend(extra);
        assert_ok(&nrc(&args));
        let report =
            nrc_eval::report::read_report_json(&Path::new(&out).join("report.json")).unwrap();
        report
            .rows
            .iter()
            .map(|r| (r.method.clone(), r.metrics.mse))
            .collect::<Vec<_>>()
    };
    let hash = run("hash", "pt-1spp,nrc-pt-sl", &["--cache-kind", "hash"]);
    let neural = run("neural", "pt-1spp,nrc-pt-sl", &[]);
    let named = run("named", "pt-1spp,hash-pt-sl", &[]);
    assert_eq!(hash[1].0, "hash-pt-sl", "{hash:?}");
    assert_eq!(neural[1].0, "nrc-pt-sl", "{neural:?}");
    // The switch and the name are one method: the same errors, bit for bit.
    assert_eq!(hash[1].1, named[1].1);
    assert_ne!(hash[1].1, neural[1].1, "the switch changed nothing");
}
