//! A small glTF 2.0 writer: one `.gltf` JSON document, one `.bin` buffer beside it and PNG
//! images, using only what the project's loader reads (indexed triangles, node transforms,
//! perspective cameras, metallic-roughness materials with the emissive-strength,
//! transmission, IOR and specular extensions, `KHR_lights_punctual` lights).

use std::collections::BTreeSet;
use std::path::Path;

use glam::{Affine3A, Quat, Vec3};
use serde_json::{Map, Value, json};

use crate::mesh::Mesh;

const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const NEAREST: u32 = 9728;
const LINEAR: u32 = 9729;
const LINEAR_MIPMAP_LINEAR: u32 = 9987;
const REPEAT: u32 = 10497;

const EMISSIVE_STRENGTH: &str = "KHR_materials_emissive_strength";
const TRANSMISSION: &str = "KHR_materials_transmission";
const IOR: &str = "KHR_materials_ior";
const SPECULAR: &str = "KHR_materials_specular";
const LIGHTS_PUNCTUAL: &str = "KHR_lights_punctual";

/// A JSON number holding exactly the `f32` (its shortest decimal form), so that
/// `0.1_f32` is written as `0.1` and reads back as the same `f32`.
pub fn num(x: f32) -> Value {
    assert!(x.is_finite(), "non-finite number in a glTF document");
    Value::from(
        x.to_string()
            .parse::<f64>()
            .expect("f32 formats as a number"),
    )
}

fn vec3(v: Vec3) -> Value {
    Value::Array(v.to_array().map(num).to_vec())
}

/// A metallic-roughness material as glTF defines it, with the extensions the loader reads.
/// Colours are linear RGB.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    pub base_color: Vec3,
    pub base_color_texture: Option<usize>,
    pub metallic: f32,
    pub roughness: f32,
    /// glTF's metallic-roughness texture: roughness in G, metallic in B (linear).
    pub metallic_roughness_texture: Option<usize>,
    /// Emitted radiance (W sr⁻¹ m⁻² per channel); zero for surfaces that do not emit.
    /// Written as `emissiveFactor` (at most 1) times `KHR_materials_emissive_strength`.
    pub emission: Vec3,
    /// `KHR_materials_transmission` factor.
    pub transmission: f32,
    /// `KHR_materials_ior`; `None` leaves the glTF default 1.5.
    pub ior: Option<f32>,
    /// `KHR_materials_specular` factor; `Some(0.0)` makes a non-metal purely diffuse.
    pub specular: Option<f32>,
    pub double_sided: bool,
}

impl Material {
    /// A Lambertian surface of albedo `albedo`: metallic 0, transmission 0, specular 0.
    pub fn diffuse(name: &str, albedo: Vec3) -> Self {
        Self {
            name: name.to_owned(),
            base_color: albedo,
            base_color_texture: None,
            metallic: 0.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            emission: Vec3::ZERO,
            transmission: 0.0,
            ior: None,
            specular: Some(0.0),
            double_sided: false,
        }
    }

    /// An area light of radiance `radiance` over a Lambertian surface of albedo `albedo`.
    /// One-sided lights emit on their front face only.
    pub fn emitter(name: &str, radiance: Vec3, albedo: Vec3, double_sided: bool) -> Self {
        Self {
            emission: radiance,
            double_sided,
            ..Self::diffuse(name, albedo)
        }
    }

    /// A GGX conductor: metallic 1, `base_color` is its normal-incidence reflectance.
    pub fn conductor(name: &str, base_color: Vec3, roughness: f32) -> Self {
        Self {
            metallic: 1.0,
            roughness,
            specular: None,
            ..Self::diffuse(name, base_color)
        }
    }

    /// A clear dielectric (glass): transmission 1, index of refraction `ior`.
    pub fn dielectric(name: &str, roughness: f32, ior: f32) -> Self {
        Self {
            roughness,
            transmission: 1.0,
            ior: Some(ior),
            specular: None,
            ..Self::diffuse(name, Vec3::ONE)
        }
    }

