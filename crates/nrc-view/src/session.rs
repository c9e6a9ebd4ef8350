//! The viewer's loop: the online loop of `nrc train` (produce → train → render the pass) frame
//! after frame, with progressive accumulation while camera and scene stand still, commands from
//! the UI between frames, and what the UI shows published after each frame. The window runs it
//! on a thread of its own ([`spawn`]); the headless mode steps it directly.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::Vec3;
use nrc_cache::Cache;
use nrc_render::passes::{self, CacheTerminatedSettings, FrameInput, RenderPass};
use nrc_render::sampler::Stream;
use nrc_render::{PassSpec, Termination, pass_seed};
use nrc_scene::image::Image;
use nrc_scene::{Camera, Scene};
use nrc_train::{CacheSource, OnlineTrainer, ProducerSpec};

use crate::display::{Shade, ToneMap};

/// Frames of statistics the plots show.
pub const HISTORY: usize = 240;

/// Mixed into the seed of frames rendered without training.
const RENDER_ONLY_SEED: u64 = 0x7265_6e64_6572_6f6e;

/// The scene's animation: its length and the scene posed at a time.
pub struct Animation {
    /// Seconds.
    pub duration: f32,
    /// Frames per second of scene time while playing.
    pub fps: f32,
    pub pose: Box<dyn Fn(f32) -> Result<Scene, String> + Send>,
}

/// What the loop starts from.
pub struct LoopSetup {
    pub scene: Scene,
    pub animation: Option<Animation>,
    /// The online trainer, as `nrc train` builds it from the same flags.
    pub trainer: OnlineTrainer,
    /// A new, untrained cache of the run's settings (the "reset the cache" button).
    pub fresh_cache: Box<dyn Fn() -> Result<Cache, String> + Send>,
    /// A snapshot loaded for this scene (its scene checked) onto the run's device.
    pub load_snapshot: Box<dyn Fn(&Path) -> Result<Cache, String> + Send>,
    /// The scene's content hash, stored in saved snapshots (as `nrc train --snapshot` does).
    pub scene_content: Option<String>,
    pub camera: Camera,
    /// A camera path to play from the first frame (one camera a frame), as `nrc train
    /// --camera-path` does.
    pub path: Option<Vec<Camera>>,
    pub width: u32,
    pub height: u32,
    /// Whether training runs from the start (else only the pass renders, from the cache).
    pub train: bool,
    /// A reference image of the scene's camera for the error view.
    pub reference: Option<Image>,
}

/// A debug view: what the viewport shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum View {
    /// The pass's output, averaged over the frames since camera or scene last changed.
    #[default]
    Final,
    /// The pass's output of the last frame alone.
    Raw,
    /// The cache's answer at each pixel's first vertex (emitters seen directly included).
    Cache,
    /// Where this frame's training records landed: a count per pixel, heat map.
    Records,
    /// The accumulated output's relative squared error against the reference, false colour.
    Error,
    /// The pass's own view number N ([`nrc_render::passes::RenderPass::debug_views`]).
    Pass(usize),
}

impl View {
    /// The views every pass has, with their names and one line on each.
    pub const FIXED: [(View, &'static str, &'static str); 5] = [
        (
            View::Final,
            "final",
            "the pass's output, accumulated while nothing moves",
        ),
        (
            View::Raw,
            "raw",
            "the pass's output of the last frame, no accumulation",
        ),
        (
            View::Cache,
            "cache",
            "the cache's radiance at the first vertex",
        ),
        (
            View::Records,
            "records",
            "where this frame's training records landed",
        ),
        (
            View::Error,
            "error",
            "relative squared error against the reference",
        ),
    ];

    /// The view's name (`--view` takes it); `pass_views` names the pass's own.
    pub fn name(self, pass_views: &[String]) -> String {
        match self {
            View::Pass(i) => pass_views
                .get(i)
                .cloned()
                .unwrap_or_else(|| format!("pass view {i}")),
            v => Self::FIXED
                .iter()
                .find(|(f, _, _)| *f == v)
                .map(|(_, n, _)| n.to_string())
                .unwrap_or_default(),
        }
    }

