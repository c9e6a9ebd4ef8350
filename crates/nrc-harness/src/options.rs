//! Options shared by the commands that load a scene, trace paths or train a cache: the scene
//! and its camera, path depth and light strategy, the cache model and its training, their value
//! parsers. They derive clap's `Args`, so their doc comments are the command line's help (as
//! brush's config structs do), and a run file's fields are their flags (`run_file.rs`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use nrc_cache::{CacheConfig, CacheDevice, HashCacheConfig};
use nrc_render::{LightStrategy, PathTracer, Termination};
use nrc_scene::{Camera, Scene};
use nrc_train::mix::ProducerOptions;

use crate::budget::CameraOffsets;
use crate::error::HarnessError;
use crate::methods::CacheMethodSettings;
use nrc_render::error::TerminationError;

/// Path depth options: every command that traces paths, so that methods and their reference
/// estimate the same image.
#[derive(clap::Args, Debug, Clone)]
pub struct DepthArgs {
    /// Maximum number of path segments, as Mitsuba counts them: 1 shows emitters seen
    /// directly, 2 adds direct illumination, 3 one indirect bounce, ...; 0 or -1: unlimited
    /// (Russian roulette ends paths).
    #[arg(long, default_value_t = -1, allow_negative_numbers = true)]
    pub max_depth: i32,

    /// Number of scattering events after which Russian roulette may end a path
    /// (Mitsuba's rr_depth), at most 1000.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(0..=1000))]
    pub rr_depth: u32,

    /// More BSDF samples of the direct light at each glossy first vertex (roughness below
    /// 0.3), one ray each, weighed against NEE by MIS with the counts: unbiased, for narrow
    /// lobes reflecting bright emitters, which NEE rarely finds. Every method takes them where
    /// its paths reach such a vertex through the shared path step; references never do (`nrc
    /// reference` refuses the flag). 0: none. At most 64
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=nrc_render::MAX_GLOSSY_SAMPLES as i64))]
    pub glossy_samples: u32,

    /// Light samples of next-event estimation at the first vertex of each walk (stratified
    /// together), weighed against BSDF sampling by MIS with the counts: unbiased, more shadow
    /// rays where the first vertex's direct light is the noise (a window seen past its frame and
    /// blinds), no more paths. Every walk that runs NEE through the shared path step takes them
    /// at its first vertex: camera paths, and equally training paths, VPLs and light-tracing
    /// targets (their cost counts in equal-time comparisons); references never do (`nrc
    /// reference` refuses the flag). At most 64
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=nrc_render::MAX_DIRECT_SAMPLES as i64))]
    pub direct_samples: u32,
}

impl DepthArgs {
    /// The reference path tracer (NEE and BSDF sampling by MIS) at these depths.
    pub fn tracer(&self) -> PathTracer {
        PathTracer {
            max_depth: self.max_depth,
            rr_depth: self.rr_depth,
            glossy_samples: self.glossy_samples,
            direct_samples: self.direct_samples,
            ..PathTracer::default()
        }
    }
}

/// The emitters' anti-aliasing (`render`, `compare`): see [`nrc_render::emitters::supersample`].
#[derive(clap::Args, Debug, Clone, Copy, Default)]
pub struct EmitterArgs {
    /// Extra camera rays, their emission only, at each pixel on the outline of an emitter the
    /// camera sees (where the pixel's neighbours disagree about it), averaged with the pass's
    /// own camera rays: unbiased, and cheap (one ray each, no shading); 0: none. At most 256
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=nrc_render::emitters::MAX_EXTRA as i64))]
    pub emitter_samples: u32,
}

/// Where camera rays lie in their pixels (`render`, `compare`, the Python module's `render`).
#[derive(clap::Args, Debug, Clone, Copy, Default)]
pub struct OffsetArgs {
    /// Where camera rays lie in their pixels: `independent` (uniform and independent), or
    /// `sobol`: a pixel's samples (a render's, or every pass of a comparison's run, every
    /// method alike) take consecutive points of one Owen-scrambled Sobol sequence, scrambled
    /// anew per pixel and run. Each sample is still uniform in the pixel, so every estimate
    /// stays unbiased; together they stratify the pixel's footprint, as a real-time renderer's
    /// jitter sequence does, which lowers the noise of edges, textures and sharp reflections
    #[arg(long, value_enum, default_value_t = CameraOffsets::Independent)]
    pub camera_offsets: CameraOffsets,
}

