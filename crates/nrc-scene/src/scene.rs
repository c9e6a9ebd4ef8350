//! The renderable scene: world-space triangles in BVH order with their shading data,
//! materials, textures, lights, camera and background, and the ray queries on them.

use std::fmt;
use std::path::PathBuf;

use glam::{Vec2, Vec3, Vec4};

use crate::accel::{Accel, Hit};
use crate::bsdf::PbrParams;
use crate::camera::Camera;
use crate::environment::Environment;
use crate::error::{Result, SceneError};
use crate::geometry::{Aabb, Ray};
use crate::interaction::SurfaceInteraction;
use crate::light::{
    LightContext, LightSample, LightSampler, LightSamplerKind, LightSource, PunctualKind,
    PunctualLight, SurfaceLightSample,
};
use crate::light_tree::{LightBounds, LightTree};
use crate::material::Material;
use crate::sampling::{luminance, sample_uniform_triangle};
use crate::texture::Texture;

/// World-space triangle meshes and materials from which a [`Scene`] is built: what the glTF
/// loader produces, and what tests or generators can fill in directly.
#[derive(Clone, Debug, Default)]
pub struct SceneDescription {
    /// Where the description came from (used in messages).
    pub source: PathBuf,
    pub positions: Vec<Vec3>,
    /// Per-vertex normals (same length as `positions`) or empty. A zero normal means "none":
    /// triangles whose interpolated normal is zero shade with their face normal.
    pub normals: Vec<Vec3>,
    /// Per-vertex texture coordinates (same length as `positions`) or empty.
    pub uvs: Vec<Vec2>,
    /// Per-vertex second texture coordinate set (`TEXCOORD_1`), same length or empty.
    pub uvs1: Vec<Vec2>,
    /// Per-vertex tangents (xyz, w = ±1 the bitangent's sign, glTF's `TANGENT`), same length
    /// or empty; where normal-mapped triangles have none, MikkTSpace tangents are generated.
    pub tangents: Vec<Vec4>,
    /// Vertex indices of each triangle; the front face is the counter-clockwise side.
    pub triangles: Vec<[u32; 3]>,
    /// Material index of each triangle.
    pub triangle_materials: Vec<u32>,
    /// Name of the mesh each triangle comes from (index into `mesh_names`), for messages.
    pub triangle_meshes: Vec<u32>,
    pub mesh_names: Vec<String>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    /// The camera; `None` gives a camera framing the scene bounds.
    pub camera: Option<Camera>,
    /// Radiance seen by rays that leave the scene (a constant is the former background).
    pub environment: Environment,
    /// Punctual lights (`KHR_lights_punctual`), in world space.
    pub lights: Vec<PunctualLight>,
    /// Messages about ignored or repaired input, reported by [`Scene::summary`].
    pub warnings: Vec<String>,
}

/// Largest vertex coordinate magnitude accepted: ray queries stay exact well beyond any
/// real scene's size, but not near the float range's end (the BVH's slab tests need
/// distances times 10²⁴ to stay finite; rays should start within this range too).
pub const MAX_COORDINATE: f32 = 1e12;

/// Shading data of one triangle.
#[derive(Clone, Copy, Debug)]
struct TriangleRecord {
    v: [u32; 3],
    material: u32,
    /// Unit geometric normal (counter-clockwise side).
    ng: Vec3,
}

/// A scene ready for rendering.
#[derive(Debug)]
pub struct Scene {
    source: PathBuf,
    accel: Accel,
    tris: Vec<TriangleRecord>,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    uvs1: Vec<Vec2>,
    /// Per triangle (BVH order), the tangents of its three corners; empty without normal maps.
    corner_tangents: Vec<[Vec4; 3]>,
    materials: Vec<Material>,
    textures: Vec<Texture>,
    lights: LightSampler,
    /// The light tree, when next-event estimation chooses lights by it.
    tree: Option<LightTree>,
    punctual: Vec<PunctualLight>,
    environment: Environment,
    /// Whether some material cuts surfaces away (rays then test alpha at every hit).
    has_cutouts: bool,
    bounds: Aabb,
    /// Centre and radius of the bounding sphere of `bounds`.
    sphere: (Vec3, f32),
    /// The camera used for rendering (from the file, the bounds, or set by the caller).
    pub camera: Camera,
    camera_from_file: bool,
    degenerate_dropped: usize,
    warnings: Vec<String>,
}

