//! End-to-end tests of the `nrc` program: rendering writes its files, `info` prints what a
//! scene holds, and bad input ends with one `error:` line and a non-zero status, never a
//! panic.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn nrc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nrc"))
        .args(args)
        .output()
        .expect("nrc runs")
}

fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The command failed cleanly: non-zero status, exactly one line on stderr, starting with
/// `error:` and mentioning `needle`, and no panic.
fn assert_clean_error(out: &Output, needle: &str) {
    let err = text(&out.stderr);
    assert!(!out.status.success(), "succeeded; stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one error line, got: {err}");
    assert!(lines[0].starts_with("error: "), "not an error line: {err}");
    assert!(
        lines[0].contains(needle),
        "error line does not name `{needle}`: {err}"
    );
}

#[test]
fn render_writes_exr_png_and_variance() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("out.exr");
    let png = dir.path().join("out.png");
    let var = dir.path().join("var.exr");
    let cornell = scene("cornell-box.gltf");
    let out = nrc(&[
        "render",
        "--scene",
        cornell.to_str().unwrap(),
        "--spp",
        "4",
        "--width",
        "40",
        "--height",
        "30",
        "--out",
        exr.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
        "--variance",
        var.to_str().unwrap(),
        "--exposure",
        "1",
        "--seed",
        "3",
        "--max-depth",
        "5",
        "--threads",
        "2",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("samples/s") && stdout.contains("rays/s"),
        "closing line: {stdout}"
    );
    let img = nrc_scene::Image::read_exr(&exr).unwrap();
    assert_eq!((img.width, img.height), (40, 30));
    assert!(img.mean().max_element() > 0.0);
    assert!(
        img.data
            .iter()
            .all(|p| p.is_finite() && p.min_element() >= 0.0)
    );
    let v = nrc_scene::Image::read_exr(&var).unwrap();
    assert_eq!((v.width, v.height), (40, 30));
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    // No temporary files left behind by the atomic writes.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 3, "{names:?}");
}

#[test]
fn render_is_reproducible_and_camera_overrides_apply() {
    let dir = tempfile::tempdir().unwrap();
    let cornell = scene("cornell-box.gltf");
    let render = |name: &str, threads: &str, extra: &[&str]| {
        let path = dir.path().join(name);
        let mut args = vec![
            "render",
            "--scene",
            cornell.to_str().unwrap(),
            "--spp",
            "2",
            "--width",
            "24",
            "--height",
            "16",
            "--out",
            path.to_str().unwrap(),
            "--threads",
            threads,
        ];
        args.extend_from_slice(extra);
        let out = nrc(&args);
        assert!(out.status.success(), "{}", text(&out.stderr));
        nrc_scene::Image::read_exr(&path).unwrap()
    };
    let a = render("a.exr", "1", &[]);
    let b = render("b.exr", "2", &[]);
    assert_eq!(a, b, "same seed, different thread counts");
    // Looking away from the box (from its front, outward) sees only black.
    let away = render(
        "c.exr",
        "2",
        &[
            "--camera-pos",
            "0.278,0.273,-0.8",
            "--camera-target",
            "0.278,0.273,-2",
            "--fov-y",
            "30",
        ],
    );
    assert_eq!(away.mean().max_element(), 0.0);
    // A grey background lights the view away from the box.
    let sky = render(
        "d.exr",
        "2",
        &[
            "--camera-pos",
            "0.278,0.273,-0.8",
            "--camera-target",
            "0.278,0.273,-2",
            "--background",
            "0.5",
        ],
    );
    assert!((sky.mean() - glam::Vec3::splat(0.5)).abs().max_element() < 1e-6);
}

