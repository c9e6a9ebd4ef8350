//! The light tree (`--light-sampler tree`): at shading points of a scene with 300 emissive
//! triangles of every orientation, point, spot and directional lights and an environment, the
//! lights `Scene::sample_light` draws follow the probabilities the scene reports for multiple
//! importance sampling (χ² goodness of fit, Šidák-corrected over the points); the same samples
//! against a tree whose bounds face the wrong way (every emitter's normal reversed) must fail.

mod stat;

use glam::{Vec2, Vec3};
use nrc_scene::{
    Environment, LightBounds, LightContext, LightSample, LightSamplerKind, LightSource, LightTree,
    Material, PunctualKind, PunctualLight, Scene, SceneDescription,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use stat::{chi2_test, sidak};

/// A floor, 300 small emissive triangles scattered above it facing every way (a third
/// double-sided), two point lights, a spot, a directional light and a constant environment.
fn many_lights() -> Scene {
    let mut rng = Pcg64::seed_from_u64(5);
    let mut desc = SceneDescription::default();
    let mut materials = vec![Material {
        name: "floor".into(),
        ..Material::default()
    }];
    desc.positions.extend([
        Vec3::new(-20.0, 0.0, -20.0),
        Vec3::new(20.0, 0.0, -20.0),
        Vec3::new(0.0, 0.0, 20.0),
    ]);
    desc.triangles.push([0, 2, 1]);
    desc.triangle_materials.push(0);
    for i in 0..300u32 {
        let o = Vec3::new(
            rng.random_range(-8.0..8.0),
            rng.random_range(0.5..4.0),
            rng.random_range(-8.0..8.0),
        );
        let s = rng.random_range(0.05..0.4);
        let a = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let b = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let base = desc.positions.len() as u32;
        desc.positions.extend([o, o + a * s, o + b * s]);
        desc.triangles.push([base, base + 1, base + 2]);
        materials.push(Material {
            name: format!("light{i}"),
            emissive: Vec3::new(
                rng.random_range(0.1..5.0),
                rng.random_range(0.1..5.0),
                rng.random_range(0.1..5.0),
            ),
            double_sided: i % 3 == 0,
            ..Material::default()
        });
        desc.triangle_materials.push(i + 1);
    }
    desc.materials = materials;
    let point = |position, intensity| PunctualLight {
        kind: PunctualKind::Point,
        position,
        direction: -Vec3::Y,
        intensity,
        range: None,
    };
    desc.lights = vec![
        point(Vec3::new(3.0, 1.0, -2.0), Vec3::splat(4.0)),
        point(Vec3::new(-6.0, 2.5, 5.0), Vec3::new(8.0, 2.0, 1.0)),
        PunctualLight {
            kind: PunctualKind::Spot {
                cos_inner: 0.3f32.cos(),
                cos_outer: 0.5f32.cos(),
            },
            position: Vec3::new(0.0, 5.0, 0.0),
            direction: Vec3::new(0.3, -1.0, 0.1).normalize(),
            intensity: Vec3::splat(30.0),
            range: None,
        },
        PunctualLight {
            kind: PunctualKind::Directional,
            position: Vec3::ZERO,
            direction: Vec3::new(0.2, -1.0, 0.3).normalize(),
            intensity: Vec3::splat(0.5),
            range: None,
        },
    ];
    desc.environment = Environment::constant(Vec3::splat(0.2));
    let mut scene = Scene::from_description(desc).unwrap();
    scene.set_light_sampler(LightSamplerKind::Tree);
    scene
}

/// The light a sample stands for.
fn source(s: &LightSample) -> LightSource {
    match *s {
        LightSample::Surface(ls) => LightSource::Triangle(ls.tri),
        LightSample::Punctual { index, .. } => LightSource::Punctual(index),
        LightSample::Environment { .. } => LightSource::Environment,
    }
}

/// Shading points: on the floor (normal up), among the lights, and a point with no surface.
fn points() -> [LightContext; 4] {
    [
        LightContext::new(Vec3::new(0.5, 0.0, 0.2), Vec3::Y),
        LightContext::new(Vec3::new(-7.0, 0.0, 6.0), Vec3::Y),
        LightContext::new(Vec3::new(2.0, 2.0, -3.0), Vec3::new(0.6, 0.0, 0.8)),
        LightContext::new(Vec3::new(-1.0, 3.0, 1.0), Vec3::ZERO),
    ]
}

const SAMPLES: usize = 200_000;

/// Counts per light of `SAMPLES` draws at `at`, in the order of `lights`, then the draws that
/// found no light (the tree met a node whose children all face away); checking on the way
/// that each sample's own density is the one the scene reports for it.
fn draw(scene: &Scene, at: &LightContext, lights: &[LightSource], seed: u64) -> Vec<f64> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut counts = vec![0.0; lights.len() + 1];
    for _ in 0..SAMPLES {
        let u = Vec2::new(rng.random(), rng.random());
        let Some(s) = scene.sample_light(at, rng.random(), u) else {
            counts[lights.len()] += 1.0;
            continue;
        };
        let l = source(&s);
        if let LightSample::Surface(ls) = s {
            let reported = scene.light_pdf_area(at, ls.tri);
            assert!(
                (ls.pdf_area - reported).abs() <= 1e-5 * reported,
                "{l:?}: sampled with {} but reported {reported}",
                ls.pdf_area
            );
        }
        counts[lights.iter().position(|x| *x == l).unwrap()] += 1.0;
    }
    counts
}