/// What `nrc info` prints about a scene.
#[derive(Clone, Debug)]
pub struct SceneSummary {
    pub source: PathBuf,
    pub triangles: usize,
    pub materials: usize,
    pub textures: usize,
    /// Emissive triangles, punctual lights, environment (0 or 1) in the light sampler.
    pub lights: (usize, usize, usize),
    /// With `--light-sampler tree`: the light tree's node count and depth.
    pub light_tree: Option<(usize, usize)>,
    /// The ray-query BVH: nodes, bytes, build time.
    pub bvh: crate::accel::AccelStats,
    pub bounds: Aabb,
    pub camera: Camera,
    /// Whether the camera came from the file (otherwise it frames the bounds).
    pub camera_from_file: bool,
    pub environment: String,
    pub degenerate_dropped: usize,
    pub warnings: Vec<String>,
}

impl fmt::Display for SceneSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = |v: Vec3| format!("({:.4}, {:.4}, {:.4})", v.x, v.y, v.z);
        writeln!(f, "scene:      {}", self.source.display())?;
        writeln!(f, "triangles:  {}", self.triangles)?;
        if self.degenerate_dropped > 0 {
            writeln!(
                f,
                "dropped:    {} degenerate (zero-area) triangles",
                self.degenerate_dropped
            )?;
        }
        writeln!(f, "materials:  {}", self.materials)?;
        writeln!(f, "textures:   {}", self.textures)?;
        writeln!(
            f,
            "lights:     {} emissive triangles, {} punctual, {} environment",
            self.lights.0, self.lights.1, self.lights.2
        )?;
        if let Some((nodes, depth)) = self.light_tree {
            writeln!(
                f,
                "light tree: {nodes} nodes of up to {} children, depth {depth}",
                crate::light_tree::WIDTH
            )?;
        }
        writeln!(
            f,
            "bvh:        {} nodes (8-wide), {:.1} MiB with the prepared triangles, built in {:.2} s",
            self.bvh.nodes,
            self.bvh.bytes as f64 / (1 << 20) as f64,
            self.bvh.build_seconds
        )?;
        writeln!(
            f,
            "bounds:     min {} max {}",
            v(self.bounds.min),
            v(self.bounds.max)
        )?;
        writeln!(
            f,
            "camera:     {} position {} forward {} up {} fov_y {:.2}°",
            if self.camera_from_file {
                "from file,"
            } else {
                "default (frames bounds),"
            },
            v(self.camera.position),
            v(self.camera.forward),
            v(self.camera.up),
            self.camera.fov_y.to_degrees()
        )?;
        write!(f, "environment: {}", self.environment)?;
        for w in &self.warnings {
            write!(f, "\nwarning:    {w}")?;
        }
        Ok(())
    }
}

