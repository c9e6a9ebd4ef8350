//! Test scenes built in memory (`nrc_scene::SceneDescription`) and statistics helpers
//! shared by the render tests.

#![allow(dead_code)]

use glam::Vec3;
use nrc_render::passes::{self, FrameInput, PassSpec};
use nrc_render::{
    PathTracer, PixelSampler, RadianceSource, RenderOutput, RenderSettings, ZeroSource, render,
};
use nrc_scene::{Camera, Image, Scene, SceneDescription};
use std::path::PathBuf;

/// Material shorthands (glTF metallic-roughness parameters).
pub mod mat {
    use glam::Vec3;
    use nrc_scene::Material;

    /// A purely diffuse (Lambertian) material of albedo `rho`.
    pub fn diffuse(rho: Vec3) -> Material {
        Material {
            base_color: rho,
            metallic: 0.0,
            roughness: 1.0,
            specular: 0.0,
            ..Default::default()
        }
    }

    /// A diffuse emitter of albedo `rho` emitting radiance `le` from its front face (or both).
    pub fn emissive(rho: Vec3, le: Vec3, double_sided: bool) -> Material {
        Material {
            emissive: le,
            double_sided,
            ..diffuse(rho)
        }
    }

    /// A smooth or rough clear dielectric of index `ior`.
    pub fn glass(ior: f32, roughness: f32) -> Material {
        Material {
            metallic: 0.0,
            roughness,
            transmission: 1.0,
            ior,
            ..Default::default()
        }
    }

    /// A GGX conductor of normal reflectance `f0`.
    pub fn metal(f0: Vec3, roughness: f32) -> Material {
        Material {
            base_color: f0,
            metallic: 1.0,
            roughness,
            ..Default::default()
        }
    }

    /// glTF's blend: a diffuse base under a dielectric GGX layer.
    pub fn plastic(base: Vec3, roughness: f32) -> Material {
        Material {
            base_color: base,
            metallic: 0.0,
            roughness,
            ..Default::default()
        }
    }
}

/// A triangle mesh in world space.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub indices: Vec<u32>,
}

impl Mesh {
    /// An axis-aligned box `[lo, hi]` with faces wound (and flat normals pointing) inward
    /// when `inward`, outward otherwise.
    pub fn cuboid(lo: Vec3, hi: Vec3, inward: bool) -> Self {
        let mut m = Mesh::default();
        let c = (lo + hi) * 0.5;
        for axis in 0..3 {
            for side in [-1.0f32, 1.0] {
                let mut n = Vec3::ZERO;
                n[axis] = side;
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let corner = |a: f32, b: f32| {
                    let mut p = c;
                    p[axis] = if side > 0.0 { hi[axis] } else { lo[axis] };
                    p[u] = if a > 0.0 { hi[u] } else { lo[u] };
                    p[v] = if b > 0.0 { hi[v] } else { lo[v] };
                    p
                };
                let quad = [
                    corner(-1.0, -1.0),
                    corner(1.0, -1.0),
                    corner(1.0, 1.0),
                    corner(-1.0, 1.0),
                ];
                m.add_quad(quad, if inward { -n } else { n });
            }
        }
        m
    }

    /// Adds a planar quad, wound counter-clockwise around `normal`.
    pub fn add_quad(&mut self, q: [Vec3; 4], normal: Vec3) {
        let base = self.positions.len() as u32;
        let geometric = (q[1] - q[0]).cross(q[2] - q[0]);
        let order: [usize; 4] = if geometric.dot(normal) >= 0.0 {
            [0, 1, 2, 3]
        } else {
            [0, 3, 2, 1]
        };
        for i in order {
            self.positions.push(q[i]);
            self.normals.push(normal.normalize());
        }
        self.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }

    /// A quad centred at `c` spanned by half-extents `a` and `b`, facing `a × b`.
    pub fn quad(c: Vec3, a: Vec3, b: Vec3) -> Self {
        let mut m = Mesh::default();
        m.add_quad([c - a - b, c + a - b, c + a + b, c - a + b], a.cross(b));
        m
    }

