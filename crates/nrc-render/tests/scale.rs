//! Scale: `scenes/large/rocks.gltf`, one rock of 20,000 triangles instanced by 256 glTF nodes
//! (5.12 M triangles from 0.34 MB of files), loads within a bounded memory per triangle (peak
//! and held, measured by the allocator) and renders a small image that is finite,
//! non-negative and lit.
//!
//! The bounds are about 1.3 times what the loader needed when they were set (BENCHMARKS.md,
//! "Scale"): a loader that keeps a second copy of the vertices, or a BVH builder that holds
//! more per primitive, fails them.

mod common;

use std::time::Instant;

use common::{project_scenes, render_scene};
use nrc_render::PathTracer;
use nrc_scene::Scene;
use nrc_scene::testing::{LargestAllocation, live_bytes, peak_live_bytes, reset_peak_live};

#[global_allocator]
static ALLOCATOR: LargestAllocation = LargestAllocation;

/// Bytes per triangle the loaded scene may hold (measured: see the module's note).
const HELD_PER_TRIANGLE: usize = 140;
/// Bytes per triangle the loader may hold at its peak (the BVH build's scratch included).
const PEAK_PER_TRIANGLE: usize = 500;

#[test]
fn five_million_instanced_triangles_load_and_render_within_memory() {
    let path = project_scenes().join("large/rocks.gltf");
    let before = live_bytes();
    reset_peak_live();
    let start = Instant::now();
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let seconds = start.elapsed().as_secs_f64();
    let held = live_bytes().saturating_sub(before);
    let peak = peak_live_bytes().saturating_sub(before);
    let n = scene.triangle_count();
    let mib = |b: usize| b as f64 / (1 << 20) as f64;
    eprintln!(
        "rocks: {n} triangles loaded in {seconds:.1} s; held {:.0} MiB ({} B a triangle), peak {:.0} MiB ({} B a triangle)",
        mib(held),
        held / n,
        mib(peak),
        peak / n
    );
    // 256 rocks of 20,000 triangles, the ground and the panel light (two each).
    assert_eq!(n, 256 * 20_000 + 4);
    assert!(scene.warnings().is_empty(), "{:?}", scene.warnings());
    assert!(
        held <= HELD_PER_TRIANGLE * n,
        "the loaded scene holds {held} bytes, over {HELD_PER_TRIANGLE} a triangle"
    );
    assert!(
        peak <= PEAK_PER_TRIANGLE * n,
        "loading peaked at {peak} bytes, over {PEAK_PER_TRIANGLE} a triangle"
    );

    // The BVH: its nodes and prepared triangles are part of what is held, and a node's eight
    // children hold at most three triangles each as leaves.
    let bvh = scene.summary().bvh;
    eprintln!(
        "rocks: bvh {} nodes, {:.0} MiB, built in {:.1} s",
        bvh.nodes,
        mib(bvh.bytes),
        bvh.build_seconds
    );
    assert!(bvh.bytes <= held && bvh.nodes >= n / 24, "{bvh:?}");

    let out = render_scene(&scene, &PathTracer::default(), 48, 27, 2, 1);
    for (i, p) in out.mean.data.iter().enumerate() {
        assert!(p.is_finite() && p.min_element() >= 0.0, "pixel {i} = {p}");
    }
    assert_eq!(out.stats.invalid_samples, 0);
    assert!(out.mean.mean().min_element() > 0.0, "a dark image");
}
