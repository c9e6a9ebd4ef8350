//! Next-event estimation and ReSTIR DI with the light tree (`--light-sampler tree`) on the
//! shipped many-light hall (`scenes/many-lights.gltf`: 2,080 emissive triangles, four point
//! lights, two spots; seen from near a spot-lit crate), direct light only (`--max-depth 2`),
//! camera rays through pixel centres:
//! each pixel's mean with the tree agrees with the power sampler's (a z-test per pixel channel,
//! Bonferroni, family false-alarm rate 10⁻³). Negative control: a tree whose spots' bounds
//! point the wrong way gives them probability zero where they shine, which no other strategy
//! makes up for (a delta light is found by light sampling alone), and must fail.

mod common;

use common::{last_frame, reference_at_centres, z_two_sided};
use nrc_render::PathTracer;
use nrc_render::passes::PassSpec;
use nrc_scene::{
    Image, LightBounds, LightSamplerKind, LightSource, LightTree, PunctualKind, Scene,
};

/// The hall, seen from near the crate the first spot lights (the spots' light is a few
/// percent of the lamps' in the hall's own view, too little for the negative control).
fn hall() -> Scene {
    let mut scene = Scene::load(&common::project_scenes().join("many-lights.gltf")).unwrap();
    scene.camera = nrc_scene::Camera::look_at(
        glam::Vec3::new(-8.5, 1.6, 3.0),
        glam::Vec3::new(-6.0, 0.3, 0.8),
        glam::Vec3::Y,
        40.0,
    )
    .unwrap();
    scene
}

const W: u32 = 16;
const H: u32 = 10;

fn direct() -> PathTracer {
    PathTracer {
        max_depth: 2,
        ..Default::default()
    }
}

/// Pixel channels of `a` (mean over `na` samples, one sample's variance `va`) and `b` beyond
/// the Bonferroni bound of a two-sample z-test, and the worst |z|.
fn beyond(a: &(Image, Image), na: u32, b: &(Image, Image), nb: u32) -> (usize, f64) {
    let cells = a.0.data.len() * 3;
    let bound = z_two_sided(1e-3 / cells as f64);
    let (mut count, mut worst) = (0, 0.0f64);
    for p in 0..a.0.data.len() {
        for c in 0..3 {
            let d = f64::from(a.0.data[p][c]) - f64::from(b.0.data[p][c]);
            let se2 = f64::from(a.1.data[p][c]) / f64::from(na)
                + f64::from(b.1.data[p][c]) / f64::from(nb);
            if se2 <= 0.0 {
                assert!(d.abs() < 1e-6, "pixel {p}: {d} apart with no variance");
                continue;
            }
            let z = d / se2.sqrt();
            worst = worst.max(z.abs());
            if z.abs() > bound {
                count += 1;
            }
        }
    }
    (count, worst)
}

#[test]
fn nee_with_the_tree_matches_the_power_sampler_per_pixel_and_a_wrong_bound_fails() {
    let power = hall();
    assert_eq!(power.light_sampler(), LightSamplerKind::Power);
    let mut tree = hall();
    tree.set_light_sampler(LightSamplerKind::Tree);
    let t = tree.light_tree().unwrap();
    println!(
        "tree: {} lights, {} nodes, depth {}",
        t.len(),
        t.node_count(),
        t.depth()
    );
    let (n_power, n_tree) = (8192, 2048);
    let reference = reference_at_centres(&power, &direct(), W, H, n_power);
    let with_tree = reference_at_centres(&tree, &direct(), W, H, n_tree);
    let (count, worst) = beyond(&with_tree, n_tree, &reference, n_power);
    // Variance of one sample, summed over the image: what the tree buys per sample.
    let var = |i: &Image| {
        i.data
            .iter()
            .map(|p| f64::from(p.element_sum()))
            .sum::<f64>()
    };
    println!(
        "tree against power: worst |z| {worst:.2}, {count} beyond; variance per sample {:.3} against {:.3} ({:.1}× lower)",
        var(&with_tree.1),
        var(&reference.1),
        var(&reference.1) / var(&with_tree.1)
    );
    assert_eq!(count, 0, "the tree's NEE is biased: worst |z| {worst:.2}");
    assert!(
        var(&with_tree.1) < var(&reference.1),
        "the tree did not lower the variance"
    );

    let broken = spot_blind();
    // A tree over another scene's lights is refused, not followed out of bounds.
    let foreign = LightTree::new(
        vec![(
            LightSource::Triangle(u32::MAX),
            LightBounds::point(glam::Vec3::ZERO, 1.0),
        )],
        vec![],
    );
    let err = hall().set_light_tree(foreign).unwrap_err();
    assert!(err.contains("Triangle(4294967295)"), "{err}");
    let with_broken = reference_at_centres(&broken, &direct(), W, H, n_tree);
    let (count, worst) = beyond(&with_broken, n_tree, &reference, n_power);
    println!("spots' bounds reversed: worst |z| {worst:.2}, {count} beyond");
    assert!(
        count > 0,
        "a tree blind to the spots passed: worst |z| {worst:.2}"
    );
}

/// The hall with a light tree whose spots' bounds point the wrong way: it gives them
/// probability zero where they shine.
fn spot_blind() -> Scene {
    let mut scene = hall();
    let (bounded, infinity) = scene.light_tree_inputs();
    let wrong: Vec<(LightSource, LightBounds)> = bounded
        .into_iter()
        .map(|(l, b)| match l {
            LightSource::Punctual(i)
                if matches!(
                    scene.punctual_lights()[i as usize].kind,
                    PunctualKind::Spot { .. }
                ) =>
            {
                (l, LightBounds { w: -b.w, ..b })
            }
            _ => (l, b),
        })
        .collect();
    scene
        .set_light_tree(LightTree::new(wrong, infinity))
        .unwrap();
    scene
}

/// Unbiased ReSTIR DI drawing its light candidates from the tree matches the power sampler's
/// depth-2 path-traced reference per pixel: 128 independent runs of 4 frames (temporal and
/// spatial reuse at work), the last frame of each a sample. Negative control: the same pass
/// with the spot-blind tree ([`spot_blind`]; its spots are delta lights, which only light
/// candidates can find) must fail it. (The biased mode, `Z = Σ M`, is not a control here: this
/// view has too little occlusion between neighbours for its bias to show; it passed.)
#[test]
fn restir_di_with_the_tree_matches_the_reference_per_pixel_and_a_wrong_bound_fails() {
    let power = hall();
    let mut tree = hall();
    tree.set_light_sampler(LightSamplerKind::Tree);
    let (w, h) = (12, 8);
    let ref_spp = 8192;
    let (reference, ref_var) = reference_at_centres(&power, &direct(), w, h, ref_spp);
    let spec: PassSpec = "restir-di:jitter=0".parse().unwrap();
    for (name, scene, expect_pass) in [
        ("tree", &tree, true),
        ("spot-blind tree", &spot_blind(), false),
    ] {
        let images: Vec<Image> = (0..128)
            .map(|r| last_frame(scene, &spec, &direct(), w, h, 4, 3000 + r))
            .collect();
        let (worst, count, bound) = common::per_pixel_z(&images, &reference, &ref_var, ref_spp);
        println!("restir-di with the {name}: worst |z| {worst:.2}, {count} beyond {bound:.2}");
        if expect_pass {
            assert_eq!(count, 0, "{name}: worst |z| {worst:.2}");
        } else {
            assert!(count > 0, "{name} passed: worst |z| {worst:.2}");
        }
    }
}
