//! The viewer's panels (egui): the viewport, the loop's controls, the debug views, the camera and
//! its paths, snapshots, and plots of the loss and of the frame time by phase. Keys (when no
//! text field has focus): WASD/QE fly, drag in the viewport to look, the wheel sets the speed;
//! 1–9 the views; R the scene's camera; Space pauses training; K adds a keyframe; P plays or
//! pauses an animated scene; F5 saves a snapshot, F9 loads it; F12 takes a screenshot.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::Instant;

use egui::Key;
use nrc_render::passes::CacheTerminatedSettings;
use nrc_render::{PassSpec, Termination};
use nrc_scene::Camera;

use crate::camera::{Fly, Held, keyframe};
use crate::display::ToneMap;
use crate::session::{Command, Published, View};

/// Pixels of the controls panel.
const PANEL_WIDTH: f32 = 290.0;

/// Height of the plots.
const PLOT_HEIGHT: f32 = 120.0;

/// The UI's own state (what is typed into its fields, the fly camera, the screenshot asked for).
pub struct UiState {
    pub fly: Fly,
    /// The scene's camera (R).
    pub home: Camera,
    pub exposure: f32,
    pub tonemap: ToneMap,
    pub view: View,
    pass: String,
    producer: String,
    termination: String,
    /// NEE in the cache pass the termination field builds.
    nee: bool,
    records: usize,
    budget_on: bool,
    budget_ms: f64,
    learning_rate: f32,
    pub snapshot: String,
    camera_path: String,
    keyframes: Vec<nrc_harness::run::Keyframe>,
    path_frames: u32,
    /// Where F12 writes the screenshot.
    pub screenshot: PathBuf,
    /// Set when a screenshot was asked for this frame (the window takes it after drawing).
    pub take_screenshot: bool,
    message: Option<String>,
    ui_frames: VecDeque<Instant>,
    last: Option<Instant>,
    /// The fields are filled from the loop's settings once its state is newer than this
    /// generation (at the start, and after each command that changes them).
    resync_after: Option<u64>,
    /// The loop's generation seen last.
    seen: u64,
    /// The adapter the UI draws with.
    pub adapter: String,
    /// Set by Escape: the window closes.
    pub quit: bool,
    /// Painted offscreen (no UI frame rate to show).
    pub headless: bool,
    /// Where the viewport goes in the window (points), as the last frame laid it out.
    pub viewport_rect: Option<egui::Rect>,
    /// Whether the last frame moved the camera or had keys held: the window draws the next
    /// frame without waiting for input.
    pub active: bool,
}

impl UiState {
    pub fn new(camera: Camera, extent: f32, snapshot: PathBuf, screenshot: PathBuf) -> Self {
        Self {
            fly: Fly::new(camera, extent),
            home: camera,
            exposure: 0.0,
            tonemap: ToneMap::Aces,
            view: View::Final,
            pass: String::new(),
            producer: String::new(),
            termination: "spread".into(),
            nee: true,
            records: 0,
            budget_on: false,
            budget_ms: 10.0,
            learning_rate: 1e-2,
            snapshot: snapshot.display().to_string(),
            camera_path: "camera-path.json".into(),
            keyframes: Vec::new(),
            path_frames: 120,
            screenshot,
            take_screenshot: false,
            message: None,
            ui_frames: VecDeque::new(),
            last: None,
            resync_after: Some(0),
            seen: 0,
            adapter: String::new(),
            quit: false,
            headless: false,
            active: false,
            viewport_rect: None,
        }
    }

    /// Shows `message` in the panel (until the next command).
    pub fn say(&mut self, message: String) {
        self.message = Some(message);
    }

    /// UI frames per second over the last second.
    pub fn ui_fps(&self) -> f32 {
        self.ui_frames.len() as f32
    }

    /// The tone-mapping command for the current settings.
    pub fn tone(&self) -> Command {
        Command::Tone {
            exposure: self.exposure,
            tonemap: self.tonemap,
        }
    }

