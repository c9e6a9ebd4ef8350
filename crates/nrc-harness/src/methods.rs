//! The method registry: every name `nrc compare` accepts, as one [`MethodSpec`] (a pass × a
//! radiance source × the producers that train it).
//!
//! - `pt-<N>spp[-nonee]`: the reference path tracer ([`PathTracedSettings`]) at N samples
//!   per pixel per estimate, NEE and BSDF sampling by MIS (or BSDF sampling only); no source.
//! - `nrc-<producer>[-<termination>]`: a cache trained online by a producer (`pt`, `pt-sl`,
//!   `bt`, `lt`, `sppc`), rendered at 1 sample per pixel by the cache-terminated pass with paths
//!   ending in it by the termination strategy (default `spread`; see [`Termination`]), e.g.
//!   `nrc-pt-sl`, `nrc-sppc-first`, `nrc-pt-bth:8`.
//!
//! A cache method is trained for [`CacheMethodSettings::train_frames`] frames in
//! [`Method::prepare`] (untimed), then each estimate is one online frame: produce, train
//! (unless frozen) and the inference pass. Its time per frame therefore includes training.

use std::fmt;
use std::str::FromStr;

use nrc_cache::{Cache, CacheConfig, CacheDevice, CacheKind, HashCacheConfig, RadianceCache};
use nrc_render::passes::{
    self, CacheTerminatedSettings, FrameInput, PathTracedSettings, RenderPass, TERMINATION_NAMES,
    Termination, Warmth,
};
use nrc_render::{LightStrategy, PassSpec, PathTracer, ZeroSource};
use nrc_scene::{Camera, Scene};
use nrc_train::mix::{PRODUCER_NAMES, ProducerOptions, ProducerSpec};
use nrc_train::online::{OnlineSettings, OnlineTrainer};
use nrc_train::query::QueryMaker;

use crate::budget::{Estimate, Method};
use crate::error::HarnessError;
use nrc_render::error::PassError;

/// The producer of the cache that a resampling pass's `-nrc` variant reads when its name
/// names none.
pub const DEFAULT_PASS_PRODUCER: &str = "pt-sl";

/// The grammar of all method names.
pub fn method_names() -> String {
    format!(
        "pt-<N>spp (reference path tracer, N samples per pixel per estimate, NEE and BSDF sampling combined by MIS), \
         pt-<N>spp-nonee (the same with next-event estimation off: BSDF sampling only), \
         nrc-<producer>[-<termination>] (a cache trained online, 1 spp; producers: {PRODUCER_NAMES}; terminations: {TERMINATION_NAMES}), \
         hash-<producer>[-<termination>] (the same with the spatial-hash radiance cache instead of the network), \
         {} \
         (the resampling, probe and instant-radiosity passes by their names at 1 spp, see `--pass`; those reading a cache read one trained online by {DEFAULT_PASS_PRODUCER}), \
         or in general <pass>@<N>spp[+[hash:]<producer>] (any pass of `--pass`, e.g. pt-light@4spp, cache-first-nonee@2spp+pt-sl, restir-gi-nrc@1spp+hash:pt-sl)",
        passes::REGISTRY
            .iter()
            .filter(|k| k.method)
            .map(|k| format!("{}[:PARAMS]", k.grammar))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// A rendering method: a pass, its samples per pixel per estimate, and the producers of the
/// cache it reads (`None`: the pass reads no source).
#[derive(Clone, Debug, PartialEq)]
pub struct MethodSpec {
    pub pass: PassSpec,
    pub spp: u32,
    pub producer: Option<ProducerSpec>,
    /// The kind of cache the producers train (`nrc-…`: neural, `hash-…`: the spatial hash).
    pub cache: CacheKind,
}

/// A name that is not a method.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParseMethodError {
    pub name: String,
    pub reason: String,
}

impl fmt::Display for ParseMethodError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "unknown method `{}`: {}; known methods: {}",
            self.name,
            self.reason,
            method_names()
        )
    }
}

impl std::error::Error for ParseMethodError {}

/// Methods separated by commas, as `nrc compare --methods` takes them: an item whose part
/// before any `@` is `key=value` (no `:`) continues the parameters of the method before it, so
/// `ddgi-restir:rays=64,k=0,restir-di` is two methods, and so is
/// `nrc-restir:light=2,direct=0@1spp+hash:pt-sl,pt-1spp` (a pass name never holds `=`).
#[derive(Clone, Debug, PartialEq)]
pub struct MethodList(pub Vec<MethodSpec>);

