//! The DDGI probe volume: octahedral maps, convergence in the emissive enclosure at the rate
//! the hysteresis predicts (eq. 5 to the full irradiance, eq. 4 to the indirect-only one), and
//! the Chebyshev visibility weight behind a wall, probe relocation and classification.

mod common;

use std::f32::consts::PI;

use common::{Mesh, SceneBuilder, mat};
use glam::{UVec3, Vec3};
use nrc_render::PixelSampler;
use nrc_render::ddgi::{DdgiSettings, ProbeRadiance, ProbeVolume, oct_decode, oct_encode};

#[test]
fn octahedral_mapping_round_trips_and_borders_copy_their_wrapped_neighbours() {
    let mut s = PixelSampler::new(1, 2, 3);
    for _ in 0..10_000 {
        let u = s.next_2d();
        let z = 1.0 - 2.0 * u.x;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let d = Vec3::new(r * (2.0 * PI * u.y).cos(), r * (2.0 * PI * u.y).sin(), z);
        let e = oct_encode(d);
        assert!(e.x.abs() <= 1.0 && e.y.abs() <= 1.0, "{e}");
        assert!(
            (oct_decode(e) - d).length() < 1e-5,
            "{d} -> {e} -> {}",
            oct_decode(e)
        );
    }
    // After an update every border texel equals the interior texel across the seam, and a
    // lookup just either side of the map's edge (the same direction's neighbourhood) agrees.
    let scene = point_lit_room(false);
    let mut v = ProbeVolume::new(
        &scene.bounds(),
        DdgiSettings {
            counts: Some(UVec3::new(2, 1, 1)),
            ..Default::default()
        },
    )
    .unwrap();
    v.update(&scene, 1);
    assert!(v.borders_are_wrapped());
    for (a, b) in [
        (Vec3::new(1e-3, 0.3, -0.95), Vec3::new(-1e-3, 0.3, -0.95)),
        (Vec3::new(0.4, 1e-3, -0.9), Vec3::new(0.4, -1e-3, -0.9)),
    ] {
        let (ea, eb) = (
            v.probe_irradiance_toward(0, a.normalize()),
            v.probe_irradiance_toward(0, b.normalize()),
        );
        assert!(
            (ea - eb).length() <= 0.02 * ea.length().max(eb.length()) + 1e-6,
            "{ea} vs {eb} across the seam"
        );
    }
}

/// Mean and largest relative deviation from `expect` over every interior texel of every probe.
fn texel_stats(v: &ProbeVolume, expect: f32) -> (f32, f32) {
    let (mut sum, mut worst, mut n) = (0.0, 0.0f32, 0);
    for p in 0..v.probe_count() {
        for (_, e) in v.irradiance_texels(p) {
            for c in 0..3 {
                sum += e[c];
                worst = worst.max((e[c] / expect - 1.0).abs());
                n += 1;
            }
        }
    }
    (sum / n as f32, worst)
}

