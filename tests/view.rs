//! End to end: `nrc view`. Headless, its viewport is the online loop's frame after the same
//! tone mapping, and every debug view renders; in a real window under Xvfb, synthetic keys
//! switch the view, move the camera, take screenshots and save a snapshot that loads; with no
//! display or no adapter it fails with one clear line.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use nrc_scene::image::Image;

fn nrc_command() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nrc"))
}

fn nrc(args: &[&str]) -> Output {
    nrc_command().args(args).output().expect("nrc runs")
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

fn ok(out: Output, what: &str) -> Output {
    assert!(
        out.status.success(),
        "{what} failed: {}{}",
        text(&out.stdout),
        text(&out.stderr)
    );
    out
}

/// A PNG's size and RGB pixels.
fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let decoder = png::Decoder::new(std::io::BufReader::new(file));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    (info.width, info.height, buf)
}

/// Largest channel difference, and the mean absolute difference.
fn diff(a: &[u8], b: &[u8]) -> (u8, f64) {
    assert_eq!(a.len(), b.len());
    let max = a
        .iter()
        .zip(b)
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap_or(0);
    let mean = a
        .iter()
        .zip(b)
        .map(|(x, y)| f64::from(x.abs_diff(*y)))
        .sum::<f64>()
        / a.len().max(1) as f64;
    (max, mean)
}

/// Whether a wgpu adapter can be had; the reason where not (the test is then skipped, with
/// "wgpu" in the reason so that CI, which installs software Vulkan, fails on it).
fn adapter(test: &str) -> bool {
    match nrc_view::display::Gpu::headless() {
        Ok(_) => true,
        Err(e) => {
            nrc_scene::testing::skipped(test, &format!("no wgpu adapter: {e}"));
            false
        }
    }
}

const SIZE: [&str; 4] = ["--width", "48", "--height", "32"];