    fn to_json(&self, used: &mut BTreeSet<&'static str>) -> Value {
        let mut pbr = Map::new();
        pbr.insert(
            "baseColorFactor".into(),
            json!([
                num(self.base_color.x),
                num(self.base_color.y),
                num(self.base_color.z),
                1.0
            ]),
        );
        pbr.insert("metallicFactor".into(), num(self.metallic));
        pbr.insert("roughnessFactor".into(), num(self.roughness));
        if let Some(t) = self.base_color_texture {
            pbr.insert("baseColorTexture".into(), json!({ "index": t }));
        }
        if let Some(t) = self.metallic_roughness_texture {
            pbr.insert("metallicRoughnessTexture".into(), json!({ "index": t }));
        }
        let mut m = Map::new();
        m.insert("name".into(), json!(self.name));
        m.insert("pbrMetallicRoughness".into(), Value::Object(pbr));
        m.insert("doubleSided".into(), json!(self.double_sided));
        let mut ext = Map::new();
        let peak = self.emission.max_element();
        assert!(
            self.emission.min_element() >= 0.0,
            "negative emission in {}",
            self.name
        );
        if peak > 0.0 {
            if peak <= 1.0 {
                m.insert("emissiveFactor".into(), vec3(self.emission));
            } else {
                m.insert("emissiveFactor".into(), vec3(self.emission / peak));
                ext.insert(
                    EMISSIVE_STRENGTH.into(),
                    json!({ "emissiveStrength": num(peak) }),
                );
            }
        }
        if self.transmission > 0.0 {
            ext.insert(
                TRANSMISSION.into(),
                json!({ "transmissionFactor": num(self.transmission) }),
            );
        }
        if let Some(ior) = self.ior {
            ext.insert(IOR.into(), json!({ "ior": num(ior) }));
        }
        if let Some(s) = self.specular {
            ext.insert(SPECULAR.into(), json!({ "specularFactor": num(s) }));
        }
        for name in ext.keys() {
            used.insert(
                [EMISSIVE_STRENGTH, TRANSMISSION, IOR, SPECULAR]
                    .into_iter()
                    .find(|e| e == name)
                    .expect("known extension"),
            );
        }
        if !ext.is_empty() {
            m.insert("extensions".into(), Value::Object(ext));
        }
        Value::Object(m)
    }
}

/// The kind of a `KHR_lights_punctual` light, with a spot's cone angles (radians).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    Point,
    Spot {
        inner_cone_angle: f32,
        outer_cone_angle: f32,
    },
    Directional,
}

/// A `KHR_lights_punctual` light. `color × intensity` is the radiant intensity (point, spot;
/// glTF's candela, used as W sr⁻¹ per channel) or the irradiance at normal incidence
/// (directional; glTF's lux, used as W m⁻² per channel): the project uses no 683 lm/W factor.
/// It shines down its node's local −z.
#[derive(Clone, Debug)]
pub struct Light {
    pub name: String,
    pub kind: LightKind,
    pub color: Vec3,
    pub intensity: f32,
}

impl Light {
    fn to_json(&self) -> Value {
        let mut m = Map::new();
        m.insert("name".into(), json!(self.name));
        m.insert("color".into(), vec3(self.color));
        m.insert("intensity".into(), num(self.intensity));
        let kind = match self.kind {
            LightKind::Point => "point",
            LightKind::Directional => "directional",
            LightKind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                m.insert(
                    "spot".into(),
                    json!({
                        "innerConeAngle": num(inner_cone_angle),
                        "outerConeAngle": num(outer_cone_angle),
                    }),
                );
                "spot"
            }
        };
        m.insert("type".into(), json!(kind));
        Value::Object(m)
    }
}

/// Accessors of one mesh's vertex data in the buffer; several glTF meshes (with different
/// materials) may share them.
#[derive(Clone, Debug)]
pub struct Geometry {
    position: usize,
    normal: Option<usize>,
    uv: Option<usize>,
    indices: usize,
    mesh: Mesh,
}

/// A node's local transform, applied as glTF does: scale, then rotation, then translation.
#[derive(Clone, Copy, Debug)]
pub struct Transform {
    pub translation: Vec3,
    pub rotation: Quat,
    pub scale: f32,
}

impl Transform {
    pub const IDENTITY: Self = Self {
        translation: Vec3::ZERO,
        rotation: Quat::IDENTITY,
        scale: 1.0,
    };