impl FromStr for MethodList {
    type Err = ParseMethodError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut items: Vec<String> = Vec::new();
        for part in s.split(',') {
            let head = part.split_once('@').map_or(part, |(head, _)| head);
            let continues = head.contains('=') && !head.contains(':');
            match items.last_mut() {
                Some(last) if continues => {
                    last.push(',');
                    last.push_str(part);
                }
                _ => items.push(part.to_string()),
            }
        }
        items
            .iter()
            .map(|m| m.parse())
            .collect::<Result<_, _>>()
            .map(Self)
    }
}

impl FromStr for MethodSpec {
    type Err = ParseMethodError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        let err = |reason: &str| ParseMethodError {
            name: s.to_string(),
            reason: reason.to_string(),
        };
        // The general form: <pass>@<N>spp[+<producer>].
        if let Some((pass, rest)) = s.split_once('@') {
            let pass: PassSpec = pass.parse().map_err(|e: PassError| err(&e.to_string()))?;
            let (spp, producer, cache) = match rest.split_once('+') {
                Some((spp, p)) => {
                    let (p, cache) = match p.strip_prefix("hash:") {
                        Some(p) => (p, CacheKind::Hash),
                        None => (p, CacheKind::Neural),
                    };
                    let p = p.parse::<ProducerSpec>().map_err(|e| err(&e.to_string()))?;
                    (spp, Some(p), cache)
                }
                None => (rest, None, CacheKind::Neural),
            };
            let spp: u32 = spp
                .strip_suffix("spp")
                .and_then(|n| n.parse().ok())
                .filter(|n| *n >= 1)
                .ok_or_else(|| err("after `@`: samples per pixel, e.g. @4spp"))?;
            if pass.uses_source() != producer.is_some() {
                return Err(err(if producer.is_some() {
                    "this pass reads no cache: leave out +<producer>"
                } else {
                    "this pass reads a cache: name its producer, e.g. +pt-sl"
                }));
            }
            return Ok(Self {
                pass,
                spp,
                producer,
                cache,
            });
        }
        // The resampling and instant-radiosity passes by their pass names, at 1 sample per pixel.
        // `-nrc` variants read a cache trained online by `pt-sl` (other producers: the general
        // form, e.g. wsrestir-gi-nrc@1spp+bt).
        if let Some((kind, pass)) = passes::find(s)
            && kind.method
        {
            let pass = pass.map_err(|e| err(&e.to_string()))?;
            let producer = pass.uses_source().then(|| {
                DEFAULT_PASS_PRODUCER
                    .parse::<ProducerSpec>()
                    .expect("a producer name")
            });
            return Ok(Self {
                pass,
                spp: 1,
                producer,
                cache: CacheKind::Neural,
            });
        }
        let cache_name = s
            .strip_prefix("nrc-")
            .map(|r| (r, CacheKind::Neural))
            .or_else(|| s.strip_prefix("hash-").map(|r| (r, CacheKind::Hash)));
        if let Some((rest, cache)) = cache_name {
            if rest.starts_with("mix:") {
                return Err(err(
                    "mixes are not method names; train a mix with `nrc train --producer mix:...`",
                ));
            }
            // `<producer>-<termination>` when the last part is a termination, else all producer.
            let (producer, termination) = match rest.rsplit_once('-') {
                Some((p, t)) if t.parse::<Termination>().is_ok() => {
                    (p, t.parse::<Termination>().expect("just parsed"))
                }
                _ => (rest, Termination::default()),
            };
            let producer = producer
                .parse::<ProducerSpec>()
                .map_err(|e| err(&e.to_string()))?;
            return Ok(Self {
                pass: CacheTerminatedSettings {
                    termination,
                    nee: true,
                }
                .into(),
                spp: 1,
                producer: Some(producer),
                cache,
            });
        }
        let mut parts = s.split('-');
        if parts.next() != Some("pt") {
            return Err(err(
                "no such method family (cache methods: nrc-<producer>[-<termination>])",
            ));
        }
        let spp = parts
            .next()
            .and_then(|p| p.strip_suffix("spp"))
            .ok_or_else(|| {
                err("the path tracer's name needs its samples per pixel, e.g. pt-16spp")
            })?;
        let spp: u32 = spp
            .parse()
            .map_err(|_| err("samples per pixel must be a whole number, e.g. pt-16spp"))?;
        if spp == 0 {
            return Err(err("samples per pixel must be at least 1"));
        }
        let strategy = match parts.next() {
            None | Some("nee") => LightStrategy::Mis,
            Some("nonee") => LightStrategy::BsdfOnly,
            Some(_) => {
                return Err(err(
                    "the only path tracer options are -nee (default) and -nonee",
                ));
            }
        };
        if parts.next().is_some() {
            return Err(err("too many parts"));
        }
        Ok(Self {
            pass: PathTracedSettings { strategy }.into(),
            spp,
            producer: None,
            cache: CacheKind::Neural,
        })
    }
}