/// In the enclosure (`L_e = 1`, `ρ = ½`): eq. 5 probes converge to the full irradiance
/// `E = π L_e / (1 − ρ) = 2π` at every texel, eq. 4 probes to the indirect-only `π ρ L_e /
/// (1 − ρ) = π`. From the first frame (`E₁ = π L_e` resp. `π ρ L_e`, the history empty) the
/// `k`-th update blends `E₁ + ρ E_k` with weight `h_k = min(h, k / (k + 1))` on the history
/// (a running mean, then the hysteresis): after 30 frames at the default hysteresis 0.97 the
/// texels' mean lies within 2 % of that recursion's value, and 5 frames tell it from the
/// hysteresis alone (`h_k = h` from the second frame on, which gives
/// `E∞ − (E∞ − E₁) λ^(k−1)`, `λ = h + (1 − h) ρ`); with hysteresis 0.9, after 120 frames the
/// mean is within 1 % of the limit and every texel within 5 % (eq. 4's one-sample NEE at each
/// hit is the noise).
#[test]
fn enclosure_probes_converge_at_the_rate_the_hysteresis_predicts() {
    let scene = common::enclosure(Vec3::X);
    let rho = 0.5f32;
    for (radiance, limit, first) in [
        (ProbeRadiance::Full, 2.0 * PI, PI),
        (ProbeRadiance::Indirect, PI, PI * rho),
    ] {
        let settings = DdgiSettings {
            counts: Some(UVec3::splat(3)),
            radiance,
            ..Default::default()
        };
        let h = settings.hysteresis;
        let ramped = |frames: u32| {
            (1..frames).fold(first, |e, k| {
                let hk = h.min(k as f32 / (k as f32 + 1.0));
                hk * e + (1.0 - hk) * (first + rho * e)
            })
        };
        let lambda = h + (1.0 - h) * rho;
        let plain = |frames: u32| limit - (limit - first) * lambda.powi(frames as i32 - 1);
        let mut v = ProbeVolume::new(&scene.bounds(), settings).unwrap();
        for f in 0..30 {
            v.update(&scene, 100 + f);
            if f == 4 {
                let (mean, _) = texel_stats(&v, 1.0);
                let (r, p) = (ramped(5), plain(5));
                println!(
                    "{radiance:?}: mean after 5 frames {mean:.4}, ramped {r:.4}, plain {p:.4}"
                );
                assert!((mean / r - 1.0).abs() < 0.02, "{radiance:?}: {mean} vs {r}");
                // The control: the hysteresis from the second update on is far off.
                assert!((mean / p - 1.0).abs() > 0.1, "{radiance:?}: {mean} vs {p}");
            }
        }
        let predicted = ramped(30);
        let (mean, _) = texel_stats(&v, predicted);
        println!(
            "{radiance:?}: mean after 30 frames {mean:.4}, predicted {predicted:.4}, limit {limit:.4}"
        );
        assert!(
            (mean / predicted - 1.0).abs() < 0.02,
            "{radiance:?}: {mean} vs {predicted}"
        );

        let mut fast = ProbeVolume::new(
            &scene.bounds(),
            DdgiSettings {
                hysteresis: 0.9,
                ..settings
            },
        )
        .unwrap();
        for f in 0..120 {
            fast.update(&scene, 200 + f);
        }
        let (mean, worst) = texel_stats(&fast, limit);
        println!(
            "{radiance:?}, hysteresis 0.9, 120 frames: mean {mean:.4} (limit {limit:.4}), worst texel {:.2} %",
            100.0 * worst
        );
        assert!(
            (mean / limit - 1.0).abs() < 0.01,
            "{radiance:?}: mean {mean} vs {limit}"
        );
        assert!(
            worst < 0.05,
            "{radiance:?}: worst texel {worst} off the limit"
        );
        // The volume as a radiance source: ρ/π E on a wall.
        let q = nrc_render::RadianceQuery {
            position: Vec3::new(0.2, -1.0, 0.1),
            direction: Vec3::Y,
            normal: Vec3::Y,
            roughness: 1.0,
            diffuse: Vec3::splat(rho),
            specular: Vec3::ZERO,
        };
        let l = nrc_render::RadianceSource::radiance(&fast, &[q])[0];
        assert!(
            (l.x / (rho / PI * limit) - 1.0).abs() < 0.03,
            "{radiance:?}: {l}"
        );
    }
}