/// Direct-illumination estimators, as named on the command line.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strategy {
    /// Next-event estimation and BSDF sampling combined by MIS (power heuristic).
    Mis,
    /// BSDF sampling only (next-event estimation off).
    Bsdf,
    /// Next-event estimation only.
    Light,
}

/// The path depth and the direct-illumination estimators (`render`, `train`, `bench trace`).
#[derive(clap::Args, Debug, Clone)]
pub struct TracerArgs {
    #[command(flatten)]
    pub depth: DepthArgs,

    /// Estimators of direct illumination.
    #[arg(long, value_enum, default_value_t = Strategy::Mis)]
    pub strategy: Strategy,
}

impl TracerArgs {
    pub fn tracer(&self) -> PathTracer {
        PathTracer {
            strategy: match self.strategy {
                Strategy::Mis => LightStrategy::Mis,
                Strategy::Bsdf => LightStrategy::BsdfOnly,
                Strategy::Light => LightStrategy::LightOnly,
            },
            ..self.depth.tracer()
        }
    }
}

/// Parses `x,y,z` into a vector of three finite numbers.
pub fn parse_vec3(s: &str) -> Result<Vec3, HarnessError> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(HarnessError::NotThreeNumbers(s.to_string()));
    }
    let mut v = [0.0f32; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = match p.parse::<f32>() {
            Ok(x) if x.is_finite() => x,
            _ => {
                return Err(HarnessError::NotANumber {
                    text: p.to_string(),
                    context: format!(" (in `{s}`)"),
                });
            }
        };
    }
    Ok(Vec3::from_array(v))
}

/// Parses a non-negative RGB radiance `r,g,b` (or a single number for grey).
pub fn parse_rgb(s: &str) -> Result<Vec3, HarnessError> {
    let v = if s.contains(',') {
        parse_vec3(s)?
    } else {
        let x: f32 = s.trim().parse().map_err(|_| HarnessError::NotANumber {
            text: s.to_string(),
            context: String::new(),
        })?;
        Vec3::splat(x)
    };
    if !v.is_finite() || v.min_element() < 0.0 {
        return Err(HarnessError::bounds(
            "radiance",
            "be finite and non-negative",
            format!("`{s}`"),
        ));
    }
    Ok(v)
}

/// The scene and how to look at it.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene file: glTF 2.0 (`.gltf` with its buffers, or `.glb`).
    #[arg(long)]
    pub scene: PathBuf,

    /// Camera position `x,y,z` (overrides the scene's camera; unset parts keep it).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_pos: Option<Vec3>,

    /// Point the camera looks at, `x,y,z`.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_target: Option<Vec3>,

    /// Camera up direction `x,y,z`.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_up: Option<Vec3>,

    /// Vertical field of view in degrees.
    #[arg(long)]
    pub fov_y: Option<f32>,

    /// Constant background radiance `r,g,b` (or one number for grey) for rays leaving the
    /// scene: the trivial environment, sampled by next-event estimation like any light.
    /// Default: the scene's (black for glTF files).
    #[arg(long, value_parser = parse_rgb, conflicts_with = "env")]
    pub background: Option<Vec3>,

    /// Environment map: an equirectangular HDR image (`.exr` or `.hdr`, row 0 the zenith,
    /// Mitsuba's orientation), importance-sampled by luminance.
    #[arg(long)]
    pub env: Option<PathBuf>,

    /// Scale of the environment map's radiance.
    #[arg(long, default_value_t = 1.0, requires = "env")]
    pub env_intensity: f32,

    /// Rotation of the environment map about the up axis (+y), degrees.
    #[arg(
        long,
        default_value_t = 0.0,
        requires = "env",
        allow_hyphen_values = true
    )]
    pub env_rotate: f32,

    /// How next-event estimation and the resampling passes' light candidates choose a light
    /// for a shading point: `power` (in proportion to power, the same everywhere) or `tree` (a
    /// light tree weighing each light's power by its distance and orientation to the point:
    /// for scenes with many lights). Light paths start by power either way.
    #[arg(long, default_value_t = nrc_scene::LightSamplerKind::Power)]
    pub light_sampler: nrc_scene::LightSamplerKind,
}

impl SceneArgs {
    /// Loads the scene and applies the camera, background and environment overrides.
    pub fn load(&self) -> Result<Scene> {
        let mut scene = Scene::load(&self.scene)?;
        self.apply(&mut scene)?;
        Ok(scene)
    }

    /// Loads the scene with its animation; [`SceneArgs::pose`] gives it at a time.
    pub fn load_animated(&self) -> Result<nrc_scene::AnimatedScene> {
        Ok(nrc_scene::AnimatedScene::load(&self.scene)?)
    }