impl fmt::Display for MethodSpec {
    /// The canonical name (parses back to the same spec): the short names where they exist,
    /// else the general form.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let cache = self.pass.get::<CacheTerminatedSettings>();
        let traced = self.pass.get::<PathTracedSettings>().map(|p| p.strategy);
        let (family, hash) = match self.cache {
            CacheKind::Neural => ("nrc", ""),
            CacheKind::Hash => ("hash", "hash:"),
        };
        match (&self.producer, self.spp) {
            (Some(p), 1) if cache.is_some_and(|c| c.nee) => match cache.map(|c| c.termination) {
                Some(t) if t != Termination::default() => write!(f, "{family}-{p}-{t}"),
                _ => write!(f, "{family}-{p}"),
            },
            (None, spp) if traced == Some(LightStrategy::Mis) => write!(f, "pt-{spp}spp"),
            (None, spp) if traced == Some(LightStrategy::BsdfOnly) => {
                write!(f, "pt-{spp}spp-nonee")
            }
            // The passes `from_str` takes by their own names.
            (None, 1) if self.pass.kind().method => write!(f, "{}", self.pass),
            (Some(p), 1)
                if self.pass.kind().method
                    && self.cache == CacheKind::Neural
                    && p.to_string() == DEFAULT_PASS_PRODUCER =>
            {
                write!(f, "{}", self.pass)
            }
            (None, spp) => write!(f, "{}@{spp}spp", self.pass),
            (Some(p), spp) => write!(f, "{}@{spp}spp+{hash}{p}", self.pass),
        }
    }
}

/// How cache methods are set up (shared by all cache methods of a comparison).
#[derive(Clone, Debug, PartialEq)]
pub struct CacheMethodSettings {
    pub config: CacheConfig,
    pub device: CacheDevice,
    /// Finest resolution of the encoding along the scene's longest axis (the smallest feature
    /// resolved is the longest extent divided by it).
    pub resolution: u32,
    /// Frames of online training before measurement.
    pub train_frames: u32,
    pub records_per_frame: usize,
    pub batch_size: usize,
    /// Watch for changes in the scene and recover from them (`OnlineSettings::recover`).
    pub recover: bool,
    /// Read a GPU's training losses after the frame's render (`OnlineSettings::overlap`).
    pub overlap: bool,
    /// Optimisation steps on each batch while recovering (`OnlineSettings::recovery_steps`).
    pub recovery_steps: u32,
    /// Milliseconds a frame may spend producing and training (`OnlineSettings::train_budget_ms`).
    pub train_budget_ms: Option<f64>,
    /// Keep training during measurement (each estimate is a full online frame); else frozen.
    pub online: bool,
    /// The producers' own settings.
    pub producer_options: ProducerOptions,
    pub seed: u64,
    /// The kind of cache trained, and the hash cache's settings.
    pub kind: CacheKind,
    pub hash: HashCacheConfig,
    /// `--resolution auto`: the resolution is to be chosen from the camera's pixel footprint
    /// ([`CacheMethodSettings::resolve_resolution`]) before a cache is made.
    pub resolution_auto: bool,
}

