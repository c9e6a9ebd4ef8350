//! `nrc bench`: measured throughput. `nrc bench trace` prints the path tracer's benchmark
//! (`nrc_harness::bench`), `nrc bench cache` the cache's (`nrc_cache::bench`).

use anyhow::{Result, bail};

use nrc_harness::options::SceneArgs;
use nrc_harness::options::TracerArgs;
use nrc_harness::options::thread_pool;

#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Closest-hit throughput (primary and incoherent rays, Mrays/s) and path-tracer
    /// samples/s, on one thread and on all threads.
    Trace(TraceArgs),
    /// Neural radiance cache: training samples/s and inference queries/s of both presets
    /// (models/nrc-hashgrid.json, models/nrc-trianglewave.json) at batch 2^14 and 2^16, per
    /// device, and the fused-vs-unfused ratios.
    Cache(CacheBenchArgs),
}

/// Which cache devices `nrc bench cache` measures.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BenchDevices {
    Cpu,
    Wgpu,
    /// Both (wgpu is skipped with a message when no adapter exists).
    All,
}

/// Arguments of `nrc bench cache`.
#[derive(clap::Args, Debug)]
pub struct CacheBenchArgs {
    #[arg(long, value_enum, default_value_t = BenchDevices::All)]
    pub device: BenchDevices,

    /// Measure each figure for at least this many milliseconds.
    #[arg(long, default_value_t = 2000)]
    pub min_ms: u64,

    /// Skip the unfused and custom-op paths (slow) and the fused-vs-unfused ratios.
    #[arg(long)]
    pub no_compare: bool,

    /// Measure these configurations (a preset name, `hashgrid` or `trianglewave`, or a JSON
    /// file; repeatable) instead of both presets.
    #[arg(long = "config", value_name = "CONFIG")]
    pub configs: Vec<String>,

    /// Batch sizes to measure (repeatable; default 16384 and 65536).
    #[arg(long = "batch", value_name = "N", value_parser = clap::value_parser!(u32).range(1..=(1 << 22)))]
    pub batches: Vec<u32>,
}

/// `nrc bench cache`: prints its table as it measures (nrc_cache::bench).
fn cache(a: &CacheBenchArgs) -> Result<()> {
    use nrc_cache::CacheDevice;
    if a.min_ms == 0 {
        anyhow::bail!("--min-ms must be at least 1");
    }
    let options = nrc_cache::bench::BenchOptions {
        devices: match a.device {
            BenchDevices::Cpu => vec![CacheDevice::Cpu],
            BenchDevices::Wgpu => vec![CacheDevice::Wgpu],
            BenchDevices::All => vec![CacheDevice::Cpu, CacheDevice::Wgpu],
        },
        min_time: std::time::Duration::from_millis(a.min_ms),
        compare_paths: !a.no_compare,
        configs: a
            .configs
            .iter()
            .map(|c| Ok((c.clone(), nrc_harness::options::named_config(c)?)))
            .collect::<Result<_>>()?,
        ..Default::default()
    };
    let options = nrc_cache::bench::BenchOptions {
        batches: if a.batches.is_empty() {
            options.batches
        } else {
            a.batches.iter().map(|&b| b as usize).collect()
        },
        ..options
    };
    nrc_cache::bench::run(&options);
    Ok(())
}

/// Arguments of `nrc bench trace`.
#[derive(clap::Args, Debug)]
pub struct TraceArgs {
    #[command(flatten)]
    pub scene: SceneArgs,

    /// Image width in pixels.
    #[arg(long, default_value_t = 512)]
    pub width: u32,

    /// Image height in pixels.
    #[arg(long, default_value_t = 512)]
    pub height: u32,

    /// Samples per pixel (rays per pixel for the ray tests, paths per pixel for the path
    /// tracer).
    #[arg(long, default_value_t = 4)]
    pub spp: u32,

    /// Timed runs of each measurement; the best is reported.
    #[arg(long, default_value_t = 3)]
    pub repeats: u32,

    /// Worker threads of the multi-threaded column (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,

    #[command(flatten)]
    pub tracer: TracerArgs,
}

pub fn run(cmd: &BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Trace(a) => trace(a),
        BenchCommand::Cache(a) => cache(a),
    }
}

fn trace(args: &TraceArgs) -> Result<()> {
    if args.width == 0 || args.height == 0 || args.spp == 0 {
        bail!("--width, --height and --spp must be at least 1");
    }
    let scene = args.scene.load()?;
    let one = thread_pool(Some(1))?;
    let all = thread_pool(args.threads)?;
    let (w, h, spp) = (args.width, args.height, args.spp);

    let b = nrc_harness::bench::trace_bench(
        &scene,
        (w, h, spp),
        args.repeats,
        &args.tracer.tracer(),
        &one,
        &all,
    );
    let threads = all.current_num_threads();
    println!(
        "scene {}: {} triangles; {w}x{h}, {spp} spp; max_depth {}, rr_depth {}",
        args.scene.scene.display(),
        scene.triangle_count(),
        args.tracer.depth.max_depth,
        args.tracer.depth.rr_depth,
    );
    println!(
        "wall-clock figures: best of {}; per CPU-second: {threads}-thread runs, CPU time of all threads",
        args.repeats.max(1)
    );
    println!(
        "rays: {} primary ({} hit), {} incoherent ({} hit)",
        b.primary.0, b.primary.1, b.incoherent.0, b.incoherent.1
    );
    println!(
        "{:<34} {:>12} {:>12} {:>12} {:>14}",
        "",
        "unit",
        "1 thread",
        format!("{threads} threads"),
        "per CPU-second"
    );
    for r in &b.rows {
        println!(
            "{:<34} {:>12} {:>12.3} {:>12.3} {:>14.3}",
            r.name, r.unit, r.values[0], r.values[1], r.values[2]
        );
    }
    Ok(())
}
