//! Benchmark of the metrics on a procedural HDR image pair: wall time of HDR-FLIP (and of
//! MSE/relMSE/MAPE together) at a given resolution, median of several runs.
//!
//! cargo run --release -p nrc-eval --example flip_bench -- [WIDTH HEIGHT RUNS]

use std::time::Instant;

use nrc_eval::metrics::{MetricOptions, compute_metrics};
use nrc_eval::{HdrFlipParams, ImageView, hdr_flip};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    let (w, h, runs) = (
        *args.first().unwrap_or(&1280),
        *args.get(1).unwrap_or(&720),
        *args.get(2).unwrap_or(&5),
    );
    // Reference: smooth HDR gradients with a bright light; test: a hashed ±30 % perturbation.
    let reference: Vec<[f32; 3]> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
            let light = if (x - 0.5).hypot(y - 0.2) < 0.05 {
                30.0
            } else {
                0.0
            };
            [
                0.1 + x + light,
                0.2 + 0.5 * y + light,
                0.3 * x * y + 0.05 + light,
            ]
        })
        .collect();
    let test: Vec<[f32; 3]> = reference
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let hash = (i as u32).wrapping_mul(2_654_435_761) >> 8;
            let f = 0.7 + 0.6 * (hash as f32 / (1u32 << 24) as f32);
            p.map(|v| v * f)
        })
        .collect();
    let r = ImageView::new("reference", w, h, &reference)?;
    let t = ImageView::new("test", w, h, &test)?;

    let median_ms = |f: &mut dyn FnMut()| {
        let mut times: Vec<f64> = (0..runs)
            .map(|_| {
                let start = Instant::now();
                f();
                start.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        times.sort_by(f64::total_cmp);
        times[times.len() / 2]
    };
    let mut exposures = 0;
    let flip_ms = median_ms(&mut || {
        exposures = hdr_flip(&t, &r, &HdrFlipParams::default())
            .expect("HDR-FLIP")
            .num_exposures;
    });
    let basic = MetricOptions {
        flip: None,
        ..MetricOptions::default()
    };
    let basic_ms = median_ms(&mut || {
        compute_metrics(&t, &r, &basic).expect("metrics");
    });
    println!(
        "{w}x{h}, {} rayon threads, median of {runs}: HDR-FLIP {flip_ms:.1} ms ({exposures} exposures), MSE+relMSE+MAPE {basic_ms:.2} ms",
        rayon::current_num_threads()
    );
    Ok(())
}