/// A room `[0, 2] × [0, 1] × [0, 1]` (floor, ceiling and a point light), optionally split by a
/// wall at `x = 1`; double-sided surfaces (a probe that sees a single-sided back face counts
/// itself inside geometry).
fn point_lit_room(wall: bool) -> nrc_scene::Scene {
    let mut b = SceneBuilder::new();
    let m = b.material(nrc_scene::Material {
        double_sided: true,
        ..mat::diffuse(Vec3::splat(0.6))
    });
    b.mesh(
        &Mesh::quad(
            Vec3::new(1.0, 0.0, 0.5),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -0.5),
        ),
        m,
        true,
    )
    .mesh(
        &Mesh::quad(
            Vec3::new(1.0, 1.0, 0.5),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 0.5),
        ),
        m,
        true,
    );
    if wall {
        b.mesh(
            &Mesh::quad(
                Vec3::new(1.0, 0.5, 0.5),
                Vec3::new(0.0, 0.5, 0.0),
                Vec3::new(0.0, 0.0, 0.5),
            ),
            m,
            true,
        );
    }
    b.camera(Vec3::new(1.0, 0.5, 3.0), Vec3::new(1.0, 0.5, 0.5), 60.0);
    b.desc_mut().lights.push(nrc_scene::PunctualLight {
        kind: nrc_scene::PunctualKind::Point,
        position: Vec3::new(0.4, 0.8, 0.5),
        direction: -Vec3::Y,
        intensity: Vec3::splat(1.0),
        range: None,
    });
    b.build()
}

/// A wall between a probe and the shading point drives that probe's weight to the floor: two
/// probes at x = 0.5 and 1.5, a floor point at x = 0.9 (left of the wall at x = 1). Without the
/// wall the far probe keeps a trilinear share; with it, the Chebyshev bound from its distance
/// moments (the wall at 0.56 along the direction to the point, the point at 0.67) crushes it.
#[test]
fn a_wall_between_probe_and_point_drives_the_visibility_weight_to_the_floor() {
    let weight_of_far_probe = |wall: bool| {
        let scene = point_lit_room(wall);
        let settings = DdgiSettings {
            counts: Some(UVec3::new(2, 1, 1)),
            ..Default::default()
        };
        let mut v = ProbeVolume::new(&scene.bounds(), settings).unwrap();
        for f in 0..4 {
            v.update(&scene, f);
        }
        let w = v.probe_weights(Vec3::new(0.9, 0.0, 0.5), Vec3::Y, Vec3::Y);
        w.iter()
            .filter(|(p, _)| *p == 1)
            .map(|(_, w)| *w)
            .sum::<f32>()
    };
    let (open, walled) = (weight_of_far_probe(false), weight_of_far_probe(true));
    println!("far probe's weight: open {open:.4}, behind the wall {walled:.4}");
    assert!(open > 0.2, "{open}");
    assert!(walled < 0.02, "{walled}");
}

/// Renders `frames` frames of `pass` (the probes updating each frame) and returns the last.
fn render_frames(
    scene: &nrc_scene::Scene,
    pass: &str,
    w: u32,
    h: u32,
    frames: u32,
) -> nrc_scene::Image {
    let spec: nrc_render::PassSpec = pass.parse().unwrap();
    let mut p = spec.build(&nrc_render::PathTracer::default());
    let mut last = None;
    for f in 0..frames {
        let input = nrc_render::FrameInput {
            scene,
            camera: &scene.camera,
            width: w,
            height: h,
            spp: 4,
            seed: nrc_render::pass_seed(7, f),
            emitter_samples: 0,
            sequence: None,
        };
        last = Some(nrc_render::passes::run(p.as_mut(), &input, &nrc_render::ZeroSource).image);
    }
    last.unwrap()
}

/// relMSE (ε = 0.01) of `img` against `reference` over the pixels `mask` does not mark.
fn rel_mse_off_emitters(
    img: &nrc_scene::Image,
    reference: &nrc_scene::Image,
    mask: &[bool],
) -> f64 {
    let (mut sum, mut n) = (0.0f64, 0);
    for ((a, b), m) in img.data.iter().zip(&reference.data).zip(mask) {
        if !*m {
            for c in 0..3 {
                sum += ((a[c] - b[c]) as f64).powi(2) / ((b[c] as f64).powi(2) + 0.01);
                n += 1;
            }
        }
    }
    sum / n as f64
}