#[test]
fn headless_viewport_is_the_online_loops_frame_and_every_view_renders() {
    if !adapter("headless_viewport_is_the_online_loops_frame_and_every_view_renders") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let scene = cornell();
    let common = |v: &mut Vec<String>| {
        v.extend(
            [
                "--scene",
                &scene,
                "--frames",
                "3",
                "--seed",
                "5",
                "--records",
                "2048",
                "--threads",
                "2",
            ]
            .iter()
            .chain(&SIZE)
            .map(|s| s.to_string()),
        );
    };
    // The online loop as `nrc train` runs it, every frame written.
    let mut train = vec!["train".to_string()];
    common(&mut train);
    train.extend([
        "--frames-out".into(),
        p("frames"),
        "--every".into(),
        "1".into(),
    ]);
    ok(nrc_command().args(&train).output().unwrap(), "nrc train");
    let frame =
        |i: u32| Image::read_exr(&dir.path().join(format!("frames/frame-{i:05}.exr"))).unwrap();
    let frames: Vec<Image> = (0..3).map(frame).collect();
    let mut mean = frames[0].clone();
    for (i, v) in mean.data.iter_mut().enumerate() {
        *v = (frames[0].data[i] + frames[1].data[i] + frames[2].data[i]) / 3.0;
    }
    // A reference for the error view.
    ok(
        nrc(&[
            "render",
            "--scene",
            &scene,
            "--spp",
            "16",
            "--out",
            &p("ref.exr"),
            SIZE[0],
            SIZE[1],
            SIZE[2],
            SIZE[3],
        ]),
        "nrc render",
    );

    let view = |name: &str, extra: &[&str]| {
        let mut v = vec!["view".to_string(), "--headless".into()];
        common(&mut v);
        v.extend([
            "--view".into(),
            name.into(),
            "--viewport-png".into(),
            p(&format!("{name}.png")),
        ]);
        v.extend(extra.iter().map(|s| s.to_string()));
        ok(
            nrc_command().args(&v).output().unwrap(),
            "nrc view --headless",
        )
    };
    let out = view(
        "raw",
        &[
            "--screenshot",
            &p("ui.png"),
            "--views-out",
            &p("views"),
            "--reference",
            &p("ref.exr"),
            "--window-size",
            "640x400",
        ],
    );
    assert!(
        text(&out.stdout).contains("viewed 3 frames"),
        "{}",
        text(&out.stdout)
    );

    // The raw view is the loop's last frame, tone mapped as `nrc render --png` does.
    let (w, h, raw) = read_png(&dir.path().join("raw.png"));
    assert_eq!((w, h), (48, 32));
    let (max, _) = diff(&raw, &frames[2].to_srgb8(0.0));
    assert!(
        max <= 1,
        "the raw view is off the loop's frame by {max} levels"
    );
    // Negative control: another frame of the same loop is not it.
    let (max, mean_diff) = diff(&raw, &frames[1].to_srgb8(0.0));
    assert!(
        max > 8 && mean_diff > 0.5,
        "frames 1 and 2 look alike: {max} {mean_diff}"
    );
    // The final view is the mean of the three frames.
    let (_, _, fin) = read_png(&dir.path().join("views/final.png"));
    let (max, _) = diff(&fin, &mean.to_srgb8(0.0));
    assert!(
        max <= 1,
        "the final view is off the frames' mean by {max} levels"
    );
    // Exposure: the same view two stops up is the CPU's preview two stops up.
    view("final", &["--exposure", "2"]);
    let (_, _, bright) = read_png(&dir.path().join("final.png"));
    assert!(diff(&bright, &mean.to_srgb8(2.0)).0 <= 1);
    assert!(diff(&bright, &fin).0 > 20, "exposure changed nothing");

    // Every view renders, and each differs from the others.
    let names = ["final", "raw", "cache", "records", "error"];
    let images: Vec<Vec<u8>> = names
        .iter()
        .map(|n| {
            let (vw, vh, px) = read_png(&dir.path().join(format!("views/{n}.png")));
            assert_eq!((vw, vh), (48, 32), "{n}");
            let distinct: std::collections::HashSet<&[u8]> = px.chunks_exact(3).collect();
            assert!(distinct.len() > 4, "{n}: only {} colours", distinct.len());
            px
        })
        .collect();
    for i in 0..names.len() {
        for j in i + 1..names.len() {
            let (max, _) = diff(&images[i], &images[j]);
            assert!(max > 8, "views {} and {} look alike", names[i], names[j]);
        }
    }
    // The records view counts this frame's records seen by the camera: most pixels of the box
    // got some (2,048 records over 1,536 pixels), shown above the map's bottom colour.
    let bottom = [images[3][0], images[3][1], images[3][2]];
    let hot = images[3].chunks_exact(3).filter(|p| *p != bottom).count();
    assert!(hot > 300, "records view: {hot} pixels with records");
    // The UI screenshot: the window's size, not one flat colour.
    let (sw, sh, ui) = read_png(&dir.path().join("ui.png"));
    assert_eq!((sw, sh), (640, 400));
    let distinct: std::collections::HashSet<&[u8]> = ui.chunks_exact(3).collect();
    assert!(
        distinct.len() > 50,
        "the UI screenshot has {} colours",
        distinct.len()
    );
    // The viewport is in it, each texel a square of whole pixels.
    let found = find_scaled((sw, sh, &ui), (48, 32, &raw));
    assert!(found.is_some(), "the viewport is not in the UI screenshot");
    let (_, _, scale) = found.unwrap();
    assert!(
        scale >= 2,
        "the viewport is drawn at {scale} pixels a texel"
    );
    // Negative control: another frame is not found in it.
    assert!(find_scaled((sw, sh, &ui), (48, 32, &frames[1].to_srgb8(0.0))).is_none());

    // A pass's own views: ReSTIR DI's reservoirs, DDGI resampling's probes, instant
    // radiosity's VPLs.
    for (pass, own) in [
        ("restir-di", "reservoir-m"),
        ("ddgi-restir", "probes"),
        ("ir", "vpls"),
    ] {
        let mut v = vec!["view".to_string(), "--headless".into()];
        common(&mut v);
        v.extend(["--pass".into(), pass.into(), "--views-out".into(), p(pass)]);
        let out = ok(nrc_command().args(&v).output().unwrap(), pass);
        assert!(
            text(&out.stdout).contains(own),
            "{pass}: {}",
            text(&out.stdout)
        );
        let (_, _, px) = read_png(&dir.path().join(format!("{pass}/{own}.png")));
        let distinct: std::collections::HashSet<&[u8]> = px.chunks_exact(3).collect();
        assert!(distinct.len() > 1, "{pass}'s {own} view is flat");
    }
    // A camera path plays from the first frame as in `nrc train`: the raw view after 3 frames
    // is train's third frame along the same path.
    let path = p("path.json"); // the Cornell box's camera, then closer and turned
    std::fs::write(
        &path,
        r#"[{"position": [0.278, 0.273, -0.8], "target": [0.278, 0.273, 0.2]},
            {"position": [0.2, 0.3, -0.5], "target": [0.3, 0.25, 0.3]}]"#,
    )
    .unwrap();
    let mut train = vec!["train".to_string()];
    common(&mut train);
    train.extend([
        "--camera-path".into(),
        path.clone(),
        "--frames-out".into(),
        p("path-frames"),
    ]);
    ok(
        nrc_command().args(&train).output().unwrap(),
        "nrc train --camera-path",
    );
    let along = Image::read_exr(&dir.path().join("path-frames/frame-00002.exr")).unwrap();
    view("raw", &["--camera-path", &path]);
    let (_, _, raw_path) = read_png(&dir.path().join("raw.png"));
    assert!(
        diff(&raw_path, &along.to_srgb8(0.0)).0 <= 1,
        "the camera path's last frame differs"
    );
    assert!(
        diff(&raw_path, &raw).0 > 8,
        "the camera path changed nothing"
    );

    // An animated scene is posed at frame / fps, as `nrc train` poses it.
    let moving = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box-moving.gltf")
        .to_str()
        .unwrap()
        .to_string();
    let animated = |command: &str, extra: &[String]| {
        let mut v = vec![command.to_string(), "--scene".into(), moving.clone()];
        v.extend(
            [
                "--frames",
                "3",
                "--seed",
                "5",
                "--records",
                "1024",
                "--threads",
                "2",
                "--fps",
                "4",
            ]
            .iter()
            .chain(&SIZE)
            .map(|s| s.to_string()),
        );
        v.extend(extra.iter().cloned());
        ok(nrc_command().args(&v).output().unwrap(), command)
    };
    animated("train", &["--frames-out".into(), p("moving-frames")]);
    animated(
        "view",
        &[
            "--headless".into(),
            "--view".into(),
            "raw".into(),
            "--viewport-png".into(),
            p("moving.png"),
        ],
    );
    let third = Image::read_exr(&dir.path().join("moving-frames/frame-00002.exr")).unwrap();
    let (_, _, shown) = read_png(&dir.path().join("moving.png"));
    assert!(
        diff(&shown, &third.to_srgb8(0.0)).0 <= 1,
        "the animated scene's frame differs"
    );

    // Without --reference, the error view takes the stored reference made for this scene,
    // camera and size with the most samples; for another camera none is stored.
    let store = p("store");
    for spp in ["4", "8"] {
        let mut r = vec![
            "reference",
            "--scene",
            &scene,
            "--spp",
            spp,
            "--cache-dir",
            &store,
        ];
        r.extend(SIZE);
        ok(nrc(&r), "nrc reference");
    }
    let stored = |extra: &[&str]| {
        let mut v = vec!["view".to_string(), "--headless".into()];
        common(&mut v);
        v.extend(["--cache-dir".into(), store.clone()]);
        v.extend(extra.iter().map(|s| s.to_string()));
        text(&ok(nrc_command().args(&v).output().unwrap(), "nrc view").stderr)
    };
    let err = stored(&[]);
    assert!(
        err.contains("error view: the reference") && err.contains("(8 spp)"),
        "{err}"
    );
    let err = stored(&["--camera-pos", "0.1,0.2,1.5", "--camera-target", "0,0.2,0"]);
    assert!(err.contains("error view: no reference"), "{err}");
    // A view that does not exist is an error naming the views.
    let mut v = vec!["view".to_string(), "--headless".into()];
    common(&mut v);
    v.extend(["--view".into(), "nonsense".into()]);
    let out = nrc_command().args(&v).output().unwrap();
    assert_error(&out, "no view called");
}