impl CacheMethodSettings {
    /// Resolves `--resolution auto` for renders of `scene` from its camera at
    /// `width × height` ([`footprint_resolution`]); returns the choice and why, to print.
    pub fn resolve_resolution(
        &mut self,
        scene: &Scene,
        width: u32,
        height: u32,
    ) -> Result<Option<String>, HarnessError> {
        if !self.resolution_auto {
            return Ok(None);
        }
        let (cells, why) = footprint_resolution(scene, &scene.camera, width, height)?;
        self.resolution = cells;
        self.resolution_auto = false;
        Ok(Some(why))
    }

    pub fn new(config: CacheConfig, device: CacheDevice) -> Self {
        Self {
            config,
            device,
            resolution_auto: false,
            resolution: 512,
            train_frames: 64,
            records_per_frame: nrc_train::online::DEFAULT_RECORDS_PER_FRAME,
            batch_size: 1 << 14,
            recover: true,
            overlap: true,
            recovery_steps: 1,
            train_budget_ms: None,
            online: true,
            producer_options: ProducerOptions::default(),
            seed: 0,
            kind: CacheKind::Neural,
            hash: HashCacheConfig::default(),
        }
    }
}

impl MethodSpec {
    /// Samples per pixel of one estimate.
    pub fn samples_per_pass(&self) -> u32 {
        self.spp
    }

    /// The method's state, ready to prepare and render; `tracer`: the depth limit and Russian
    /// roulette every method of a comparison shares (the light strategy is the pass's own).
    /// The method, its frames taking `emitter_samples` extra camera rays at the outline of
    /// emitters ([`nrc_render::emitters::supersample`]).
    pub fn build(
        &self,
        tracer: &PathTracer,
        cache: &CacheMethodSettings,
        emitter_samples: u32,
    ) -> Box<dyn Method> {
        match &self.producer {
            None => Box::new(PassMethod {
                name: self.to_string(),
                spp: self.spp,
                emitter_samples,
                pass: self.pass.build(tracer),
                warm_up: if self.pass.is_stateful() {
                    cache.train_frames
                } else {
                    0
                },
                stateful: self.pass.is_stateful(),
                warmth: Warmth::default(),
            }),
            Some(producer) => Box::new(CacheMethod {
                name: self.to_string(),
                spec: self.clone(),
                producer: producer.clone(),
                settings: CacheMethodSettings {
                    kind: self.cache,
                    ..cache.clone()
                },
                base_seed: cache.seed,
                tracer: *tracer,
                trainer: None,
                emitter_samples,
            }),
        }
    }
}

/// A pass that reads no source (the reference path tracer, the resampling passes) as a
/// method.
struct PassMethod {
    name: String,
    spp: u32,
    emitter_samples: u32,
    pass: Box<dyn RenderPass>,
    /// Untimed frames before each run (stateful passes: as many as cache methods train).
    warm_up: u32,
    stateful: bool,
    warmth: Warmth,
}

impl Method for PassMethod {
    fn name(&self) -> &str {
        &self.name
    }

    fn samples_per_pass(&self) -> u32 {
        self.spp
    }

    fn restart(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        _run: u32,
        seed: u64,
    ) -> Result<(), HarnessError> {
        self.pass.reset();
        self.warmth.reset();
        for f in 0..self.warm_up {
            self.render_estimate(
                scene,
                camera,
                width,
                height,
                nrc_render::pass_seed(!seed, f),
                None,
            );
        }
        Ok(())
    }

    fn debug_views(&self) -> Vec<nrc_render::passes::PassView> {
        self.pass.debug_views()
    }

    fn render_estimate(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        seed: u64,
        sequence: Option<nrc_render::PixelSequence>,
    ) -> Estimate {
        let input = FrameInput {
            scene,
            camera,
            width,
            height,
            spp: self.spp,
            seed,
            emitter_samples: self.emitter_samples,
            sequence,
        };
        let warm = self.warmth.count(&input);
        let out = passes::run(self.pass.as_mut(), &input, &ZeroSource);
        Estimate {
            image: out.image,
            invalid_samples: out.stats.invalid_samples,
            warm_frames: self.stateful.then_some(warm),
            rays: out.stats.rays,
            phases: out.stats.phases,
        }
    }
}

/// A pass reading a cache trained online, with its trainer.
struct CacheMethod {
    name: String,
    spec: MethodSpec,
    producer: ProducerSpec,
    settings: CacheMethodSettings,
    /// The cache seed of run 0 (later runs derive theirs from it).
    base_seed: u64,
    tracer: PathTracer,
    trainer: Option<OnlineTrainer>,
    emitter_samples: u32,
}