    /// `animated` at `t` seconds with the overrides applied.
    pub fn pose(&self, animated: &nrc_scene::AnimatedScene, t: f32) -> Result<Scene> {
        let mut scene = animated.at(t)?;
        self.apply(&mut scene)?;
        Ok(scene)
    }

    /// Applies the camera, background and environment overrides to `scene`.
    pub fn apply(&self, scene: &mut Scene) -> Result<()> {
        scene.camera = self
            .camera(&scene.camera)
            .with_context(|| "invalid camera")?;
        if let Some(b) = self.background {
            if !(b.is_finite() && b.min_element() >= 0.0) {
                anyhow::bail!("--background must be finite and non-negative, got {b}");
            }
            scene.set_environment(nrc_scene::Environment::constant(b));
        }
        if let Some(path) = &self.env {
            let (env, warning) =
                nrc_scene::Environment::load(path, self.env_intensity, self.env_rotate)?;
            if let Some(w) = warning {
                eprintln!("warning: {w}");
            }
            scene.set_environment(env);
        }
        if scene.light_sampler() != self.light_sampler {
            scene.set_light_sampler(self.light_sampler);
        }
        Ok(())
    }

    /// The scene's camera with the command-line overrides applied.
    fn camera(&self, base: &Camera) -> Result<Camera, nrc_scene::CameraError> {
        if self.camera_pos.is_none()
            && self.camera_target.is_none()
            && self.camera_up.is_none()
            && self.fov_y.is_none()
        {
            return Ok(*base);
        }
        let pos = self.camera_pos.unwrap_or(base.position);
        let target = self.camera_target.unwrap_or(pos + base.forward);
        let up = self.camera_up.unwrap_or(base.up);
        let fov = self.fov_y.unwrap_or(base.fov_y.to_degrees());
        Camera::look_at(pos, target, up, fov)
    }
}

/// Where the cache computes.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeviceArg {
    /// wgpu when a hardware GPU adapter exists, else the CPU.
    Auto,
    /// burn's Flex CPU backend (fused training step).
    Cpu,
    /// burn's wgpu backend.
    Wgpu,
}

impl DeviceArg {
    /// The device and the reason it was chosen.
    pub fn resolve(self) -> (CacheDevice, String) {
        match self {
            Self::Auto => CacheDevice::auto(),
            Self::Cpu => (CacheDevice::Cpu, "--device cpu".to_string()),
            Self::Wgpu => (CacheDevice::Wgpu, "--device wgpu".to_string()),
        }
    }

    /// The device, printed with the reason it was chosen.
    pub fn resolve_and_print(self) -> CacheDevice {
        let (device, reason) = self.resolve();
        eprintln!("cache device: {device} ({reason})");
        device
    }
}

/// `--resolution`: cells along the scene's longest axis, or `auto` (from the camera).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResolutionArg {
    Auto,
    Cells(u32),
}

impl std::str::FromStr for ResolutionArg {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if s == "auto" {
            return Ok(Self::Auto);
        }
        match s.parse::<u32>() {
            Ok(n) if (1..=1 << 16).contains(&n) => Ok(Self::Cells(n)),
            _ => Err(format!(
                "expected `auto` or a number of cells in 1..=65536, got `{s}`"
            )),
        }
    }
}

impl std::fmt::Display for ResolutionArg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Auto => f.write_str("auto"),
            Self::Cells(n) => write!(f, "{n}"),
        }
    }
}

/// The cache model and how it is trained.
#[derive(clap::Args, Debug, Clone)]
pub struct RadianceCacheArgs {
    /// Cache configuration: a tiny-cuda-nn-style JSON file, or a preset name: `hashgrid`
    /// (models/nrc-hashgrid.json) or `trianglewave` (models/nrc-trianglewave.json).
    #[arg(long, default_value = "hashgrid")]
    pub config: String,

    /// Where the cache computes.
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    pub device: DeviceArg,

    /// Finest resolution of the encoding along the scene's longest axis (the grid is sized
    /// from it: the smallest resolved feature is the longest extent divided by it), or `auto`:
    /// chosen from the camera, a finest cell spanning 2 pixels of the render at the median
    /// distance of the surfaces the camera sees (printed with why).
    #[arg(long, default_value = "512")]
    pub resolution: ResolutionArg,

    /// Training records produced per frame (the default is chosen by measurement:
    /// scripts/records-budget.sh, RESULTS.md).
    #[arg(long, default_value_t = nrc_train::online::DEFAULT_RECORDS_PER_FRAME)]
    pub records: usize,

