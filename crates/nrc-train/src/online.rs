//! The online loop: per frame, predict training queries, produce records, train the cache,
//! and render with it.

use std::borrow::Cow;
use std::time::Instant;

use nrc_cache::{Cache, CacheError, PendingTrain};
use nrc_render::passes::{self, FrameInput, PassOutput, PassSpec, PassStats, RenderPass, Warmth};
use nrc_render::sampler::Stream;
use nrc_render::{PathTracer, PixelSampler, pass_seed};
use nrc_scene::{Camera, Scene};

use crate::clipped::ClippedLight;
use crate::error::TrainError;
use crate::mix::{ProducerMix, ProducerOptions, ProducerSpec};
use crate::producer::{Produced, ProducerContext, ProducerStats};
use crate::query::QueryMaker;
use crate::schedule::{ChangeDetector, ChangeMonitor, Phase, TrainBudget};
use crate::source::CacheSource;
use crate::starts::{self, TerminationPoint};

/// Training records produced per frame by default.
pub const DEFAULT_RECORDS_PER_FRAME: usize = 1 << 12;

/// Training records of a frame at which the cache's predictions are compared with the targets
/// before the frame trains ([`crate::schedule`]).
pub const PROBE_RECORDS: usize = 4096;

/// Settings of the online loop.
#[derive(Clone, Debug, PartialEq)]
pub struct OnlineSettings {
    /// The producers and their shares of the record budget.
    pub producer: ProducerSpec,
    /// The producers' own settings.
    pub producer_options: ProducerOptions,
    /// Training records produced per frame.
    pub records_per_frame: usize,
    /// Records per optimisation step: a frame's records are shuffled and trained in batches
    /// of this size, one step each (NRC: 4 × 2^14).
    pub batch_size: usize,
    /// Fraction of the training queries aimed at the previous frame's termination points
    /// (the rest are camera primary hits in jittered tiles).
    pub from_terminations: f32,
    /// Depth and Russian roulette of training paths.
    pub tracer: PathTracer,
    /// The inference pass (its depth limit and Russian roulette are `tracer`'s).
    pub pass: PassSpec,
    /// The scene box of the cache's queries.
    pub queries: QueryMaker,
    /// Samples per pixel of the inference pass.
    pub spp: u32,
    /// Extra camera rays, their emission only, at each pixel on the outline of an emitter the
    /// camera sees (`nrc_render::emitters::supersample`; 0: none).
    pub emitter_samples: u32,
    pub seed: u64,
    /// Watch for changes in the scene and recover from them ([`crate::schedule`]): after a
    /// change the cache infers from its training weights and takes `recovery_steps` steps
    /// on each batch until its predictions are back at their level before it.
    pub recover: bool,
    /// Optimisation steps on each batch while the cache recovers (RESULTS.md, "Recovery after
    /// a sudden change").
    pub recovery_steps: u32,
    /// Milliseconds a frame may spend producing and training ([`TrainBudget`]); `None`: every
    /// frame produces [`OnlineSettings::records_per_frame`] records (reproducible bit for bit,
    /// which a budget measured in time is not).
    pub train_budget_ms: Option<f64>,
    /// With the cache on a GPU, queue a frame's training steps and read their losses after the
    /// render, which traces on the CPU while they run (`false`: wait for each training call).
    /// Either order gives the same cache and images; only the timing differs (the render's
    /// time then holds the wait for the steps). Not under a training budget
    /// ([`OnlineSettings::train_budget_ms`]), which prices training by its time.
    pub overlap: bool,
}

impl OnlineSettings {
    /// The defaults for `scene`: [`DEFAULT_RECORDS_PER_FRAME`] records a frame (NRC trains 2^16
    /// on a GPU) in steps of at most 2^14, camera-tile queries, spread-heuristic termination with
    /// NEE, 1 sample per pixel.
    pub fn new(producer: ProducerSpec, scene: &Scene, tracer: PathTracer) -> Self {
        Self {
            producer,
            producer_options: ProducerOptions::default(),
            records_per_frame: DEFAULT_RECORDS_PER_FRAME,
            batch_size: 1 << 14,
            from_terminations: 0.0,
            tracer,
            pass: PassSpec::default(),
            queries: QueryMaker::new(&scene.bounds()),
            spp: 1,
            emitter_samples: 0,
            seed: 0,
            recover: true,
            recovery_steps: 1,
            train_budget_ms: None,
            overlap: true,
        }
    }

