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
