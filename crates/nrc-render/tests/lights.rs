//! The lights of real glTF scenes, verified against closed forms and against each other:
//! furnaces under a constant environment, a point light's inverse-square law and a
//! directional light's cosine law per pixel, the three light strategies agreeing under an
//! environment map, a normal map shading as its normal says, and an alpha-masked quad
//! casting its masked shadow.
//!
//! Per-pixel bounds as in `furnace.rs`: `z · σ̂/√spp` with `z` Bonferroni-corrected over all
//! pixels and channels (the whole image passes with probability 1 − 10⁻⁴ when unbiased).

mod common;

use common::{Mesh, SceneBuilder, channels, mat, render_scene, test_sky, z_two_sided};
use glam::{Vec2, Vec3, Vec4};
use nrc_render::{LightStrategy, PathStats, PathTracer, PixelSampler, RenderOutput};
use nrc_scene::{
    AlphaMode, Environment, PunctualKind, PunctualLight, Ray, Scene, Texture, TextureRef,
    bsdf::Bsdf, sampling::Frame,
};
use std::f32::consts::PI;

/// Checks every pixel of `out` against `expected[pixel]` (per channel) within the Bonferroni
/// bound plus a relative allowance `rel` for the expectation's own quadrature error.
fn assert_pixels(out: &RenderOutput, spp: u32, expected: &[Vec3], rel: f64, what: &str) {
    let mean = channels(&out.mean);
    let var = channels(out.variance.as_ref().expect("variance requested"));
    let z = z_two_sided(1e-4 / mean.len() as f64);
    let mut worst = 0.0f64;
    for (i, (&m, &v)) in mean.iter().zip(&var).enumerate() {
        let e = expected[i / 3][i % 3] as f64;
        let se = (v / spp as f64).sqrt();
        let d = (m - e).abs();
        worst = worst.max(d / (z * se + rel * e.abs() + 1e-6));
        assert!(
            d <= z * se + rel * e.abs() + 1e-6,
            "{what}: pixel {} channel {}: mean {m:.5}, expected {e:.5}, se {se:.2e} (z bound {z:.2})",
            i / 3,
            i % 3
        );
    }
    println!("{what}: worst pixel at {worst:.2} of its bound");
}

/// The mean over a `k × k` grid of sub-pixel positions of `f(primary ray)` for every pixel.
fn pixel_average(scene: &Scene, w: u32, h: u32, k: u32, f: impl Fn(&Ray) -> Vec3) -> Vec<Vec3> {
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let mut sum = Vec3::ZERO;
            for j in 0..k {
                for i in 0..k {
                    let film = Vec2::new(
                        x as f32 + (i as f32 + 0.5) / k as f32,
                        y as f32 + (j as f32 + 0.5) / k as f32,
                    );
                    sum += f(&scene.camera.generate_ray(film, w, h));
                }
            }
            out.push(sum / (k * k) as f32);
        }
    }
    out
}

/// A sphere filling the whole frame (camera 3 radii away, 20° field of view): every primary
/// ray hits it. Flat facets, so the shading normal is the geometric one and no reflected ray
/// meets the (convex) sphere again.
fn sphere_filling_the_frame(m: nrc_scene::Material, env: Environment) -> Scene {
    let mut b = SceneBuilder::new();
    let id = b.material(m);
    b.mesh(&Mesh::sphere(Vec3::ZERO, 1.0, 48, 96), id, false)
        .camera(Vec3::new(0.0, 0.4, 3.0), Vec3::ZERO, 20.0);
    b.desc_mut().environment = env;
    b.build()
}

/// The directional albedo `∫ f(wo, wi) cos θi dωi` of `bsdf` as a function of `cos θo`,
/// tabulated at 65 points by a midpoint quadrature (512 × 512 in (cos θi, φ)).
fn albedo_table(bsdf: &Bsdf) -> Vec<f32> {
    (0..=64)
        .map(|k| {
            let mu = (k as f32 / 64.0).max(1e-3);
            let wo = Vec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
            let n = 512;
            let mut sum = 0.0f64;
            for a in 0..n {
                let c = (a as f32 + 0.5) / n as f32;
                let s = (1.0 - c * c).sqrt();
                for p in 0..n {
                    let phi = 2.0 * PI * (p as f32 + 0.5) / n as f32;
                    let wi = Vec3::new(s * phi.cos(), s * phi.sin(), c);
                    sum += (bsdf.eval(wo, wi).x * c) as f64;
                }
            }
            (sum * (2.0 * std::f64::consts::PI) / (n * n) as f64) as f32
        })
        .collect()
}