    /// Draws the whole UI for the loop's state `p`, leaving room for the viewport of `size`
    /// pixels ([`UiState::viewport_rect`], filled by the canvas); the commands for the loop go
    /// to `out`.
    pub fn show(
        &mut self,
        ui: &mut egui::Ui,
        p: &Published,
        size: [u32; 2],
        out: &mut Vec<Command>,
    ) {
        let now = Instant::now();
        let dt = self
            .last
            .map_or(0.0, |t| now.duration_since(t).as_secs_f32().min(0.25));
        self.last = Some(now);
        self.ui_frames.push_back(now);
        while self
            .ui_frames
            .front()
            .is_some_and(|t| now.duration_since(*t).as_secs_f32() > 1.0)
        {
            self.ui_frames.pop_front();
        }
        self.seen = p.generation;
        if self
            .resync_after
            .is_some_and(|g| p.generation > g || g == 0)
        {
            self.pass = p.pass.clone();
            self.nee = !p.pass.ends_with("-nonee");
            self.producer = p.producer.clone();
            self.records = p.records;
            self.budget_on = p.budget_ms.is_some();
            self.budget_ms = p.budget_ms.unwrap_or(self.budget_ms);
            self.learning_rate = p.learning_rate.unwrap_or(self.learning_rate);
            self.resync_after = None;
        }
        let sent = out.len();
        if p.on_path {
            self.fly.camera = p.camera;
        }
        self.keys(ui, p, dt, out);
        // Panels without a fill: the clear colour is their background. On Mesa's software
        // Vulkan a panel's fill (a bilinear texture read and a blend per pixel) cost ~9 ms a
        // frame each at 1280 × 800, most of the UI's frame.
        let bare = egui::Frame::NONE.inner_margin(egui::Margin::same(8));
        egui::Panel::left("controls")
            .exact_size(PANEL_WIDTH)
            .resizable(false)
            .frame(bare)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.controls(ui, p, out));
            });
        egui::Panel::bottom("plots")
            .exact_size(PLOT_HEIGHT + 24.0)
            .frame(bare)
            .show(ui, |ui| plots(ui, p));
        egui::CentralPanel::no_frame().show(ui, |ui| self.viewport(ui, size, out));
        // A command sent: its outcome is the loop's message, and the fields follow the loop.
        if out[sent..].iter().any(|c| {
            !matches!(
                c,
                Command::Camera(_) | Command::Tone { .. } | Command::View(_)
            )
        }) {
            self.message = None;
            self.resync_after = Some(self.seen);
        }
    }

    fn keys(&mut self, ui: &mut egui::Ui, p: &Published, dt: f32, out: &mut Vec<Command>) {
        if ui.ctx().egui_wants_keyboard_input() {
            return;
        }
        let down = |k| ui.input(|i| i.key_down(k));
        let axis = |plus, minus| f32::from(u8::from(down(plus))) - f32::from(u8::from(down(minus)));
        let held = Held {
            right: axis(Key::D, Key::A),
            up: axis(Key::E, Key::Q),
            forward: axis(Key::W, Key::S),
        };
        self.active = held.any();
        if self.fly.translate(held, dt) {
            out.push(Command::Camera(self.fly.camera));
        }
        let pressed = |k| ui.input(|i| i.key_pressed(k));
        const NUMBERS: [Key; 9] = [
            Key::Num1,
            Key::Num2,
            Key::Num3,
            Key::Num4,
            Key::Num5,
            Key::Num6,
            Key::Num7,
            Key::Num8,
            Key::Num9,
        ];
        for (i, k) in NUMBERS.into_iter().enumerate() {
            if pressed(k) {
                let view = View::FIXED.get(i).map(|(v, _, _)| *v).or_else(|| {
                    let j = i - View::FIXED.len();
                    (j < p.pass_views.len()).then_some(View::Pass(j))
                });
                if let Some(v) = view {
                    self.view = v;
                    out.push(Command::View(v));
                }
            }
        }
        if pressed(Key::R) {
            self.fly.camera = self.home;
            out.push(Command::Camera(self.home));
        }
        if pressed(Key::Space) {
            out.push(Command::Training(!p.training));
        }
        if pressed(Key::K) {
            self.keyframes.push(keyframe(&self.fly.camera));
            self.message = Some(format!("{} keyframes", self.keyframes.len()));
        }
        if pressed(Key::P)
            && let Some((_, _, playing)) = p.time
        {
            out.push(Command::Play(!playing));
        }
        if pressed(Key::F5) {
            out.push(Command::SaveSnapshot(PathBuf::from(&self.snapshot)));
        }
        if pressed(Key::F9) {
            out.push(Command::LoadSnapshot(PathBuf::from(&self.snapshot)));
        }
        if pressed(Key::F12) {
            self.take_screenshot = true;
        }
        if pressed(Key::Escape) {
            self.quit = true;
        }
    }

    fn viewport(&mut self, ui: &mut egui::Ui, size: [u32; 2], out: &mut Vec<Command>) {
        let avail = ui.available_rect_before_wrap();
        let (w, h) = (size[0].max(1) as f32, size[1].max(1) as f32);
        // Whole target pixels per texel where the viewport fits at least once (crisp, as the
        // renderer's pixels are), snapped to target pixels.
        let ppp = ui.ctx().pixels_per_point();
        let fit = (avail.width() / w).min(avail.height() / h) * ppp;
        let scale = if fit >= 1.0 {
            fit.floor()
        } else {
            fit.max(0.05)
        } / ppp;
        let rect = egui::Rect::from_center_size(avail.center(), egui::vec2(w * scale, h * scale));
        let min = (rect.min.to_vec2() * ppp).round() / ppp;
        let rect = egui::Rect::from_min_size(min.to_pos2(), rect.size());
        self.viewport_rect = Some(rect);
        let response = ui.allocate_rect(rect, egui::Sense::click_and_drag());
        if response.dragged() {
            self.active = true;
            let d = response.drag_delta() / scale;
            if self.fly.look(d.x, d.y) {
                out.push(Command::Camera(self.fly.camera));
            }
        }
        if response.hovered() {
            // One speed step per wheel event (not per frame of smoothed scrolling).
            let notches: f32 = ui.input(|i| {
                i.raw
                    .events
                    .iter()
                    .filter_map(|e| match e {
                        egui::Event::MouseWheel { delta, .. } if delta.y != 0.0 => {
                            Some(delta.y.signum())
                        }
                        _ => None,
                    })
                    .sum()
            });
            self.fly.wheel(notches);
        }
    }

    fn controls(&mut self, ui: &mut egui::Ui, p: &Published, out: &mut Vec<Command>) {
        ui.heading("nrc view");
        let ui_rate = if self.headless {
            "UI headless".to_string()
        } else {
            format!("UI {:.0} frames/s", self.ui_fps())
        };
        ui.label(format!(
            "loop {:.1} frames/s · {ui_rate}\nframe {} · {} accumulated",
            p.loop_fps, p.frames, p.accumulated
        ));
        if !self.adapter.is_empty() {
            ui.small(format!("display: {}", self.adapter));
        }
        // The UI's own message (a field it could not parse), then the loop's (what the last
        // command did, or why it failed).
        for m in [self.message.as_ref(), p.message.as_ref()]
            .into_iter()
            .flatten()
        {
            let colour = if m.starts_with("error") {
                egui::Color32::LIGHT_RED
            } else {
                egui::Color32::LIGHT_GREEN
            };
            ui.colored_label(colour, m);
        }
        ui.separator();

        ui.strong("View");
        let mut views: Vec<(View, String, String)> = View::FIXED
            .iter()
            .map(|(v, n, d)| (*v, n.to_string(), d.to_string()))
            .collect();
        views.extend(
            p.pass_views
                .iter()
                .enumerate()
                .map(|(i, n)| (View::Pass(i), n.clone(), "the pass's own view".into())),
        );
        for (i, (v, name, what)) in views.iter().enumerate() {
            let label = format!("{} {name}", i + 1);
            let enabled = *v != View::Error || p.has_reference;
            let r = ui.add_enabled(enabled, egui::RadioButton::new(self.view == *v, label));
            if r.on_hover_text(what.as_str()).clicked() {
                self.view = *v;
                out.push(Command::View(*v));
            }
        }
        ui.horizontal(|ui| {
            ui.label("exposure");
            if ui
                .add(egui::Slider::new(&mut self.exposure, -10.0..=10.0).step_by(0.25))
                .changed()
            {
                out.push(self.tone());
            }
        });
        egui::ComboBox::from_label("tone mapping")
            .selected_text(self.tonemap.name())
            .show_ui(ui, |ui| {
                for t in ToneMap::ALL {
                    if ui
                        .selectable_value(&mut self.tonemap, t, t.name())
                        .changed()
                    {
                        out.push(self.tone());
                    }
                }
            });
        ui.separator();

        ui.strong("Pass");
        ui.horizontal(|ui| {
            ui.add(egui::TextEdit::singleline(&mut self.pass).desired_width(190.0))
                .on_hover_text("any --pass of nrc render (nrc render --help lists them)");
            if ui.button("apply").clicked() {
                match self.pass.parse::<PassSpec>() {
                    Ok(spec) => out.push(Command::Pass(spec)),
                    Err(e) => self.message = Some(format!("error: pass: {e}")),
                }
            }
        });
        ui.horizontal(|ui| {
            ui.label("termination");
            ui.add(egui::TextEdit::singleline(&mut self.termination).desired_width(70.0))
                .on_hover_text(
                    "first, diffuse[:R], spread[:C], bth[:K]: the cache pass ending there",
                );
            ui.checkbox(&mut self.nee, "NEE");
            if ui.button("apply").clicked() {
                match self.termination.parse::<Termination>() {
                    Ok(termination) => {
                        let spec = PassSpec::from(CacheTerminatedSettings {
                            termination,
                            nee: self.nee,
                        });
                        self.pass = spec.to_string();
                        out.push(Command::Pass(spec));
                    }
                    Err(e) => self.message = Some(format!("error: termination: {e}")),
                }
            }
        });
        ui.strong("Producer");
        ui.horizontal(|ui| {
            ui.add(egui::TextEdit::singleline(&mut self.producer).desired_width(190.0))
                .on_hover_text("pt, pt-sl, bt, lt, sppc, or mix:NAME=SHARE,...");
            if ui.button("apply").clicked() {
                match self.producer.parse() {
                    Ok(spec) => out.push(Command::Producer(spec)),
                    Err(e) => self.message = Some(format!("error: producer: {e}")),
                }
            }
        });
        ui.separator();

        ui.strong("Training");
        let mut training = p.training;
        if ui.checkbox(&mut training, "train (Space)").changed() {
            out.push(Command::Training(training));
        }
        let mut records_changed = false;
        ui.horizontal(|ui| {
            ui.label("records/frame");
            records_changed |= ui
                .add(egui::DragValue::new(&mut self.records).range(1..=1 << 22))
                .changed();
        });
        ui.horizontal(|ui| {
            records_changed |= ui.checkbox(&mut self.budget_on, "budget ms").changed();
            records_changed |= ui
                .add_enabled(
                    self.budget_on,
                    egui::DragValue::new(&mut self.budget_ms)
                        .range(0.1..=10_000.0)
                        .speed(0.1),
                )
                .changed();
        });
        if records_changed {
            out.push(Command::Records(
                self.records,
                self.budget_on.then_some(self.budget_ms),
            ));
        }
        if p.learning_rate.is_some() {
            ui.horizontal(|ui| {
                ui.label("learning rate");
                if ui
                    .add(
                        egui::DragValue::new(&mut self.learning_rate)
                            .range(1e-6..=1.0)
                            .speed(1e-4)
                            .max_decimals(6),
                    )
                    .changed()
                {
                    out.push(Command::LearningRate(self.learning_rate));
                }
            });
        }
        if ui.button("reset the cache").clicked() {
            out.push(Command::ResetCache);
        }
        ui.separator();

        ui.strong("Snapshot");
        ui.text_edit_singleline(&mut self.snapshot);
        ui.horizontal(|ui| {
            if ui.button("save (F5)").clicked() {
                out.push(Command::SaveSnapshot(PathBuf::from(&self.snapshot)));
            }
            if ui.button("load (F9)").clicked() {
                out.push(Command::LoadSnapshot(PathBuf::from(&self.snapshot)));
            }
        });
        ui.separator();

        ui.strong("Camera");
        ui.label(format!(
            "speed {:.3}/s (wheel) · {} keyframes",
            self.fly.speed,
            self.keyframes.len()
        ));
        ui.horizontal(|ui| {
            if ui.button("scene camera (R)").clicked() {
                self.fly.camera = self.home;
                out.push(Command::Camera(self.home));
            }
            if ui.button("keyframe (K)").clicked() {
                self.keyframes.push(keyframe(&self.fly.camera));
            }
        });
        ui.text_edit_singleline(&mut self.camera_path);
        ui.horizontal(|ui| {
            if ui.button("save path").clicked() {
                self.message = Some(self.save_path());
            }
            ui.add(egui::DragValue::new(&mut self.path_frames).range(1..=100_000))
                .on_hover_text("frames to play the path over");
            if ui.button("play path").clicked() {
                match nrc_harness::run::camera_path(
                    Some(std::path::Path::new(&self.camera_path)),
                    &self.home,
                    self.path_frames,
                ) {
                    Ok(cams) => out.push(Command::CameraPath(cams)),
                    Err(e) => self.message = Some(format!("error: {e:#}")),
                }
            }
        });
        if let Some((t, duration, playing)) = p.time {
            ui.separator();
            ui.strong("Animation");
            let mut play = playing;
            if ui.checkbox(&mut play, "play (P)").changed() {
                out.push(Command::Play(play));
            }
            let mut time = t;
            if ui
                .add(egui::Slider::new(&mut time, 0.0..=duration).text("s"))
                .changed()
            {
                out.push(Command::Seek(time));
            }
        }
        ui.separator();
        ui.collapsing("cache", |ui| ui.small(p.describe.as_str()));
    }

    /// Writes the keyframes as a camera path (the JSON `--camera-path` reads), atomically.
    fn save_path(&self) -> String {
        if self.keyframes.is_empty() {
            return "error: no keyframes yet (K adds the camera)".into();
        }
        let path = std::path::Path::new(&self.camera_path);
        let json = serde_json::to_string_pretty(&self.keyframes).expect("keyframes serialise");
        match nrc_scene::image::write_atomic(path, json.as_bytes()) {
            Ok(()) => format!(
                "{} keyframes saved to {}",
                self.keyframes.len(),
                path.display()
            ),
            Err(e) => format!("error: {e}"),
        }
    }
}

