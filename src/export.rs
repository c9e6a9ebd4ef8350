//! `nrc export`: a neural cache snapshot as portable weights (safetensors) and a
//! tiny-cuda-nn–style JSON description (`docs/export.md`).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

/// Arguments of `nrc export`.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// The snapshot to export (written by `nrc train --snapshot`).
    #[arg(long)]
    pub cache: PathBuf,

    /// Folder to write `config.json` and `weights.safetensors` into (created if missing).
    #[arg(long)]
    pub out: PathBuf,
}

/// Loads the snapshot and writes its export; prints what was written and the sizes.
pub fn run(args: &ExportArgs) -> Result<()> {
    let cache = nrc_cache::Cache::load(&args.cache, nrc_cache::CacheDevice::Cpu)
        .with_context(|| format!("cannot load the cache snapshot {}", args.cache.display()))?;
    let Some(neural) = cache.neural() else {
        bail!(
            "{} holds a spatial-hash cache: only the neural cache exports (its cells are not a network)",
            args.cache.display()
        );
    };
    let written = nrc_cache::export::export(neural, &args.out)?;
    let snapshot_bytes = std::fs::metadata(&args.cache).map(|m| m.len()).unwrap_or(0);
    println!(
        "exported {} to {} and {}: {:.2} MB (the snapshot: {:.2} MB)",
        args.cache.display(),
        written.config.display(),
        written.weights.display(),
        written.bytes as f64 * 1e-6,
        snapshot_bytes as f64 * 1e-6
    );
    Ok(())
}
