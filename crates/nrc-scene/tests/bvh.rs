//! The BVH's closest-hit and occlusion queries agree with brute-force intersection of every
//! triangle, on random rays over every scene the project ships (`scenes/`) and every scene
//! in `../shared/scenes/` (skipped with a message when absent).
//!
//! Both sides use the same ray–triangle routine, so the BVH must find exactly the same
//! closest distance (bit for bit) and the same occlusion answer: any difference is a
//! traversal bug, and no tolerance is allowed.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use nrc_scene::accel::IsectTriangle;
use nrc_scene::sampling::{sample_uniform_sphere, sample_uniform_triangle};
use nrc_scene::{Ray, Scene, spawn_ray, spawn_ray_between};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn scene_files() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut dirs = vec![root.join("scenes")];
    let shared = root.join("../shared/scenes");
    if shared.is_dir() {
        dirs.push(shared);
    } else {
        nrc_scene::testing::skipped(
            "shared scenes (bvh.rs)",
            &format!("{} is absent", shared.display()),
        );
    }
    let mut files = Vec::new();
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                dirs.push(p);
            } else if matches!(p.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")) {
                files.push(p);
            }
        }
    }
    files.sort();
    files
}

struct BruteForce {
    tris: Vec<IsectTriangle>,
}

impl BruteForce {
    fn new(scene: &Scene) -> Self {
        let tris = (0..scene.triangle_count() as u32)
            .map(|i| {
                let [a, b, c] = scene.triangle_vertices(i);
                IsectTriangle::new(a, b, c)
            })
            .collect();
        Self { tris }
    }

    /// Closest t with 0 ≤ t < t_max, and every triangle hit at exactly that t.
    fn closest(&self, ray: &Ray) -> Option<(f32, Vec<u32>)> {
        let mut best: Option<(f32, Vec<u32>)> = None;
        for (i, t) in self.tris.iter().enumerate() {
            if let Some((t, _, _)) = t.intersect(ray.o.into(), ray.d.into(), ray.t_max)
                && t < ray.t_max
            {
                match &mut best {
                    Some((bt, ids)) if t == *bt => ids.push(i as u32),
                    Some((bt, _)) if t > *bt => {}
                    _ => best = Some((t, vec![i as u32])),
                }
            }
        }
        best
    }
}

fn random_surface_point(scene: &Scene, rng: &mut Pcg64Mcg) -> (Vec3, Vec3, u32) {
    let tri = rng.random_range(0..scene.triangle_count() as u32);
    let (b1, b2) = sample_uniform_triangle(Vec2::new(rng.random(), rng.random()));
    let [a, b, c] = scene.triangle_vertices(tri);
    (
        a * (1.0 - b1 - b2) + b * b1 + c * b2,
        scene.triangle_normal(tri),
        tri,
    )
}

#[test]
fn bvh_agrees_with_brute_force_on_every_scene() {
    let files = scene_files();
    println!("{} scenes", files.len());
    for file in files {
        let scene = Scene::load(&file).unwrap_or_else(|e| panic!("{e}"));
        let brute = BruteForce::new(&scene);
        let mut rng = Pcg64Mcg::seed_from_u64(0x5eed);
        let b = scene.bounds();
        let (lo, size) = (b.min - 0.1 * b.extent(), 1.2 * b.extent());
        // Keep each scene to about 4·10⁸ brute-force triangle tests.
        let n = (4e8 / scene.triangle_count() as f64 / 4.0).clamp(200.0, 4000.0) as usize;
        let (mut hits, mut occluded, mut checked) = (0, 0, 0);
        for i in 0..4 * n {
            let u = Vec2::new(rng.random(), rng.random());
            let mut source = None;
            let ray = match i % 4 {
                // Rays from anywhere in and around the bounds.
                0 => {
                    let o = lo + size * Vec3::new(rng.random(), rng.random(), rng.random());
                    Ray::new(o, sample_uniform_sphere(u))
                }
                // Rays leaving surface points (offset origins).
                1 => {
                    let (p, n, tri) = random_surface_point(&scene, &mut rng);
                    source = Some(tri);
                    spawn_ray(p, n, sample_uniform_sphere(u))
                }
                // Bounded rays between surface points (shadow rays).
                2 => {
                    let (p0, n0, _) = random_surface_point(&scene, &mut rng);
                    let (p1, n1, _) = random_surface_point(&scene, &mut rng);
                    if (p1 - p0).length() == 0.0 {
                        continue;
                    }
                    spawn_ray_between(p0, n0, p1, n1)
                }
                // Camera rays.
                _ => scene.camera.generate_ray(
                    Vec2::new(rng.random::<f32>() * 64.0, rng.random::<f32>() * 48.0),
                    64,
                    48,
                ),
            };
            checked += 1;
            let expected = brute.closest(&ray);
            let got = scene.intersect(&ray);
            match (&expected, got) {
                (None, None) => {}
                (Some((t, ids)), Some(h)) => {
                    assert_eq!(h.t, *t, "{}: closest t differs for {ray:?}", file.display());
                    assert!(ids.contains(&h.tri), "{}: wrong triangle", file.display());
                    let p = scene.interaction(&ray, &h).p;
                    assert!(
                        (p - ray.at(h.t)).length()
                            <= 1e-4 * (1.0 + h.t + ray.o.abs().max_element()),
                        "barycentrics of the hit do not reproduce its point"
                    );
                    // A planar triangle cannot be hit again by a ray leaving it: such a
                    // hit would be self-intersection, which the origin offset prevents.
                    assert_ne!(source, Some(h.tri), "{}: self-intersection", file.display());
                    hits += 1;
                }
                _ => panic!(
                    "{}: BVH {:?} vs brute force {:?} for {ray:?}",
                    file.display(),
                    got,
                    expected
                ),
            }
            let occ = scene.occluded(&ray);
            assert_eq!(
                occ,
                expected.is_some(),
                "{}: occlusion differs for {ray:?}",
                file.display()
            );
            occluded += occ as usize;
        }
        println!(
            "{}: {} triangles, {checked} rays, {hits} hits, {occluded} occluded: agree",
            file.display(),
            scene.triangle_count()
        );
        assert!(
            hits > 0 && hits < checked,
            "the rays exercise hits and misses"
        );
    }
}