    pub fn at(translation: Vec3) -> Self {
        Self {
            translation,
            ..Self::IDENTITY
        }
    }

    /// The placement of a camera at `eye` looking at `target`: glTF cameras look down
    /// their local −Z with +Y up.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3) -> Self {
        Self::oriented(eye, (target - eye).normalize(), up)
    }

    /// The placement of a node at `position` whose local −Z points along `direction` (a
    /// light's beam), with local +Y as close to `up` as possible.
    pub fn facing(position: Vec3, direction: Vec3, up: Vec3) -> Self {
        Self::oriented(position, direction.normalize(), up)
    }

    fn oriented(eye: Vec3, forward: Vec3, up: Vec3) -> Self {
        let right = forward.cross(up).normalize();
        let true_up = right.cross(forward);
        let rotation =
            Quat::from_mat3(&glam::Mat3::from_cols(right, true_up, -forward)).normalize();
        Self {
            translation: eye,
            rotation,
            scale: 1.0,
        }
    }

    pub fn affine(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(
            Vec3::splat(self.scale),
            self.rotation,
            self.translation,
        )
    }
}

struct Node {
    json: Map<String, Value>,
    transform: Transform,
    mesh: Option<usize>,
    children: Vec<usize>,
    is_child: bool,
}

/// Per-scene figures, counted over node instances.
#[derive(Clone, Debug, Default)]
pub struct Stats {
    pub triangles: usize,
    pub emissive_triangles: usize,
    /// `KHR_lights_punctual` lights, in world space: (kind, colour × intensity, position,
    /// direction of the beam).
    pub punctual: Vec<(LightKind, Vec3, Vec3, Vec3)>,
    /// Emitted power Φ = π · L · A per emitting side, per channel (W, in RGB units).
    pub power: Vec3,
}

/// A glTF document under construction.
#[derive(Default)]
pub struct Document {
    bin: Vec<u8>,
    buffer_views: Vec<Value>,
    accessors: Vec<Value>,
    meshes: Vec<(Value, usize, usize)>,
    geometries: Vec<Geometry>,
    materials: Vec<Material>,
    nodes: Vec<Node>,
    cameras: Vec<Value>,
    lights: Vec<Light>,
    /// `(node, light)` pairs.
    light_nodes: Vec<(usize, usize)>,
    images: Vec<Value>,
    textures: Vec<Value>,
    samplers: Vec<Value>,
    png_files: Vec<(String, Vec<u8>)>,
    animations: Vec<Value>,
}

impl Document {
    fn add_view(&mut self, bytes: &[u8], target: u32) -> usize {
        // Every view starts on a 4-byte boundary, as the component types require.
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut view = json!({
            "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len(),
        });
        // Animation data has no target (it is neither vertex nor index data).
        if target != 0 {
            view["target"] = json!(target);
        }
        self.buffer_views.push(view);
        self.bin.extend_from_slice(bytes);
        self.buffer_views.len() - 1
    }