/// Where `small` (RGB, w × h) appears in `big` magnified by a whole factor (each texel a
/// square of equal pixels): the offset and the factor.
fn find_scaled(big: (u32, u32, &[u8]), small: (u32, u32, &[u8])) -> Option<(u32, u32, u32)> {
    let (bw, bh, b) = big;
    let (w, h, p) = small;
    let at = |img: &[u8], width: u32, x: u32, y: u32| {
        let i = 3 * (y * width + x) as usize;
        [img[i], img[i + 1], img[i + 2]]
    };
    for s in 1..=(bw / w).min(bh / h) {
        for oy in 0..=bh - h * s {
            for ox in 0..=bw - w * s {
                let all = (0..h).all(|y| {
                    (0..w).all(|x| {
                        let want = at(p, w, x, y);
                        // A texel's first and last pixel.
                        at(b, bw, ox + x * s, oy + y * s) == want
                            && at(b, bw, ox + x * s + s - 1, oy + y * s + s - 1) == want
                    })
                });
                if all {
                    return Some((ox, oy, s));
                }
            }
        }
    }
    None
}

/// Failed cleanly: exit status 1, no panic, an `error: ...` line naming `needle`.
fn assert_error(out: &Output, needle: &str) {
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(
        err.lines()
            .any(|l| l.starts_with("error: ") && l.contains(needle)),
        "{err}"
    );
}