/// Pixels a cell of the finest level spans at the camera's typical distance: two, the
/// sampling theorem's bound (a finer grid holds detail no pixel of the render can show, and
/// its entries see fewer training records each).
pub const PIXELS_PER_CELL: f32 = 2.0;

/// The finest resolution (cells along the scene box's longest axis) at which a cell spans
/// [`PIXELS_PER_CELL`] pixels of a `width × height` render from `camera` at the median
/// distance of the surfaces it sees (a 32 × 32 grid of primary rays): the pixel footprint at
/// distance `d` is `2 d tan(fov/2) / height`. Returns the cells and a line saying why; an error
/// when no ray hits the scene or the box is degenerate.
pub fn footprint_resolution(
    scene: &Scene,
    camera: &Camera,
    width: u32,
    height: u32,
) -> Result<(u32, String), HarnessError> {
    const GRID: u32 = 32;
    if width == 0 || height == 0 {
        return Err(HarnessError::bounds("the image size", "be at least 1×1", 0));
    }
    let mut distances: Vec<f32> = (0..GRID * GRID)
        .filter_map(|i| {
            let film = glam::Vec2::new(
                ((i % GRID) as f32 + 0.5) / GRID as f32 * width as f32,
                ((i / GRID) as f32 + 0.5) / GRID as f32 * height as f32,
            );
            let ray = camera.generate_ray(film, width, height);
            let hit = scene.intersect(&ray)?;
            let d = hit.t * ray.d.length();
            (d.is_finite() && d > 0.0).then_some(d)
        })
        .collect();
    if distances.is_empty() {
        return Err(HarnessError::Setup(
            "--resolution auto: no camera ray hits the scene, so it has no distance to size the cache for; give --resolution N".into(),
        ));
    }
    distances.sort_by(f32::total_cmp);
    let d = distances[distances.len() / 2];
    let footprint = 2.0 * d * (0.5 * camera.fov_y).tan() / height as f32;
    let cell = PIXELS_PER_CELL * footprint;
    let ext = QueryMaker::new(&scene.bounds()).scene_box.extent();
    let longest = ext.iter().copied().fold(0.0f32, f32::max);
    if !(longest.is_finite() && longest > 0.0) {
        return Err(HarnessError::Setup(format!(
            "--resolution auto: the scene box is degenerate (extent {ext:?})"
        )));
    }
    let cells = (longest / cell).ceil().clamp(16.0, 65_536.0) as u32;
    let why = format!(
        "cache resolution {cells} (auto): {}/{} camera rays hit the scene at a median distance of {d:.3}; a pixel there spans {footprint:.4} at {width}x{height}, a finest cell {PIXELS_PER_CELL} pixels ({cell:.4}), the longest axis {longest:.3}",
        distances.len(),
        GRID * GRID
    );
    Ok((cells, why))
}

/// A new cache of `settings.kind` over `scene_box`: the neural one sized to it (its finest
/// resolution `settings.resolution` cells along the longest axis), or the hash cache.
pub fn scene_cache(
    scene_box: nrc_cache::SceneBox,
    settings: &CacheMethodSettings,
) -> Result<Cache, HarnessError> {
    let longest = scene_box.extent().iter().copied().fold(0.0f32, f32::max);
    if settings.resolution_auto {
        return Err(HarnessError::Setup(
            "--resolution auto is chosen from a camera and an image size, which this cache was not given; give --resolution N".into(),
        ));
    }
    if settings.resolution == 0 {
        return Err(HarnessError::bounds(
            "the cache resolution",
            "be at least 1",
            0,
        ));
    }
    Ok(match settings.kind {
        CacheKind::Neural => RadianceCache::for_scene_extent(
            &settings.config,
            scene_box,
            longest / settings.resolution as f32,
            settings.device,
        )?
        .0
        .into(),
        CacheKind::Hash => Cache::hash(settings.hash, scene_box)?,
    })
}