    /// Milliseconds a frame may spend producing training records and training on them: the
    /// loop chooses the records (from --records on) to fit, half the budget once the cache has
    /// settled and all of it while it warms up or recovers from a change; the statistics show
    /// what each frame chose. Default: no budget, --records every frame (reproducible).
    #[arg(long)]
    pub train_budget_ms: Option<f64>,

    /// Records per optimisation step (a frame trains records/batch steps).
    #[arg(long, default_value_t = 1 << 14)]
    pub batch: usize,

    /// Do not watch for changes in the scene: the cache always infers from the average of its
    /// weights, and no frame predicts its training records to score them (by default a jump in
    /// how far the training targets are from the cache's predictions switches inference to the
    /// training weights until the cache has caught up; nrc-train's `schedule` module). Under
    /// --train-budget-ms the cache is then never taken as settled: every frame spends the whole
    /// budget.
    #[arg(long)]
    pub no_recover: bool,

    /// Optimisation steps on each batch while the cache recovers from a change in the scene.
    #[arg(long, default_value_t = 1)]
    pub recovery_steps: u32,

    /// Wait for each training call before the frame goes on. By default, with the cache on a
    /// GPU, the frame's training steps are queued and the render traces on the CPU while they
    /// run (its cache queries wait for them); their losses are read after the render. No effect
    /// on the CPU, whose steps run when queued, or under --train-budget-ms, which prices
    /// training by its time and so waits for it.
    #[arg(long)]
    pub no_overlap: bool,

    /// Light training: fraction of its records at uniformly chosen surface points.
    #[arg(long, default_value_t = 0.0)]
    pub lt_surface_balance: f32,

    /// Light training: fraction of its records at camera primary hits.
    #[arg(long, default_value_t = 0.0)]
    pub lt_camera_balance: f32,

    /// SPPC: persistent query balls kept (ring buffer).
    #[arg(long, default_value_t = 16384)]
    pub sppc_capacity: usize,

    /// SPPC: fraction of the balls replaced each frame, oldest first.
    #[arg(long, default_value_t = 0.25)]
    pub sppc_replace: f32,

    /// SPPC: initial ball radius as a fraction of the scene bounds' diagonal.
    #[arg(long, default_value_t = 0.01)]
    pub sppc_radius: f32,

    /// SPPC: photon paths traced per training record.
    #[arg(long, default_value_t = 4.0)]
    pub sppc_photons: f32,

    /// SPPC: progressive radius reduction α in (0, 1].
    #[arg(long, default_value_t = 0.7)]
    pub sppc_alpha: f32,

    /// SPPC: gather photons whatever their normal (default: reject those whose normal differs
    /// from the ball's, n·n < 0.9).
    #[arg(long)]
    pub sppc_no_normal_reject: bool,

    /// Hash cache (`hash-…` methods, `--cache-kind hash`): finest cell edge as a fraction of the
    /// scene box's largest extent.
    #[arg(long, default_value_t = HashCacheConfig::default().cell)]
    pub hash_cell: f32,

    /// Hash cache: levels of detail (the cell doubles per level with the distance to the camera).
    #[arg(long, default_value_t = HashCacheConfig::default().levels)]
    pub hash_levels: u32,

    /// Hash cache: also key cells by the outgoing direction's dominant axis (glossy surfaces).
    #[arg(long)]
    pub hash_direction_bins: bool,

    /// Hash cache: jitter lookups by up to half a cell (hides cell borders, adds noise).
    #[arg(long)]
    pub hash_jitter: bool,

    /// Hash cache: the table holds 2^N cells (its fixed memory budget).
    #[arg(long, default_value_t = HashCacheConfig::default().log2_capacity)]
    pub hash_log2_capacity: u32,

    /// Hash cache: the running mean's sample count saturates here (its time constant).
    #[arg(long, default_value_t = HashCacheConfig::default().max_samples)]
    pub hash_max_samples: f32,

    /// Hash cache: cells not updated for this many frames are evicted.
    #[arg(long, default_value_t = HashCacheConfig::default().stale_frames)]
    pub hash_stale_frames: u32,
}

/// A cache configuration named on the command line: a preset (`hashgrid`, `trianglewave`) or a
/// JSON file.
pub fn named_config(name: &str) -> Result<CacheConfig> {
    Ok(match name {
        "hashgrid" => CacheConfig::hash_grid_preset(),
        "trianglewave" => CacheConfig::triangle_wave_preset(),
        // An inline configuration (a run file's `config` object).
        json if json.trim_start().starts_with('{') => {
            CacheConfig::from_json_str(json).context("the inline cache configuration")?
        }
        path => CacheConfig::from_file(&PathBuf::from(path))
            .with_context(|| format!("--config {path}"))?,
    })
}