    /// A UV sphere with smooth outward normals.
    pub fn sphere(center: Vec3, radius: f32, rings: u32, segments: u32) -> Self {
        let mut m = Mesh::default();
        for r in 0..=rings {
            let theta = std::f32::consts::PI * r as f32 / rings as f32;
            for s in 0..=segments {
                let phi = std::f32::consts::TAU * s as f32 / segments as f32;
                let n = Vec3::new(
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                );
                m.positions.push(center + radius * n);
                m.normals.push(n);
            }
        }
        let row = segments + 1;
        for r in 0..rings {
            for s in 0..segments {
                let (a, b) = (r * row + s, (r + 1) * row + s);
                // Counter-clockwise seen from outside.
                if r != 0 {
                    m.indices.extend_from_slice(&[a, a + 1, b]);
                }
                if r + 1 != rings {
                    m.indices.extend_from_slice(&[a + 1, b + 1, b]);
                }
            }
        }
        m
    }
}

/// Collects meshes and materials into a [`Scene`].
#[derive(Default)]
pub struct SceneBuilder {
    desc: SceneDescription,
}

impl SceneBuilder {
    pub fn new() -> Self {
        Self {
            desc: SceneDescription {
                source: PathBuf::from("<test scene>"),
                ..Default::default()
            },
        }
    }

    /// Adds a material; returns its index.
    pub fn material(&mut self, m: nrc_scene::Material) -> u32 {
        self.desc.materials.push(m);
        self.desc.materials.len() as u32 - 1
    }

    /// Adds a mesh with one material. `smooth`: keep its vertex normals (else flat shading).
    pub fn mesh(&mut self, mesh: &Mesh, material: u32, smooth: bool) -> &mut Self {
        let base = self.desc.positions.len() as u32;
        self.desc.positions.extend_from_slice(&mesh.positions);
        let normals: Vec<Vec3> = if smooth && !mesh.normals.is_empty() {
            mesh.normals.clone()
        } else {
            vec![Vec3::ZERO; mesh.positions.len()]
        };
        self.desc.normals.extend(normals);
        self.desc
            .mesh_names
            .push(format!("mesh {}", self.desc.mesh_names.len()));
        let mesh_index = self.desc.mesh_names.len() as u32 - 1;
        for t in mesh.indices.chunks_exact(3) {
            self.desc
                .triangles
                .push([base + t[0], base + t[1], base + t[2]]);
            self.desc.triangle_materials.push(material);
            self.desc.triangle_meshes.push(mesh_index);
        }
        self
    }

    pub fn camera(&mut self, pos: Vec3, target: Vec3, fov_y_deg: f32) -> &mut Self {
        self.desc.camera = Some(Camera::look_at(pos, target, Vec3::Y, fov_y_deg).unwrap());
        self
    }

    pub fn background(&mut self, b: Vec3) -> &mut Self {
        self.desc.environment = nrc_scene::Environment::constant(b);
        self
    }

    /// The description being built, for what the builder has no method for (lights, an
    /// environment map, texture coordinates, textures).
    pub fn desc_mut(&mut self) -> &mut SceneDescription {
        &mut self.desc
    }

    pub fn build(&self) -> Scene {
        Scene::from_description(self.desc.clone()).unwrap()
    }
}

/// Renders `scene` with its camera at `w × h`, `spp` samples, per-pixel variance on.
pub fn render_scene(
    scene: &Scene,
    tracer: &PathTracer,
    w: u32,
    h: u32,
    spp: u32,
    seed: u64,
) -> RenderOutput {
    let settings = RenderSettings {
        width: w,
        height: h,
        spp,
        seed,
        variance: true,
        sequence: None,
    };
    render(scene, &scene.camera, tracer, &settings, &|_| {})
}