/// `ddgi-secondary` in the enclosure: with converged eq. 5 probes the secondary vertex's
/// radiance is exact, so the image is `L_e / (1 − ρ) = 2` everywhere (mean within 1 %).
#[test]
fn ddgi_secondary_renders_the_enclosure_exactly() {
    let scene = common::enclosure(Vec3::X);
    let img = render_frames(&scene, "ddgi-secondary:probes=3,hysteresis=0.5", 16, 16, 20);
    let mean = img.data.iter().map(|p| p.x as f64).sum::<f64>() / img.data.len() as f64;
    println!("ddgi-secondary in the enclosure: mean {mean:.4} (exact 2)");
    assert!((mean / 2.0 - 1.0).abs() < 0.01, "{mean}");
}

/// `ddgi-secondary` on the Cornell box: its error against the path-traced reference falls as
/// the probe grid densifies, 4³ → 8³ → 16³ (relMSE of the emitter-excluded image; 16 frames
/// of probe updates, 4 spp).
#[test]
fn ddgi_secondary_error_falls_as_the_probe_grid_densifies() {
    let scene = nrc_scene::Scene::load(&common::project_scenes().join("cornell-box.gltf")).unwrap();
    let (w, h) = (32, 32);
    let reference =
        common::render_scene(&scene, &nrc_render::PathTracer::default(), w, h, 1024, 3).mean;
    let mask = nrc_render::emitters::emitter_pixels(&scene, w, h);
    let rel_mse = |img: &nrc_scene::Image| rel_mse_off_emitters(img, &reference, &mask);
    let errors: Vec<f64> = [4, 8, 16]
        .iter()
        .map(|n| {
            rel_mse(&render_frames(
                &scene,
                &format!("ddgi-secondary:probes={n},rays=128,hysteresis=0.8"),
                w,
                h,
                16,
            ))
        })
        .collect();
    println!("ddgi-secondary relMSE with 4³, 8³, 16³ probes: {errors:.4?}");
    assert!(errors[1] < errors[0] && errors[2] < errors[1], "{errors:?}");
}

/// A probe under an emissive disc (radius 1, height 1 above it, `L_e = 1`, a 64-gon facing
/// down; nothing else lit): the uniform cone of half-angle α = 45° gives the irradiance
/// `π L_e sin²α cos θ` (Nusselt) for every normal within `90° − α` of the axis. After 100 eq. 5
/// updates at hysteresis 0.9, the probe's texels within 40° of the axis agree within 3 %.
/// With §3.3's attenuation at `s = 1` the same texels hold a quarter of that (see below).
#[test]
fn a_probe_under_an_emissive_disc_matches_the_closed_form() {
    let mut b = SceneBuilder::new();
    let light = b.material(mat::emissive(Vec3::ZERO, Vec3::ONE, false));
    let black = b.material(mat::diffuse(Vec3::ZERO));
    let mut disc = Mesh::default();
    let segments = 64;
    for k in 0..segments {
        let (a0, a1) = (
            2.0 * PI * k as f32 / segments as f32,
            2.0 * PI * (k + 1) as f32 / segments as f32,
        );
        let (p0, p1) = (
            Vec3::new(a0.cos(), 1.0, a0.sin()),
            Vec3::new(a1.cos(), 1.0, a1.sin()),
        );
        // A degenerate quad (centre twice) is the triangle (centre, p0, p1), facing down.
        disc.add_quad(
            [Vec3::new(0.0, 1.0, 0.0), p0, p1, Vec3::new(0.0, 1.0, 0.0)],
            -Vec3::Y,
        );
    }
    b.mesh(&disc, light, false)
        // A wide black floor below sets the box (the probe sits at its centre, the origin).
        .mesh(
            &Mesh::quad(
                Vec3::new(0.0, -1.0, 0.0),
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(0.0, 0.0, -10.0),
            ),
            black,
            false,
        )
        .camera(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 60.0);
    let scene = b.build();
    let texels = |attenuation: f32| {
        let settings = DdgiSettings {
            counts: Some(UVec3::ONE),
            hysteresis: 0.9,
            attenuation,
            ..Default::default()
        };
        let mut v = ProbeVolume::new(&scene.bounds(), settings).unwrap();
        for f in 0..100 {
            v.update(&scene, 500 + f);
        }
        v.irradiance_texels(0)
    };
    let polygon = segments as f32 / (2.0 * PI) * (2.0 * PI / segments as f32).sin();
    let (mut checked, mut worst) = (0, 0.0f32);
    // §3.3's attenuation at s = 1: the floor lies as far below the probe as the disc above it
    // in every direction of the cone, so each disc ray's emission is scaled by (t / 2t)² = ¼.
    let (mut lowest, mut highest) = (f32::INFINITY, 0.0f32);
    for ((n, e), (_, e_att)) in texels(0.0).into_iter().zip(texels(1.0)) {
        let cos = n.dot(Vec3::Y);
        if cos < 40f32.to_radians().cos() {
            continue;
        }
        // sin²α of the cone, its area scaled by the 64-gon's (inscribed) area.
        let expect = PI * 0.5 * polygon * cos;
        worst = worst.max((e.x / expect - 1.0).abs());
        lowest = lowest.min(e_att.x / e.x);
        highest = highest.max(e_att.x / e.x);
        checked += 1;
    }
    println!(
        "disc: {checked} texels within 40° of the axis, worst relative error {:.2} %; attenuated (s = 1) by {lowest:.3} to {highest:.3} (expected about 0.25: the moments average 1/cos over their lobe, so b is a little above t)",
        100.0 * worst
    );
    assert!(checked >= 4, "{checked} texels checked");
    assert!(worst < 0.03, "worst {worst}");
    assert!(lowest > 0.2 && highest < 0.3, "{lowest} … {highest}");
}