/// White furnace: a convex object under a constant environment of radiance 1 reflects, toward
/// every direction, exactly its directional albedo (no light is shadowed, none
/// interreflects). The white diffuse sphere's pixels are all 1; the rough conductor's (F0 = 1)
/// are its albedo at the pixel's viewing angle, tabulated by quadrature.
#[test]
fn white_furnace_under_a_constant_environment() {
    let (w, h, spp) = (24, 18, 64);
    let tracer = PathTracer::default();
    let diffuse =
        sphere_filling_the_frame(mat::diffuse(Vec3::ONE), Environment::constant(Vec3::ONE));
    assert_eq!(diffuse.light_count(), 1, "the environment is a light");
    let out = render_scene(&diffuse, &tracer, w, h, spp, 5);
    assert_eq!(out.stats.invalid_samples, 0);
    assert_pixels(
        &out,
        spp,
        &vec![Vec3::ONE; (w * h) as usize],
        1e-5,
        "diffuse furnace",
    );

    let metal = mat::metal(Vec3::ONE, 0.6);
    let scene = sphere_filling_the_frame(metal.clone(), Environment::constant(Vec3::ONE));
    let bsdf = Bsdf::from_pbr(&metal.pbr(&[], &[Vec2::ZERO; 2]));
    let table = albedo_table(&bsdf);
    assert!(
        table[32] < 0.99 && table[32] > 0.5,
        "rough conductor albedo {}",
        table[32]
    );
    let expected = pixel_average(&scene, w, h, 6, |ray| {
        let hit = scene.intersect(ray).expect("the sphere fills the frame");
        let si = scene.interaction(ray, &hit);
        let t = si.ns.dot(si.wo).clamp(0.0, 1.0) * 64.0;
        let (i, f) = (t.floor() as usize, t.fract());
        let a = if i >= 64 {
            table[64]
        } else {
            table[i] * (1.0 - f) + table[i + 1] * f
        };
        Vec3::splat(a)
    });
    let out = render_scene(&scene, &tracer, w, h, spp, 6);
    assert_pixels(&out, spp, &expected, 3e-3, "rough conductor furnace");
}

/// A diffuse floor `y = 0` (albedo ρ) seen from above, lit by one punctual light and
/// nothing else.
fn floor_under(light: PunctualLight, rho: f32) -> Scene {
    let mut b = SceneBuilder::new();
    let m = b.material(mat::diffuse(Vec3::splat(rho)));
    b.mesh(
        &Mesh::quad(
            Vec3::ZERO,
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -4.0),
        ),
        m,
        false,
    )
    .camera(Vec3::new(0.3, 2.0, 0.2), Vec3::new(0.0, 0.0, 0.0), 50.0);
    b.desc_mut().lights.push(light);
    b.build()
}

/// A point light of intensity I at height 1 over the diffuse floor: every pixel is
/// `ρ/π · I cos θ / d²` at the point it sees (the pixel footprint averaged over 8 × 8
/// sub-pixel points), the inverse-square law; BSDF sampling alone never finds the light.
#[test]
fn point_light_follows_the_inverse_square_law() {
    let rho = 0.6;
    let light = PunctualLight {
        kind: PunctualKind::Point,
        position: Vec3::new(0.2, 1.0, -0.1),
        direction: Vec3::NEG_Y,
        intensity: Vec3::new(2.0, 1.0, 0.5),
        range: None,
    };
    let scene = floor_under(light, rho);
    let (w, h, spp) = (20, 16, 32);
    let expected = pixel_average(&scene, w, h, 8, |ray| {
        let Some(hit) = scene.intersect(ray) else {
            return Vec3::ZERO;
        };
        let p = ray.at(hit.t);
        let d = light.position - p;
        light.intensity * (rho / PI) * (d.y / d.length()) / d.length_squared()
    });
    let out = render_scene(&scene, &PathTracer::default(), w, h, spp, 2);
    assert_pixels(&out, spp, &expected, 2e-3, "point light");
    let bsdf_only = PathTracer {
        strategy: LightStrategy::BsdfOnly,
        ..PathTracer::default()
    };
    let dark = render_scene(&scene, &bsdf_only, w, h, 4, 2);
    assert!(
        dark.mean.data.iter().all(|p| *p == Vec3::ZERO),
        "BSDF sampling hit a delta light"
    );
}

/// A directional light of irradiance E at 40° from the vertical over the diffuse floor:
/// every pixel is `ρ/π · E cos θ` (the floor is lit evenly).
#[test]
fn directional_light_follows_the_cosine_law() {
    let rho = 0.5;
    let theta = 40f32.to_radians();
    let light = PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: Vec3::new(theta.sin(), -theta.cos(), 0.0),
        intensity: Vec3::new(3.0, 2.0, 1.0),
        range: None,
    };
    let scene = floor_under(light, rho);
    let (w, h, spp) = (20, 16, 8);
    let expected = pixel_average(&scene, w, h, 1, |ray| {
        if scene.intersect(ray).is_some() {
            light.intensity * (rho / PI) * theta.cos()
        } else {
            Vec3::ZERO
        }
    });
    let out = render_scene(&scene, &PathTracer::default(), w, h, spp, 3);
    assert_pixels(&out, spp, &expected, 1e-4, "directional light");
}

