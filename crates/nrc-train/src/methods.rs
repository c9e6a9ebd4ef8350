//! The comparison registry with the cache methods: every name `nrc compare` accepts.
//!
//! `pt-<N>spp[-nonee]` are the reference path tracer ([`nrc_render::MethodSpec`]);
//! `nrc-<producer>[-<termination>]` is a cache trained online by a producer (`pt`, `pt-sl`,
//! `bt`, `lt`, `sppc`) and rendered at 1 sample per pixel with paths ending in it by the
//! termination strategy (default `spread`; see [`Termination`]), e.g. `nrc-pt-sl`,
//! `nrc-sppc-first`, `nrc-pt-bth:8`.
//!
//! A cache method is trained for [`CacheMethodSettings::train_frames`] frames in
//! [`Method::prepare`] (untimed), then each pass is one online frame: produce, train
//! (unless frozen) and the inference pass. Its time per frame therefore includes training.

use std::fmt;
use std::str::FromStr;

use nrc_cache::{CacheConfig, CacheDevice, RadianceCache};
use nrc_render::methods::{METHOD_NAMES, MethodSettings, ParseMethodError, Pass};
use nrc_render::{Method, MethodSpec as RenderSpec};
use nrc_scene::{Camera, Scene};

use crate::inference::{TERMINATION_NAMES, Termination};
use crate::online::{OnlineSettings, OnlineTrainer};
use crate::producer::{PRODUCER_NAMES, ProducerOptions, ProducerSpec};
use crate::query::QueryMaker;

/// The grammar of all method names.
pub fn method_names() -> String {
    format!(
        "{METHOD_NAMES}; nrc-<producer>[-<termination>] (a cache trained online, 1 spp; producers: {PRODUCER_NAMES}; terminations: {TERMINATION_NAMES})"
    )
}

/// A cache method: which producer trains it and where paths end in it.
#[derive(Clone, Debug, PartialEq)]
pub struct CacheMethodSpec {
    pub producer: ProducerSpec,
    pub termination: Termination,
}

/// Any method of the registry.
#[derive(Clone, Debug, PartialEq)]
pub enum MethodSpec {
    Render(RenderSpec),
    Cache(CacheMethodSpec),
}

impl FromStr for MethodSpec {
    type Err = ParseMethodError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        let Some(rest) = s.strip_prefix("nrc-") else {
            return s
                .parse::<RenderSpec>()
                .map(Self::Render)
                .map_err(|e| ParseMethodError {
                    name: e.name,
                    reason: format!(
                        "{} (cache methods: nrc-<producer>[-<termination>])",
                        e.reason
                    ),
                });
        };
        let err = |reason: String| ParseMethodError {
            name: s.to_string(),
            reason,
        };
        if rest.starts_with("mix:") {
            return Err(err(
                "mixes are not method names; train a mix with `nrc train --producer mix:...`"
                    .into(),
            ));
        }
        // `<producer>-<termination>` when the last part is a termination, else all producer.
        if let Some((p, t)) = rest.rsplit_once('-')
            && let Ok(termination) = t.parse::<Termination>()
        {
            let producer = p.parse::<ProducerSpec>().map_err(err)?;
            return Ok(Self::Cache(CacheMethodSpec {
                producer,
                termination,
            }));
        }
        let producer = rest.parse::<ProducerSpec>().map_err(err)?;
        Ok(Self::Cache(CacheMethodSpec {
            producer,
            termination: Termination::default(),
        }))
    }
}

impl fmt::Display for MethodSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Render(r) => write!(f, "{r}"),
            Self::Cache(c) if c.termination == Termination::default() => {
                write!(f, "nrc-{}", c.producer)
            }
            Self::Cache(c) => write!(f, "nrc-{}-{}", c.producer, c.termination),
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
    /// Keep training during measurement (each pass is a full online frame); else frozen.
    pub online: bool,
    /// The producers' own settings.
    pub producer_options: ProducerOptions,
    pub seed: u64,
}

impl CacheMethodSettings {
    pub fn new(config: CacheConfig, device: CacheDevice) -> Self {
        Self {
            config,
            device,
            resolution: 512,
            train_frames: 64,
            records_per_frame: 1 << 16,
            batch_size: 1 << 14,
            online: true,
            producer_options: ProducerOptions::default(),
            seed: 0,
        }
    }
}