/// Relocation and classification on the Cornell box (8³ probes, 256 rays). Without
/// relocation the probes inside the two blocks stay there (more than a quarter of their rays
/// hit back faces: the negative control); with it at least two thirds of them step out within
/// two updates (the rest lie deeper than the 0.45 of a cell a probe may move). Classification
/// switches off the probes whose eight cells hold no surface (the middle of the room) and
/// those still inside geometry, and keeps those by the walls: the update then traces fewer
/// rays, and the `ddgi-secondary` image loses nothing (relMSE within 10 % of the plain
/// volume's).
#[test]
fn relocation_leaves_geometry_and_classification_switches_off_empty_cells() {
    let scene = nrc_scene::Scene::load(&common::project_scenes().join("cornell-box.gltf")).unwrap();
    let inside = |relocate: bool| {
        let mut v = ProbeVolume::new(
            &scene.bounds(),
            DdgiSettings {
                counts: Some(UVec3::splat(8)),
                relocate,
                ..Default::default()
            },
        )
        .unwrap();
        let count = |v: &ProbeVolume| {
            (0..v.probe_count())
                .filter(|&p| v.probe_back_fraction(p) > 0.25)
                .count()
        };
        v.update(&scene, 1);
        let first = count(&v);
        v.update(&scene, 2);
        v.update(&scene, 3);
        (first, count(&v))
    };
    let (still_before, still_after) = inside(false);
    let (moved_before, moved_after) = inside(true);
    println!(
        "probes inside geometry: {still_before} → {still_after} without relocation, {moved_before} → {moved_after} with it"
    );
    assert!(still_before > 0 && still_after == still_before);
    assert_eq!(moved_before, still_before);
    assert!(3 * moved_after <= still_before);

    let mut v = ProbeVolume::new(
        &scene.bounds(),
        DdgiSettings {
            counts: Some(UVec3::splat(8)),
            classify: true,
            relocate: true,
            ..Default::default()
        },
    )
    .unwrap();
    let all = v.update(&scene, 1).closest_rays;
    v.update(&scene, 2);
    let after = v.update(&scene, 3).closest_rays;
    let off = (0..v.probe_count()).filter(|&p| !v.probe_active(p)).count();
    println!(
        "classification: {off} of {} probes off, rays per update {all} → {after}",
        v.probe_count()
    );
    assert!(off > 0 && off < v.probe_count());
    assert!(after < all);
    // The probes relocation could not free (deeper in a block than 0.45 of a cell) are off.
    assert!((0..v.probe_count()).all(|p| !v.probe_active(p) || v.probe_back_fraction(p) <= 0.25));

    let (w, h) = (32, 32);
    let reference =
        common::render_scene(&scene, &nrc_render::PathTracer::default(), w, h, 1024, 3).mean;
    let mask = nrc_render::emitters::emitter_pixels(&scene, w, h);
    let rel_mse = |pass: &str| {
        rel_mse_off_emitters(&render_frames(&scene, pass, w, h, 16), &reference, &mask)
    };
    let plain = rel_mse("ddgi-secondary:probes=8,rays=128,hysteresis=0.8");
    let classified =
        rel_mse("ddgi-secondary:probes=8,rays=128,hysteresis=0.8,classify=1,relocate=1");
    println!("ddgi-secondary relMSE: {plain:.4} plain, {classified:.4} classified and relocated");
    assert!(classified < 1.1 * plain, "{classified} against {plain}");
}