    /// One line on how the loop controls training: recovery after changes, and the budget.
    pub fn describe_control(&self) -> String {
        let recovery = if self.recover {
            format!(
                "watching for changes in the scene (after one: inference from the training weights, {} step(s) a batch, until the cache has caught up; the learning rate's decay restarts once the change lasts a second frame)",
                self.recovery_steps
            )
        } else {
            "not watching for changes in the scene".to_string()
        };
        let budget = match self.train_budget_ms {
            Some(ms) => format!(
                "records chosen to fit {ms} ms a frame of producing and training (half once settled)"
            ),
            None => format!("{} records a frame", self.records_per_frame),
        };
        format!("online loop: {recovery}; {budget}")
    }

    /// Checks the settings, naming the first bad one.
    pub fn validate(&self) -> Result<(), TrainError> {
        if self.records_per_frame == 0 {
            return Err(TrainError::bounds("records per frame", "be at least 1", 0));
        }
        if self.batch_size == 0 {
            return Err(TrainError::bounds("the batch size", "be at least 1", 0));
        }
        if !(0.0..=1.0).contains(&self.from_terminations) {
            return Err(TrainError::bounds(
                "the fraction of queries from termination points",
                "be in [0, 1]",
                self.from_terminations,
            ));
        }
        if self.recovery_steps == 0 {
            return Err(TrainError::bounds(
                "steps while recovering",
                "be at least 1",
                0,
            ));
        }
        if let Some(ms) = self.train_budget_ms
            && !(ms.is_finite() && ms > 0.0)
        {
            return Err(TrainError::bounds(
                "the training budget (ms per frame)",
                "be finite and > 0",
                ms,
            ));
        }
        if self.spp == 0 {
            return Err(TrainError::bounds("samples per pixel", "be at least 1", 0));
        }
        self.producer_options.validate()
    }
}

/// What one frame did and cost.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct FrameStats {
    pub frame: u64,
    /// Milliseconds producing training records (query prediction and producers).
    pub produce_ms: f64,
    /// Milliseconds training.
    pub train_ms: f64,
    /// Milliseconds of the inference pass (0 when the frame was not rendered).
    pub infer_ms: f64,
    /// Records produced.
    pub records: usize,
    /// Records trained on.
    pub used: usize,
    /// Records dropped for a NaN or infinite query field or target.
    pub dropped_nonfinite: usize,
    /// Records dropped for a negative or absurdly large target.
    pub dropped_absurd: usize,
    /// Optimisation steps taken.
    pub steps: u32,
    /// Mean loss of the frame's last step.
    pub loss: f32,
    /// Mean luminance of the frame's finite targets (zero: the producers found no light).
    pub target_mean: f32,
    /// How far the frame's targets were from the cache's predictions beyond their noise
    /// ([`crate::schedule::ChangeMonitor::score`]).
    pub change_z: f32,
    /// What the change detector made of the frame.
    pub phase: Phase,
    /// Under a training budget, the milliseconds the frame planned to spend producing and
    /// training (0 without a budget).
    pub spend_ms: f64,
    /// The learning rate of the frame's first step, decayed as the cache's configuration says
    /// (0 for the hash cache).
    pub learning_rate: f32,
    /// Records whose target was clamped at the loss bound, the light returned to their bins
    /// ([`crate::clipped`]; 0 when the cache's loss does not return it).
    pub clamped: usize,
    /// The records' mean gain from the light returned to their bins (1 when none was; 0 when
    /// the cache's loss does not return it). The bins start empty with a new cache and after a
    /// confirmed change.
    pub clip_gain: f32,
    pub producer: ProducerStats,
    pub inference: PassStats,
}