impl MethodSpec {
    /// Samples per pixel of one pass.
    pub fn samples_per_pass(&self) -> u32 {
        match self {
            Self::Render(r) => r.samples_per_pass(),
            Self::Cache(_) => 1,
        }
    }

    /// The method's state, ready to prepare and render.
    pub fn build(&self, settings: &MethodSettings, cache: &CacheMethodSettings) -> Box<dyn Method> {
        match self {
            Self::Render(r) => r.build(settings),
            Self::Cache(c) => Box::new(CacheMethod {
                name: self.to_string(),
                spec: c.clone(),
                settings: cache.clone(),
                method: *settings,
                trainer: None,
            }),
        }
    }
}

/// A cache-terminated renderer with its online-trained cache.
struct CacheMethod {
    name: String,
    spec: CacheMethodSpec,
    settings: CacheMethodSettings,
    method: MethodSettings,
    trainer: Option<OnlineTrainer>,
}

/// Builds a cache sized for `scene` and its online trainer.
pub fn scene_trainer(
    scene: &Scene,
    producer: ProducerSpec,
    termination: Termination,
    settings: &CacheMethodSettings,
    tracer: nrc_render::PathTracer,
) -> Result<OnlineTrainer, String> {
    let queries = QueryMaker::new(&scene.bounds());
    let ext = queries.scene_box.extent();
    let longest = ext.iter().copied().fold(0.0f32, f32::max);
    if settings.resolution == 0 {
        return Err("the cache resolution must be at least 1".into());
    }
    let (cache, _) = RadianceCache::for_scene_extent(
        &settings.config,
        queries.scene_box,
        longest / settings.resolution as f32,
        settings.device,
    )
    .map_err(|e| e.to_string())?;
    let mut online = OnlineSettings::new(producer, scene, tracer);
    online.records_per_frame = settings.records_per_frame;
    online.producer_options = settings.producer_options;
    online.batch_size = settings.batch_size;
    online.renderer.termination = termination;
    online.renderer.queries = queries;
    online.seed = settings.seed;
    OnlineTrainer::new(cache, online)
}

impl CacheMethod {
    fn trainer(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
    ) -> Result<&mut OnlineTrainer, String> {
        if self.trainer.is_none() {
            let mut t = scene_trainer(
                scene,
                self.spec.producer.clone(),
                self.spec.termination,
                &self.settings,
                self.method.tracer,
            )?;
            for _ in 0..self.settings.train_frames {
                t.frame(scene, camera, width, height, false)
                    .map_err(|e| e.to_string())?;
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
        1
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
    ) -> Result<(), String> {
        self.trainer(scene, camera, width, height).map(|_| ())
    }

    fn render_pass(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        seed: u64,
    ) -> Pass {
        let online = self.settings.online;
        let name = self.name.clone();
        let trainer = match self.trainer(scene, camera, width, height) {
            Ok(t) => t,
            Err(e) => {
                // Only reachable without prepare(); an unusable cache renders black, counted.
                eprintln!("{name}: {e}");
                return Pass {
                    image: nrc_scene::Image::from_data(
                        width as usize,
                        height as usize,
                        vec![glam::Vec3::ZERO; width as usize * height as usize],
                    )
                    .expect("one value per pixel"),
                    invalid_samples: width as u64 * height as u64,
                };
            }
        };
        if online && let Err(e) = trainer.frame(scene, camera, width, height, false) {
            eprintln!("{name}: training skipped: {e}");
        }
        let out =
            trainer
                .settings
                .renderer
                .render(scene, camera, &trainer.cache, width, height, 1, seed);
        Pass {
            image: out.image,
            invalid_samples: out.stats.invalid_samples,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_print_back() {
        for name in [
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
        ] {
            let spec: MethodSpec = name.parse().unwrap();
            assert_eq!(spec.to_string(), name);
        }
        assert_eq!(
            "nrc-pt-spread".parse::<MethodSpec>().unwrap().to_string(),
            "nrc-pt"
        );
        for bad in [
            "nrc-",
            "nrc-foo",
            "nrc-pt-foo",
            "nrc-mix:pt=1",
            "px-1spp",
            "nrc-pt-sl-spread:0",
        ] {
            let e = bad.parse::<MethodSpec>().unwrap_err().to_string();
            assert!(e.contains("unknown method"), "{bad}: {e}");
        }
    }
}