    fn add_accessor(&mut self, accessor: Value) -> usize {
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    /// Stores a mesh's vertex attributes and indices in the buffer.
    pub fn add_geometry(&mut self, mesh: &Mesh) -> usize {
        assert!(!mesh.indices.is_empty() && mesh.indices.len().is_multiple_of(3));
        let count = mesh.positions.len();
        let floats =
            |vs: &mut dyn Iterator<Item = f32>| vs.flat_map(f32::to_le_bytes).collect::<Vec<u8>>();
        let view = self.add_view(
            &floats(&mut mesh.positions.iter().flat_map(|p| p.to_array())),
            ARRAY_BUFFER,
        );
        let (lo, hi) = mesh
            .positions
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
        let position = self.add_accessor(json!({
            "bufferView": view, "componentType": FLOAT, "count": count, "type": "VEC3",
            "min": vec3(lo), "max": vec3(hi),
        }));
        let normal = mesh.normals.as_ref().map(|ns| {
            assert_eq!(ns.len(), count);
            let view = self.add_view(&floats(&mut ns.iter().flat_map(|n| n.to_array())), ARRAY_BUFFER);
            self.add_accessor(json!({ "bufferView": view, "componentType": FLOAT, "count": count, "type": "VEC3" }))
        });
        let uv = mesh.uvs.as_ref().map(|uvs| {
            assert_eq!(uvs.len(), count);
            let view = self.add_view(&floats(&mut uvs.iter().flat_map(|t| t.to_array())), ARRAY_BUFFER);
            self.add_accessor(json!({ "bufferView": view, "componentType": FLOAT, "count": count, "type": "VEC2" }))
        });
        // 16-bit indices where they fit; the type's largest value is reserved by glTF
        // (primitive restart), so u16 serves meshes of at most 65535 vertices.
        let max_index = *mesh.indices.iter().max().expect("non-empty");
        assert!((max_index as usize) < count, "index out of range");
        let (bytes, component) = if max_index < u32::from(u16::MAX) {
            (
                mesh.indices
                    .iter()
                    .flat_map(|&i| (i as u16).to_le_bytes())
                    .collect::<Vec<u8>>(),
                UNSIGNED_SHORT,
            )
        } else {
            (
                mesh.indices.iter().flat_map(|&i| i.to_le_bytes()).collect(),
                UNSIGNED_INT,
            )
        };
        let view = self.add_view(&bytes, ELEMENT_ARRAY_BUFFER);
        let indices = self.add_accessor(json!({
            "bufferView": view, "componentType": component, "count": mesh.indices.len(), "type": "SCALAR",
        }));
        self.geometries.push(Geometry {
            position,
            normal,
            uv,
            indices,
            mesh: mesh.clone(),
        });
        self.geometries.len() - 1
    }

    pub fn add_material(&mut self, material: Material) -> usize {
        self.materials.push(material);
        self.materials.len() - 1
    }

    /// A glTF mesh: one triangle primitive of `geometry` with `material`.
    pub fn add_mesh(&mut self, name: &str, geometry: usize, material: usize) -> usize {
        let g = &self.geometries[geometry];
        let mut attributes = Map::new();
        attributes.insert("POSITION".into(), json!(g.position));
        if let Some(n) = g.normal {
            attributes.insert("NORMAL".into(), json!(n));
        }
        if let Some(t) = g.uv {
            attributes.insert("TEXCOORD_0".into(), json!(t));
        }
        let mesh = json!({
            "name": name,
            "primitives": [{ "attributes": attributes, "indices": g.indices, "material": material, "mode": 4 }],
        });
        self.meshes.push((mesh, geometry, material));
        self.meshes.len() - 1
    }

    fn add_node_json(&mut self, name: &str, transform: Transform, mesh: Option<usize>) -> usize {
        let mut json = Map::new();
        json.insert("name".into(), json!(name));
        if transform.translation != Vec3::ZERO {
            json.insert("translation".into(), vec3(transform.translation));
        }
        if transform.rotation != Quat::IDENTITY {
            json.insert(
                "rotation".into(),
                Value::Array(transform.rotation.to_array().map(num).to_vec()),
            );
        }
        if transform.scale != 1.0 {
            json.insert("scale".into(), vec3(Vec3::splat(transform.scale)));
        }
        if let Some(m) = mesh {
            json.insert("mesh".into(), json!(m));
        }
        self.nodes.push(Node {
            json,
            transform,
            mesh,
            children: Vec::new(),
            is_child: false,
        });
        self.nodes.len() - 1
    }

    /// A node holding `mesh`, placed by `transform`.
    pub fn add_mesh_node(&mut self, name: &str, mesh: usize, transform: Transform) -> usize {
        self.add_node_json(name, transform, Some(mesh))
    }

    /// A mesh made of `geometry` and `material`, instanced once with `transform`.
    pub fn add_object(
        &mut self,
        name: &str,
        mesh: &Mesh,
        material: usize,
        transform: Transform,
    ) -> usize {
        let g = self.add_geometry(mesh);
        let m = self.add_mesh(name, g, material);
        self.add_mesh_node(name, m, transform)
    }

    /// An animation of node `node`'s translation (`"translation"`) or scale through `values`
    /// at `times` seconds (`interpolation`: `"STEP"` or `"LINEAR"`).
    pub fn add_vec3_animation(
        &mut self,
        name: &str,
        node: usize,
        path: &str,
        interpolation: &str,
        keys: &[(f32, Vec3)],
    ) {
        assert!(
            keys.windows(2).all(|w| w[1].0 > w[0].0),
            "increasing key times"
        );
        let floats =
            |vs: &mut dyn Iterator<Item = f32>| vs.flat_map(f32::to_le_bytes).collect::<Vec<u8>>();
        let times = self.add_view(&floats(&mut keys.iter().map(|k| k.0)), 0);
        let (t0, t1) = (keys[0].0, keys[keys.len() - 1].0);
        let input = self.add_accessor(json!({
            "bufferView": times, "componentType": FLOAT, "count": keys.len(), "type": "SCALAR",
            "min": [num(t0)], "max": [num(t1)],
        }));
        let values = self.add_view(&floats(&mut keys.iter().flat_map(|k| k.1.to_array())), 0);
        let output = self.add_accessor(json!({
            "bufferView": values, "componentType": FLOAT, "count": keys.len(), "type": "VEC3",
        }));
        self.animations.push(json!({
            "name": name,
            "samplers": [{ "input": input, "output": output, "interpolation": interpolation }],
            "channels": [{ "sampler": 0, "target": { "node": node, "path": path } }],
        }));
    }

    /// An empty node that groups children under one transform.
    pub fn add_group(&mut self, name: &str, transform: Transform) -> usize {
        self.add_node_json(name, transform, None)
    }

    pub fn add_child(&mut self, parent: usize, child: usize) {
        assert!(!self.nodes[child].is_child, "node already has a parent");
        self.nodes[child].is_child = true;
        self.nodes[parent].children.push(child);
    }

    /// A perspective camera (vertical field of view `yfov_degrees`, square aspect) at `placement`.
    pub fn add_camera(&mut self, name: &str, yfov_degrees: f32, placement: Transform) -> usize {
        self.cameras.push(json!({
            "name": name,
            "type": "perspective",
            "perspective": { "yfov": num(yfov_degrees.to_radians()), "aspectRatio": 1.0, "znear": 0.01 },
        }));
        let node = self.add_node_json(name, placement, None);
        self.nodes[node]
            .json
            .insert("camera".into(), json!(self.cameras.len() - 1));
        node
    }

    /// A `KHR_lights_punctual` light on a node of its own, placed by `placement` (the light
    /// shines down the node's local −z; see [`Transform::facing`]).
    pub fn add_light(&mut self, light: Light, placement: Transform) -> usize {
        self.lights.push(light);
        let index = self.lights.len() - 1;
        let name = self.lights[index].name.clone();
        let node = self.add_node_json(&name, placement, None);
        self.nodes[node].json.insert(
            "extensions".into(),
            json!({ LIGHTS_PUNCTUAL: { "light": index } }),
        );
        self.light_nodes.push((node, index));
        node
    }

    /// A texture from an encoded PNG written beside the document as `file_name`.
    /// `nearest` selects nearest-neighbour filtering (crisp checkers).
    pub fn add_png_texture(&mut self, file_name: &str, png: Vec<u8>, nearest: bool) -> usize {
        let (mag, min) = if nearest {
            (NEAREST, NEAREST)
        } else {
            (LINEAR, LINEAR_MIPMAP_LINEAR)
        };
        self.samplers
            .push(json!({ "magFilter": mag, "minFilter": min, "wrapS": REPEAT, "wrapT": REPEAT }));
        self.images
            .push(json!({ "name": file_name, "uri": file_name, "mimeType": "image/png" }));
        self.png_files.push((file_name.to_owned(), png));
        self.textures
            .push(json!({ "source": self.images.len() - 1, "sampler": self.samplers.len() - 1 }));
        self.textures.len() - 1
    }

    /// Triangle and light figures over every node instance.
    pub fn stats(&self) -> Stats {
        let mut stats = Stats::default();
        let mut stack: Vec<(usize, Affine3A)> = (0..self.nodes.len())
            .filter(|&i| !self.nodes[i].is_child)
            .map(|i| (i, Affine3A::IDENTITY))
            .collect();
        while let Some((i, parent)) = stack.pop() {
            let node = &self.nodes[i];
            let world = parent * node.transform.affine();
            for &(_, l) in self.light_nodes.iter().filter(|(n, _)| *n == i) {
                let light = &self.lights[l];
                stats.punctual.push((
                    light.kind,
                    light.color * light.intensity,
                    world.transform_point3(Vec3::ZERO),
                    world.transform_vector3(Vec3::NEG_Z).normalize(),
                ));
            }
            if let Some(m) = node.mesh {
                let (_, geometry, material) = self.meshes[m];
                let mesh = &self.geometries[geometry].mesh;
                let material = &self.materials[material];
                stats.triangles += mesh.triangle_count();
                if material.emission.max_element() > 0.0 {
                    stats.emissive_triangles += mesh.triangle_count();
                    let sides = if material.double_sided { 2.0 } else { 1.0 };
                    stats.power +=
                        material.emission * (std::f32::consts::PI * mesh.area(world) * sides);
                }
            }
            stack.extend(node.children.iter().map(|&c| (c, world)));
        }
        stats
    }

    /// Writes `<name>.gltf`, `<name>.bin` and the PNG images into `dir`, each through a
    /// temporary file renamed into place.
    pub fn write(&self, dir: &Path, name: &str) -> std::io::Result<()> {
        let bin_name = format!("{name}.bin");
        let mut used = BTreeSet::new();
        if !self.lights.is_empty() {
            used.insert(LIGHTS_PUNCTUAL);
        }
        let materials: Vec<Value> = self
            .materials
            .iter()
            .map(|m| m.to_json(&mut used))
            .collect();
        let nodes: Vec<Value> = self
            .nodes
            .iter()
            .map(|n| {
                let mut json = n.json.clone();
                if !n.children.is_empty() {
                    json.insert("children".into(), json!(n.children));
                }
                Value::Object(json)
            })
            .collect();
        let roots: Vec<usize> = (0..self.nodes.len())
            .filter(|&i| !self.nodes[i].is_child)
            .collect();
        let mut doc = Map::new();
        doc.insert(
            "asset".into(),
            json!({ "version": "2.0", "generator": "nrc make_scenes (crates/nrc-scene/examples/make_scenes)" }),
        );
        if !used.is_empty() {
            doc.insert("extensionsUsed".into(), json!(used));
        }
        doc.insert("scene".into(), json!(0));
        doc.insert("scenes".into(), json!([{ "name": name, "nodes": roots }]));
        doc.insert("nodes".into(), Value::Array(nodes));
        // glTF forbids empty arrays: each list is written only when it has entries.
        let lists = [
            ("cameras", self.cameras.clone()),
            (
                "meshes",
                self.meshes.iter().map(|(m, _, _)| m.clone()).collect(),
            ),
            ("materials", materials),
            ("textures", self.textures.clone()),
            ("images", self.images.clone()),
            ("samplers", self.samplers.clone()),
            ("accessors", self.accessors.clone()),
            ("bufferViews", self.buffer_views.clone()),
            ("animations", self.animations.clone()),
        ];
        for (key, list) in lists {
            if !list.is_empty() {
                doc.insert(key.into(), Value::Array(list));
            }
        }
        if !self.lights.is_empty() {
            doc.insert(
                "extensions".into(),
                json!({ LIGHTS_PUNCTUAL: { "lights": self.lights.iter().map(Light::to_json).collect::<Vec<_>>() } }),
            );
        }
        doc.insert(
            "buffers".into(),
            json!([{ "byteLength": self.bin.len(), "uri": bin_name }]),
        );
        let text = serde_json::to_string_pretty(&Value::Object(doc))
            .map_err(std::io::Error::other)?
            + "\n";

        write_atomic(&dir.join(&bin_name), &self.bin)?;
        for (file, bytes) in &self.png_files {
            write_atomic(&dir.join(file), bytes)?;
        }
        write_atomic(&dir.join(format!("{name}.gltf")), text.as_bytes())
    }
}

/// Writes `bytes` to `path` atomically (the library's one way: a `tempfile` in the same
/// folder, renamed), so that a reader never sees a half-written file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    nrc_scene::image::write_atomic(path, bytes).map_err(std::io::Error::other)
}