/// Builds a cache sized for `scene` and its online trainer, rendering with `pass`.
pub fn scene_trainer(
    scene: &Scene,
    producer: ProducerSpec,
    pass: PassSpec,
    settings: &CacheMethodSettings,
    tracer: PathTracer,
) -> Result<OnlineTrainer, HarnessError> {
    let queries = QueryMaker::new(&scene.bounds());
    let cache = scene_cache(queries.scene_box, settings)?;
    let mut online = OnlineSettings::new(producer, scene, tracer);
    online.records_per_frame = settings.records_per_frame;
    online.producer_options = settings.producer_options;
    online.batch_size = settings.batch_size;
    online.recover = settings.recover;
    online.overlap = settings.overlap;
    online.recovery_steps = settings.recovery_steps;
    online.train_budget_ms = settings.train_budget_ms;
    online.pass = pass;
    online.queries = queries;
    online.seed = settings.seed;
    Ok(OnlineTrainer::new(cache, online, scene)?)
}

impl CacheMethod {
    fn trainer(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
    ) -> Result<&mut OnlineTrainer, HarnessError> {
        if self.trainer.is_none() {
            let mut t = scene_trainer(
                scene,
                self.producer.clone(),
                self.spec.pass.clone(),
                &self.settings,
                self.tracer,
            )?;
            // Stateful passes (the resampling -nrc variants) render while training, so that
            // their history is warm too.
            let render = self.spec.pass.is_stateful();
            for _ in 0..self.settings.train_frames {
                t.frame(scene, camera, width, height, render)?;
            }
            self.trainer = Some(t);
        }
        Ok(self.trainer.as_mut().expect("just built"))
    }
}

impl Method for CacheMethod {
    fn name(&self) -> &str {
        &self.name
    }

    fn samples_per_pass(&self) -> u32 {
        self.spec.spp
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
    ) -> Result<(), HarnessError> {
        self.trainer(scene, camera, width, height).map(|_| ())
    }

    /// A stateful pass rendered every training frame of `prepare` at this size.
    fn warm_after_prepare(&self) -> bool {
        self.spec.pass.is_stateful()
    }

    fn restart(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        run: u32,
        _seed: u64,
    ) -> Result<(), HarnessError> {
        // Run 0 uses the cache `prepare` trained; each later run trains its own from scratch
        // (its own seed), so that runs are independent.
        if run > 0 {
            self.trainer = None;
            self.settings.seed = nrc_render::pass_seed(self.base_seed, run);
            self.trainer(scene, camera, width, height)?;
        }
        Ok(())
    }

    fn debug_views(&self) -> Vec<nrc_render::passes::PassView> {
        self.trainer
            .as_ref()
            .map(|t| t.pass_views())
            .unwrap_or_default()
    }