/// A cache trained online on one scene.
pub struct OnlineTrainer {
    pub cache: Cache,
    pub settings: OnlineSettings,
    mix: ProducerMix,
    pass: Box<dyn RenderPass>,
    /// The inference pass's frames (how warm its history is).
    warmth: Warmth,
    /// Frames of its size the pass had rendered before the last one.
    warm_frames: u32,
    previous: Vec<TerminationPoint>,
    frame: u64,
    monitor: ChangeMonitor,
    detector: ChangeDetector,
    budget: Option<TrainBudget>,
    /// The last frame's training records' positions (normalised to the scene box, as the
    /// cache sees them): where the frame trained (the viewer's heat map).
    record_positions: Vec<[f32; 3]>,
    /// The light the loss bound clipped, per bin (when the cache's loss returns it).
    clipped: Option<ClippedLight>,
}

impl OnlineTrainer {
    /// A trainer of `cache` (whose scene box should be `settings.queries.scene_box`) on
    /// `scene`; an error names a bad setting or a producer that cannot serve the scene.
    pub fn new(
        cache: impl Into<Cache>,
        settings: OnlineSettings,
        scene: &Scene,
    ) -> Result<Self, TrainError> {
        settings.validate()?;
        let mix = ProducerMix::new(&settings.producer, &settings.producer_options);
        mix.check(scene)?;
        Ok(Self {
            cache: cache.into(),
            mix,
            pass: settings.pass.build(&settings.tracer),
            warmth: Warmth::default(),
            warm_frames: 0,
            previous: Vec::new(),
            frame: 0,
            monitor: ChangeMonitor::default(),
            detector: ChangeDetector::default(),
            budget: settings
                .train_budget_ms
                .map(|ms| TrainBudget::new(ms, settings.records_per_frame)),
            record_positions: Vec::new(),
            clipped: None,
            settings,
        })
    }

    /// Replaces the inference pass (its state starts afresh).
    pub fn set_pass(&mut self, pass: PassSpec) {
        self.pass = pass.build(&self.settings.tracer);
        self.settings.pass = pass;
        self.warmth.reset();
        self.previous.clear();
    }

    /// Replaces the producers; an error names a producer that cannot serve `scene` (the
    /// trainer is then unchanged).
    pub fn set_producer(
        &mut self,
        producer: ProducerSpec,
        scene: &Scene,
    ) -> Result<(), TrainError> {
        let mix = ProducerMix::new(&producer, &self.settings.producer_options);
        mix.check(scene)?;
        self.mix = mix;
        self.settings.producer = producer;
        Ok(())
    }

    /// Sets the records a frame produces without a budget, and the per-frame training budget
    /// (`None`: none); an error names a bad value (the trainer is then unchanged).
    pub fn set_records(
        &mut self,
        records_per_frame: usize,
        train_budget_ms: Option<f64>,
    ) -> Result<(), TrainError> {
        let settings = OnlineSettings {
            records_per_frame,
            train_budget_ms,
            ..self.settings.clone()
        };
        settings.validate()?;
        if settings.train_budget_ms != self.settings.train_budget_ms
            || settings.records_per_frame != self.settings.records_per_frame
        {
            self.budget = train_budget_ms.map(|ms| TrainBudget::new(ms, records_per_frame));
        }
        self.settings = settings;
        Ok(())
    }

    /// Replaces the cache (a fresh one, or a loaded snapshot): the change watch and the
    /// pass's history start afresh, since both describe the old cache's answers.
    pub fn set_cache(&mut self, cache: impl Into<Cache>) {
        self.cache = cache.into();
        self.monitor = ChangeMonitor::default();
        self.detector = ChangeDetector::default();
        self.pass.reset();
        self.warmth.reset();
        self.previous.clear();
        self.clipped = None;
    }

    /// The inference pass's own debug views after its last frame.
    pub fn pass_views(&self) -> Vec<passes::PassView> {
        self.pass.debug_views()
    }

    /// The last frame's training records' positions, normalised to the scene box (empty
    /// before the first frame).
    pub fn record_positions(&self) -> &[[f32; 3]] {
        &self.record_positions
    }

    /// Renders a frame with the inference pass and the cache as it is (no training).
    pub fn render(&mut self, input: &FrameInput) -> PassOutput {
        let source = CacheSource {
            cache: &self.cache,
            queries: self.settings.queries,
        };
        self.warm_frames = self.warmth.count(input);
        passes::run(self.pass.as_mut(), input, &source)
    }