impl Scene {
    /// Builds a scene from world-space meshes: validates indices and positions, drops
    /// zero-area triangles (counted in the summary), builds the BVH and the light sampler.
    pub fn from_description(desc: SceneDescription) -> Result<Scene> {
        let SceneDescription {
            source,
            positions,
            normals,
            uvs,
            uvs1,
            tangents,
            triangles,
            triangle_materials,
            triangle_meshes,
            mesh_names,
            mut materials,
            textures,
            camera,
            environment,
            lights: punctual,
            warnings,
        } = desc;
        let invalid = |message: String| SceneError::Invalid {
            path: source.clone(),
            message,
        };
        if !normals.is_empty() && normals.len() != positions.len() {
            return Err(invalid("normals and positions differ in count".into()));
        }
        if !uvs.is_empty() && uvs.len() != positions.len() {
            return Err(invalid(
                "texture coordinates and positions differ in count".into(),
            ));
        }
        if !uvs1.is_empty() && uvs1.len() != positions.len() {
            return Err(invalid(
                "second texture coordinates and positions differ in count".into(),
            ));
        }
        if !tangents.is_empty() && tangents.len() != positions.len() {
            return Err(invalid("tangents and positions differ in count".into()));
        }
        if triangle_materials.len() != triangles.len() {
            return Err(invalid("every triangle needs a material index".into()));
        }
        if materials.is_empty() {
            materials.push(Material::default());
        }
        for m in &materials {
            for t in [
                &m.base_color_texture,
                &m.metallic_roughness_texture,
                &m.emissive_texture,
                &m.transmission_texture,
                &m.specular_texture,
                &m.specular_color_texture,
                &m.normal_texture,
            ]
            .into_iter()
            .flatten()
            {
                if t.texture as usize >= textures.len() {
                    return Err(invalid(format!(
                        "material `{}` refers to missing texture {}",
                        m.name, t.texture
                    )));
                }
            }
        }
        let mesh_name = |i: usize| -> String {
            triangle_meshes
                .get(i)
                .and_then(|&m| mesh_names.get(m as usize))
                .cloned()
                .unwrap_or_else(|| format!("triangle {i}"))
        };

        // Validate and drop degenerate triangles.
        let mut kept: Vec<TriangleRecord> = Vec::with_capacity(triangles.len());
        let mut corners: Vec<[Vec3; 3]> = Vec::with_capacity(triangles.len());
        let mut degenerate_dropped = 0;
        for (i, (&v, &material)) in triangles.iter().zip(&triangle_materials).enumerate() {
            if v.iter().any(|&k| k as usize >= positions.len()) {
                return Err(SceneError::Mesh {
                    path: source.clone(),
                    mesh: mesh_name(i),
                    message: format!(
                        "vertex index out of range ({v:?}, {} vertices)",
                        positions.len()
                    ),
                });
            }
            if material as usize >= materials.len() {
                return Err(invalid(format!(
                    "triangle {i} refers to missing material {material}"
                )));
            }
            let p = v.map(|k| positions[k as usize]);
            if !p.iter().all(|q| q.is_finite()) {
                return Err(SceneError::Mesh {
                    path: source.clone(),
                    mesh: mesh_name(i),
                    message: "non-finite (NaN or infinite) vertex position".into(),
                });
            }
            if p.iter().any(|q| q.abs().max_element() > MAX_COORDINATE) {
                return Err(SceneError::Mesh {
                    path: source.clone(),
                    mesh: mesh_name(i),
                    message: format!(
                        "vertex position beyond ±{MAX_COORDINATE:e} (unsupported scene scale)"
                    ),
                });
            }
            let ng = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
            if ng == Vec3::ZERO || !ng.is_finite() {
                degenerate_dropped += 1;
                continue;
            }
            kept.push(TriangleRecord { v, material, ng });
            corners.push(p);
        }
        if kept.is_empty() {
            return Err(SceneError::Empty { path: source });
        }
        let mut warnings = warnings;
        if degenerate_dropped > 0 {
            warnings.push(format!(
                "dropped {degenerate_dropped} degenerate (zero-area) triangles"
            ));
        }

        let mut bounds = Aabb::EMPTY;
        for c in &corners {
            for &p in c {
                bounds.extend(p);
            }
        }
        // What only the validation needed goes before the BVH's build, the peak of loading.
        drop((triangles, triangle_materials, triangle_meshes));

        let sphere = (bounds.center(), (0.5 * bounds.extent().length()).max(1e-6));

        // BVH, then triangle records in BVH order.
        let (accel, order) = Accel::build(corners, sphere);
        let tris: Vec<TriangleRecord> = order.iter().map(|&i| kept[i as usize]).collect();
        drop((kept, order));
        let corner_tangents = if materials.iter().any(|m| m.normal_texture.is_some()) {
            crate::tangents::corner_tangents(
                &positions,
                &normals,
                [&uvs, &uvs1],
                &tangents,
                &tris.iter().map(|t| (t.v, t.ng)).collect::<Vec<_>>(),
                |t| {
                    materials[tris[t].material as usize]
                        .normal_texture
                        .map(|r| r.tex_coord)
                },
            )
        } else {
            Vec::new()
        };
        let has_cutouts = materials.iter().any(Material::has_cutout);

        for (i, l) in punctual.iter().enumerate() {
            let ok = l.intensity.is_finite()
                && l.intensity.min_element() >= 0.0
                && l.position.is_finite()
                && l.direction.is_finite()
                && (l.direction.length() - 1.0).abs() < 1e-3
                && l.range.is_none_or(|r| r.is_finite() && r > 0.0);
            if !ok {
                return Err(invalid(format!(
                    "punctual light {i} has a negative or non-finite intensity, position, direction or range"
                )));
            }
        }
        // The loader grew these by pushing: give back their spare capacity (up to half).
        let (mut positions, mut normals, mut uvs, mut uvs1) = (positions, normals, uvs, uvs1);
        positions.shrink_to_fit();
        normals.shrink_to_fit();
        uvs.shrink_to_fit();
        uvs1.shrink_to_fit();
        let mut scene = Scene {
            source,
            accel,
            tris,
            positions,
            normals,
            uvs,
            uvs1,
            corner_tangents,
            materials,
            textures,
            lights: LightSampler::default(),
            tree: None,
            punctual,
            environment,
            has_cutouts,
            bounds,
            sphere,
            camera: Camera::framing(&bounds),
            camera_from_file: false,
            degenerate_dropped,
            warnings,
        };
        if let Some(c) = camera {
            scene.camera = c;
            scene.camera_from_file = true;
        }
        scene.lights = scene.build_lights();
        Ok(scene)
    }