#[test]
fn rays_per_probe_follow_the_frame_where_the_settings_leave_them_open() {
    use nrc_render::ddgi::auto_rays;
    // A quarter of the frame's pixels over the probes, in multiples of 32 within [32, 256]:
    // the kitchen's 144 probes at 160 × 90 (25 → 32), 320 × 180 (100 → 128), 640 × 360
    // (400 → 256); the seed paper's 2,048 probes at 1920 × 1080 (253 → 256).
    assert_eq!(auto_rays(160 * 90, 144), 32);
    assert_eq!(auto_rays(320 * 180, 144), 128);
    assert_eq!(auto_rays(640 * 360, 144), 256);
    assert_eq!(auto_rays(1920 * 1080, 2048), 256);
    assert_eq!(auto_rays(0, 0), 32);
    let scene = point_lit_room(false);
    let open = DdgiSettings {
        counts: Some(UVec3::new(2, 2, 2)),
        ..Default::default()
    };
    let mut v = ProbeVolume::new(&scene.bounds(), open).unwrap();
    // Until told the frame, the paper's 256.
    assert_eq!(v.rays, 256);
    v.fit_rays_to_frame(64 * 64);
    assert_eq!(v.rays, 128);
    let stats = v.update(&scene, 1);
    assert_eq!(
        stats.closest_rays,
        8 * 128,
        "each of the 8 probes traces its 128 rays"
    );
    // A count in the settings is kept whatever the frame.
    let set = DdgiSettings {
        rays_per_probe: Some(48),
        ..open
    };
    let mut v = ProbeVolume::new(&scene.bounds(), set).unwrap();
    v.fit_rays_to_frame(1920 * 1080);
    assert_eq!(v.rays, 48);
}