#[test]
fn info_prints_counts() {
    let out = nrc(&[
        "info",
        "--scene",
        scene("cornell-box.gltf").to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    for key in ["triangles:", "materials:", "lights:", "bounds:", "camera:"] {
        assert!(s.contains(key), "`{key}` missing from: {s}");
    }
    let triangles: usize = s
        .lines()
        .find_map(|l| l.strip_prefix("triangles:"))
        .and_then(|v| v.trim().parse().ok())
        .expect("triangle count");
    assert!(triangles > 0);
}

#[test]
fn bench_trace_prints_table() {
    let out = nrc(&[
        "bench",
        "trace",
        "--scene",
        scene("cornell-box.gltf").to_str().unwrap(),
        "--width",
        "16",
        "--height",
        "16",
        "--spp",
        "1",
        "--repeats",
        "1",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    for row in ["primary rays", "incoherent", "path tracer"] {
        assert!(s.contains(row), "`{row}` missing from: {s}");
    }
}

#[test]
fn missing_scene_is_one_error_line() {
    let out = nrc(&["info", "--scene", "/nonexistent/nothing.gltf"]);
    assert_clean_error(&out, "nothing.gltf");
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("o.exr");
    let out = nrc(&[
        "render",
        "--scene",
        "/nonexistent/nothing.glb",
        "--out",
        exr.to_str().unwrap(),
    ]);
    assert_clean_error(&out, "nothing.glb");
}

#[test]
fn malformed_scenes_are_one_error_line() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bad.gltf");
    std::fs::write(
        &json,
        "{ \"asset\": { \"version\": \"2.0\" }, \"nodes\": [ oops ",
    )
    .unwrap();
    assert_clean_error(
        &nrc(&["info", "--scene", json.to_str().unwrap()]),
        "bad.gltf",
    );

    // A .glb header that promises more bytes than the file holds.
    let glb = dir.path().join("truncated.glb");
    let mut bytes = b"glTF".to_vec();
    bytes.extend_from_slice(&2u32.to_le_bytes());
    bytes.extend_from_slice(&4096u32.to_le_bytes());
    bytes.extend_from_slice(&100u32.to_le_bytes());
    bytes.extend_from_slice(b"JSON{\"asset\":");
    std::fs::write(&glb, &bytes).unwrap();
    let exr = dir.path().join("o.exr");
    assert_clean_error(
        &nrc(&[
            "render",
            "--scene",
            glb.to_str().unwrap(),
            "--out",
            exr.to_str().unwrap(),
            "--spp",
            "1",
        ]),
        "truncated.glb",
    );

    // A buffer file that is not there.
    let nobuf = dir.path().join("nobuffer.gltf");
    std::fs::write(
        &nobuf,
        r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"missing.bin","byteLength":36}],
            "bufferViews":[{"buffer":0,"byteLength":36}],
            "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}],
            "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],
            "nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}],"scene":0}"#,
    )
    .unwrap();
    assert_clean_error(
        &nrc(&["info", "--scene", nobuf.to_str().unwrap()]),
        "nobuffer.gltf",
    );
    assert!(!exr.exists(), "no output after a failed load");
}

#[test]
fn bad_options_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("o.exr");
    let cornell = scene("cornell-box.gltf");
    let base = [
        "render",
        "--scene",
        cornell.to_str().unwrap(),
        "--out",
        exr.to_str().unwrap(),
    ];
    let with = |extra: &[&str]| {
        let mut a = base.to_vec();
        a.extend_from_slice(extra);
        nrc(&a)
    };
    assert_clean_error(&with(&["--spp", "0"]), "spp");
    assert_clean_error(&with(&["--width", "0"]), "0x");
    assert_clean_error(
        &with(&[
            "--camera-pos",
            "0.278,0.273,-0.8",
            "--camera-target",
            "0.278,0.273,-0.8",
        ]),
        "camera",
    );
    // The sample variance is not that of stratified samples.
    let var = dir.path().join("v.exr");
    assert_clean_error(
        &with(&[
            "--camera-offsets",
            "sobol",
            "--variance",
            var.to_str().unwrap(),
            "--spp",
            "2",
        ]),
        "--camera-offsets sobol",
    );
    // Value syntax errors come from the argument parser: non-zero, no panic.
    let out = with(&["--camera-offsets", "halton"]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("--camera-offsets"));
    let out = with(&["--camera-pos", "1,2"]);
    assert!(!out.status.success());
    assert!(!text(&out.stderr).contains("panicked"));
    // An output folder that does not exist.
    let out = nrc(&[
        "render",
        "--scene",
        cornell.to_str().unwrap(),
        "--out",
        "/nonexistent/dir/o.exr",
        "--spp",
        "1",
        "--width",
        "8",
        "--height",
        "8",
    ]);
    assert_clean_error(&out, "/nonexistent/dir/o.exr");
}