    /// The light sampler over the emissive triangles, punctual lights and environment, by power.
    fn build_lights(&self) -> LightSampler {
        let emitters: Vec<(u32, f32, f32)> = self
            .emitters()
            .iter()
            .map(|&(i, area, power)| (i, area, power))
            .collect();
        let r = self.sphere.1;
        let punctual: Vec<f32> = self.punctual.iter().map(|l| l.power(r)).collect();
        LightSampler::new(
            self.tris.len(),
            &emitters,
            &punctual,
            self.environment_power(),
        )
    }

    /// The environment's power in the light sampler's units.
    fn environment_power(&self) -> f32 {
        let r = self.sphere.1;
        (r as f64 * r as f64 * self.environment.luminance_integral() / std::f64::consts::PI) as f32
    }

    /// The light tree over the emissive triangles and the punctual lights, with the
    /// environment and directional lights at infinity.
    fn build_tree(&self) -> LightTree {
        let (bounded, infinity) = self.light_tree_inputs();
        LightTree::new(bounded, infinity)
    }

    /// What the light tree is built from: each bounded light (emissive triangles, point and
    /// spot lights) with its bounds, in the power sampler's units, and the lights at infinity
    /// (directional lights, the environment).
    pub fn light_tree_inputs(&self) -> (Vec<(LightSource, LightBounds)>, Vec<LightSource>) {
        let r = self.sphere.1;
        let mut bounded: Vec<(LightSource, LightBounds)> = self
            .emitters()
            .into_iter()
            .map(|(i, _, power)| {
                let [a, b, c] = self.triangle_vertices(i);
                let rec = &self.tris[i as usize];
                let two_sided = self.materials[rec.material as usize].double_sided;
                (
                    LightSource::Triangle(i),
                    LightBounds::surface(
                        a.min(b).min(c),
                        a.max(b).max(c),
                        rec.ng,
                        power,
                        two_sided,
                    ),
                )
            })
            .collect();
        let mut infinity = Vec::new();
        for (i, l) in self.punctual.iter().enumerate() {
            let source = LightSource::Punctual(i as u32);
            let power = l.power(r);
            if !(power > 0.0 && power.is_finite()) {
                continue;
            }
            match l.kind {
                PunctualKind::Point => {
                    bounded.push((source, LightBounds::point(l.position, power)))
                }
                PunctualKind::Spot {
                    cos_inner,
                    cos_outer,
                } => bounded.push((
                    source,
                    LightBounds::spot(l.position, l.direction, power, cos_inner, cos_outer),
                )),
                PunctualKind::Directional => infinity.push(source),
            }
        }
        let env = self.environment_power();
        if env > 0.0 && env.is_finite() {
            infinity.push(LightSource::Environment);
        }
        (bounded, infinity)
    }