/// The two-sided standard-normal quantile for a two-sided tail probability `alpha`
/// (Acklam's rational approximation of the inverse normal CDF, relative error < 1.2e-9).
pub fn z_two_sided(alpha: f64) -> f64 {
    let p = alpha / 2.0;
    // Lower-tail quantile of p, then negate.
    let a = [
        -3.969683028665376e+01,
        2.209460984245205e+02,
        -2.759285104469687e+02,
        1.383577518672690e+02,
        -3.066479806614716e+01,
        2.506628277459239e+00,
    ];
    let b = [
        -5.447609879822406e+01,
        1.615858368580409e+02,
        -1.556989798598866e+02,
        6.680131188771972e+01,
        -1.328068155288572e+01,
    ];
    let c = [
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e+00,
        -2.549732539343734e+00,
        4.374664141464968e+00,
        2.938163982698783e+00,
    ];
    let d = [
        7.784695709041462e-03,
        3.224671290700398e-01,
        2.445134137142996e+00,
        3.754408661907416e+00,
    ];
    let q = if p < 0.02425 {
        let q = (-2.0 * p.ln()).sqrt();
        (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
            / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0)
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q
            / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)
    };
    -q
}

/// Per-channel pixel values of an image as f64, flattened.
pub fn channels(img: &Image) -> Vec<f64> {
    img.data
        .iter()
        .flat_map(|p| [p.x as f64, p.y as f64, p.z as f64])
        .collect()
}

/// The folder of third-party scenes, if present.
pub fn shared_scenes() -> Option<PathBuf> {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    p.is_dir().then_some(p)
}

/// The project's shipped scenes folder.
pub fn project_scenes() -> PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

/// An environment map for tests: a sky gradient with a soft bright sun, `2n × n` texels.
pub fn test_sky(n: usize) -> nrc_scene::Environment {
    let (w, h) = (2 * n, n);
    let sun = Vec3::new(0.5, 0.6, -0.62).normalize();
    let texels = (0..w * h)
        .map(|i| {
            let uv = glam::Vec2::new(
                ((i % w) as f32 + 0.5) / w as f32,
                ((i / w) as f32 + 0.5) / h as f32,
            );
            let d = nrc_scene::environment::uv_to_direction(uv);
            let sky = Vec3::new(0.3, 0.5, 0.9) * (0.4 + 0.6 * d.y.max(0.0)) + Vec3::splat(0.05);
            let glow = (d.dot(sun) - 0.9).max(0.0) * 60.0;
            sky + Vec3::new(1.0, 0.9, 0.7) * glow
        })
        .collect();
    nrc_scene::Environment::from_texels(std::path::Path::new("<test sky>"), w, h, texels, 1.0, 30.0)
        .unwrap()
        .0
}

/// The last of `frames` frames of `spec` (state restarted first), seed `seed`.
pub fn last_frame(
    scene: &Scene,
    spec: &PassSpec,
    tracer: &PathTracer,
    w: u32,
    h: u32,
    frames: u32,
    seed: u64,
) -> Image {
    last_frame_with(scene, spec, tracer, w, h, frames, seed, &ZeroSource)
}

/// [`last_frame`] with the queries answered by `source`.
#[allow(clippy::too_many_arguments)]
pub fn last_frame_with(
    scene: &Scene,
    spec: &PassSpec,
    tracer: &PathTracer,
    w: u32,
    h: u32,
    frames: u32,
    seed: u64,
    source: &dyn RadianceSource,
) -> Image {
    let mut pass = spec.build(tracer);
    accumulate_frames(pass.as_mut(), scene, w, h, frames, seed, source).1
}

