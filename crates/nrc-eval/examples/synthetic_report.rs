//! The whole evaluation pipeline on synthetic data: a procedural HDR "reference", noisy
//! "renders" at 1–16 spp (Gaussian noise falling as 1/√spp, one method with a small bias),
//! metrics, bias/variance, a sweep with its time-to-error table, the plot, false-colour images
//! and the report. Times are synthetic (proportional to spp), not measured.
//!
//! cargo run --release -p nrc-eval --example synthetic_report -- OUT_DIR

use std::path::PathBuf;

use nrc_eval::metrics::{Metric, REL_MSE_EPSILON, rel_mse_map};
use nrc_eval::plot::plot_error_vs_time;
use nrc_eval::png_output::{ColorMap, Scale, write_false_color_png, write_srgb_png};
use nrc_eval::sweep::time_to_error_table;
use nrc_eval::{
    BiasVarianceAccumulator, HdrFlipParams, ImageView, MetricOptions, Report, ReportRow,
    SweepPoint, SweepSeries, compute_metrics, hdr_flip, write_report,
};

const W: usize = 96;
const H: usize = 64;

/// A small deterministic PRNG (SplitMix64) and Box–Muller normals, to keep the example free of
/// extra dependencies.
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f32 {
        let (u, v) = (self.uniform().max(1e-300), self.uniform());
        ((-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()) as f32
    }
}

fn reference() -> Vec<[f32; 3]> {
    (0..W * H)
        .map(|i| {
            let (x, y) = ((i % W) as f32 / W as f32, (i / W) as f32 / H as f32);
            let light = if (x - 0.7).hypot(y - 0.3) < 0.08 {
                20.0
            } else {
                0.0
            };
            [
                0.3 + 0.5 * x + light,
                0.2 + 0.4 * y + light,
                0.25 + 0.2 * (8.0 * x).sin().abs() + light,
            ]
        })
        .collect()
}

/// A render with `spp` samples: noise σ = 0.5·value/√spp, plus `bias`.
fn render(reference: &[[f32; 3]], spp: f32, bias: f32, rng: &mut Rng) -> Vec<[f32; 3]> {
    reference
        .iter()
        .map(|p| p.map(|v| v + bias + 0.5 * v * rng.normal() / spp.sqrt()))
        .collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "out/synthetic-report".into()),
    );
    std::fs::create_dir_all(&out)?;
    let y = reference();
    let reference_view = ImageView::new("reference", W, H, &y)?;
    let options = MetricOptions::default();
    let mut rng = Rng(1);

    let methods = [("unbiased", 0.0f32, 1.0f64), ("biased-fast", 0.02, 0.4)];
    let mut report = Report::new("Synthetic comparison", W, H);
    report.reference = Some("procedural image".into());
    report.notes.push(
        "Synthetic data: times are 1 ms per spp (×0.4 for biased-fast), not measured.".into(),
    );
    for (name, bias, ms_per_spp) in methods {
        let mut series = SweepSeries {
            method: name.into(),
            points: Vec::new(),
        };
        for spp in [1.0f32, 2.0, 4.0, 8.0, 16.0] {
            let x = render(&y, spp, bias, &mut rng);
            let metrics =
                compute_metrics(&ImageView::new(name, W, H, &x)?, &reference_view, &options)?;
            series.points.push(SweepPoint {
                time_ms: ms_per_spp * spp as f64,
                samples_per_pixel: spp as f64,
                metrics,
            });
        }
        // Bias and variance at 1 spp from 32 independent renders.
        let mut acc = BiasVarianceAccumulator::new(W, H);
        for _ in 0..32 {
            acc.add(&ImageView::new(
                name,
                W,
                H,
                &render(&y, 1.0, bias, &mut rng),
            )?)?;
        }
        let x = render(&y, 4.0, bias, &mut rng);
        let test = ImageView::new(name, W, H, &x)?;
        write_srgb_png(&out.join(format!("{name}.png")), &test, 0.0)?;
        write_false_color_png(
            &out.join(format!("{name}-relmse.png")),
            &rel_mse_map(&test, &reference_view, REL_MSE_EPSILON)?,
            ColorMap::Viridis,
            Scale::Log {
                min: 1e-4,
                max: 10.0,
            },
        )?;
        let flip = hdr_flip(&test, &reference_view, &HdrFlipParams::default())?;
        write_false_color_png(
            &out.join(format!("{name}-flip.png")),
            &flip.error_map,
            ColorMap::Magma,
            Scale::Linear { min: 0.0, max: 1.0 },
        )?;
        report.rows.push(ReportRow {
            method: format!("{name}-4spp"),
            time_per_frame_ms: 4.0 * ms_per_spp,
            samples_per_pixel: 4.0,
            metrics: compute_metrics(&test, &reference_view, &options)?,
            bias_variance: Some(acc.finish(&reference_view, None)?),
            temporal: None,
            concentration: None,
            cost: None,
        });
        report.sweeps.push(series);
    }
    report.time_to_error.push(time_to_error_table(
        &report.sweeps,
        Metric::RelMse,
        "unbiased",
        8.0,
    )?);
    plot_error_vs_time(
        &report.sweeps,
        Metric::RelMse,
        "relMSE against time (synthetic)",
        &out.join("error-vs-time.png"),
        &out.join("error-vs-time.svg"),
    )?;
    let files = write_report(&out, &report)?;
    print!("{}", std::fs::read_to_string(files.markdown)?);
    Ok(())
}