/// Under an environment map, next-event estimation alone, BSDF sampling alone and their MIS
/// combination are three unbiased estimators of the same image: their means agree per pixel
/// (Bonferroni-corrected z-test of the difference) and on the image mean.
#[test]
fn nee_bsdf_and_mis_agree_under_an_environment_map() {
    let mut b = SceneBuilder::new();
    let floor = b.material(mat::diffuse(Vec3::new(0.7, 0.6, 0.5)));
    let ball = b.material(mat::plastic(Vec3::new(0.8, 0.3, 0.2), 0.4));
    b.mesh(
        &Mesh::quad(
            Vec3::ZERO,
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -3.0),
        ),
        floor,
        false,
    )
    .mesh(
        &Mesh::sphere(Vec3::new(0.0, 0.5, 0.0), 0.5, 16, 32),
        ball,
        true,
    )
    .camera(Vec3::new(0.0, 1.2, 2.5), Vec3::new(0.0, 0.4, 0.0), 50.0);
    b.desc_mut().environment = test_sky(32);
    let scene = b.build();
    let (w, h, spp) = (16, 12, 256);
    let render = |strategy, seed| {
        let t = PathTracer {
            strategy,
            max_depth: 4,
            ..PathTracer::default()
        };
        render_scene(&scene, &t, w, h, spp, seed)
    };
    let mis = render(LightStrategy::Mis, 1);
    let nee = render(LightStrategy::LightOnly, 2);
    let bsdf = render(LightStrategy::BsdfOnly, 3);
    let z = z_two_sided(1e-4 / (2 * w * h * 3) as f64);
    for (name, other) in [("nee", &nee), ("bsdf", &bsdf)] {
        let (a, va) = (
            channels(&mis.mean),
            channels(mis.variance.as_ref().unwrap()),
        );
        let (b, vb) = (
            channels(&other.mean),
            channels(other.variance.as_ref().unwrap()),
        );
        let (mut diff, mut var) = ([0.0f64; 3], [0.0f64; 3]);
        for i in 0..a.len() {
            let se = ((va[i] + vb[i]) / spp as f64).sqrt();
            assert!(
                (a[i] - b[i]).abs() <= z * se + 1e-6,
                "{name} vs mis: pixel {} channel {}: {:.4} vs {:.4} ({:.1} se)",
                i / 3,
                i % 3,
                b[i],
                a[i],
                (a[i] - b[i]) / se
            );
            diff[i % 3] += a[i] - b[i];
            var[i % 3] += (va[i] + vb[i]) / spp as f64;
        }
        for c in 0..3 {
            let zc = diff[c] / var[c].sqrt();
            println!("{name} vs mis: image mean channel {c} differs by {zc:+.2} se");
            assert!(
                zc.abs() < 4.0,
                "{name} vs mis: image mean channel {c}: {zc:.2} se"
            );
        }
    }
    assert!(
        mis.mean.mean().min_element() > 0.05,
        "the sky lights the scene"
    );
}

/// A tangent-space normal map on a plane: the shading normal is `T x + B y + N z` of the
/// texel's normal (the MikkTSpace tangent along +u), and a directional light shades the plane
/// with that normal's cosine, not the geometric one's.
#[test]
fn a_normal_mapped_plane_shades_as_the_mapped_normal_says() {
    let tilt = 0.5f32;
    let mapped = Vec3::new(tilt.sin(), 0.0, tilt.cos());
    let encoded = (mapped * 0.5 + Vec3::splat(0.5)).extend(1.0);
    let mut b = SceneBuilder::new();
    let mut m = mat::diffuse(Vec3::splat(0.8));
    m.normal_texture = Some(TextureRef {
        texture: 0,
        transform: None,
        tex_coord: 0,
    });
    let id = b.material(m);
    // The floor y = 0 with u along +x, v along +z: T = +x, N = +y, B = N × T = −z.
    b.mesh(
        &Mesh::quad(
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -2.0),
        ),
        id,
        false,
    )
    .camera(Vec3::new(0.0, 2.0, 0.01), Vec3::ZERO, 40.0);
    let light = PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: Vec3::new(-0.6, -0.8, 0.0),
        intensity: Vec3::ONE,
        range: None,
    };
    {
        let d = b.desc_mut();
        d.uvs = d.positions.iter().map(|p| Vec2::new(p.x, p.z)).collect();
        d.textures.push(Texture::new(1, 1, vec![encoded]).unwrap());
        d.lights.push(light);
    }
    let scene = b.build();
    let ray = Ray::new(Vec3::new(0.1, 1.0, 0.1), Vec3::NEG_Y);
    let si = scene.interaction(&ray, &scene.intersect(&ray).unwrap());
    let want = Vec3::new(tilt.sin(), tilt.cos(), 0.0);
    assert!(
        (si.ns - want).length() < 1e-3,
        "shading normal {} vs {want}",
        si.ns
    );
    assert_eq!(si.ng, Vec3::Y);
    let (w, h) = (8, 6);
    let out = render_scene(&scene, &PathTracer::default(), w, h, 4, 1);
    let cos_mapped = want.dot(-light.direction);
    let cos_flat = Vec3::Y.dot(-light.direction);
    assert!((cos_mapped - cos_flat).abs() > 0.1);
    let expected = vec![Vec3::splat(0.8 / PI * cos_mapped); (w * h) as usize];
    assert_pixels(&out, 4, &expected, 1e-4, "normal-mapped plane");
}