/// `frames` consecutive frames of `pass` (restarted first) through `scene`'s camera, seed
/// `seed`, at 1 spp, its queries answered by `source`: their mean (what the harness
/// accumulates) and the last frame.
pub fn accumulate_frames(
    pass: &mut dyn nrc_render::passes::RenderPass,
    scene: &Scene,
    w: u32,
    h: u32,
    frames: u32,
    seed: u64,
    source: &dyn RadianceSource,
) -> (Image, Image) {
    pass.reset();
    let mut sum = vec![Vec3::ZERO; (w * h) as usize];
    let mut last = None;
    for f in 0..frames {
        let input = FrameInput {
            scene,
            camera: &scene.camera,
            width: w,
            height: h,
            spp: 1,
            seed: nrc_render::pass_seed(seed, f),
            emitter_samples: 0,
            sequence: None,
        };
        let img = passes::run(pass, &input, source).image;
        for (s, p) in sum.iter_mut().zip(&img.data) {
            *s += *p / frames as f32;
        }
        last = Some(img);
    }
    let mean = Image::from_data(w as usize, h as usize, sum).unwrap();
    (mean, last.expect("at least one frame"))
}

/// Per pixel and channel: the mean of `runs` against the reference (its variance of one
/// sample `ref_var` over `ref_spp`), as the largest |z| and the count of pixel channels
/// beyond the Bonferroni bound for a family-wise false alarm of 10⁻³.
pub fn per_pixel_z(
    runs: &[Image],
    reference: &Image,
    ref_var: &Image,
    ref_spp: u32,
) -> (f64, usize, f64) {
    per_pixel_z_floored(runs, reference, ref_var, ref_spp, f64::INFINITY)
}

/// [`per_pixel_z`] with a run's variance estimated from the runs but never below the
/// reference's per-sample variance over `floor`: where a pixel's value is a rare event (an
/// emitter's edge that barely crosses it, hit by a few runs or missed by a few), the runs
/// alone understate its variance (none hit it: zero).
pub fn per_pixel_z_floored(
    runs: &[Image],
    reference: &Image,
    ref_var: &Image,
    ref_spp: u32,
    floor: f64,
) -> (f64, usize, f64) {
    let n = runs.len() as f64;
    let cells = reference.data.len() * 3;
    let bound = z_two_sided(1e-3 / cells as f64);
    let (mut worst, mut beyond) = (0.0f64, 0);
    for p in 0..reference.data.len() {
        for c in 0..3 {
            let xs: Vec<f64> = runs.iter().map(|r| r.data[p][c] as f64).collect();
            let mean = xs.iter().sum::<f64>() / n;
            let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0);
            let rv = ref_var.data[p][c] as f64;
            let se2 = var.max(rv / floor) / n + rv / ref_spp as f64;
            if se2 <= 0.0 {
                assert!(
                    (mean - reference.data[p][c] as f64).abs() < 1e-6,
                    "pixel {p}: {mean} with no variance"
                );
                continue;
            }
            let z = (mean - reference.data[p][c] as f64) / se2.sqrt();
            worst = worst.max(z.abs());
            if z.abs() > bound && std::env::var("DIAG").is_ok() {
                eprintln!(
                    "pixel ({}, {}) channel {c}: mean {mean:.4} ref {:.4} z {z:.1}",
                    p % reference.width,
                    p / reference.width,
                    reference.data[p][c]
                );
            }
            if z.abs() > bound {
                beyond += 1;
            }
        }
    }
    (worst, beyond, bound)
}

/// The path-traced radiance through each pixel's centre (`spp` samples): the mean and the
/// variance of one sample.
pub fn reference_at_centres(
    scene: &Scene,
    tracer: &PathTracer,
    w: u32,
    h: u32,
    spp: u32,
) -> (Image, Image) {
    reference_at_centres_from(scene, &scene.camera, tracer, w, h, spp)
}