#[test]
fn without_a_display_or_an_adapter_view_fails_with_one_clear_line() {
    let scene = cornell();
    let mut args = vec!["view", "--scene", &scene];
    args.extend(SIZE);
    let out = nrc_command()
        .args(&args)
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    assert_error(&out, "cannot open a window");
    // Headless with no Vulkan driver to be found.
    args.extend(["--headless", "--frames", "1"]);
    let out = nrc_command()
        .args(&args)
        .env("WGPU_BACKEND", "vulkan")
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .output()
        .unwrap();
    assert_error(&out, "no GPU adapter");
}

/// An Xvfb server on a free display, stopped on drop.
struct Xvfb {
    child: Child,
    display: String,
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        // SIGTERM, so that the server removes its lock file and the display number is free again.
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let _ = self.child.wait();
    }
}

/// A child process killed if the test ends before it does.
struct Guard(Option<Child>);

impl Drop for Guard {
    fn drop(&mut self) {
        if let Some(c) = &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn xvfb() -> Result<Xvfb, String> {
    for n in 91..140 {
        if Path::new(&format!("/tmp/.X{n}-lock")).exists() {
            continue;
        }
        let display = format!(":{n}");
        let child = Command::new("Xvfb")
            .args([&display, "-screen", "0", "1024x768x24", "-nolisten", "tcp"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("Xvfb: {e}"))?;
        let mut x = Xvfb { child, display };
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(10) {
            if Path::new(&format!("/tmp/.X11-unix/X{n}")).exists() {
                return Ok(x);
            }
            if let Ok(Some(_)) = x.child.try_wait() {
                break;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let _ = x.child.kill();
    }
    Err("no Xvfb display could be started".into())
}

fn xdotool(display: &str, args: &[&str]) -> Output {
    Command::new("xdotool")
        .args(args)
        .env("DISPLAY", display)
        .output()
        .expect("xdotool runs")
}

/// Waits until `path` exists (written atomically by the viewer), up to `secs`.
fn wait_for(path: &Path, secs: u64) -> bool {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(secs) {
        if path.exists() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    false
}

/// Presses F12 and returns the screenshot the viewer wrote.
fn screenshot(display: &str, path: &Path) -> Vec<u8> {
    let _ = std::fs::remove_file(path);
    xdotool(display, &["key", "F12"]);
    assert!(wait_for(path, 30), "no screenshot after F12");
    read_png(path).2
}

#[test]
fn window_under_xvfb_switches_views_moves_the_camera_and_saves_a_snapshot() {
    let test = "window_under_xvfb_switches_views_moves_the_camera_and_saves_a_snapshot";
    for tool in ["Xvfb", "xdotool"] {
        if Command::new("which")
            .arg(tool)
            .output()
            .map_or(true, |o| !o.status.success())
        {
            nrc_scene::testing::skipped(test, &format!("no xvfb: {tool} is not installed"));
            return;
        }
    }
    if !adapter(test) {
        return;
    }
    let x = match xvfb() {
        Ok(x) => x,
        Err(e) => panic!("{e}"),
    };
    let dir = tempfile::tempdir().unwrap();
    let shot: PathBuf = dir.path().join("shot.png");
    let snapshot = dir.path().join("snap.nrc");
    let scene = cornell();
    let mut guard = Guard(Some(
        nrc_command()
            .args([
                "view",
                "--scene",
                &scene,
                "--width",
                "64",
                "--height",
                "48",
                "--records",
                "1024",
                "--threads",
                "1",
                "--window-size",
                "800x560",
                "--print-rates",
            ])
            .arg("--screenshot")
            .arg(&shot)
            .arg("--snapshot")
            .arg(&snapshot)
            .env("DISPLAY", &x.display)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    ));
    let viewer = guard.0.as_mut().unwrap();
    // The window appears and takes the keyboard.
    let start = Instant::now();
    let window = loop {
        let found = xdotool(&x.display, &["search", "--name", "nrc view"]);
        let id = text(&found.stdout).lines().next().map(str::to_string);
        if let Some(id) = id.filter(|s| !s.is_empty()) {
            break id;
        }
        if let Ok(Some(status)) = viewer.try_wait() {
            let out = guard.0.take().unwrap().wait_with_output().unwrap();
            panic!("nrc view exited ({status}): {}", text(&out.stderr));
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no window in 60 s"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    xdotool(&x.display, &["windowfocus", "--sync", &window]);
    std::thread::sleep(Duration::from_secs(3));

    // Two screenshots of the still view: close to each other (accumulation goes on).
    let a = screenshot(&x.display, &shot);
    std::thread::sleep(Duration::from_millis(500));
    let a2 = screenshot(&x.display, &shot);
    let (_, still) = diff(&a, &a2);
    let changed = |from: &[u8], what: &str| {
        // Screenshots until the window differs from `from` by more than three times what the
        // still view moved (the loop, at low priority, may take a while under a busy machine).
        let bar = 3.0 * still.max(0.05);
        let start = Instant::now();
        loop {
            let now = screenshot(&x.display, &shot);
            let (_, d) = diff(from, &now);
            if d > bar {
                return now;
            }
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "{what} changed the window by {d} only (still: {still})"
            );
            std::thread::sleep(Duration::from_millis(300));
        }
    };
    // View 4, the records' heat map: another picture.
    xdotool(&x.display, &["key", "4"]);
    let records = changed(&a2, "switching to the records view");
    // Back to the final view (polled until the window looks more like the final view than like
    // the records), then fly forward for a second: the view moves.
    xdotool(&x.display, &["key", "1"]);
    let start = Instant::now();
    let before = loop {
        let now = screenshot(&x.display, &shot);
        if diff(&a2, &now).1 < diff(&records, &now).1 {
            break now;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "key 1 did not bring the final view back"
        );
        std::thread::sleep(Duration::from_millis(300));
    };
    xdotool(&x.display, &["keydown", "w"]);
    std::thread::sleep(Duration::from_millis(1200));
    xdotool(&x.display, &["keyup", "w"]);
    changed(&before, "flying forward");
    // F5 saves the snapshot; it loads for rendering.
    xdotool(&x.display, &["key", "F5"]);
    assert!(wait_for(&snapshot, 30), "no snapshot after F5");
    std::thread::sleep(Duration::from_millis(500));
    // The snapshot renders with `nrc render --cache`.
    let renders = |what: &str| {
        let out = dir.path().join("r.exr");
        let mut a = vec!["render", "--scene", &scene, "--spp", "1", "--width", "16"];
        a.extend(["--height", "16", "--cache", snapshot.to_str().unwrap()]);
        a.extend(["--out", out.to_str().unwrap()]);
        ok(nrc(&a), what);
    };
    renders("nrc render --cache (the viewer's snapshot)");
    // F5 and Escape at once: the window closes, the loop ends cleanly, and the snapshot asked
    // for before is written all the same.
    std::fs::remove_file(&snapshot).unwrap();
    xdotool(&x.display, &["key", "F5", "Escape"]);
    let start = Instant::now();
    let viewer = guard.0.as_mut().unwrap();
    while viewer.try_wait().unwrap().is_none() {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the viewer did not close"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = guard.0.take().unwrap().wait_with_output().unwrap();
    let err = text(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        snapshot.exists(),
        "the snapshot asked for on closing was not written"
    );
    renders("nrc render --cache (the snapshot saved on closing)");
    eprintln!("viewer's log:\n{err}");
}