/// A quad cut by alphaMode MASK (alpha 0 on its x < 0 half, 1 on the other) over a floor lit
/// straight from above: rays and shadow rays pass the cut-away half, so next-event estimation
/// at floor points finds the light under it and a shadow under the solid half; a camera ray
/// through the cut-away half reaches the floor.
#[test]
fn a_masked_quad_casts_the_masked_shadow() {
    let mut b = SceneBuilder::new();
    let floor = b.material(mat::diffuse(Vec3::splat(0.5)));
    let mut cut = mat::diffuse(Vec3::splat(0.5));
    cut.alpha_mode = AlphaMode::Mask;
    cut.alpha_cutoff = 0.5;
    cut.double_sided = true;
    cut.base_color_texture = Some(TextureRef {
        texture: 0,
        transform: None,
        tex_coord: 0,
    });
    let cut = b.material(cut);
    b.mesh(
        &Mesh::quad(
            Vec3::ZERO,
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -3.0),
        ),
        floor,
        false,
    )
    .mesh(
        &Mesh::quad(
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -1.0),
        ),
        cut,
        false,
    )
    .camera(Vec3::new(0.0, 3.0, 0.01), Vec3::ZERO, 40.0);
    {
        let d = b.desc_mut();
        // u = (x + 1)/2 over the quad [-1, 1]; the floor's coordinates do not matter.
        d.uvs = d
            .positions
            .iter()
            .map(|p| Vec2::new((p.x + 1.0) / 2.0, 0.5))
            .collect();
        let mut t = Texture::new(
            2,
            1,
            vec![Vec4::new(1.0, 1.0, 1.0, 0.0), Vec4::new(1.0, 1.0, 1.0, 1.0)],
        )
        .unwrap();
        t.nearest = true;
        d.textures.push(t);
        d.lights.push(PunctualLight {
            kind: PunctualKind::Directional,
            position: Vec3::ZERO,
            direction: Vec3::NEG_Y,
            intensity: Vec3::ONE,
            range: None,
        });
    }
    let scene = b.build();
    let direct_at = |x: f32| {
        let ray = Ray::new(Vec3::new(x, 0.5, -0.2), Vec3::NEG_Y);
        let hit = scene.intersect(&ray).unwrap();
        let si = scene.interaction(&ray, &hit);
        assert_eq!(si.ng, Vec3::Y, "the ray below the quad reaches the floor");
        let bsdf = Bsdf::from_pbr(&scene.pbr(&si));
        let frame = Frame::from_normal(si.ns);
        let mut sampler = PixelSampler::new(1, 0, 0);
        nrc_render::nee::next_event(
            &scene,
            &si,
            &bsdf,
            &frame,
            frame.to_local(si.wo),
            true,
            nrc_render::nee::Counts::ONE,
            sampler.next_1d(),
            sampler.next_2d(),
            &mut PathStats::default(),
        )
    };
    let lit = Vec3::splat(0.5 / PI);
    assert!(
        (direct_at(-0.5) - lit).length() < 1e-5,
        "under the cut-away half: {}",
        direct_at(-0.5)
    );
    assert_eq!(direct_at(0.5), Vec3::ZERO, "under the solid half");
    assert!((direct_at(-1.5) - lit).length() < 1e-5, "beside the quad");
    // From above: through the cut-away half to the floor, stopped by the solid half.
    let down = |x: f32| {
        scene
            .intersect(&Ray::new(Vec3::new(x, 2.0, -0.2), Vec3::NEG_Y))
            .unwrap()
            .t
    };
    assert!((down(-0.5) - 2.0).abs() < 1e-4);
    assert!((down(0.5) - 1.0).abs() < 1e-4);
}