    /// Frames of its size the inference pass had rendered (since it was built) before the last
    /// one: how warm the history of a stateful pass was.
    pub fn warm_frames(&self) -> u32 {
        self.warm_frames
    }

    /// Frames run so far.
    pub fn frames(&self) -> u64 {
        self.frame
    }

    /// One frame: produce and train, then (when `render`) the inference pass of a
    /// `width × height` image from `camera`.
    pub fn frame(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        render: bool,
    ) -> Result<(FrameStats, Option<PassOutput>), CacheError> {
        let s = &self.settings;
        let seed = pass_seed(s.seed, self.frame as u32);
        let mut stats = FrameStats {
            frame: self.frame,
            ..Default::default()
        };

        self.cache.set_camera(camera.position.to_array());
        // The frame's records: fixed, or what the budget affords at the steps the cache is
        // taking (more while it recovers).
        let recovering = s.recover && self.detector.recovering();
        let steps = if recovering { s.recovery_steps } else { 1 };
        let records = match &self.budget {
            Some(b) => {
                let plan = b.plan(steps, self.detector.settled());
                stats.spend_ms = plan.spend_ms;
                plan.records
            }
            None => s.records_per_frame,
        };
        let t = Instant::now();
        let source = CacheSource {
            cache: &self.cache,
            queries: s.queries,
        };
        let view = FrameView {
            scene,
            camera,
            width,
            height,
        };
        let mut produced = produce_frame(
            &mut self.mix,
            s,
            &source,
            &view,
            &self.previous,
            records,
            seed,
        );
        stats.produce_ms = t.elapsed().as_secs_f64() * 1e3;
        stats.records = produced.batch.queries.len();
        self.record_positions.clear();
        self.record_positions
            .extend(produced.batch.queries.iter().map(|q| q.position));
        stats.producer = produced.stats;
        let finite: Vec<f32> = produced
            .batch
            .targets
            .iter()
            .map(|t| nrc_scene::sampling::luminance(glam::Vec3::from(*t)))
            .filter(|l| l.is_finite())
            .collect();
        stats.target_mean = finite.iter().sum::<f32>() / finite.len().max(1) as f32;

        let t = Instant::now();
        let order = shuffled(produced.batch.queries.len(), seed);
        // The cache's predictions at every record, where the loss returns the light its bound
        // clips (the clamp is at the prediction).
        let returned = self.cache.neural().and_then(|c| {
            c.config()
                .loss
                .return_clipped
                .clone()
                .map(|r| (r, c.config().loss.clone()))
        });
        let all = returned
            .is_some()
            .then(|| self.cache.infer(&produced.batch.queries));
        // The change score: the cache's predictions (what the passes read) at the frame's
        // training queries, before it learns from them (not watched without recovery). Beyond
        // PROBE_RECORDS records a shuffled subset, so that a mix's producers all take part.
        if s.recover {
            let n = produced.batch.queries.len();
            let probe = n.min(PROBE_RECORDS);
            let probed = if probe < n {
                Cow::Owned(produced.batch.select(&order[..probe]))
            } else {
                Cow::Borrowed(&produced.batch)
            };
            let predictions = match &all {
                Some(p) if probe < n => Cow::Owned(order[..probe].iter().map(|&i| p[i]).collect()),
                Some(p) => Cow::Borrowed(p.as_slice()),
                None => Cow::Owned(self.cache.infer(&probed.queries)),
            };
            stats.change_z = self.monitor.score(&probed, &predictions).z;
            stats.phase = self.detector.observe(stats.change_z);
            match stats.phase {
                Phase::Changed => self.cache.begin_recovery(),
                Phase::Confirmed => {
                    self.cache.confirm_change();
                    // The bins' light is the scene's before the change.
                    self.clipped = None;
                }
                Phase::Recovered => self.cache.end_recovery(),
                _ => {}
            }
        }
        // The light the bound would clip, returned to its bins (after the change score, which
        // reads the targets as the producers made them).
        if let (Some((spec, loss)), Some(predictions)) = (returned, &all) {
            let light = match self.clipped.take() {
                Some(c) if c.spec() == &spec => c,
                _ => ClippedLight::new(&spec),
            };
            let done = self
                .clipped
                .insert(light)
                .apply(&mut produced.batch, predictions, &loss);
            stats.clamped = done.clamped;
            stats.clip_gain = done.gain;
        }
        // Recovering, the cache takes more steps on each batch (decided before this frame's
        // score, which may start or end a recovery: the steps follow one frame later). On a
        // GPU the steps are queued and the render below traces on the CPU while they run
        // (its cache queries wait for them); their losses are read after it.
        // Under a time budget each call is waited for: the budget prices training by its time,
        // which a wait hidden in the render would move out of sight.
        stats.learning_rate = self
            .cache
            .neural()
            .map_or(0.0, |c| c.current_learning_rate());
        let overlap = s.overlap && self.budget.is_none();
        let mut pending = Vec::new();
        for chunk in order.chunks(s.batch_size) {
            let batch = produced.batch.select(chunk);
            pending.push(self.cache.train_submit(&batch, steps)?);
            if !overlap {
                let done = pending.pop().expect("just pushed").wait();
                pending.push(PendingTrain::ready(done));
            }
        }
        stats.train_ms = t.elapsed().as_secs_f64() * 1e3;

        let mut output = None;
        if render {
            let t = Instant::now();
            let input = FrameInput {
                scene,
                camera,
                width,
                height,
                spp: s.spp,
                seed: Stream::TrainingRender.seed(seed),
                emitter_samples: s.emitter_samples,
                sequence: None,
            };
            let source = CacheSource {
                cache: &self.cache,
                queries: s.queries,
            };
            self.warm_frames = self.warmth.count(&input);
            let out = passes::run(self.pass.as_mut(), &input, &source);
            stats.infer_ms = t.elapsed().as_secs_f64() * 1e3;
            stats.inference = out.stats;
            self.previous = out.terminations.clone();
            output = Some(out);
        }
        let t = Instant::now();
        for p in pending {
            let st = p.wait();
            stats.used += st.used;
            stats.dropped_nonfinite += st.dropped_nonfinite;
            stats.dropped_absurd += st.dropped_absurd;
            stats.steps += st.steps;
            if st.steps > 0 {
                stats.loss = st.loss;
            }
        }
        stats.train_ms += t.elapsed().as_secs_f64() * 1e3;
        if let Some(b) = &mut self.budget {
            b.observe(stats.records, steps, stats.produce_ms, stats.train_ms);
        }
        self.frame += 1;
        Ok((stats, output))
    }
}

