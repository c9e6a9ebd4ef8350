//! The renderable scene: world-space triangles in BVH order with their shading data,
//! materials, textures, lights, camera and background, and the ray queries on them.

use std::fmt;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

use crate::accel::{Accel, Hit};
use crate::bsdf::PbrParams;
use crate::camera::Camera;
use crate::error::{Result, SceneError};
use crate::geometry::{Aabb, Ray};
use crate::interaction::SurfaceInteraction;
use crate::light::{LightSample, LightSampler};
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
    /// Constant radiance seen by rays that leave the scene.
    pub background: Vec3,
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
    materials: Vec<Material>,
    textures: Vec<Texture>,
    lights: LightSampler,
    bounds: Aabb,
    /// The camera used for rendering (from the file, the bounds, or set by the caller).
    pub camera: Camera,
    camera_from_file: bool,
    /// Constant background radiance for rays that leave the scene (default 0).
    pub background: Vec3,
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
    pub lights: usize,
    pub bounds: Aabb,
    pub camera: Camera,
    /// Whether the camera came from the file (otherwise it frames the bounds).
    pub camera_from_file: bool,
    pub background: Vec3,
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
        writeln!(f, "lights:     {} emissive triangles", self.lights)?;
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
        write!(f, "background: {}", v(self.background))?;
        for w in &self.warnings {
            write!(f, "\nwarning:    {w}")?;
        }
        Ok(())
    }
}

impl Scene {
    /// Loads a glTF 2.0 scene (`.gltf` with its buffers and images, or `.glb`).
    pub fn load(path: &Path) -> Result<Scene> {
        crate::gltf_load::load(path)
    }

    /// Builds a scene from world-space meshes: validates indices and positions, drops
    /// zero-area triangles (counted in the summary), builds the BVH and the light sampler.
    pub fn from_description(desc: SceneDescription) -> Result<Scene> {
        let SceneDescription {
            source,
            positions,
            normals,
            uvs,
            triangles,
            triangle_materials,
            triangle_meshes,
            mesh_names,
            mut materials,
            textures,
            camera,
            background,
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

        // BVH, then triangle records in BVH order.
        let (accel, order) = Accel::build(&corners);
        let tris: Vec<TriangleRecord> = order.iter().map(|&i| kept[i as usize]).collect();

        let mut bounds = Aabb::EMPTY;
        for c in &corners {
            for &p in c {
                bounds.extend(p);
            }
        }

        let mut scene = Scene {
            source,
            accel,
            tris,
            positions,
            normals,
            uvs,
            materials,
            textures,
            lights: LightSampler::default(),
            bounds,
            camera: Camera::framing(&bounds),
            camera_from_file: false,
            background,
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

    /// Emissive triangles with their power, for the light sampler.
    fn build_lights(&self) -> LightSampler {
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
                    .map(|&(b1, b2)| m.emission(&self.textures, self.uv_at(i, b1, b2)))
                    .sum::<Vec3>()
                    / PROBES.len() as f32
            } else {
                m.emissive
            };
            let area = self.triangle_area(i as u32);
            let sides = if m.double_sided { 2.0 } else { 1.0 };
            emitters.push((i as u32, area, luminance(le_mean) * area * sides));
        }
        LightSampler::new(self.tris.len(), &emitters)
    }

    #[inline]
    fn uv_at(&self, tri: usize, b1: f32, b2: f32) -> Vec2 {
        if self.uvs.is_empty() {
            return Vec2::ZERO;
        }
        let [a, b, c] = self.tris[tri].v.map(|k| self.uvs[k as usize]);
        a * (1.0 - b1 - b2) + b * b1 + c * b2
    }

    #[inline]
    fn position_at(&self, tri: usize, b1: f32, b2: f32) -> Vec3 {
        let [a, b, c] = self.tris[tri].v.map(|k| self.positions[k as usize]);
        a * (1.0 - b1 - b2) + b * b1 + c * b2
    }

    /// The closest intersection along the ray with `0 ≤ t < ray.t_max`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.accel.intersect(ray)
    }

    /// Whether any surface lies along the ray with `0 ≤ t < ray.t_max`.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.accel.occluded(ray)
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
        let ns = if self.normals.is_empty() {
            ng
        } else {
            let [a, b, c] = rec.v.map(|k| self.normals[k as usize]);
            let n = (a * b0 + b * b1 + c * b2).normalize_or_zero();
            if n == Vec3::ZERO {
                ng
            } else if n.dot(ng) < 0.0 {
                -n
            } else {
                n
            }
        };
        SurfaceInteraction {
            p,
            ng,
            ns,
            uv: self.uv_at(i, b1, b2),
            wo: -ray.d.normalize(),
            material: rec.material,
            tri: hit.tri,
        }
    }

    /// Material parameters at a surface point, textures applied.
    #[inline]
    pub fn pbr(&self, si: &SurfaceInteraction) -> PbrParams {
        self.materials[si.material as usize].pbr(&self.textures, si.uv)
    }

    /// Radiance emitted from the surface point toward `si.wo` (zero on the back face of a
    /// single-sided material; see [`Material::emits_toward`]).
    #[inline]
    pub fn emission(&self, si: &SurfaceInteraction) -> Vec3 {
        let m = &self.materials[si.material as usize];
        if m.is_emissive() && m.emits_toward(si.ng, si.wo) {
            m.emission(&self.textures, si.uv)
        } else {
            Vec3::ZERO
        }
    }

    /// A point on the lights: a light chosen in proportion to power with `u_select`, a
    /// uniform point on it with `u_tri`. `None` when the scene has no light.
    #[inline]
    pub fn sample_light(&self, u_select: f32, u_tri: Vec2) -> Option<LightSample> {
        let (tri, _) = self.lights.select(u_select)?;
        let (b1, b2) = sample_uniform_triangle(u_tri);
        let i = tri as usize;
        let rec = &self.tris[i];
        let m = &self.materials[rec.material as usize];
        let uv = self.uv_at(i, b1, b2);
        Some(LightSample {
            p: self.position_at(i, b1, b2),
            n: rec.ng,
            uv,
            le: m.emission(&self.textures, uv),
            two_sided: m.double_sided,
            pdf_area: self.lights.pdf_area(tri),
            tri,
        })
    }

    /// Area density of [`Scene::sample_light`] producing a point on triangle `tri` (zero
    /// when the triangle is not a light: then only BSDF sampling can find its emission,
    /// which multiple importance sampling must weight by 1).
    #[inline]
    pub fn light_pdf_area(&self, tri: u32) -> f32 {
        self.lights.pdf_area(tri)
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

    /// Number of lights (emissive triangles).
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
            lights: self.lights.len(),
            bounds: self.bounds,
            camera: self.camera,
            camera_from_file: self.camera_from_file,
            background: self.background,
            degenerate_dropped: self.degenerate_dropped,
            warnings: self.warnings.clone(),
        }
    }
}