/// A volume sized to a frame: as many probes as the frame's ray budget (a quarter ray a pixel)
/// refreshes at 32 rays each within the sweep, at most 4,096, in near-cubic cells; a 1 m box
/// and a 100 m one get the same counts at the same frame (spaced to their extents), a 100 m
/// street ten times longer than it is wide gets them along its length; a flat box still gets
/// 2 along its thin axis.
#[test]
fn frame_sized_counts_follow_the_ray_budget_and_the_box() {
    use nrc_render::ddgi::{MAX_AUTO_PROBES, auto_counts};
    let count = |c: UVec3| (c.x * c.y * c.z) as usize;
    // The Country Kitchen's box at 160 × 90: 112 probes a frame, 16 frames.
    let kitchen = Vec3::new(6.92, 3.38, 8.65);
    let small = auto_counts(kitchen, 160 * 90, 16);
    assert!((1500..=1792).contains(&count(small)), "{small}");
    let spacing = kitchen / small.as_vec3();
    assert!(
        spacing.max_element() < 1.25 * spacing.min_element(),
        "{spacing}"
    );
    // At 640 × 360 the cap.
    let large = auto_counts(kitchen, 640 * 360, 16);
    assert!((3500..=MAX_AUTO_PROBES).contains(&count(large)), "{large}");
    // A longer sweep affords more probes at the same frame.
    assert!(count(auto_counts(kitchen, 160 * 90, 32)) > count(small));
    // The same frame in a 1 m box and a 100 m one: the same counts.
    let bx = auto_counts(Vec3::ONE, 128 * 128, 16);
    let street = auto_counts(Vec3::splat(100.0), 128 * 128, 16);
    assert_eq!(bx, street);
    let long = auto_counts(Vec3::new(100.0, 10.0, 10.0), 128 * 128, 16);
    assert!(long.x >= 8 * long.y, "{long}");
    // Flat: 2 along the thin axis, the rest spread over the other two; tiny frames and
    // degenerate boxes: the floor of 2 × 2 × 2.
    let flat = auto_counts(Vec3::new(10.0, 0.0, 10.0), 160 * 90, 16);
    assert!(flat.y == 2 && flat.x >= 20 && flat.x == flat.z, "{flat}");
    assert_eq!(auto_counts(Vec3::ONE, 1, 1), UVec3::splat(2));
    assert_eq!(auto_counts(Vec3::ZERO, 160 * 90, 16), UVec3::splat(2));
    assert_eq!(
        auto_counts(Vec3::splat(f32::NAN), 160 * 90, 16),
        UVec3::splat(2)
    );
    // A sweep of 0 is refused with a message naming it, by the volume and by the pass.
    let unit = nrc_scene::Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };
    let zero = DdgiSettings {
        sweep: 0,
        ..Default::default()
    };
    let e = ProbeVolume::for_frame(&unit, zero, 64)
        .unwrap_err()
        .to_string();
    assert!(e.contains("sweep"), "{e}");
    let e = "ddgi-restir:sweep=0"
        .parse::<nrc_render::PassSpec>()
        .unwrap_err()
        .to_string();
    assert!(e.contains("sweep"), "{e}");
}