    /// The view called `name`, among the fixed ones and `pass_views`.
    pub fn parse(name: &str, pass_views: &[String]) -> Option<View> {
        Self::FIXED
            .iter()
            .find(|(_, n, _)| *n == name)
            .map(|(v, _, _)| *v)
            .or_else(|| pass_views.iter().position(|p| p == name).map(View::Pass))
    }
}

/// What the UI asks of the loop (applied between frames, in order).
#[derive(Clone, Debug)]
pub enum Command {
    Camera(Camera),
    /// Play a camera path (one camera a frame), then stay at its end.
    CameraPath(Vec<Camera>),
    Pass(PassSpec),
    Producer(ProducerSpec),
    /// Records a frame and the training budget (ms; `None`: none).
    Records(usize, Option<f64>),
    LearningRate(f32),
    Training(bool),
    ResetCache,
    SaveSnapshot(PathBuf),
    LoadSnapshot(PathBuf),
    Play(bool),
    /// Scene time, seconds.
    Seek(f32),
    View(View),
    /// Tone mapping of the tone-mapped views (kept here so a screenshot matches the window).
    Tone {
        exposure: f32,
        tonemap: ToneMap,
    },
}

/// One frame's cost and loss, for the plots.
#[derive(Clone, Copy, Debug, Default)]
pub struct FrameLine {
    pub frame: u64,
    /// Mean loss of the frame's last step (NaN when it did not train).
    pub loss: f32,
    pub produce_ms: f64,
    pub train_ms: f64,
    /// The pass's tracing (its time less the cache's).
    pub trace_ms: f64,
    /// The cache's inference within the pass.
    pub infer_ms: f64,
    /// Accumulation and the debug view.
    pub view_ms: f64,
    pub records: usize,
}

impl FrameLine {
    pub fn total_ms(&self) -> f64 {
        self.produce_ms + self.train_ms + self.trace_ms + self.infer_ms + self.view_ms
    }
}

/// What the UI shows after a frame.
#[derive(Clone)]
pub struct Published {
    /// Bumped at each frame (and after each command).
    pub generation: u64,
    /// Frames the loop has run.
    pub frames: u64,
    /// Frames in the accumulated image.
    pub accumulated: u32,
    /// The view's image and, where it needs one, its second input (reference, counts).
    pub image: Image,
    pub aux: Option<Image>,
    pub shade: Shade,
    pub view: View,
    pub pass_views: Vec<String>,
    pub camera: Camera,
    pub history: VecDeque<FrameLine>,
    pub training: bool,
    pub pass: String,
    pub producer: String,
    pub records: usize,
    pub budget_ms: Option<f64>,
    pub learning_rate: Option<f32>,
    /// The cache's description (`nrc train` prints it).
    pub describe: String,
    /// The last thing a command did, or why it failed.
    pub message: Option<String>,
    /// Scene time, duration and whether it plays (animated scenes).
    pub time: Option<(f32, f32, bool)>,
    /// Whether a camera path is playing.
    pub on_path: bool,
    /// Loop frames per second over the last second.
    pub loop_fps: f32,
    pub has_reference: bool,
}

/// The loop's state.
pub struct Session {
    scene: Scene,
    animation: Option<Animation>,
    time: f32,
    playing: bool,
    trainer: OnlineTrainer,
    fresh_cache: Box<dyn Fn() -> Result<Cache, String> + Send>,
    load_snapshot: Box<dyn Fn(&Path) -> Result<Cache, String> + Send>,
    scene_content: Option<String>,
    camera: Camera,
    path: Option<(Vec<Camera>, usize)>,
    width: u32,
    height: u32,
    train: bool,
    reference: Option<Image>,
    view: View,
    tone: Shade,
    /// The pass rendering the cache view (first vertex, no NEE).
    cache_pass: Box<dyn RenderPass>,
    /// Frames rendered without training (their seeds).
    render_only_frames: u64,
    sum: Vec<Vec3>,
    accumulated: u32,
    raw: Image,
    pass_views: Vec<(String, bool, Image)>,
    history: VecDeque<FrameLine>,
    message: Option<String>,
    frames: u64,
    generation: u64,
    frame_times: VecDeque<Instant>,
    /// The last view image computed (and its second input and shade).
    shown: (Image, Option<Image>, Shade),
}

