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
                // Timings differ between processes; the rays a pass traced do not.
                if matches!(k.as_str(), "time_per_frame_ms" | "ms_per_pass" | "phases") {
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
    std::fs::write(plan.join("jobs/.nrc-a1b2c3.tmp"), b"half a result").unwrap();
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
    assert_eq!(b.len(), 3);
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x["method"], y["method"]);
        assert!(
            x["bias_variance"].is_object(),
            "2 runs give bias and variance"
        );
        same_errors(x, y, 1e-4, x["method"].as_str().unwrap()).unwrap();
    }
    // The merged reference is the single render's, within float rounding.
    let reference = |dir: &str, file: &str| {
        let entries: Vec<_> = std::fs::read_dir(t.join(dir))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        assert_eq!(entries.len(), 1, "one reference in {dir}");
        nrc_scene::Image::read_exr(&entries[0].join(file)).unwrap()
    };
    for file in ["mean.exr", "variance.exr"] {
        let (ra, rb) = (
            reference("refs-single", file),
            reference("refs-merged", file),
        );
        assert_eq!(ra.data.len(), 32 * 32);
        assert_eq!(ra.data.len(), rb.data.len());
        assert!(
            ra.data.iter().zip(&rb.data).all(|(x, y)| {
                (*x - *y).abs().max_element() <= 1e-5 * x.abs().max_element() + 1e-9
            }),
            "{file}"
        );
    }

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

    // An edited plan: a job writing outside its folder, changed settings; each refused.
    let plan_json = std::fs::read_to_string(plan.join("plan.json")).unwrap();
    std::fs::write(
        plan.join("plan.json"),
        plan_json.replace("jobs/0005.safetensors", "../0005.safetensors"),
    )
    .unwrap();
    clean_error(
        &nrc(&["job", &p, "5"]),
        &["job list is not the one its settings give"],
    );
    assert!(plan_json.contains("\"32\""));
    std::fs::write(
        plan.join("plan.json"),
        plan_json.replacen("\"32\"", "\"33\"", 1),
    )
    .unwrap();
    clean_error(
        &nrc(&["compare", "--merge", &p]),
        &["changed since it was planned"],
    );
    std::fs::write(plan.join("plan.json"), &plan_json).unwrap();
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

