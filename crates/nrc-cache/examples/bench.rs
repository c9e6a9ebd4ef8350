//! `cargo run --release -p nrc-cache --example bench [-- --quick] [-- --device cpu|wgpu|all] [-- --no-compare]`
//!
//! Prints training samples/s and inference queries/s of both presets at batch 2^14 and 2^16
//! per device, and the fused-vs-unfused ratios.

use std::time::Duration;

use nrc_cache::CacheDevice;
use nrc_cache::bench::{BenchOptions, run};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut options = BenchOptions::default();
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--quick" => options.min_time = Duration::from_millis(500),
            "--no-compare" => options.compare_paths = false,
            "--device" => {
                i += 1;
                options.devices = match args.get(i).map(String::as_str) {
                    Some("all") => vec![CacheDevice::Cpu, CacheDevice::Wgpu],
                    Some(d) => match d.parse() {
                        Ok(d) => vec![d],
                        Err(e) => {
                            eprintln!("{e}");
                            std::process::exit(2);
                        }
                    },
                    None => {
                        eprintln!("--device needs cpu, wgpu or all");
                        std::process::exit(2);
                    }
                };
            }
            other => {
                eprintln!(
                    "unknown argument {other:?} (expected --quick, --no-compare, --device cpu|wgpu|all)"
                );
                std::process::exit(2);
            }
        }
        i += 1;
    }
    run(&options);
}