impl Session {
    pub fn new(setup: LoopSetup) -> Self {
        let (w, h) = (setup.width, setup.height);
        let tracer = setup.trainer.settings.tracer;
        Self {
            scene: setup.scene,
            animation: setup.animation,
            time: 0.0,
            playing: true,
            trainer: setup.trainer,
            fresh_cache: setup.fresh_cache,
            load_snapshot: setup.load_snapshot,
            scene_content: setup.scene_content,
            camera: setup
                .path
                .as_ref()
                .and_then(|p| p.first().copied())
                .unwrap_or(setup.camera),
            path: setup.path.filter(|p| !p.is_empty()).map(|p| (p, 0)),
            width: w,
            height: h,
            train: setup.train,
            reference: setup
                .reference
                .filter(|r| (r.width, r.height) == (w as usize, h as usize)),
            view: View::Final,
            tone: Shade::Tone {
                exposure: 0.0,
                tonemap: ToneMap::Aces,
            },
            cache_pass: PassSpec::from(CacheTerminatedSettings {
                termination: Termination::FirstVertex,
                nee: false,
            })
            .build(&tracer),
            render_only_frames: 0,
            sum: vec![Vec3::ZERO; (w * h) as usize],
            accumulated: 0,
            raw: Image::new(w as usize, h as usize),
            pass_views: Vec::new(),
            history: VecDeque::new(),
            message: None,
            frames: 0,
            generation: 0,
            frame_times: VecDeque::new(),
            shown: (Image::new(w as usize, h as usize), None, Shade::RelError),
        }
    }

    pub fn camera(&self) -> Camera {
        self.camera
    }

    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The last frame's output of the pass, not accumulated.
    pub fn raw(&self) -> &Image {
        &self.raw
    }

    /// The names of the pass's own debug views (after its first frame).
    pub fn pass_view_names(&self) -> Vec<String> {
        self.pass_views.iter().map(|(n, _, _)| n.clone()).collect()
    }

    fn restart_accumulation(&mut self) {
        self.sum.iter_mut().for_each(|s| *s = Vec3::ZERO);
        self.accumulated = 0;
    }

    /// Applies a command; a message for the UI on what it did (an error: why not).
    pub fn apply(&mut self, command: Command) {
        let result: Result<Option<String>, String> = match command {
            Command::Camera(c) => {
                if c != self.camera {
                    self.camera = c;
                    self.path = None;
                    self.restart_accumulation();
                }
                Ok(None)
            }
            Command::CameraPath(cameras) => {
                if cameras.is_empty() {
                    Err("the camera path has no cameras".into())
                } else {
                    let n = cameras.len();
                    self.path = Some((cameras, 0));
                    Ok(Some(format!("playing a camera path of {n} frames")))
                }
            }
            Command::Pass(spec) => {
                let (w, h, spp) = (self.width, self.height, self.trainer.settings.spp);
                let memory = nrc_harness::run::available_memory();
                match nrc_harness::run::check_frame_memory(&spec, w, h, spp, memory) {
                    Err(e) => Err(e.to_string()),
                    Ok(()) => {
                        let name = spec.to_string();
                        self.trainer.set_pass(spec);
                        self.pass_views.clear();
                        self.restart_accumulation();
                        Ok(Some(format!("pass {name}")))
                    }
                }
            }
            Command::Producer(spec) => {
                let name = spec.to_string();
                self.trainer
                    .set_producer(spec, &self.scene)
                    .map(|()| Some(format!("producer {name}")))
                    .map_err(|e| e.to_string())
            }
            Command::Records(records, budget) => self
                .trainer
                .set_records(records, budget)
                .map(|()| None)
                .map_err(|e| e.to_string()),
            Command::LearningRate(lr) => match self.trainer.cache.neural_mut() {
                Some(c) => c
                    .set_learning_rate(lr)
                    .map(|()| Some(format!("learning rate {lr}")))
                    .map_err(|e| e.to_string()),
                None => Err("the hash cache has no learning rate".into()),
            },
            Command::Training(on) => {
                self.train = on;
                Ok(Some(if on { "training" } else { "training paused" }.into()))
            }
            Command::ResetCache => (self.fresh_cache)().map(|c| {
                self.trainer.set_cache(c);
                self.restart_accumulation();
                Some("the cache starts afresh".into())
            }),
            Command::SaveSnapshot(path) => {
                self.trainer
                    .cache
                    .set_scene_content(self.scene_content.clone());
                self.trainer
                    .cache
                    .save(&path)
                    .map(|()| Some(format!("snapshot saved to {}", path.display())))
                    .map_err(|e| format!("cannot save the snapshot {}: {e}", path.display()))
            }
            Command::LoadSnapshot(path) => (self.load_snapshot)(&path).map(|c| {
                self.trainer.set_cache(c);
                self.restart_accumulation();
                Some(format!("snapshot {} loaded", path.display()))
            }),
            Command::Play(on) => {
                self.playing = on;
                Ok(None)
            }
            Command::Seek(t) => self.seek(t).map(|()| None),
            Command::View(v) => {
                self.view = v;
                Ok(None)
            }
            Command::Tone { exposure, tonemap } => {
                self.tone = Shade::Tone { exposure, tonemap };
                Ok(None)
            }
        };
        match result {
            Ok(Some(m)) => self.message = Some(m),
            Ok(None) => {}
            Err(e) => self.message = Some(format!("error: {e}")),
        }
        self.generation += 1;
    }