    fn render_estimate(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        seed: u64,
        sequence: Option<nrc_render::PixelSequence>,
    ) -> Estimate {
        let online = self.settings.online;
        let name = self.name.clone();
        let spp = self.spec.spp;
        let emitter_samples = self.emitter_samples;
        let stateful = self.spec.pass.is_stateful();
        let trainer = match self.trainer(scene, camera, width, height) {
            Ok(t) => t,
            Err(e) => {
                // Only reachable without prepare(); an unusable cache renders black, counted.
                eprintln!("{name}: {e}");
                return Estimate {
                    image: nrc_scene::Image::from_data(
                        width as usize,
                        height as usize,
                        vec![glam::Vec3::ZERO; width as usize * height as usize],
                    )
                    .expect("one value per pixel"),
                    invalid_samples: width as u64 * height as u64,
                    warm_frames: None,
                    rays: 0,
                    phases: Default::default(),
                };
            }
        };
        if online && let Err(e) = trainer.frame(scene, camera, width, height, false) {
            eprintln!("{name}: training skipped: {e}");
        }
        let out = trainer.render(&FrameInput {
            scene,
            camera,
            width,
            height,
            spp,
            seed,
            emitter_samples,
            sequence,
        });
        Estimate {
            image: out.image,
            invalid_samples: out.stats.invalid_samples,
            warm_frames: stateful.then(|| trainer.warm_frames()),
            rays: out.stats.rays,
            phases: out.stats.phases,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_print_back() {
        for name in [
            "pt-1spp",
            "pt-16spp",
            "pt-4spp",
            "pt-1spp-nonee",
            "nrc-pt",
            "nrc-pt-sl",
            "nrc-bt",
            "nrc-lt",
            "nrc-sppc",
            "nrc-pt-first",
            "nrc-pt-sl-bth:8",
            "nrc-sppc-diffuse",
            "pt-light@4spp",
            "cache-first-nonee@1spp+pt-sl",
            "cache-bth:8@2spp+bt",
            "restir-di",
            "restir-di-biased:k=3",
            "restir-gi",
            "wsrestir-gi",
            "wsrestir-gi-nrc",
            "restir-gi-nrc",
            "wsrestir-gi-nrc@1spp+bt",
            "restir-di@4spp",
            "ddgi-secondary",
            "ddgi-restir",
            "nrc-restir",
            "nrc-restir:clamp=0.05",
            "ddgi-nrc-restir",
            "nrc-restir@1spp+bt",
            "ir",
            "ir:vpls=512",
            "smc-ir",
            "smc-ir-nrc:mmax=8",
            "hash-pt-sl",
            "hash-bt-first",
            "restir-gi-nrc@1spp+hash:pt-sl",
            "cache-first@2spp+hash:sppc",
        ] {
            let spec: MethodSpec = name.parse().unwrap();
            assert_eq!(spec.to_string(), name);
        }
        // The general form of the short names prints as the short name.
        for (general, short) in [
            ("pt@4spp", "pt-4spp"),
            ("pt-nonee@2spp", "pt-2spp-nonee"),
            ("cache@1spp+pt-sl", "nrc-pt-sl"),
            ("cache-first@1spp+bt", "nrc-bt-first"),
            ("wsrestir-gi-nrc@1spp+pt-sl", "wsrestir-gi-nrc"),
            ("restir-di@1spp", "restir-di"),
            ("cache@1spp+hash:pt-sl", "hash-pt-sl"),
        ] {
            assert_eq!(general.parse::<MethodSpec>().unwrap().to_string(), short);
        }
        assert_eq!(
            "pt-4spp-nonee".parse::<MethodSpec>().unwrap(),
            MethodSpec {
                pass: PathTracedSettings {
                    strategy: LightStrategy::BsdfOnly
                }
                .into(),
                spp: 4,
                producer: None,
                cache: CacheKind::Neural,
            }
        );
        for (alias, canonical) in [("nrc-pt-spread", "nrc-pt"), ("pt-8spp-nee", "pt-8spp")] {
            assert_eq!(alias.parse::<MethodSpec>().unwrap().to_string(), canonical);
        }
        for bad in [
            "",
            "pt",
            "pt-0spp",
            "pt-xspp",
            "pt-4",
            "pt-4spp-foo",
            "pt-4spp-nonee-x",
            "pt--1spp",
            "nrc-",
            "nrc-foo",
            "nrc-pt-foo",
            "nrc-mix:pt=1",
            "px-1spp",
            "nrc-pt-sl-spread:0",
            "pt@0spp",
            "pt@4",
            "pt@4spp+pt-sl",
            "cache@1spp",
            "cache-nope@1spp+pt",
            "hash-",
            "hash-foo",
            "cache@1spp+hash:",
            "cache@1spp+hash:mix",
        ] {
            let e = bad.parse::<MethodSpec>().unwrap_err().to_string();
            assert!(
                e.contains("unknown method") && e.contains("pt-<N>spp"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn method_lists_keep_parameters_with_their_method() {
        let l: MethodList =
            "ddgi-restir:rays=64,k=0,restir-di,pt-1spp,wsrestir-gi:samples=5,cell=0.05"
                .parse()
                .unwrap();
        let names: Vec<String> = l.0.iter().map(|m| m.to_string()).collect();
        assert_eq!(
            names,
            [
                "ddgi-restir:k=0,rays=64",
                "restir-di",
                "pt-1spp",
                "wsrestir-gi:samples=5,cell=0.05"
            ]
        );
        assert!("k=0,pt-1spp".parse::<MethodList>().is_err());
        // Several parameters before a general form's `@`, and a producer mix after it.
        let l: MethodList =
            "nrc-restir:light=2,direct=0@1spp+hash:pt-sl,pt-1spp,cache-first@2spp+mix:pt-sl=0.5,sppc=0.5"
                .parse()
                .unwrap();
        assert_eq!(l.0.len(), 3, "{:?}", l.0);
        let first = l.0[0].to_string();
        assert!(
            first.contains("light=2") && first.contains("direct=0"),
            "{first}"
        );
    }
}
