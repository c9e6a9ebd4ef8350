//! `nrc reference`: a reference image with its per-pixel variance, from the reference store
//! of `nrc-harness` (`nrc_harness::reference`: the cache folder, its content key and its
//! checks), and the depth and cache-folder options `nrc compare` shares.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use nrc_harness::options::{CacheArgs, DepthArgs, SceneArgs};
use nrc_harness::reference::{ReferenceRequest, obtain_showing_progress};

/// Arguments of `nrc reference`.
#[derive(clap::Args, Debug)]
pub struct ReferenceArgs {
    #[command(flatten)]
    pub scene: SceneArgs,

    /// Samples (paths) per pixel, at least 2 (the variance needs two).
    #[arg(long, default_value_t = 1024)]
    pub spp: u32,

    /// Image width in pixels.
    #[arg(long, default_value_t = 320)]
    pub width: u32,

    /// Image height in pixels.
    #[arg(long, default_value_t = 240)]
    pub height: u32,

    /// Seed of the reference's random numbers (part of the key).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,

    #[command(flatten)]
    pub depth: DepthArgs,

    #[command(flatten)]
    pub cache: CacheArgs,

    /// Render again even when a matching reference is cached (replaces it).
    #[arg(long)]
    pub force: bool,

    /// Also write a tone-mapped PNG preview of the reference here.
    #[arg(long)]
    pub png: Option<PathBuf>,

    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Runs `nrc reference`.
pub fn run(args: &ReferenceArgs) -> Result<()> {
    if args.depth.glossy_samples > 0 || args.depth.direct_samples > 1 {
        bail!(
            "--glossy-samples and --direct-samples do not apply to references: they are rendered \
             by the plain path tracer, one estimator per cache key"
        );
    }
    let scene = args.scene.load()?;
    for w in scene.warnings() {
        eprintln!("warning: {w}");
    }
    let pool = nrc_harness::options::thread_pool(args.threads)?;
    let req = ReferenceRequest {
        scene_path: &args.scene.scene,
        scene: &scene,
        width: args.width,
        height: args.height,
        spp: args.spp,
        seed: args.seed,
        tracer: args.depth.tracer(),
    };
    let cache = args.cache.dir();
    let start = Instant::now();
    let r = pool.install(|| obtain_showing_progress(&req, &cache, args.force))?;
    if let Some(png) = &args.png {
        r.mean.write_png_preview(png, 0.0)?;
    }
    let meta = r.meta.as_ref().expect("cache entries have metadata");
    if r.reused {
        println!(
            "reused reference {} ({}x{}, {} spp, rendered earlier in {:.3} s; looked up in {:.3} s)",
            r.location.display(),
            meta.width,
            meta.height,
            meta.spp,
            meta.render_seconds,
            start.elapsed().as_secs_f64()
        );
    } else {
        if meta.invalid_samples > 0 {
            eprintln!(
                "warning: {} samples were NaN or infinite and counted as black",
                meta.invalid_samples
            );
        }
        println!(
            "rendered reference {} ({}x{}, {} spp) in {:.3} s on {} threads",
            r.location.display(),
            meta.width,
            meta.height,
            meta.spp,
            meta.render_seconds,
            pool.current_num_threads()
        );
    }
    Ok(())
}