    /// Samples lights for shading points by `tree`, built over this scene's lights
    /// ([`Scene::light_tree_inputs`], perhaps altered: tests use it to check that a wrong bound
    /// is caught). A tree naming a light this scene does not have (an emissive triangle, a
    /// punctual light, the environment) is refused, naming it.
    pub fn set_light_tree(&mut self, tree: LightTree) -> std::result::Result<(), String> {
        let env = self.lights.environment_pmf() > 0.0;
        if let Some(l) = tree.lights().find(|&l| match l {
            LightSource::Triangle(t) => self.lights.pdf_area(t) == 0.0,
            LightSource::Punctual(i) => i as usize >= self.punctual.len(),
            LightSource::Environment => !env,
        }) {
            return Err(format!(
                "the light tree names {l:?}, which this scene does not light with"
            ));
        }
        self.tree = Some(tree);
        Ok(())
    }

    /// The emissive triangles as `(index, area, power)`, power in the light sampler's units.
    fn emitters(&self) -> Vec<(u32, f32, f32)> {
        // Barycentrics (b1, b2) at which a textured emitter's radiance is averaged: the
        // centroid, the three vertices and three interior points.
        const PROBES: [(f32, f32); 7] = [
            (1.0 / 3.0, 1.0 / 3.0),
            (0.0, 0.0),
            (1.0, 0.0),
            (0.0, 1.0),
            (1.0 / 6.0, 1.0 / 6.0),
            (2.0 / 3.0, 1.0 / 6.0),
            (1.0 / 6.0, 2.0 / 3.0),
        ];
        let mut emitters = Vec::new();
        for (i, t) in self.tris.iter().enumerate() {
            let m = &self.materials[t.material as usize];
            if !m.is_emissive() {
                continue;
            }
            let le_mean = if m.emissive_texture.is_some() {
                PROBES
                    .iter()
                    .map(|&(b1, b2)| m.emission(&self.textures, &self.uv_at(i, b1, b2)))
                    .sum::<Vec3>()
                    / PROBES.len() as f32
            } else {
                m.emissive
            };
            let area = self.triangle_area(i as u32);
            let sides = if m.double_sided { 2.0 } else { 1.0 };
            emitters.push((i as u32, area, luminance(le_mean) * area * sides));
        }
        emitters
    }

    /// Chooses how lights are sampled for shading points (building the light tree for
    /// [`LightSamplerKind::Tree`]). Light paths always start by power.
    pub fn set_light_sampler(&mut self, kind: LightSamplerKind) {
        self.tree = (kind == LightSamplerKind::Tree).then(|| self.build_tree());
    }

    /// How lights are sampled for shading points.
    pub fn light_sampler(&self) -> LightSamplerKind {
        if self.tree.is_some() {
            LightSamplerKind::Tree
        } else {
            LightSamplerKind::Power
        }
    }

    /// The light tree, when lights are sampled by it.
    pub fn light_tree(&self) -> Option<&LightTree> {
        self.tree.as_ref()
    }

    /// Both texture coordinate sets at barycentrics `(b1, b2)` of triangle `tri`.
    #[inline]
    fn uv_at(&self, tri: usize, b1: f32, b2: f32) -> [Vec2; 2] {
        let v = self.tris[tri].v;
        let at = |uvs: &[Vec2]| {
            if uvs.is_empty() {
                return Vec2::ZERO;
            }
            let [a, b, c] = v.map(|k| uvs[k as usize]);
            a * (1.0 - b1 - b2) + b * b1 + c * b2
        };
        [at(&self.uvs), at(&self.uvs1)]
    }

    /// Whether the surface exists at barycentrics `(b1, b2)` of triangle `tri` (alpha cut-outs).
    #[inline]
    fn solid_at(&self, tri: u32, b1: f32, b2: f32) -> bool {
        let m = &self.materials[self.tris[tri as usize].material as usize];
        !m.has_cutout() || m.is_solid(&self.textures, &self.uv_at(tri as usize, b1, b2))
    }