/// [`reference_at_centres`] from another camera.
pub fn reference_at_centres_from(
    scene: &Scene,
    camera: &nrc_scene::Camera,
    tracer: &PathTracer,
    w: u32,
    h: u32,
    spp: u32,
) -> (Image, Image) {
    let pixels: Vec<(glam::Vec3, glam::Vec3)> = (0..w * h)
        .map(|p| {
            let (x, y) = ((p % w) as f32 + 0.5, (p / w) as f32 + 0.5);
            let ray = camera.generate_ray(glam::Vec2::new(x, y), w, h);
            let (mut sum, mut sum2) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
            let mut stats = nrc_render::PathStats::default();
            for s in 0..spp {
                let mut sampler = PixelSampler::new(77, p as u64, s as u64);
                let l = tracer
                    .radiance(scene, ray, &mut sampler, &mut stats)
                    .as_dvec3();
                sum += l;
                sum2 += l * l;
            }
            let n = spp as f64;
            let mean = sum / n;
            (
                (mean).as_vec3(),
                ((sum2 / n - mean * mean) * (n / (n - 1.0))).as_vec3(),
            )
        })
        .collect();
    let image = |f: fn(&(glam::Vec3, glam::Vec3)) -> glam::Vec3| {
        Image::from_data(w as usize, h as usize, pixels.iter().map(f).collect()).unwrap()
    };
    (image(|p| p.0), image(|p| p.1))
}

/// The emissive enclosure `[-1, 1]³`: every wall emits 1 and reflects diffusely with albedo ½
/// (radiance `L_e / (1 − ρ) = 2` everywhere); the camera at the centre looks at `target`.
pub fn enclosure(target: Vec3) -> Scene {
    let mut b = SceneBuilder::new();
    let m = b.material(mat::emissive(Vec3::splat(0.5), Vec3::ONE, false));
    b.mesh(
        &Mesh::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), true),
        m,
        false,
    )
    .camera(Vec3::ZERO, target, 60.0);
    b.build()
}

/// A diffuse wall with a bright emissive rectangle on it, turned 17° so that its edges cross
/// pixels at every coverage, a thin diffuse bar in front of it and a sill below that it lights
/// (a window, its mullion and its sill, small).
pub fn window() -> Scene {
    let mut b = SceneBuilder::new();
    let wall = b.material(mat::diffuse(Vec3::splat(0.5)));
    let light = b.material(mat::emissive(Vec3::ZERO, Vec3::new(12.0, 10.0, 8.0), false));
    let bar = b.material(mat::diffuse(Vec3::splat(0.3)));
    b.mesh(
        &Mesh::quad(
            Vec3::ZERO,
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(0.0, 3.0, 0.0),
        ),
        wall,
        false,
    );
    let (s, c) = 17f32.to_radians().sin_cos();
    b.mesh(
        &Mesh::quad(
            Vec3::new(0.1, 0.05, 0.01),
            Vec3::new(c, s, 0.0) * 0.9,
            Vec3::new(-s, c, 0.0) * 0.55,
        ),
        light,
        false,
    );
    b.mesh(
        &Mesh::quad(
            Vec3::new(0.13, 0.0, 0.5),
            Vec3::new(0.03, 0.0, 0.0),
            Vec3::new(0.0, 1.2, 0.0),
        ),
        bar,
        false,
    );
    // A sill below, lit by the emitter (the direct light of the depth-2 renders).
    b.mesh(
        &Mesh::quad(
            Vec3::new(0.0, -0.75, 0.8),
            Vec3::new(0.0, 0.0, 0.8),
            Vec3::new(1.5, 0.0, 0.0),
        ),
        wall,
        false,
    );
    b.camera(Vec3::new(0.0, 0.5, 3.0), Vec3::new(0.0, -0.1, 0.0), 50.0);
    b.build()
}

/// The runs' variance of a pixel channel, summed over the image.
pub fn summed_variance(runs: &[Image]) -> f64 {
    let n = runs.len() as f64;
    (0..runs[0].data.len())
        .flat_map(|p| (0..3).map(move |c| (p, c)))
        .map(|(p, c)| {
            let xs: Vec<f64> = runs.iter().map(|r| r.data[p][c] as f64).collect();
            let mean = xs.iter().sum::<f64>() / n;
            xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
        })
        .sum()
}