/// A fake `sbatch` that records its calls and, with `RUN=1`, runs what they submit: each
/// array task in `--chdir` with `SLURM_ARRAY_TASK_ID` set, then the dependent merge.
const FAKE_SBATCH: &str = r#"#!/usr/bin/env bash
printf '%s\x1f' "$@" >> "$LOG"; printf '\n' >> "$LOG"
array= wrap= chdir= offset=
for a in "$@"; do
  case "$a" in
    --array=*) array=${a#--array=} ;;
    --wrap=*) wrap=${a#--wrap=} ;;
    --chdir=*) chdir=${a#--chdir=} ;;
    --export=ALL,NRC_OFFSET=*) offset=${a#--export=ALL,NRC_OFFSET=} ;;
  esac
done
if [[ -n "${RUN:-}" ]]; then
  if [[ -n "$array" ]]; then
    for ((i = ${array%-*}; i <= ${array#*-}; i++)); do
      (cd "$chdir" && NRC_OFFSET=$offset SLURM_ARRAY_TASK_ID=$i bash -c "$wrap") > /dev/null 2>&1 || exit 1
    done
  else
    (cd "$chdir" && bash -c "$wrap") > /dev/null 2>&1 || exit 1
  fi
fi
echo "$((1000 + $(wc -l < "$LOG")));cluster"
"#;

fn slurm(plan: &Path, bin: &Path, log: &Path, run: bool) -> Output {
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut cmd = Command::new("bash");
    cmd.args([
        "scripts/slurm_study.sh",
        &plan.display().to_string(),
        "--partition=cpu",
    ])
    .current_dir(env!("CARGO_MANIFEST_DIR"))
    .env("PATH", path)
    .env("LOG", log)
    .env("NRC", env!("CARGO_BIN_EXE_nrc"))
    .env("CPUS", "2");
    if run {
        cmd.env("RUN", "1");
    }
    cmd.output().unwrap()
}

/// `scripts/slurm_study.sh` submits the jobs as arrays of at most 1000 tasks running `nrc job`
/// and the merge after all of them; run by the fake `sbatch`, the study's report appears.
#[test]
fn slurm_script_submits_arrays_and_the_merge() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let bin = t.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    std::fs::write(bin.join("sbatch"), FAKE_SBATCH).unwrap();
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(bin.join("sbatch"), std::fs::Permissions::from_mode(0o755))
            .unwrap();
    }
    let calls = |log: &Path| -> Vec<Vec<String>> {
        std::fs::read_to_string(log)
            .unwrap()
            .lines()
            .map(|l| {
                l.split('\x1f')
                    .filter(|a| !a.is_empty())
                    .map(String::from)
                    .collect()
            })
            .collect()
    };

    // A small study, run through the fake scheduler.
    let plan = t.join("plan");
    let mut args = vec!["compare".to_string()];
    args.extend(study_flags(&t.join("report"), &t.join("refs")));
    args.extend([
        "--plan".into(),
        plan.display().to_string(),
        "--chunks".into(),
        "2".into(),
    ]);
    ok(nrc(&args.iter().map(String::as_str).collect::<Vec<_>>()));
    let log = t.join("log");
    let out = ok(slurm(&plan, &bin, &log, true));
    assert!(
        text(&out.stdout)
            .contains("submitted 8 jobs as array job(s) 1001 and the merge as job 1002")
    );
    let c = calls(&log);
    assert_eq!(c.len(), 2);
    let abs = plan.canonicalize().unwrap().display().to_string();
    for a in [
        "--parsable",
        "--partition=cpu",
        "--cpus-per-task=2",
        "--array=0-7",
        "--export=ALL,NRC_OFFSET=0",
        &format!("--chdir={}", env!("CARGO_MANIFEST_DIR")),
    ] {
        assert!(c[0].iter().any(|x| x == a), "{a} not in {:?}", c[0]);
    }
    assert!(
        c[0].iter().any(|x| x
            == &format!(
                "--wrap={} job {abs} $((NRC_OFFSET + SLURM_ARRAY_TASK_ID)) --threads 2",
                env!("CARGO_BIN_EXE_nrc")
            )),
        "{:?}",
        c[0]
    );
    assert!(
        c[1].iter().any(|x| x == "--dependency=afterok:1001"),
        "{:?}",
        c[1]
    );
    assert!(c[1].iter().any(|x| x == "--kill-on-invalid-dep=yes"));
    assert!(
        c[1].iter()
            .any(|x| x == &format!("--wrap={} compare --merge {abs}", env!("CARGO_BIN_EXE_nrc")))
    );
    assert_eq!(
        report_rows(&t.join("report")).len(),
        3,
        "the merge ran and wrote the report"
    );

    // A study of 1,002 jobs: two arrays, the merge after both.
    let big = t.join("big");
    ok(nrc(&[
        "compare",
        "--scene",
        "scenes/cornell-box.gltf",
        "--methods",
        "pt-1spp",
        "--equal-spp",
        "1",
        "--runs",
        "1001",
        "--plan",
        &big.display().to_string(),
    ]));
    let log = t.join("log-big");
    let out = ok(slurm(&big, &bin, &log, false));
    assert!(
        text(&out.stdout)
            .contains("submitted 1002 jobs as array job(s) 1001 1002 and the merge as job 1003")
    );
    let c = calls(&log);
    assert!(c[0].iter().any(|x| x == "--array=0-999"));
    assert!(c[0].iter().any(|x| x == "--export=ALL,NRC_OFFSET=0"));
    assert!(c[1].iter().any(|x| x == "--array=0-1"));
    assert!(c[1].iter().any(|x| x == "--export=ALL,NRC_OFFSET=1000"));
    assert!(c[2].iter().any(|x| x == "--dependency=afterok:1001:1002"));

    // No plan: one clear error.
    let out = slurm(&t.join("nowhere"), &bin, &t.join("log-none"), false);
    assert!(!out.status.success() && text(&out.stderr).starts_with("error: no study plan"));
}

/// Equal-time frames timed on different kinds of machine (here: other thread counts) are not
/// merged into one comparison, unless the plan allows it.
#[test]
fn equal_time_merge_refuses_mixed_machines() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let plan_with = |dir: &Path, allow: bool| {
        let mut args: Vec<String> = [
            "compare",
            "--scene",
            "scenes/cornell-box.gltf",
            "--methods",
            "pt-1spp",
            "--equal-time",
            "20",
            "--width",
            "16",
            "--height",
            "16",
            "--runs",
            "2",
            "--reference-spp",
            "8",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        args.extend([
            "--out".into(),
            t.join("out").display().to_string(),
            "--cache-dir".into(),
            t.join("refs").display().to_string(),
            "--plan".into(),
            dir.display().to_string(),
        ]);
        if allow {
            args.push("--allow-mixed-machines".into());
        }
        ok(nrc(&args.iter().map(String::as_str).collect::<Vec<_>>()));
        let d = dir.display().to_string();
        ok(nrc(&["job", &d, "0", "--threads", "1"]));
        ok(nrc(&["job", &d, "1", "--threads", "1"]));
        ok(nrc(&["job", &d, "2", "--threads", "2"]));
        nrc(&["compare", "--merge", &d])
    };
    clean_error(
        &plan_with(&t.join("strict"), false),
        &["2 kinds of machine", "1 thread(s)", "2 thread(s)"],
    );
    ok(plan_with(&t.join("allowed"), true));
}
