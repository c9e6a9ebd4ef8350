//! A render is a function of its seed alone: bit-identical on 1, 2 and 3 threads (the
//! per-pixel random streams do not depend on scheduling), different for another seed.

mod common;

use common::{project_scenes, render_scene};
use nrc_render::PathTracer;
use nrc_scene::Scene;

#[test]
fn same_seed_same_image_whatever_the_thread_count() {
    let scene =
        Scene::load(&project_scenes().join("cornell-box.gltf")).unwrap_or_else(|e| panic!("{e}"));
    let tracer = PathTracer::default();
    let on = |threads: usize, seed: u64| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| render_scene(&scene, &tracer, 37, 29, 3, seed))
    };
    let one = on(1, 5);
    for threads in [2, 3] {
        let other = on(threads, 5);
        assert_eq!(
            one.mean, other.mean,
            "{threads} threads differ from 1 thread"
        );
        assert_eq!(one.variance, other.variance);
        assert_eq!(one.stats.rays, other.stats.rays);
    }
    let reseeded = on(2, 6);
    assert_ne!(one.mean, reseeded.mean, "another seed gave the same image");
}

/// A render split into ranges of sample indices (the chunks of a study's reference, run as
/// separate jobs) and merged gives the single render's mean and variance per pixel, within
/// float rounding, for 1, 3 and 7 chunks; merging a chunk twice does not (negative control).
#[test]
fn split_render_merges_to_the_single_render() {
    let scene =
        Scene::load(&project_scenes().join("cornell-box.gltf")).unwrap_or_else(|e| panic!("{e}"));
    let tracer = PathTracer::default();
    let (w, h, spp, seed) = (23, 17, 22u32, 9);
    let single = render_scene(&scene, &tracer, w, h, spp, seed);
    let single_var = single.variance.as_ref().unwrap();
    let chunked = |bounds: &[u32]| {
        let mut merged: Option<nrc_render::Moments> = None;
        for pair in bounds.windows(2) {
            let (m, _) = nrc_render::render_moments(
                &scene,
                &scene.camera,
                &tracer,
                (w, h),
                seed,
                pair[0]..pair[1],
                &|_| {},
            );
            match &mut merged {
                None => merged = Some(m),
                Some(acc) => acc.merge(&m).unwrap(),
            }
        }
        merged.unwrap()
    };
    let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * a.abs().max(b.abs()) + 1e-7;
    let agree = |m: &nrc_render::Moments| {
        let (mean, var) = (m.mean_image(), m.variance_image().unwrap());
        m.count == u64::from(spp)
            && mean
                .data
                .iter()
                .zip(&single.mean.data)
                .all(|(a, b)| (0..3).all(|c| close(a[c], b[c])))
            && var
                .data
                .iter()
                .zip(&single_var.data)
                .all(|(a, b)| (0..3).all(|c| close(a[c], b[c])))
    };
    for bounds in [
        vec![0, 22],
        vec![0, 7, 8, 22],
        vec![0, 1, 4, 9, 10, 15, 21, 22],
    ] {
        assert!(agree(&chunked(&bounds)), "{} chunks", bounds.len() - 1);
    }
    // Negative control: samples 0..7 counted twice (22 samples, but not the render's).
    let wrong = chunked(&[0, 7, 0, 15]);
    assert_eq!(wrong.count, 22);
    assert!(!agree(&wrong));
}