    fn seek(&mut self, t: f32) -> Result<(), String> {
        let Some(a) = &self.animation else {
            return Err("the scene is not animated".into());
        };
        let t = if t.is_finite() {
            t.clamp(0.0, a.duration)
        } else {
            0.0
        };
        self.scene = (a.pose)(t)?;
        self.time = t;
        self.restart_accumulation();
        Ok(())
    }

    /// One frame of the loop: camera path and animation advance, produce and train (unless
    /// paused), render the pass, accumulate, and compute the view shown.
    pub fn step(&mut self) -> Result<(), String> {
        if let Some((cameras, i)) = &mut self.path {
            let c = cameras[*i];
            *i += 1;
            if *i == cameras.len() {
                self.path = None;
            }
            if c != self.camera {
                self.camera = c;
                self.restart_accumulation();
            }
        }
        // An animated scene is posed at the frame's time (frame / fps from the start, as
        // `nrc train` poses it), looping at its end.
        let playing = self.playing && self.animation.is_some();
        if playing {
            self.seek(self.time)?;
        }
        let (w, h) = (self.width, self.height);
        let mut line = FrameLine {
            frame: self.frames,
            loss: f32::NAN,
            ..Default::default()
        };
        let out = if self.train {
            let (stats, out) = self
                .trainer
                .frame(&self.scene, &self.camera, w, h, true)
                .map_err(|e| e.to_string())?;
            line.loss = stats.loss;
            line.produce_ms = stats.produce_ms;
            line.train_ms = stats.train_ms;
            line.records = stats.records;
            line.trace_ms = stats.infer_ms - stats.inference.phases.source_ms;
            line.infer_ms = stats.inference.phases.source_ms;
            out.ok_or("the loop rendered no frame")?
        } else {
            let s = &self.trainer.settings;
            // Frames without training draw from their own seeds: reusing the training frames'
            // (pass_seed of the frame index) would average identical noise when training
            // resumes.
            let seed = pass_seed(s.seed ^ RENDER_ONLY_SEED, self.render_only_frames as u32);
            let input = FrameInput {
                scene: &self.scene,
                camera: &self.camera,
                width: w,
                height: h,
                spp: s.spp,
                seed: Stream::TrainingRender.seed(seed),
                emitter_samples: s.emitter_samples,
                sequence: None,
            };
            self.render_only_frames += 1;
            let t = Instant::now();
            let out = self.trainer.render(&input);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            line.trace_ms = ms - out.stats.phases.source_ms;
            line.infer_ms = out.stats.phases.source_ms;
            out
        };
        let t = Instant::now();
        for (s, v) in self.sum.iter_mut().zip(&out.image.data) {
            *s += if v.is_finite() { *v } else { Vec3::ZERO };
        }
        self.accumulated += 1;
        self.raw = out.image;
        self.pass_views = self
            .trainer
            .pass_views()
            .into_iter()
            .map(|v| (v.name.to_string(), v.scalar, v.image))
            .collect();
        self.shown = self.compute_view(self.view);
        line.view_ms = t.elapsed().as_secs_f64() * 1e3;
        self.history.push_back(line);
        while self.history.len() > HISTORY {
            self.history.pop_front();
        }
        if playing && let Some(a) = &self.animation {
            let t = self.time + 1.0 / a.fps;
            self.time = if a.duration > 0.0 && t > a.duration {
                0.0
            } else {
                t
            };
        }
        self.frames += 1;
        self.generation += 1;
        let now = Instant::now();
        self.frame_times.push_back(now);
        while self
            .frame_times
            .front()
            .is_some_and(|t| now.duration_since(*t) > Duration::from_secs(1))
        {
            self.frame_times.pop_front();
        }
        Ok(())
    }