impl RadianceCacheArgs {
    /// The configuration named by `--config`.
    pub fn config(&self) -> Result<CacheConfig> {
        named_config(&self.config)
    }

    /// The settings of cache methods, checked; `print` reports the device chosen.
    pub fn method_settings(
        &self,
        train_frames: u32,
        seed: u64,
        print: bool,
    ) -> Result<CacheMethodSettings> {
        if self.records == 0 || self.batch == 0 {
            bail!("--records and --batch must be at least 1");
        }
        let device = if print {
            self.device.resolve_and_print()
        } else {
            self.device.resolve().0
        };
        let mut s = CacheMethodSettings::new(self.config()?, device);
        match self.resolution {
            ResolutionArg::Cells(n) => s.resolution = n,
            ResolutionArg::Auto => s.resolution_auto = true,
        }
        s.records_per_frame = self.records;
        s.batch_size = self.batch;
        s.recover = !self.no_recover;
        s.overlap = !self.no_overlap;
        if self.recovery_steps == 0 || self.recovery_steps > 64 {
            bail!(
                "--recovery-steps must be in 1..=64, got {}",
                self.recovery_steps
            );
        }
        s.recovery_steps = self.recovery_steps;
        if let Some(ms) = self.train_budget_ms
            && !(ms.is_finite() && ms > 0.0)
        {
            bail!("--train-budget-ms must be finite and > 0, got {ms}");
        }
        s.train_budget_ms = self.train_budget_ms;
        s.train_frames = train_frames;
        s.seed = seed;
        s.producer_options = ProducerOptions {
            lt_surface_balance: self.lt_surface_balance,
            lt_camera_balance: self.lt_camera_balance,
            sppc_capacity: self.sppc_capacity,
            sppc_replace_fraction: self.sppc_replace,
            sppc_initial_radius: self.sppc_radius,
            sppc_photons_per_record: self.sppc_photons,
            sppc_alpha: self.sppc_alpha,
            sppc_normal_reject: !self.sppc_no_normal_reject,
        };
        s.producer_options.validate()?;
        s.hash = HashCacheConfig {
            cell: self.hash_cell,
            levels: self.hash_levels,
            direction_bins: self.hash_direction_bins,
            jitter: self.hash_jitter,
            log2_capacity: self.hash_log2_capacity,
            max_samples: self.hash_max_samples,
            stale_frames: self.hash_stale_frames,
            ..HashCacheConfig::default()
        };
        s.hash.validate().map_err(anyhow::Error::msg)?;
        Ok(s)
    }
}

/// Parses a termination strategy for clap.
pub fn parse_termination(s: &str) -> Result<Termination, TerminationError> {
    s.parse()
}

/// Where references are cached.
#[derive(clap::Args, Debug, Clone)]
pub struct CacheArgs {
    /// Folder of cached references (default: $NRC_CACHE_DIR/references if NRC_CACHE_DIR is
    /// set, else out/references).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
}

impl CacheArgs {
    pub fn dir(&self) -> PathBuf {
        match (&self.cache_dir, std::env::var_os("NRC_CACHE_DIR")) {
            (Some(d), _) => d.clone(),
            (None, Some(root)) if !root.is_empty() => PathBuf::from(root).join("references"),
            _ => PathBuf::from("out/references"),
        }
    }
}

/// The worker threads of `--threads` (all cores when not given).
pub fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    if threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
        .context("cannot start worker threads")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vec3_parsing() {
        assert_eq!(parse_vec3("1, -2.5,3").unwrap(), Vec3::new(1.0, -2.5, 3.0));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,x").is_err());
        assert!(parse_vec3("1,2,NaN").is_err());
        assert_eq!(parse_rgb("0.5").unwrap(), Vec3::splat(0.5));
        assert!(parse_rgb("1,-1,0").is_err());
    }
}

/// Refuses outputs whose folder does not exist (before a long run, not after it).
pub fn check_output_folders<'a>(paths: impl IntoIterator<Item = &'a PathBuf>) -> Result<()> {
    for path in paths {
        let parent = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !parent.is_dir() {
            bail!(
                "{}: the folder {} does not exist",
                path.display(),
                parent.display()
            );
        }
    }
    Ok(())
}