#[test]
fn tree_sampling_follows_its_probabilities_and_a_wrong_bound_fails() {
    let scene = many_lights();
    let (bounded, infinity) = scene.light_tree_inputs();
    assert_eq!(bounded.len(), 300 + 3);
    assert_eq!(infinity.len(), 2);
    let tree = scene.light_tree().expect("the tree was asked for");
    // `nrc info` says so: a tree of nodes of up to 8 children over the 303 bounded lights.
    // Full nodes would be ⌈302 / 7⌉ = 44; the nodes near the lights are not full, and this
    // scene's build gives 93, within a third of a binary tree's 302 interior nodes. A descent
    // takes at least log8(303) choices, far fewer than a binary tree's at least 9.
    let info = scene.summary().to_string();
    assert!(
        info.contains(&format!(
            "light tree: {} nodes of up to {} children, depth {}",
            tree.node_count(),
            nrc_scene::light_tree::WIDTH,
            tree.depth()
        )),
        "{info}"
    );
    assert!(
        (44..=303 / 3).contains(&tree.node_count()),
        "{} nodes",
        tree.node_count()
    );
    assert!((3..=6).contains(&tree.depth()), "depth {}", tree.depth());
    let lights: Vec<LightSource> = bounded
        .iter()
        .map(|b| b.0)
        .chain(infinity.clone())
        .collect();
    // The same lights with every emitter's normal reversed: a bound that says the wrong side.
    let wrong = LightTree::new(
        bounded
            .iter()
            .map(|&(l, b)| {
                let b = match l {
                    LightSource::Triangle(_) => LightBounds { w: -b.w, ..b },
                    _ => b,
                };
                (l, b)
            })
            .collect(),
        infinity,
    );
    let alpha = sidak(1e-4, points().len());
    for (k, at) in points().iter().enumerate() {
        let counts = draw(&scene, at, &lights, 100 + k as u64);
        let expected = |t: &LightTree| -> Vec<f64> {
            let mut e: Vec<f64> = lights
                .iter()
                .map(|&l| t.pmf(at.p, at.n, l) as f64 * SAMPLES as f64)
                .collect();
            let found: f64 = e.iter().sum();
            e.push((SAMPLES as f64 - found).max(0.0));
            e
        };
        let right = chi2_test(&counts, &expected(tree)).unwrap_or_else(|e| panic!("{e}"));
        let against_wrong = chi2_test(&counts, &expected(&wrong));
        println!(
            "point {k}: χ² {:.1} ({} dof), p {:.3e}; against the wrong bound: {}",
            right.statistic,
            right.dof,
            right.p_value,
            match &against_wrong {
                Ok(r) => format!("p {:.3e}", r.p_value),
                Err(e) => e.clone(),
            }
        );
        assert!(right.p_value > alpha, "point {k}: p {}", right.p_value);
        assert!(
            against_wrong.is_err() || against_wrong.unwrap().p_value < alpha,
            "point {k}: the wrong bound passed"
        );
    }
}