    /// The accumulated mean of the frames since the last change.
    pub fn accumulated(&self) -> Image {
        let n = self.accumulated.max(1) as f32;
        Image::from_data(
            self.width as usize,
            self.height as usize,
            self.sum.iter().map(|s| *s / n).collect(),
        )
        .expect("sizes match")
    }

    /// The image of `view` now (with its second input and how to shade it); a view that has
    /// nothing to show (no reference, a pass view the pass lacks) is black.
    pub fn compute_view(&mut self, view: View) -> (Image, Option<Image>, Shade) {
        let (w, h) = (self.width, self.height);
        let black = || Image::new(w as usize, h as usize);
        match view {
            View::Final => (self.accumulated(), None, self.tone),
            View::Raw => (self.raw.clone(), None, self.tone),
            View::Cache => {
                let input = FrameInput {
                    scene: &self.scene,
                    camera: &self.camera,
                    width: w,
                    height: h,
                    spp: 1,
                    seed: pass_seed(0x5eed, 0),
                    emitter_samples: 0,
                    sequence: None,
                };
                let source = CacheSource::new(&self.trainer.cache);
                let out = passes::run(self.cache_pass.as_mut(), &input, &source);
                (out.image, None, self.tone)
            }
            View::Records => {
                // Paused, no records land: the last trained frame's are not shown as this one's.
                let counts = if self.train {
                    self.record_counts()
                } else {
                    black()
                };
                let max = counts.data.iter().map(|c| c.x).fold(0.0, f32::max);
                (black(), Some(counts), Shade::Heat { max })
            }
            View::Error => match &self.reference {
                Some(r) => (self.accumulated(), Some(r.clone()), Shade::RelError),
                None => (black(), Some(black()), Shade::RelError),
            },
            View::Pass(i) => match self.pass_views.get(i) {
                Some((_, true, img)) => {
                    let (lo, hi) = img
                        .data
                        .iter()
                        .fold((f32::MAX, 0.0f32), |(lo, hi), v| (lo.min(v.x), hi.max(v.x)));
                    (
                        img.clone(),
                        None,
                        Shade::Scalar {
                            min: lo.min(hi),
                            max: hi.max(lo + 1e-6),
                        },
                    )
                }
                Some((_, false, img)) => (img.clone(), None, self.tone),
                None => (black(), None, self.tone),
            },
        }
    }

    /// The last frame's training records per pixel (in red): their positions projected
    /// through the camera.
    fn record_counts(&self) -> Image {
        let (w, h) = (self.width, self.height);
        let mut counts = Image::new(w as usize, h as usize);
        let b = self.trainer.settings.queries.scene_box;
        let (min, max) = (Vec3::from(b.min), Vec3::from(b.max));
        for p in self.trainer.record_positions() {
            let world = min + Vec3::from(*p) * (max - min);
            if let Some(film) = self.camera.project(world, w, h) {
                let (x, y) = (film.x as usize, film.y as usize);
                let i = y * w as usize + x;
                if let Some(c) = counts.data.get_mut(i) {
                    c.x += 1.0;
                }
            }
        }
        counts
    }