/// The resampling passes run from the command line: `nrc render --pass ... --frames N` (with a
/// camera path), `nrc train --pass` with a `-nrc` variant reading the cache it trains, and bad
/// pass parameters are one error line.
#[test]
fn resampling_passes_render_and_train_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.exr");
    let path = dir.path().join("path.json");
    std::fs::write(
        &path,
        r#"[{"position": [0.278, 0.273, -0.8], "target": [0.278, 0.273, 0.3]}, {"position": [0.3, 0.28, -0.8], "target": [0.278, 0.273, 0.3]}]"#,
    )
    .unwrap();
    let cornell = scene("cornell-box.gltf");
    let s = cornell.to_str().unwrap();
    for pass in ["restir-di", "restir-gi-biased", "wsrestir-gi:samples=2"] {
        let o = nrc(&[
            "render",
            "--scene",
            s,
            "--pass",
            pass,
            "--frames",
            "3",
            "--camera-path",
            path.to_str().unwrap(),
            "--spp",
            "1",
            "--width",
            "16",
            "--height",
            "12",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{pass}: {}", text(&o.stderr));
        let stdout = text(&o.stdout);
        assert!(
            stdout.contains("last of 3 frames")
                && stdout.contains("phases: ")
                && stdout.contains("candidates "),
            "{stdout}"
        );
        let img = nrc_scene::Image::read_exr(&out).unwrap();
        assert!(
            img.data.iter().any(|p| p.max_element() > 0.0),
            "{pass} rendered black"
        );
    }
    let o = nrc(&[
        "train",
        "--scene",
        s,
        "--producer",
        "pt-sl",
        "--pass",
        "wsrestir-gi-nrc",
        "--frames",
        "2",
        "--width",
        "16",
        "--height",
        "12",
        "--records",
        "512",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    for bad in ["restir-di:k=x", "wsrestir-gi:k=3", "restir-gi:mcap=0"] {
        let o = nrc(&[
            "render",
            "--scene",
            s,
            "--pass",
            bad,
            "--spp",
            "1",
            "--width",
            "8",
            "--height",
            "8",
            "--out",
            out.to_str().unwrap(),
        ]);
        // Rejected by the argument parser: its error line names the pass, no panic.
        let err = text(&o.stderr);
        assert!(
            !o.status.success() && !err.contains("panicked"),
            "{bad}: {err}"
        );
        assert!(
            err.lines()
                .next()
                .is_some_and(|l| l.starts_with("error: ") && l.contains(bad)),
            "{err}"
        );
    }
}

/// A pass holds every pixel sample of a frame at once: a frame too large for the memory
/// available ends with one `error:` line naming `--spp`, before anything is allocated for it
/// (without the check, 640 × 360 at 64 spp of `wsrestir-gi` grew to 24 GB and was killed).
#[test]
fn a_pass_frame_too_large_for_the_memory_is_refused_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.exr");
    let s = scene("cornell-box.gltf");
    let args = |pass: &'static str, spp: &'static str| {
        let mut a = vec!["render", "--scene", s.to_str().unwrap(), "--pass", pass];
        a.extend(["--spp", spp, "--width", "640", "--height", "360"]);
        a.extend(["--out", out.to_str().unwrap()]);
        a
    };
    // 2.3 × 10¹¹ pixel samples: hundreds of TB at any pass's size.
    let o = nrc(&args("wsrestir-gi", "1000000"));
    assert_clean_error(&o, "--spp");
    assert!(
        text(&o.stderr).contains("wsrestir-gi holds all"),
        "{}",
        text(&o.stderr)
    );
    assert!(!out.exists(), "an image was written");
    // The same frame asked of `nrc compare` (before its reference is rendered) and of `nrc
    // train`'s inference pass.
    let dir_out = dir.path().join("cmp");
    let o = nrc(&[
        "compare",
        "--scene",
        s.to_str().unwrap(),
        "--methods",
        "pt-1spp,wsrestir-gi@1000000spp",
        "--width",
        "640",
        "--height",
        "360",
        "--equal-spp",
        "1",
        "--out",
        dir_out.to_str().unwrap(),
    ]);
    assert_clean_error(&o, "wsrestir-gi@1000000spp");
    assert!(!dir_out.exists(), "compare wrote its folder");
    let o = nrc(&[
        "train",
        "--scene",
        s.to_str().unwrap(),
        "--pass",
        "wsrestir-gi",
        "--spp",
        "1000000",
        "--width",
        "640",
        "--height",
        "360",
        "--frames",
        "1",
    ]);
    assert_clean_error(&o, "holds all");
}
