//! The path tracer's benchmark (`nrc bench trace`): closest-hit queries on two kinds of rays,
//! and the path tracer, each on one thread and on all threads (two separate rayon pools):
//! - primary rays: one jittered camera ray per pixel sample (coherent);
//! - incoherent rays: diffuse-bounce rays, cosine-distributed about the geometric normal
//!   at the primary hits (what a path tracer traces after the first bounce);
//! - path tracer: full paths per second (and rays per second) at the given size and spp.
//!
//! Each wall-clock figure is the best of the repeats, so that a busy machine disturbs it
//! less. On a machine shared with other work, threads wait for a core and wall-clock
//! throughput understates what the code does; the last column therefore also gives the
//! throughput per CPU-second of the process (all repeats of the multi-threaded runs, CPU
//! time from `/proc/self/stat` on Linux, 10 ms resolution), which the load barely changes.

use std::hint::black_box;
use std::time::{Duration, Instant};

use glam::Vec2;
use nrc_render::{PathTracer, PixelSampler, RenderSettings, render};
use nrc_scene::{
    Ray, Scene,
    sampling::{Frame, sample_cosine_hemisphere},
    spawn_ray,
};
use rayon::prelude::*;

/// One measured row: 1 thread, all threads (wall clock), per CPU-second (all threads).
#[derive(Clone, Debug)]
pub struct Row {
    pub name: &'static str,
    pub unit: &'static str,
    pub values: [f64; 3],
}

/// The benchmark's figures.
#[derive(Clone, Debug)]
pub struct TraceBench {
    pub rows: Vec<Row>,
    /// Primary rays traced and how many hit.
    pub primary: (usize, usize),
    /// Incoherent rays traced and how many hit.
    pub incoherent: (usize, usize),
}

/// Measures the rays and the path tracer on `scene` at `w × h`, `spp` samples per pixel, with
/// `repeats` timed runs each, on the one-thread pool `one` and the pool `all`.
pub fn trace_bench(
    scene: &Scene,
    (w, h, spp): (u32, u32, u32),
    repeats: u32,
    tracer: &PathTracer,
    one: &rayon::ThreadPool,
    all: &rayon::ThreadPool,
) -> TraceBench {
    let primary = primary_rays(scene, w, h, spp);
    let bounce = all.install(|| bounce_rays(scene, &primary));
    let settings = RenderSettings {
        width: w,
        height: h,
        spp,
        seed: 1,
        variance: false,
        sequence: None,
    };

    let mut rows = vec![
        Row {
            name: "primary rays",
            unit: "Mrays/s",
            values: [0.0; 3],
        },
        Row {
            name: "incoherent (diffuse-bounce) rays",
            unit: "Mrays/s",
            values: [0.0; 3],
        },
        Row {
            name: "path tracer",
            unit: "M samples/s",
            values: [0.0; 3],
        },
        Row {
            name: "path tracer rays",
            unit: "Mrays/s",
            values: [0.0; 3],
        },
    ];
    let rate = |work: f64, t: Duration| work / t.as_secs_f64() * 1e-6;
    let per_cpu = |work: f64, t: Option<Duration>| t.map_or(f64::NAN, |t| rate(work, t));
    let mut hits = (0, 0);
    for (col, pool) in [&one, &all].into_iter().enumerate() {
        let m = measure(repeats, || pool.install(|| trace_all(scene, &primary)));
        rows[0].values[col] = rate(primary.len() as f64, m.best);
        rows[0].values[2] = per_cpu(primary.len() as f64, m.cpu_per_run);
        hits.0 = m.value;
        let m = measure(repeats, || pool.install(|| trace_all(scene, &bounce)));
        rows[1].values[col] = rate(bounce.len() as f64, m.best);
        rows[1].values[2] = per_cpu(bounce.len() as f64, m.cpu_per_run);
        hits.1 = m.value;
        let m = measure(repeats, || {
            pool.install(|| render(scene, &scene.camera, tracer, &settings, &|_| {}))
        });
        let (samples, rays) = (
            m.value.stats.samples as f64,
            m.value.stats.rays.rays() as f64,
        );
        rows[2].values[col] = rate(samples, m.best);
        rows[2].values[2] = per_cpu(samples, m.cpu_per_run);
        rows[3].values[col] = rate(rays, m.best);
        rows[3].values[2] = per_cpu(rays, m.cpu_per_run);
    }

    TraceBench {
        rows,
        primary: (primary.len(), hits.0),
        incoherent: (bounce.len(), hits.1),
    }
}

/// Rays handed to a worker at a time.
const CHUNK: usize = 256;

/// Traces every ray (closest hit) on the current pool; returns the number of hits.
fn trace_all(scene: &Scene, rays: &[Ray]) -> usize {
    rays.par_chunks(CHUNK)
        .map(|c| {
            c.iter()
                .filter(|r| black_box(scene.intersect(r)).is_some())
                .count()
        })
        .sum()
}

/// A measurement: the best wall-clock time over the repeats, the CPU time per run
/// (averaged over all repeats) when known, and the last run's result.
struct Timing<T> {
    best: Duration,
    cpu_per_run: Option<Duration>,
    value: T,
}

/// Runs `f` `repeats` times.
fn measure<T>(repeats: u32, mut f: impl FnMut() -> T) -> Timing<T> {
    let repeats = repeats.max(1);
    let mut best = Duration::MAX;
    let mut last = None;
    let cpu0 = nrc_scene::cpu::process_cpu_time();
    for _ in 0..repeats {
        let t = Instant::now();
        let v = f();
        best = best.min(t.elapsed());
        last = Some(v);
    }
    let cpu_per_run = match (cpu0, nrc_scene::cpu::process_cpu_time()) {
        (Some(a), Some(b)) if b > a => Some((b - a) / repeats),
        _ => None,
    };
    Timing {
        best,
        cpu_per_run,
        value: last.expect("at least one run"),
    }
}

/// One jittered camera ray per pixel sample.
fn primary_rays(scene: &Scene, w: u32, h: u32, spp: u32) -> Vec<Ray> {
    let mut rays = Vec::with_capacity((w * h * spp) as usize);
    for y in 0..h {
        for x in 0..w {
            for s in 0..spp {
                let mut sampler = PixelSampler::new(0, (y * w + x) as u64, s as u64);
                let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                rays.push(scene.camera.generate_ray(film, w, h));
            }
        }
    }
    rays
}

/// Diffuse-bounce rays: from each primary hit, a cosine-distributed direction about the
/// geometric normal on the side the primary ray came from.
fn bounce_rays(scene: &Scene, primary: &[Ray]) -> Vec<Ray> {
    primary
        .par_iter()
        .enumerate()
        .filter_map(|(i, ray)| {
            let hit = scene.intersect(ray)?;
            let si = scene.interaction(ray, &hit);
            let n = if si.front_face() { si.ng } else { -si.ng };
            let mut sampler = PixelSampler::new(1, i as u64, 0);
            let d = Frame::from_normal(n).to_world(sample_cosine_hemisphere(sampler.next_2d()));
            Some(spawn_ray(si.p, si.ng, d))
        })
        .collect()
}
