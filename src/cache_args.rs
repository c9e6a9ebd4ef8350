//! Options shared by the subcommands that build, train or read a radiance cache.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use nrc_cache::{CacheConfig, CacheDevice};
use nrc_harness::CacheMethodSettings;
use nrc_render::Termination;
use nrc_train::producer::ProducerOptions;

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
    /// from it: the smallest resolved feature is the longest extent divided by it).
    #[arg(long, default_value_t = 512)]
    pub resolution: u32,

    /// Training records produced per frame (the default is chosen by measurement:
    /// scripts/records-budget.sh, RESULTS.md).
    #[arg(long, default_value_t = nrc_train::online::DEFAULT_RECORDS_PER_FRAME)]
    pub records: usize,

    /// Records per optimisation step (a frame trains records/batch steps).
    #[arg(long, default_value_t = 1 << 14)]
    pub batch: usize,

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
        if self.resolution == 0 || self.resolution > 1 << 16 {
            bail!("--resolution must be in 1..=65536, got {}", self.resolution);
        }
        if self.records == 0 || self.batch == 0 {
            bail!("--records and --batch must be at least 1");
        }
        let device = if print {
            self.device.resolve_and_print()
        } else {
            self.device.resolve().0
        };
        let mut s = CacheMethodSettings::new(self.config()?, device);
        s.resolution = self.resolution;
        s.records_per_frame = self.records;
        s.batch_size = self.batch;
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
        s.producer_options.validate().map_err(anyhow::Error::msg)?;
        Ok(s)
    }
}

/// Parses a termination strategy for clap.
pub fn parse_termination(s: &str) -> Result<Termination, String> {
    s.parse()
}