/// The scene and camera of a frame, and its image size (query prediction's tiles).
#[derive(Clone, Copy)]
pub struct FrameView<'a> {
    pub scene: &'a Scene,
    pub camera: &'a Camera,
    pub width: u32,
    pub height: u32,
}

/// A frame's training records as the online loop produces them ([`OnlineTrainer::frame`]):
/// query prediction from the camera (the fraction `settings.from_terminations` aimed at the
/// previous frame's termination points `previous`), then the mix's producers on `records`
/// records, reading `source` (the cache) for self-learning; `seed` is the frame's
/// ([`pass_seed`] of the settings' seed and the frame index).
pub fn produce_frame(
    mix: &mut ProducerMix,
    settings: &OnlineSettings,
    source: &dyn nrc_render::RadianceSource,
    view: &FrameView,
    previous: &[TerminationPoint],
    records: usize,
    seed: u64,
) -> Produced {
    let starts = starts::predict(
        view.camera,
        view.width,
        view.height,
        previous,
        settings.from_terminations,
        records,
        seed,
    );
    let ctx = ProducerContext {
        scene: view.scene,
        camera: view.camera,
        cache: source,
        queries: &settings.queries,
        starts: &starts,
        tracer: settings.tracer,
    };
    mix.produce(&ctx, records, seed)
}

/// A permutation of `0..n` (Fisher–Yates on the stream `seed`).
fn shuffled(n: usize, seed: u64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..n).collect();
    let mut s = PixelSampler::new(seed, u64::MAX - 3, 0);
    for i in (1..n).rev() {
        let j = ((s.next_1d() as f64 * (i + 1) as f64) as usize).min(i);
        order.swap(i, j);
    }
    order
}
