//! `nrc view --headless`: the loop run for a number of frames, then the UI painted offscreen
//! exactly as the window paints it (a screenshot), the viewport alone, and every debug view.
//! No window system is needed, only an adapter (Mesa's software Vulkan will do).

use std::path::PathBuf;

use crate::ViewError;
use crate::canvas::{Canvas, offscreen_input};
use crate::display::{self, Display, Gpu, ToneMap};
use crate::session::{Command, LoopSetup, Session, View};
use crate::ui::UiState;

/// What the headless run writes.
#[derive(Clone, Debug)]
pub struct HeadlessOptions {
    /// Loop frames to run before the pictures.
    pub frames: u32,
    /// The whole UI as a PNG.
    pub screenshot: Option<PathBuf>,
    /// The viewport alone as a PNG (the view's pixels, one per image pixel).
    pub viewport: Option<PathBuf>,
    /// A folder to write every debug view into (`NAME.png`).
    pub views: Option<PathBuf>,
    /// The view shown (`final` unless named).
    pub view: Option<String>,
    /// The UI's size in pixels.
    pub size: [u32; 2],
    pub exposure: f32,
    pub tonemap: ToneMap,
    /// Where the UI's snapshot field points.
    pub snapshot: PathBuf,
    /// The scene's largest extent (the fly camera's speed).
    pub extent: f32,
}

/// What the headless run did.
#[derive(Clone, Debug)]
pub struct HeadlessReport {
    pub frames: u64,
    /// Loop seconds per frame (all frames).
    pub seconds_per_frame: f64,
    /// The adapter that drew.
    pub adapter: String,
    /// The views written (names).
    pub views: Vec<String>,
}

/// Runs the loop `options.frames` frames on `pool` and writes what `options` asks for.
pub fn run_headless(
    setup: LoopSetup,
    options: &HeadlessOptions,
    pool: &rayon::ThreadPool,
) -> Result<HeadlessReport, ViewError> {
    let gpu = Gpu::headless()?;
    gpu.check_size("the image", setup.width, setup.height)?;
    gpu.check_size("the window", options.size[0], options.size[1])?;
    let camera = setup.camera;
    let mut session = Session::new(setup);
    session.apply(Command::Tone {
        exposure: options.exposure,
        tonemap: options.tonemap,
    });
    let start = std::time::Instant::now();
    pool.install(|| (0..options.frames).try_for_each(|_| session.step().map_err(ViewError::Loop)))?;
    let seconds_per_frame = start.elapsed().as_secs_f64() / f64::from(options.frames.max(1));
    let pass_views = session.pass_view_names();
    let view = match &options.view {
        Some(name) => View::parse(name, &pass_views).ok_or_else(|| {
            ViewError::Option(format!(
                "no view called {name:?}: the views are {}",
                all_views(&pass_views).join(", ")
            ))
        })?,
        None => View::Final,
    };
    session.apply(Command::View(view));
    let shown = pool.install(|| session.compute_view(view));
    let mut published = session.publish();
    (published.image, published.aux, published.shade) = shown;

    let (w, h) = (published.image.width as u32, published.image.height as u32);
    let mut ui = UiState::new(
        camera,
        options.extent,
        options.snapshot.clone(),
        PathBuf::new(),
    );
    ui.exposure = options.exposure;
    ui.tonemap = options.tonemap;
    ui.view = view;
    ui.adapter = gpu.describe();
    ui.headless = true;
    let mut canvas = Canvas::new(&gpu, display::FORMAT, w, h, ui);
    canvas.update_viewport(&gpu, &published);
    if let Some(path) = &options.viewport {
        let rgba = canvas.display.read(&gpu)?;
        display::write_png(path, w, h, &rgba)?;
    }
    if let Some(path) = &options.screenshot {
        // egui lays out on its first pass and settles on the second.
        let mut painted = None;
        for pass in 0..3 {
            let (output, _) = canvas.run(
                offscreen_input(options.size, f64::from(pass) * 0.1),
                &published,
            );
            let p = canvas.tessellate(output);
            canvas.prepare(&gpu, &p);
            if let Some(old) = painted.replace(p) {
                canvas.finish(old);
            }
        }
        let painted = painted.expect("three passes ran");
        let rgba = canvas.screenshot(&gpu, &painted, options.size)?;

        canvas.finish(painted);
        display::write_png(path, options.size[0], options.size[1], &rgba)?;
    }
    let mut written = Vec::new();
    if let Some(dir) = &options.views {
        std::fs::create_dir_all(dir)
            .map_err(|e| ViewError::Output(dir.display().to_string(), e.to_string()))?;
        let mut display = Display::new(&gpu, w, h);
        let mut views: Vec<View> = View::FIXED.iter().map(|(v, _, _)| *v).collect();
        views.extend((0..pass_views.len()).map(View::Pass));
        for v in views {
            let (image, aux, shade) = pool.install(|| session.compute_view(v));
            display.resize(&gpu, image.width as u32, image.height as u32);
            display.upload(&gpu, &image, aux.as_ref());
            display.draw(&gpu, shade);
            let rgba = display.read(&gpu)?;
            let name = v.name(&pass_views);
            display::write_png(
                &dir.join(format!("{name}.png")),
                display.width,
                display.height,
                &rgba,
            )?;
            written.push(name);
        }
    }
    Ok(HeadlessReport {
        frames: session.frames(),
        seconds_per_frame,
        adapter: gpu.describe(),
        views: written,
    })
}

/// Every view's name: the fixed ones, then the pass's.
pub fn all_views(pass_views: &[String]) -> Vec<String> {
    View::FIXED
        .iter()
        .map(|(_, n, _)| n.to_string())
        .chain(pass_views.iter().cloned())
        .collect()
}