/// The loss and the frame time by phase over the last frames.
fn plots(ui: &mut egui::Ui, p: &Published) {
    use egui_plot::{Legend, Line, Plot};
    let half = (ui.available_width() - 8.0) / 2.0;
    ui.horizontal(|ui| {
        ui.vertical(|ui| {
            ui.set_width(half);
            ui.small("log10 of the loss (each frame's last step)");
            Plot::new("loss")
                .height(PLOT_HEIGHT)
                .allow_scroll(false)
                .allow_zoom(false)
                .allow_drag(false)
                .show(ui, |plot| {
                    let points: Vec<[f64; 2]> = p
                        .history
                        .iter()
                        .filter(|l| l.loss.is_finite() && l.loss > 0.0)
                        .map(|l| [l.frame as f64, f64::from(l.loss).log10()])
                        .collect();
                    plot.line(Line::new("loss", points));
                });
        });
        ui.vertical(|ui| {
            ui.set_width(half);
            ui.small("frame time by phase, ms");
            Plot::new("phases")
                .height(PLOT_HEIGHT)
                .legend(Legend::default())
                .allow_scroll(false)
                .allow_zoom(false)
                .allow_drag(false)
                .include_y(0.0)
                .show(ui, |plot| {
                    type Phase = fn(&crate::session::FrameLine) -> f64;
                    let phases: [(&str, Phase); 6] = [
                        ("producing", |l| l.produce_ms),
                        ("training", |l| l.train_ms),
                        ("tracing", |l| l.trace_ms),
                        ("inference", |l| l.infer_ms),
                        ("view", |l| l.view_ms),
                        ("total", |l| l.total_ms()),
                    ];
                    for (name, f) in phases {
                        let points: Vec<[f64; 2]> =
                            p.history.iter().map(|l| [l.frame as f64, f(l)]).collect();
                        plot.line(Line::new(name, points));
                    }
                });
        });
    });
}
