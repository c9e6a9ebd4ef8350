//! Studies split into jobs: `nrc compare --plan DIR`, `nrc job DIR K`, `nrc compare --merge
//! DIR` give the single process's errors (timings aside), and every way a study's results can
//! be incomplete or wrong ends in one clear error line.

use std::path::Path;
use std::process::{Command, Output};

fn nrc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nrc"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("nrc runs")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn ok(out: Output) -> Output {
    assert!(
        out.status.success(),
        "failed: {}\n{}",
        text(&out.stderr),
        text(&out.stdout)
    );
    out
}

fn clean_error(out: &Output, needles: &[&str]) {
    let err = text(&out.stderr);
    assert!(!out.status.success(), "succeeded; stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error: ")).collect();
    assert_eq!(lines.len(), 1, "expected one error line, got: {err}");
    for n in needles {
        assert!(
            lines[0].contains(n),
            "error line does not name `{n}`: {err}"
        );
    }
}

/// The comparison's flags (3 methods, 2 runs, 32², equal samples), with its output folders.
fn study_flags(out: &Path, refs: &Path) -> Vec<String> {
    [
        "--scene",
        "scenes/cornell-box.gltf",
        "--methods",
        "pt-1spp,nrc-pt-sl-first,restir-di",
        "--equal-spp",
        "2",
        "--width",
        "32",
        "--height",
        "32",
        "--runs",
        "2",
        "--reference-spp",
        "48",
        "--train-frames",
        "4",
        "--records",
        "1024",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain([
        "--out".into(),
        out.display().to_string(),
        "--cache-dir".into(),
        refs.display().to_string(),
    ])
    .collect()
}

fn report_rows(dir: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("report.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["rows"].as_array().unwrap().clone()
}

/// Every number of two report rows but the timings, within `tol` relative.
fn same_errors(
    a: &serde_json::Value,
    b: &serde_json::Value,
    tol: f64,
    path: &str,
) -> Result<(), String> {
    match (a, b) {
        (serde_json::Value::Object(x), serde_json::Value::Object(y)) => {
            for (k, v) in x {
                if k == "time_per_frame_ms" {
                    continue;
                }
                let w = y.get(k).ok_or(format!("{path}.{k} missing"))?;
                same_errors(v, w, tol, &format!("{path}.{k}"))?;
            }
            Ok(())
        }
        (serde_json::Value::Number(x), serde_json::Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            if (x - y).abs() <= tol * x.abs().max(y.abs()) + 1e-12 {
                Ok(())
            } else {
                Err(format!("{path}: {x} against {y}"))
            }
        }
        _ if a == b => Ok(()),
        _ => Err(format!("{path}: {a} against {b}")),
    }
}

#[test]
fn jobs_then_merge_give_the_single_process_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let single = study_flags(&t.join("single"), &t.join("refs-single"));
    let mut args = vec!["compare".to_string()];
    args.extend(single);
    ok(nrc(&args.iter().map(String::as_str).collect::<Vec<_>>()));

    let plan = t.join("plan");
    let mut args = vec!["compare".to_string()];
    args.extend(study_flags(&t.join("merged"), &t.join("refs-merged")));
    args.extend([
        "--plan".into(),
        plan.display().to_string(),
        "--chunks".into(),
        "3".into(),
    ]);
    let out = ok(nrc(&args.iter().map(String::as_str).collect::<Vec<_>>()));
    assert!(text(&out.stdout).contains("planned 9 jobs (3 reference chunks, 3 methods × 2 runs)"));
    let p = plan.display().to_string();

    // Not all jobs run: the merge lists the missing ones and writes no report.
    ok(nrc(&["job", &p, "0"]));
    ok(nrc(&["job", &p, "4"]));
    clean_error(
        &nrc(&["compare", "--merge", &p]),
        &["7 of 9 jobs have no result yet", "jobs 1-3, 5-8"],
    );
    assert!(!t.join("merged/report.json").exists());
    // A job killed mid-write leaves only its temporary file, which is not a result.
    std::fs::write(plan.join("jobs/.0001.safetensors.tmp123"), b"half a result").unwrap();
    clean_error(&nrc(&["compare", "--merge", &p]), &["jobs 1-3, 5-8"]);

    let out = ok(nrc(&["job", &p, "--all"]));
    assert!(
        text(&out.stderr).contains("job 0: its result exists"),
        "a done job is skipped"
    );
    ok(nrc(&["compare", "--merge", &p]));
    let (a, b) = (
        report_rows(&t.join("single")),
        report_rows(&t.join("merged")),
    );
    assert_eq!(a.len(), 3);
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x["method"], y["method"]);
        assert!(
            x["bias_variance"].is_object(),
            "2 runs give bias and variance"
        );
        same_errors(x, y, 1e-4, x["method"].as_str().unwrap()).unwrap();
    }
    // The merged reference is the single render's, within float rounding.
    let reference = |dir: &str| {
        let d = std::fs::read_dir(t.join(dir))
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .path();
        nrc_scene::Image::read_exr(&d.join("variance.exr")).unwrap()
    };
    let (ra, rb) = (reference("refs-single"), reference("refs-merged"));
    assert!(
        ra.data
            .iter()
            .zip(&rb.data)
            .all(|(x, y)| (*x - *y).abs().max_element() <= 1e-5 * x.abs().max_element() + 1e-9)
    );

    // Negative control: another method list gives other errors (the comparison above could
    // not pass by accident).
    let mut other = b[0].clone();
    other["mse"] = serde_json::json!(b[0]["mse"].as_f64().unwrap() * 1.01);
    assert!(same_errors(&a[0], &other, 1e-4, "control").is_err());

    // A corrupt result, a result of another job, a result of another plan: one clear error each.
    let job3 = plan.join("jobs/0003.safetensors");
    let good = std::fs::read(&job3).unwrap();
    std::fs::write(&job3, &good[..good.len() / 2]).unwrap();
    clean_error(&nrc(&["compare", "--merge", &p]), &["job 3", "corrupt"]);
    std::fs::copy(plan.join("jobs/0004.safetensors"), &job3).unwrap();
    clean_error(
        &nrc(&["compare", "--merge", &p]),
        &["job 3", "is the result of job 4"],
    );
    let plan2 = t.join("plan2");
    let mut args = vec!["compare".to_string()];
    args.extend(study_flags(&t.join("merged2"), &t.join("refs-merged")));
    args.extend([
        "--plan".into(),
        plan2.display().to_string(),
        "--seed".into(),
        "7".into(),
    ]);
    ok(nrc(&args.iter().map(String::as_str).collect::<Vec<_>>()));
    ok(nrc(&["job", &plan2.display().to_string(), "3"]));
    std::fs::copy(plan2.join("jobs/0003.safetensors"), &job3).unwrap();
    clean_error(
        &nrc(&["compare", "--merge", &p]),
        &["job 3", "belongs to another plan"],
    );
    std::fs::write(&job3, &good).unwrap();
    ok(nrc(&["compare", "--merge", &p]));

    // Bad requests.
    clean_error(&nrc(&["job", &p, "99"]), &["no job 99", "0 to 8"]);
    clean_error(
        &nrc(&[
            "compare",
            "--merge",
            &t.join("nowhere").display().to_string(),
        ]),
        &["plan.json"],
    );
}