/// Where the frame's budget does not cover every probe, an update takes the next
/// `per_update` probes in turn: each update traces exactly those probes' rays, every probe
/// is updated once within the sweep, a probe not yet updated does not darken a query, and in
/// the enclosure the frame-sized volume converges to the same limit (within 1 %) as one that
/// updates every probe each frame.
#[test]
fn frame_sized_volumes_update_their_probes_in_turn_within_the_sweep() {
    let scene = common::enclosure(Vec3::X);
    let settings = DdgiSettings {
        hysteresis: 0.9,
        ..Default::default()
    };
    let pixels = 32 * 32;
    let mut v = ProbeVolume::for_frame(&scene.bounds(), settings, pixels).unwrap();
    let n = v.probe_count();
    // 256 rays a frame: 8 probes of 32 rays, at most 128 probes within 16 frames (5 × 5 × 5,
    // 0.4 apart, at -0.8, -0.4, ...).
    assert_eq!((v.counts, v.rays, v.per_update()), (UVec3::splat(5), 32, 8));
    let mut first_update = vec![None; n];
    for f in 0..16u32 {
        let stats = v.update(&scene, 300 + u64::from(f));
        assert_eq!(stats.closest_rays, 8 * 32, "frame {f}");
        for (p, seen) in first_update.iter_mut().enumerate() {
            if seen.is_none() && v.irradiance_texels(p).iter().any(|(_, e)| e.x > 0.0) {
                *seen = Some(f);
            }
        }
        if f == 0 {
            // Only the first 8 probes (z = -0.8) hold anything; a query between probe 0 and
            // the empty one above it, facing it, still sees probe 0's irradiance (π), not
            // the empty one's.
            let e = v.irradiance(Vec3::new(-0.8, -0.8, -0.6), Vec3::Z, Vec3::Z);
            assert!(e.x > 0.75 * PI, "{e}");
        }
    }
    assert!(first_update.iter().all(|f| f.is_some()), "{first_update:?}");
    for f in 0..(16 * 120) {
        v.update(&scene, 1000 + f);
    }
    let (mean, worst) = texel_stats(&v, 2.0 * PI);
    println!(
        "frame-sized, 120 sweeps: mean {mean:.4} (limit {:.4}), worst {worst:.3}",
        2.0 * PI
    );
    assert!((mean / (2.0 * PI) - 1.0).abs() < 0.01, "{mean}");
    // Rays set in the settings: the counts of `new` (8 along the longest axis); counts set:
    // kept. Either way every probe, every update.
    for (fixed, counts) in [
        (
            DdgiSettings {
                rays_per_probe: Some(32),
                ..settings
            },
            UVec3::splat(8),
        ),
        (
            DdgiSettings {
                counts: Some(UVec3::new(8, 4, 4)),
                ..settings
            },
            UVec3::new(8, 4, 4),
        ),
    ] {
        let v = ProbeVolume::for_frame(&scene.bounds(), fixed, pixels).unwrap();
        assert_eq!((v.counts, v.per_update()), (counts, v.probe_count()));
    }
    // A frame whose budget covers every probe at the floor updates them all, at the rays the
    // budget gives each (rounded down to a multiple of 32): the 125 probes at 128 × 128
    // (4,096 rays, 32.8 each → 32) and at 320 × 320 (25,600, 204.8 → 192).
    let mut v = ProbeVolume::for_frame(&scene.bounds(), settings, pixels).unwrap();
    v.fit_rays_to_frame(128 * 128);
    assert_eq!((v.rays, v.per_update()), (32, n));
    v.fit_rays_to_frame(320 * 320);
    assert_eq!((v.rays, v.per_update()), (192, n));
}

/// An update of a frame-sized volume is, probe for probe, the update a volume of the same
/// counts that updates every probe makes: after one update the traced probes' maps, places
/// and states (relocation and classification on) equal the full volume's bit for bit, the
/// others are untouched; the next update takes the next probes.
#[test]
fn a_frame_sized_update_is_the_full_update_restricted_to_its_probes() {
    let scene = point_lit_room(true);
    let settings = DdgiSettings {
        relocate: true,
        classify: true,
        ..Default::default()
    };
    let pixels = 48 * 48;
    let mut part = ProbeVolume::for_frame(&scene.bounds(), settings, pixels).unwrap();
    let (n, k) = (part.probe_count(), part.per_update());
    assert!(k < n && 2 * k <= n, "{n} probes, {k} an update");
    let mut full = ProbeVolume::new(
        &scene.bounds(),
        DdgiSettings {
            counts: Some(part.counts),
            rays_per_probe: Some(part.rays),
            ..settings
        },
    )
    .unwrap();
    let empty = part.clone();
    part.update(&scene, 11);
    full.update(&scene, 11);
    for p in 0..n {
        let source = if p < k { &full } else { &empty };
        assert_eq!(
            part.probe_irradiance(p),
            source.probe_irradiance(p),
            "probe {p}"
        );
        assert_eq!(part.probe_moments(p), source.probe_moments(p), "probe {p}");
        assert_eq!(part.probe_origin(p), source.probe_origin(p), "probe {p}");
        assert_eq!(part.probe_active(p), source.probe_active(p), "probe {p}");
        assert_eq!(part.probe_updates(p), u32::from(p < k), "probe {p}");
    }
    assert!(
        (0..k).any(|p| part.probe_origin(p) != empty.probe_origin(p) || !part.probe_active(p)),
        "the room's probes near its wall neither moved nor switched off: nothing was compared"
    );
    part.update(&scene, 12);
    assert!((0..n).all(|p| part.probe_updates(p) == u32::from(p < 2 * k)));
}