    /// What the UI shows now.
    pub fn publish(&self) -> Published {
        let (image, aux, shade) = self.shown.clone();
        let pass_views = self.pass_view_names();
        Published {
            generation: self.generation,
            frames: self.frames,
            accumulated: self.accumulated,
            image,
            aux,
            shade,
            view: self.view,
            pass_views,
            camera: self.camera,
            history: self.history.clone(),
            training: self.train,
            pass: self.trainer.settings.pass.to_string(),
            producer: self.trainer.settings.producer.to_string(),
            records: self.trainer.settings.records_per_frame,
            budget_ms: self.trainer.settings.train_budget_ms,
            learning_rate: self.trainer.cache.neural().map(|c| c.learning_rate()),
            describe: self.trainer.cache.describe(),
            message: self.message.clone(),
            time: self
                .animation
                .as_ref()
                .map(|a| (self.time, a.duration, self.playing)),
            on_path: self.path.is_some(),
            loop_fps: self.frame_times.len() as f32,
            has_reference: self.reference.is_some(),
        }
    }
}

/// The loop on its own thread: commands from `commands` between frames, what to show into
/// `shared` after each. It stops when `stop` is set or the command channel closes, after the
/// frame (or the snapshot being written) it is in; its error, if a frame fails, is published
/// as the message and the loop waits for commands.
pub struct Running {
    pub commands: Sender<Command>,
    pub shared: Arc<Mutex<Published>>,
    /// The generation last published (a cheap check for a new frame).
    pub generation: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Running {
    /// Stops the loop and waits for it.
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Starts `session` on a thread whose frames run on `pool`. The loop's threads run at a lower
/// priority than the UI's: they take every core the UI leaves, and the UI (whose frames on a
/// software adapter cost tens of milliseconds of CPU) gets the cores when it draws.
pub fn spawn(session: Session, pool: rayon::ThreadPool) -> Running {
    let (tx, rx) = std::sync::mpsc::channel();
    let shared = Arc::new(Mutex::new(session.publish()));
    let generation = Arc::new(AtomicU64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let (shared, generation, stop) = (shared.clone(), generation.clone(), stop.clone());
        std::thread::Builder::new()
            .name("nrc view loop".into())
            .spawn(move || {
                lower_priority();
                pool.broadcast(|_| lower_priority());
                pool.install(move || run_loop(session, rx, &shared, &generation, &stop))
            })
            .expect("a thread can be started")
    };
    Running {
        commands: tx,
        shared,
        generation,
        stop,
        thread: Some(thread),
    }
}

/// Lowers the calling thread's scheduling priority (nice +10: about a tenth of the CPU share of
/// a normal thread when both want a core).
fn lower_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: setpriority on the calling thread's own id has no memory effects; a failure only
    // leaves the priority as it was.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 10);
    }
}

fn run_loop(
    mut session: Session,
    commands: Receiver<Command>,
    shared: &Mutex<Published>,
    generation: &AtomicU64,
    stop: &AtomicBool,
) {
    let mut failed = false;
    loop {
        if stop.load(Ordering::SeqCst) {
            // Commands sent before the window closed (a snapshot to save) are carried out.
            while let Ok(c) = commands.try_recv() {
                session.apply(c);
            }
            return;
        }
        // After a failed frame, wait for a command (one that may fix it) instead of spinning.
        if failed {
            match commands.recv_timeout(Duration::from_millis(100)) {
                Ok(c) => {
                    session.apply(c);
                    failed = false;
                }
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => return,
            }
        }
        loop {
            match commands.try_recv() {
                Ok(c) => session.apply(c),
                Err(std::sync::mpsc::TryRecvError::Empty) => break,
                Err(std::sync::mpsc::TryRecvError::Disconnected) => return,
            }
        }
        let stepped = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| session.step()));
        let error = match stepped {
            Ok(Ok(())) => None,
            Ok(Err(e)) => Some(e),
            Err(panic) => Some(format!(
                "the loop failed: {}",
                panic
                    .downcast_ref::<String>()
                    .map(String::as_str)
                    .or_else(|| panic.downcast_ref::<&str>().copied())
                    .unwrap_or("a panic")
            )),
        };
        if let Some(e) = error {
            session.message = Some(format!("error: {e}"));
            session.generation += 1;
            failed = true;
        }
        let published = session.publish();
        let g = published.generation;
        if let Ok(mut s) = shared.lock() {
            *s = published;
        }
        generation.store(g, Ordering::SeqCst);
    }
}