    #[inline]
    fn position_at(&self, tri: usize, b1: f32, b2: f32) -> Vec3 {
        let [a, b, c] = self.tris[tri].v.map(|k| self.positions[k as usize]);
        a * (1.0 - b1 - b2) + b * b1 + c * b2
    }

    /// The closest intersection along the ray with `0 ≤ t < ray.t_max`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if self.has_cutouts {
            self.accel
                .intersect(ray, |t, b1, b2| self.solid_at(t, b1, b2))
        } else {
            self.accel.intersect(ray, |_, _, _| true)
        }
    }

    /// Whether any surface lies along the ray with `0 ≤ t < ray.t_max`.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        if self.has_cutouts {
            self.accel
                .occluded(ray, |t, b1, b2| self.solid_at(t, b1, b2))
        } else {
            self.accel.occluded(ray, |_, _, _| true)
        }
    }

    /// The surface description at a hit of `ray`.
    #[inline]
    pub fn interaction(&self, ray: &Ray, hit: &Hit) -> SurfaceInteraction {
        let i = hit.tri as usize;
        let rec = &self.tris[i];
        let (b1, b2) = (hit.b1, hit.b2);
        let b0 = 1.0 - b1 - b2;
        let p = self.position_at(i, b1, b2);
        let ng = rec.ng;
        let uv = self.uv_at(i, b1, b2);
        let mut n = if self.normals.is_empty() {
            ng
        } else {
            let [a, b, c] = rec.v.map(|k| self.normals[k as usize]);
            let n = (a * b0 + b * b1 + c * b2).normalize_or_zero();
            if n == Vec3::ZERO { ng } else { n }
        };
        // Tangent-space normal map: n' = T x + B y + N z with the interpolated tangent made
        // orthogonal to N and B = w (N × T) (glTF's convention, MikkTSpace's reconstruction).
        if let Some(t) = self.corner_tangents.get(i)
            && let Some(m) =
                self.materials[rec.material as usize].mapped_normal(&self.textures, &uv)
        {
            let t4 = t[0] * b0 + t[1] * b1 + t[2] * b2;
            let tangent = (t4.truncate() - n * n.dot(t4.truncate())).normalize_or_zero();
            if tangent != Vec3::ZERO {
                let sign = if t4.w < 0.0 { -1.0 } else { 1.0 };
                let bitangent = sign * n.cross(tangent);
                let mapped = (tangent * m.x + bitangent * m.y + n * m.z).normalize_or_zero();
                if mapped != Vec3::ZERO && mapped.is_finite() {
                    n = mapped;
                }
            }
        }
        let ns = if n.dot(ng) < 0.0 { -n } else { n };
        SurfaceInteraction {
            p,
            ng,
            ns,
            uv,
            wo: -ray.d.normalize(),
            material: rec.material,
            tri: hit.tri,
        }
    }

    /// The surface description at point `p` of triangle `tri` (a light sample's point), seen
    /// from direction `wo` (unit, pointing away from the surface): what a ray arriving along
    /// `-wo` would report there. `p` is projected onto the triangle's plane by barycentrics.
    pub fn interaction_at(&self, tri: u32, p: Vec3, wo: Vec3) -> SurfaceInteraction {
        let [a, b, c] = self.triangle_vertices(tri);
        let (e1, e2, d) = (b - a, c - a, p - a);
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (d1, d2) = (d.dot(e1), d.dot(e2));
        let den = d11 * d22 - d12 * d12;
        let (b1, b2) = if den > 0.0 {
            ((d22 * d1 - d12 * d2) / den, (d11 * d2 - d12 * d1) / den)
        } else {
            (0.0, 0.0)
        };
        let hit = Hit {
            t: 0.0,
            tri,
            b1: b1.clamp(0.0, 1.0),
            b2: b2.clamp(0.0, 1.0),
        };
        self.interaction(&Ray::new(p + wo, -wo), &hit)
    }

    /// Material parameters at a surface point, textures applied.
    #[inline]
    pub fn pbr(&self, si: &SurfaceInteraction) -> PbrParams {
        self.materials[si.material as usize].pbr(&self.textures, &si.uv)
    }

    /// Radiance emitted from the surface point toward `si.wo` (zero on the back face of a
    /// single-sided material; see [`Material::emits_toward`]).
    #[inline]
    pub fn emission(&self, si: &SurfaceInteraction) -> Vec3 {
        let m = &self.materials[si.material as usize];
        if m.is_emissive() && m.emits_toward(si.ng, si.wo) {
            m.emission(&self.textures, &si.uv)
        } else {
            Vec3::ZERO
        }
    }

    /// A sample of the lights for the shading point `at`: a light chosen with `u_select` (by
    /// the scene's light sampler: in proportion to power, or by the light tree), then with
    /// `u`: a uniform point on an emissive triangle, or a direction from the environment's
    /// distribution (punctual lights use no number). `None` when no light can reach `at`.
    #[inline]
    pub fn sample_light(&self, at: &LightContext, u_select: f32, u: Vec2) -> Option<LightSample> {
        let (source, pmf) = match &self.tree {
            Some(tree) => tree.sample(at.p, at.n, u_select)?,
            None => self.lights.select(u_select)?,
        };
        self.light_sample_of(source, pmf, u)
    }

    /// A sample of the lights chosen in proportion to power, wherever it is used from: where
    /// light paths start.
    #[inline]
    pub fn sample_light_by_power(&self, u_select: f32, u: Vec2) -> Option<LightSample> {
        let (source, pmf) = self.lights.select(u_select)?;
        self.light_sample_of(source, pmf, u)
    }

    /// The sample of light `source`, chosen with probability `pmf`, drawn with `u`.
    #[inline]
    fn light_sample_of(&self, source: LightSource, pmf: f32, u: Vec2) -> Option<LightSample> {
        match source {
            LightSource::Triangle(tri) => {
                let (b1, b2) = sample_uniform_triangle(u);
                let i = tri as usize;
                let rec = &self.tris[i];
                let m = &self.materials[rec.material as usize];
                let uv = self.uv_at(i, b1, b2);
                Some(LightSample::Surface(SurfaceLightSample {
                    p: self.position_at(i, b1, b2),
                    n: rec.ng,
                    uv: uv[0],
                    le: m.emission(&self.textures, &uv),
                    two_sided: m.double_sided,
                    pdf_area: if self.tree.is_some() {
                        pmf / self.triangle_area(tri)
                    } else {
                        self.lights.pdf_area(tri)
                    },
                    tri,
                }))
            }
            LightSource::Punctual(index) => Some(LightSample::Punctual {
                light: self.punctual[index as usize],
                index,
                pmf,
            }),
            LightSource::Environment => {
                let (dir, pdf) = self.environment.sample(u)?;
                Some(LightSample::Environment {
                    dir,
                    le: self.environment.radiance(dir),
                    pdf: pdf * pmf,
                })
            }
        }
    }

    /// The emitter point `si` (reached by a ray from `at`) as the light sample
    /// [`Scene::sample_light`] could have drawn there for `at`: a BSDF-sampled emitter hit as a
    /// resampling candidate. `None` on surfaces that do not emit.
    pub fn light_sample_at(
        &self,
        at: &LightContext,
        si: &SurfaceInteraction,
    ) -> Option<LightSample> {
        let m = &self.materials[si.material as usize];
        if !m.is_emissive() {
            return None;
        }
        Some(LightSample::Surface(SurfaceLightSample {
            p: si.p,
            n: si.ng,
            uv: si.uv[0],
            le: m.emission(&self.textures, &si.uv),
            two_sided: m.double_sided,
            pdf_area: self.light_pdf_area(at, si.tri),
            tri: si.tri,
        }))
    }

    /// The environment seen along unit direction `d` as a light sample (`None` where it is
    /// black).
    pub fn environment_sample(&self, at: &LightContext, d: Vec3) -> Option<LightSample> {
        let le = self.environment.radiance(d);
        (le != Vec3::ZERO).then_some(LightSample::Environment {
            dir: d,
            le,
            pdf: self.environment_light_pdf(at, d),
        })
    }

    /// Solid-angle density with which [`Scene::sample_light`] produces environment direction
    /// `d` for `at` (zero when the environment is not among the lights).
    #[inline]
    pub fn environment_light_pdf(&self, at: &LightContext, d: Vec3) -> f32 {
        let pmf = match &self.tree {
            Some(tree) => tree.pmf(at.p, at.n, LightSource::Environment),
            None => self.lights.environment_pmf(),
        };
        if pmf > 0.0 {
            pmf * self.environment.pdf(d)
        } else {
            0.0
        }
    }

    /// The environment.
    pub fn environment(&self) -> &Environment {
        &self.environment
    }

    /// Replaces the environment (and rebuilds the light sampler, whose powers depend on it).
    pub fn set_environment(&mut self, environment: Environment) {
        self.environment = environment;
        self.lights = self.build_lights();
        if self.tree.is_some() {
            self.tree = Some(self.build_tree());
        }
    }

    /// The punctual lights.
    pub fn punctual_lights(&self) -> &[PunctualLight] {
        &self.punctual
    }

    /// Centre and radius of the scene's bounding sphere (where light paths from lights at
    /// infinity start).
    pub fn bounding_sphere(&self) -> (Vec3, f32) {
        self.sphere
    }

    /// Area density of [`Scene::sample_light`] producing a point on triangle `tri` for `at`
    /// (zero when the triangle is not a light, or the light tree finds that it cannot light
    /// `at`: then only BSDF sampling can find its emission, which multiple importance sampling
    /// must weight by 1).
    #[inline]
    pub fn light_pdf_area(&self, at: &LightContext, tri: u32) -> f32 {
        match &self.tree {
            Some(tree) => {
                if self.lights.pdf_area(tri) == 0.0 {
                    return 0.0;
                }
                tree.pmf(at.p, at.n, LightSource::Triangle(tri)) / self.triangle_area(tri)
            }
            None => self.lights.pdf_area(tri),
        }
    }

    /// The light sampler.
    pub fn lights(&self) -> &LightSampler {
        &self.lights
    }

    /// Area of triangle `tri`.
    pub fn triangle_area(&self, tri: u32) -> f32 {
        let [a, b, c] = self.triangle_vertices(tri);
        0.5 * (b - a).cross(c - a).length()
    }

    /// World-space vertices of triangle `tri`.
    pub fn triangle_vertices(&self, tri: u32) -> [Vec3; 3] {
        self.tris[tri as usize]
            .v
            .map(|k| self.positions[k as usize])
    }

    /// Unit geometric normal of triangle `tri`.
    pub fn triangle_normal(&self, tri: u32) -> Vec3 {
        self.tris[tri as usize].ng
    }

    /// Material index of triangle `tri`.
    pub fn triangle_material(&self, tri: u32) -> u32 {
        self.tris[tri as usize].material
    }

    /// Number of triangles (after dropping degenerate ones).
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Number of lights (emissive triangles, punctual lights, the environment unless black).
    pub fn light_count(&self) -> usize {
        self.lights.len()
    }

    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    pub fn textures(&self) -> &[Texture] {
        &self.textures
    }

    /// Bounding box of all triangles.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Whether the camera came from the file (otherwise it frames the bounds).
    pub fn camera_from_file(&self) -> bool {
        self.camera_from_file
    }

    /// Messages about ignored or repaired input.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Number of zero-area triangles dropped while building.
    pub fn degenerate_dropped(&self) -> usize {
        self.degenerate_dropped
    }

    /// Counts, bounds and camera, for `nrc info`.
    pub fn summary(&self) -> SceneSummary {
        SceneSummary {
            source: self.source.clone(),
            triangles: self.tris.len(),
            materials: self.materials.len(),
            textures: self.textures.len(),
            lights: self.lights.counts(),
            light_tree: self.tree.as_ref().map(|t| (t.node_count(), t.depth())),
            bvh: self.accel.stats(),
            bounds: self.bounds,
            camera: self.camera,
            camera_from_file: self.camera_from_file,
            environment: self.environment.describe(),
            degenerate_dropped: self.degenerate_dropped,
            warnings: self.warnings.clone(),
        }
    }
}
