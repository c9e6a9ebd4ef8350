//! glTF 2.0 loading (`.gltf` + external or embedded buffers, `.glb`) into a
//! [`SceneDescription`]: meshes flattened to world space through the node hierarchy,
//! materials with their textures (normal maps, alpha modes, both texture coordinate sets),
//! `KHR_lights_punctual` lights, and the first perspective camera.
//!
//! Every problem in the input is reported as a [`SceneError`] naming the file, buffer,
//! image or mesh at fault; nothing in the input can make the loader panic (accessor types
//! and ranges are checked before the `gltf` crate's readers see them).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Quat, Vec2, Vec3, Vec4};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;

use crate::animation::{
    AnimatedScene, Animation, Binding, Channel, Interpolation, Local, Property,
};
use crate::camera::Camera;
use crate::error::{Result, SceneError};
use crate::light::{PunctualKind, PunctualLight};
use crate::material::{AlphaMode, Material};
use crate::scene::{Scene, SceneDescription};
use crate::texture::{Texture, TextureRef, UvTransform, WrapMode, srgb_to_linear};

/// Extensions this loader implements; a file may require them.
pub const SUPPORTED_EXTENSIONS: [&str; 6] = [
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_materials_specular",
    "KHR_texture_transform",
];

/// Loads a `.gltf` or `.glb` file into a [`Scene`].
pub fn load(path: &Path) -> Result<Scene> {
    Scene::from_description(load_description(path)?)
}

/// Loads a `.gltf` or `.glb` file into a [`SceneDescription`] (world-space meshes).
pub fn load_description(path: &Path) -> Result<SceneDescription> {
    load_animated(path).map(|(d, _)| d)
}

/// Loads a `.gltf` or `.glb` file into a [`SceneDescription`] at rest and its node animations
/// (translation, rotation and scale channels; see [`crate::animation`]).
pub fn load_animated(path: &Path) -> Result<(SceneDescription, Animation)> {
    let bytes = std::fs::read(path).map_err(|source| SceneError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let parse = |message: String| SceneError::Parse {
        path: path.to_path_buf(),
        message,
    };
    check_glb_header(&bytes).map_err(parse)?;
    let describe = |e: gltf::Error| match e {
        gltf::Error::Deserialize(e) => format!("invalid JSON: {e}"),
        gltf::Error::Binary(e) => format!("corrupt .glb container: {e}"),
        gltf::Error::Validation(errors) => format!(
            "invalid glTF document: {}",
            errors
                .iter()
                .map(|(p, e)| format!("{}: {e}", p.as_str()))
                .collect::<Vec<_>>()
                .join("; ")
        ),
        e => e.to_string(),
    };
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(&bytes).map_err(|e| parse(describe(e)))?;
    // Before validation: required extensions get their own error (the gltf crate's
    // validation would report them as a generic failure), and a POSITION accessor index
    // out of range would make that validation panic.
    check_required_extensions(path, &document)?;
    let json = document.into_json();
    let n_accessors = json.accessors.len();
    for (m, mesh) in json.meshes.iter().enumerate() {
        for prim in &mesh.primitives {
            for (_, index) in prim.attributes.iter() {
                if index.value() >= n_accessors {
                    return Err(parse(format!(
                        "invalid glTF document: mesh {m} refers to missing accessor {}",
                        index.value()
                    )));
                }
            }
        }
    }
    // Fields the gltf crate's accessors unwrap (the mutation tests found both panics): an
    // animation channel's target path and interpolation that did not parse, an image with
    // neither a URI nor a buffer view, or a buffer view without a MIME type.
    for (a, anim) in json.animations.iter().enumerate() {
        let bad = |m: &str| parse(format!("invalid glTF document: animation {a}: {m}"));
        for c in &anim.channels {
            if !matches!(c.target.path, gltf::json::validation::Checked::Valid(_)) {
                return Err(bad(
                    "a channel's target path is not translation, rotation, scale or weights",
                ));
            }
            if c.sampler.value() >= anim.samplers.len() || c.target.node.value() >= json.nodes.len()
            {
                return Err(bad("a channel refers to a missing sampler or node"));
            }
        }
        for sm in &anim.samplers {
            if !matches!(sm.interpolation, gltf::json::validation::Checked::Valid(_)) {
                return Err(bad(
                    "a sampler's interpolation is not STEP, LINEAR or CUBICSPLINE",
                ));
            }
            if sm.input.value() >= n_accessors || sm.output.value() >= n_accessors {
                return Err(bad("a sampler refers to a missing accessor"));
            }
        }
    }
    for (i, image) in json.images.iter().enumerate() {
        let bad = |m: &str| parse(format!("invalid glTF document: image {i}: {m}"));
        match (&image.uri, &image.buffer_view) {
            (None, None) => return Err(bad("neither a uri nor a bufferView")),
            (_, Some(_)) if image.mime_type.is_none() => {
                return Err(bad("a bufferView image needs a mimeType"));
            }
            _ => {}
        }
    }
    let document = gltf::Document::from_json(json).map_err(|e| parse(describe(e)))?;
    let mut loader = Loader {
        path: path.to_path_buf(),
        base: path.parent().map(Path::to_path_buf).unwrap_or_default(),
        document: &document,
        buffers: Vec::new(),
        images: HashMap::new(),
        textures: Vec::new(),
        texture_keys: HashMap::new(),
        warnings: Vec::new(),
    };
    loader.warn_unused_extensions();
    loader.load_buffers(blob)?;
    let mut animation = loader.animation()?;
    let (desc, bindings) = loader.build()?;
    animation.bindings = bindings;
    Ok((desc, animation))
}

/// Unsupported required extensions are errors.
fn check_required_extensions(path: &Path, document: &gltf::Document) -> Result<()> {
    match document
        .extensions_required()
        .find(|e| !SUPPORTED_EXTENSIONS.contains(e))
    {
        Some(name) => Err(SceneError::UnsupportedExtension {
            path: path.to_path_buf(),
            name: name.to_string(),
        }),
        None => Ok(()),
    }
}

/// Checks the 12-byte `.glb` header against the file length, so that a truncated file is
/// reported as such (the `gltf` crate's message for it is vague).
fn check_glb_header(bytes: &[u8]) -> std::result::Result<(), String> {
    if !bytes.starts_with(b"glTF") {
        return Ok(());
    }
    if bytes.len() < 12 {
        return Err(format!(
            "truncated .glb: {} bytes, shorter than the 12-byte header",
            bytes.len()
        ));
    }
    let declared = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
    if declared > bytes.len() {
        return Err(format!(
            "truncated .glb: header declares {declared} bytes but the file has {}",
            bytes.len()
        ));
    }
    Ok(())
}

/// Decodes `%XX` escapes of a relative URI.
pub fn percent_decode(uri: &str) -> String {
    let hex = |c: u8| (c as char).to_digit(16).map(|d| d as u8);
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push(h * 16 + l);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Per-vertex attributes gathered over all primitives (`None` where a primitive lacks one).
#[derive(Default)]
struct VertexAttributes {
    normals: Vec<Option<Vec3>>,
    uvs: Vec<Option<Vec2>>,
    uvs1: Vec<Option<Vec2>>,
    tangents: Vec<Option<Vec4>>,
}

struct Loader<'a> {
    path: PathBuf,
    base: PathBuf,
    document: &'a gltf::Document,
    buffers: Vec<gltf::buffer::Data>,
    /// Decoded images by glTF image index.
    images: HashMap<usize, gltf::image::Data>,
    textures: Vec<Texture>,
    /// (glTF texture index, sRGB) → index into `textures`.
    texture_keys: HashMap<(usize, bool), u32>,
    warnings: Vec<String>,
}

impl Loader<'_> {
    fn warn(&mut self, message: String) {
        eprintln!("warning: {}: {message}", self.path.display());
        self.warnings.push(message);
    }

    fn mesh_error(&self, mesh: &gltf::Mesh, message: String) -> SceneError {
        SceneError::Mesh {
            path: self.path.clone(),
            mesh: mesh
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("#{}", mesh.index())),
            message,
        }
    }

    fn invalid(&self, message: String) -> SceneError {
        SceneError::Invalid {
            path: self.path.clone(),
            message,
        }
    }

    /// Unknown extensions that the file uses (but does not require) are ignored with a
    /// warning.
    fn warn_unused_extensions(&mut self) {
        let ignored: Vec<String> = self
            .document
            .extensions_used()
            .filter(|e| !SUPPORTED_EXTENSIONS.contains(e))
            .map(str::to_string)
            .collect();
        for e in ignored {
            self.warn(format!("ignoring unsupported glTF extension `{e}`"));
        }
    }

    fn load_buffers(&mut self, mut blob: Option<Vec<u8>>) -> Result<()> {
        for buffer in self.document.buffers() {
            let index = buffer.index();
            let err = |uri: &str, message: String| SceneError::Buffer {
                path: self.path.clone(),
                index,
                uri: uri.to_string(),
                message,
            };
            let data = match buffer.source() {
                gltf::buffer::Source::Bin => blob
                    .take()
                    .ok_or_else(|| err("GLB BIN chunk", "the .glb has no BIN chunk".into()))?,
                gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                    gltf::buffer::Data::from_source(buffer.source(), None)
                        .map_err(|e| err("data URI", format!("cannot decode data URI: {e}")))?
                        .0
                }
                gltf::buffer::Source::Uri(uri) => {
                    let file = self.base.join(percent_decode(uri));
                    std::fs::read(&file).map_err(|e| {
                        err(
                            uri,
                            format!("cannot read buffer file {}: {e}", file.display()),
                        )
                    })?
                }
            };
            if data.len() < buffer.length() {
                let uri = match buffer.source() {
                    gltf::buffer::Source::Uri(u) if !u.starts_with("data:") => u,
                    gltf::buffer::Source::Uri(_) => "data URI",
                    gltf::buffer::Source::Bin => "GLB BIN chunk",
                };
                return Err(err(
                    uri,
                    format!(
                        "truncated buffer: {} bytes, the document declares {}",
                        data.len(),
                        buffer.length()
                    ),
                ));
            }
            self.buffers.push(gltf::buffer::Data(data));
        }
        Ok(())
    }

    /// The description at rest, and what each node carries (for [`Animation`]).
    fn build(&mut self) -> Result<(SceneDescription, Vec<Binding>)> {
        let mut bindings = Vec::new();
        let document = self.document;
        let mut desc = SceneDescription {
            source: self.path.clone(),
            ..Default::default()
        };

        // Materials; the glTF default material goes last for primitives without one.
        for m in document.materials() {
            let material = self.material(&m)?;
            desc.materials.push(material);
        }
        let default_material = desc.materials.len() as u32;
        desc.materials.push(Material::default());

        // Walk the node hierarchy of the default scene (or the first, or every root node).
        let roots: Vec<gltf::Node> = match document
            .default_scene()
            .or_else(|| document.scenes().next())
        {
            Some(s) => s.nodes().collect(),
            None => {
                let mut is_child = vec![false; document.nodes().len()];
                for n in document.nodes() {
                    for c in n.children() {
                        is_child[c.index()] = true;
                    }
                }
                document.nodes().filter(|n| !is_child[n.index()]).collect()
            }
        };
        let mut stack: Vec<(gltf::Node, Mat4, usize)> = roots
            .into_iter()
            .rev()
            .map(|n| (n, Mat4::IDENTITY, 0))
            .collect();
        let mut attrs = VertexAttributes::default();
        while let Some((node, parent, depth)) = stack.pop() {
            if depth > 256 {
                return Err(self.invalid("node hierarchy deeper than 256 levels (a cycle?)".into()));
            }
            let local = Mat4::from_cols_array_2d(&node.transform().matrix());
            let world = parent * local;
            if !world.is_finite() {
                return Err(self.invalid(format!(
                    "node {} has a non-finite transform",
                    node.name()
                        .map(str::to_string)
                        .unwrap_or_else(|| format!("#{}", node.index()))
                )));
            }
            if let Some(cam) = node.camera()
                && desc.camera.is_none()
            {
                match cam.projection() {
                    gltf::camera::Projection::Perspective(p) => {
                        match Camera::from_world_matrix(&world, p.yfov()) {
                            Ok(c) => {
                                desc.camera = Some(c);
                                bindings.push(Binding::Camera {
                                    node: node.index(),
                                    fov_y: p.yfov(),
                                });
                            }
                            Err(e) => self.warn(format!("ignoring camera {}: {e}", cam.index())),
                        }
                    }
                    gltf::camera::Projection::Orthographic(_) => {
                        self.warn(format!("ignoring orthographic camera {}", cam.index()))
                    }
                }
            }
            if let Some(light) = node.light() {
                let l = self.light(&light, &world)?;
                bindings.push(Binding::Light {
                    node: node.index(),
                    light: desc.lights.len(),
                });
                desc.lights.push(l);
            }
            if let Some(mesh) = node.mesh() {
                let first = desc.positions.len();
                for prim in mesh.primitives() {
                    self.primitive(
                        &mesh,
                        &prim,
                        &world,
                        default_material,
                        &mut desc,
                        &mut attrs,
                    )?;
                }
                bindings.push(Binding::Vertices {
                    node: node.index(),
                    range: first..desc.positions.len(),
                });
            }
            for child in node.children() {
                stack.push((child, world, depth + 1));
            }
        }
        let VertexAttributes {
            normals,
            uvs,
            uvs1,
            tangents,
        } = attrs;
        fn fill<T: Copy>(v: Vec<Option<T>>, zero: T) -> Vec<T> {
            if v.iter().any(Option::is_some) {
                v.into_iter().map(|x| x.unwrap_or(zero)).collect()
            } else {
                Vec::new()
            }
        }
        desc.normals = fill(normals, Vec3::ZERO);
        desc.uvs = fill(uvs, Vec2::ZERO);
        desc.uvs1 = fill(uvs1, Vec2::ZERO);
        desc.tangents = fill(tangents, Vec4::ZERO);
        desc.textures = std::mem::take(&mut self.textures);
        desc.warnings = std::mem::take(&mut self.warnings);
        Ok((desc, bindings))
    }

    /// The node hierarchy at rest and the animation channels (all animations of the document
    /// play together, from time 0).
    fn animation(&mut self) -> Result<Animation> {
        let document = self.document;
        let mut nodes: Vec<(Local, Option<usize>)> = document
            .nodes()
            .map(|n| {
                let local = match n.transform() {
                    gltf::scene::Transform::Decomposed {
                        translation,
                        rotation,
                        scale,
                    } => Local::Trs(
                        Vec3::from(translation),
                        Quat::from_array(rotation),
                        Vec3::from(scale),
                    ),
                    gltf::scene::Transform::Matrix { matrix } => {
                        Local::Matrix(Mat4::from_cols_array_2d(&matrix))
                    }
                };
                (local, None)
            })
            .collect();
        for n in document.nodes() {
            for c in n.children() {
                nodes[c.index()].1 = Some(n.index());
            }
        }
        // Every chain of parents ends (no node is its own ancestor).
        for start in 0..nodes.len() {
            let (mut at, mut steps) = (start, 0);
            while let Some(p) = nodes[at].1 {
                at = p;
                steps += 1;
                if steps > nodes.len() {
                    return Err(self.invalid(format!("node {start} is its own ancestor")));
                }
            }
        }
        let mut channels = Vec::new();
        for anim in document.animations() {
            for channel in anim.channels() {
                let node = channel.target().node().index();
                let property = match channel.target().property() {
                    gltf::animation::Property::Translation => Property::Translation,
                    gltf::animation::Property::Rotation => Property::Rotation,
                    gltf::animation::Property::Scale => Property::Scale,
                    gltf::animation::Property::MorphTargetWeights => {
                        self.warn(format!(
                            "animation {}: ignoring a morph-target weights channel",
                            anim.index()
                        ));
                        continue;
                    }
                };
                if matches!(nodes[node].0, Local::Matrix(_)) {
                    return Err(self.invalid(format!(
                        "animation {} drives node {node}, which has a matrix (glTF allows animating only translation, rotation and scale)",
                        anim.index()
                    )));
                }
                let sampler = channel.sampler();
                let interpolation = match sampler.interpolation() {
                    gltf::animation::Interpolation::Step => Interpolation::Step,
                    gltf::animation::Interpolation::Linear => Interpolation::Linear,
                    gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
                };
                let what = |m: &str| format!("animation {}: {m}", anim.index());
                let (input, output) = (sampler.input(), sampler.output());
                let dims = if property == Property::Rotation {
                    Dimensions::Vec4
                } else {
                    Dimensions::Vec3
                };
                let float_or_normalized = property == Property::Rotation
                    && output.normalized()
                    && output.data_type() != DataType::U32;
                if input.data_type() != DataType::F32
                    || input.dimensions() != Dimensions::Scalar
                    || (output.data_type() != DataType::F32 && !float_or_normalized)
                    || output.dimensions() != dims
                {
                    return Err(self.invalid(what(
                        "sampler accessors must be float scalars (times) and float vectors (values)",
                    )));
                }
                for a in [&input, &output] {
                    if a.view().is_none() || a.count() == 0 {
                        return Err(self.invalid(what("sampler accessor without data")));
                    }
                }
                let buffers = &self.buffers;
                let reader = channel.reader(|b| buffers.get(b.index()).map(|d| d.0.as_slice()));
                let times: Vec<f32> = reader
                    .read_inputs()
                    .ok_or_else(|| self.invalid(what("unreadable key times")))?
                    .collect();
                let values: Vec<Vec4> = match reader.read_outputs() {
                    Some(gltf::animation::util::ReadOutputs::Translations(it))
                    | Some(gltf::animation::util::ReadOutputs::Scales(it)) => {
                        it.map(|v| Vec3::from(v).extend(0.0)).collect()
                    }
                    Some(gltf::animation::util::ReadOutputs::Rotations(r)) => {
                        r.into_f32().map(Vec4::from).collect()
                    }
                    _ => return Err(self.invalid(what("unreadable key values"))),
                };
                let c = Channel::new(node, property, interpolation, times, values)
                    .map_err(|e| self.invalid(what(&e)))?;
                channels.push(c);
            }
        }
        Ok(Animation {
            nodes,
            channels,
            bindings: Vec::new(),
        })
    }

    /// Appends one primitive's triangles, transformed to world space.
    fn primitive(
        &mut self,
        mesh: &gltf::Mesh,
        prim: &gltf::Primitive,
        world: &Mat4,
        default_material: u32,
        desc: &mut SceneDescription,
        attrs: &mut VertexAttributes,
    ) -> Result<()> {
        let mode = prim.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            self.warn(format!(
                "mesh `{}`: skipping a primitive of mode {mode:?} (only triangles are rendered)",
                mesh.name().unwrap_or("")
            ));
            return Ok(());
        }
        let buffers = &self.buffers;
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| d.0.as_slice()));

        // Check accessor types and sizes first: the gltf readers assume them.
        let pos_acc = prim
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| self.mesh_error(mesh, "primitive has no POSITION attribute".into()))?;
        self.check_accessor(
            mesh,
            &pos_acc,
            "POSITION",
            &[DataType::F32],
            &[Dimensions::Vec3],
        )?;
        let n_vertices = pos_acc.count();
        let normal_acc = prim.get(&gltf::Semantic::Normals);
        if let Some(a) = &normal_acc {
            self.check_accessor(mesh, a, "NORMAL", &[DataType::F32], &[Dimensions::Vec3])?;
        }
        let uv_accs = [0, 1].map(|set| prim.get(&gltf::Semantic::TexCoords(set)));
        for (set, a) in uv_accs.iter().enumerate() {
            if let Some(a) = a {
                self.check_accessor(
                    mesh,
                    a,
                    &format!("TEXCOORD_{set}"),
                    &[DataType::F32, DataType::U8, DataType::U16],
                    &[Dimensions::Vec2],
                )?;
            }
        }
        let tangent_acc = prim.get(&gltf::Semantic::Tangents);
        if let Some(a) = &tangent_acc {
            self.check_accessor(mesh, a, "TANGENT", &[DataType::F32], &[Dimensions::Vec4])?;
        }
        if let Some(a) = prim.indices() {
            self.check_accessor(
                mesh,
                &a,
                "indices",
                &[DataType::U8, DataType::U16, DataType::U32],
                &[Dimensions::Scalar],
            )?;
        }

        let out_of_range =
            |what: &str| self.mesh_error(mesh, format!("{what} accessor lies outside its buffer"));
        let positions: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| out_of_range("POSITION"))?
            .map(Vec3::from)
            .collect();
        if positions.len() != n_vertices {
            return Err(out_of_range("POSITION"));
        }
        if let Some(bad) = positions.iter().position(|p| !p.is_finite()) {
            return Err(self.mesh_error(
                mesh,
                format!("non-finite (NaN or infinite) vertex position at vertex {bad}"),
            ));
        }
        let normals: Option<Vec<Vec3>> = match normal_acc {
            Some(a) => {
                let n: Vec<Vec3> = reader
                    .read_normals()
                    .ok_or_else(|| out_of_range("NORMAL"))?
                    .map(Vec3::from)
                    .collect();
                if n.len() != n_vertices || a.count() != n_vertices {
                    return Err(self.mesh_error(mesh, "NORMAL and POSITION counts differ".into()));
                }
                Some(n)
            }
            None => None,
        };
        let mut uvs: [Option<Vec<Vec2>>; 2] = [None, None];
        for (set, a) in uv_accs.iter().enumerate() {
            if let Some(a) = a {
                let name = format!("TEXCOORD_{set}");
                let t: Vec<Vec2> = reader
                    .read_tex_coords(set as u32)
                    .ok_or_else(|| out_of_range(&name))?
                    .into_f32()
                    .map(Vec2::from)
                    .collect();
                if t.len() != n_vertices || a.count() != n_vertices {
                    return Err(self.mesh_error(mesh, format!("{name} and POSITION counts differ")));
                }
                uvs[set] = Some(t);
            }
        }
        let tangents: Option<Vec<Vec4>> = match tangent_acc {
            Some(a) => {
                let t: Vec<Vec4> = reader
                    .read_tangents()
                    .ok_or_else(|| out_of_range("TANGENT"))?
                    .map(Vec4::from)
                    .collect();
                if t.len() != n_vertices || a.count() != n_vertices {
                    return Err(self.mesh_error(mesh, "TANGENT and POSITION counts differ".into()));
                }
                Some(t)
            }
            None => None,
        };
        let indices: Vec<u32> = match prim.indices() {
            Some(_) => reader
                .read_indices()
                .ok_or_else(|| out_of_range("indices"))?
                .into_u32()
                .collect(),
            None => (0..n_vertices as u32).collect(),
        };
        if let Some(&bad) = indices.iter().find(|&&i| i as usize >= n_vertices) {
            return Err(self.mesh_error(
                mesh,
                format!("vertex index {bad} out of range ({n_vertices} vertices)"),
            ));
        }
        let triangles: Vec<[u32; 3]> = match mode {
            Mode::Triangles => {
                if !indices.len().is_multiple_of(3) {
                    self.warn(format!(
                        "mesh `{}`: index count {} is not a multiple of 3; ignoring the rest",
                        mesh.name().unwrap_or(""),
                        indices.len()
                    ));
                }
                indices
                    .chunks_exact(3)
                    .map(|c| [c[0], c[1], c[2]])
                    .collect()
            }
            // Strips alternate winding so that every triangle keeps the first one's.
            Mode::TriangleStrip => (0..indices.len().saturating_sub(2))
                .map(|i| {
                    if i.is_multiple_of(2) {
                        [indices[i], indices[i + 1], indices[i + 2]]
                    } else {
                        [indices[i + 1], indices[i], indices[i + 2]]
                    }
                })
                .collect(),
            _ => (1..indices.len().saturating_sub(1))
                .map(|i| [indices[i], indices[i + 1], indices[0]])
                .collect(),
        };

        // World transform; normals by the inverse transpose. A mirroring transform
        // (negative determinant) flips the winding, which glTF says defines the front face.
        let m3 = Mat3::from_mat4(*world);
        let det = m3.determinant();
        let normal_matrix = if det != 0.0 {
            m3.inverse().transpose()
        } else {
            Mat3::ZERO
        };
        let base = desc.positions.len() as u32;
        for p in &positions {
            let q = world.transform_point3(*p);
            if !q.is_finite() {
                return Err(self.mesh_error(
                    mesh,
                    "vertex position becomes non-finite under its node transform".into(),
                ));
            }
            desc.positions.push(q);
        }
        fn extend<T: Clone>(
            out: &mut Vec<Option<T>>,
            values: Option<Vec<T>>,
            n: usize,
            f: impl Fn(T) -> Option<T>,
        ) {
            match values {
                Some(v) => out.extend(v.into_iter().map(f)),
                None => out.extend(std::iter::repeat_n(None, n)),
            }
        }
        extend(&mut attrs.normals, normals, n_vertices, |n: Vec3| {
            let w = (normal_matrix * n).normalize_or_zero();
            (w.is_finite() && w != Vec3::ZERO).then_some(w)
        });
        let [uvs0, uvs1] = uvs;
        extend(&mut attrs.uvs, uvs0, n_vertices, |t: Vec2| {
            t.is_finite().then_some(t)
        });
        extend(&mut attrs.uvs1, uvs1, n_vertices, |t: Vec2| {
            t.is_finite().then_some(t)
        });
        // Tangents transform as directions; a mirroring transform flips the handedness.
        let flip = if det < 0.0 { -1.0 } else { 1.0 };
        extend(&mut attrs.tangents, tangents, n_vertices, |t: Vec4| {
            let d = (m3 * t.truncate()).normalize_or_zero();
            (d.is_finite() && d != Vec3::ZERO && t.w.is_finite())
                .then(|| d.extend(if t.w < 0.0 { -flip } else { flip }))
        });
        let material = prim
            .material()
            .index()
            .map_or(default_material, |i| i as u32);
        let mesh_id = desc.mesh_names.len() as u32;
        desc.mesh_names.push(
            mesh.name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("#{}", mesh.index())),
        );
        for t in triangles {
            let t = if det < 0.0 { [t[0], t[2], t[1]] } else { t };
            desc.triangles.push(t.map(|i| base + i));
            desc.triangle_materials.push(material);
            desc.triangle_meshes.push(mesh_id);
        }
        Ok(())
    }

    /// A `KHR_lights_punctual` light under the node transform `world` (position from the
    /// translation, direction the node's −z). Validated here: a negative or non-finite
    /// intensity or colour, a range that is not positive, and a spot whose outer cone angle is
    /// below its inner one or beyond π/2 are errors naming the light.
    fn light(
        &self,
        light: &gltf::khr_lights_punctual::Light,
        world: &Mat4,
    ) -> Result<PunctualLight> {
        let name = light
            .name()
            .map(|n| format!("`{n}`"))
            .unwrap_or_else(|| format!("#{}", light.index()));
        let bad = |field: &str, why: String| {
            self.invalid(format!("KHR_lights_punctual light {name}: {field} {why}"))
        };
        let color = Vec3::from(light.color());
        if !color.is_finite() || color.min_element() < 0.0 {
            return Err(bad(
                "color",
                format!("must be finite and non-negative, got {color}"),
            ));
        }
        let intensity = light.intensity();
        if !intensity.is_finite() || intensity < 0.0 {
            return Err(bad(
                "intensity",
                format!("must be finite and non-negative, got {intensity}"),
            ));
        }
        let range = light.range();
        if let Some(r) = range
            && !(r.is_finite() && r > 0.0)
        {
            return Err(bad("range", format!("must be positive, got {r}")));
        }
        let kind = match light.kind() {
            gltf::khr_lights_punctual::Kind::Point => PunctualKind::Point,
            gltf::khr_lights_punctual::Kind::Directional => PunctualKind::Directional,
            gltf::khr_lights_punctual::Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                let ok = inner_cone_angle.is_finite()
                    && outer_cone_angle.is_finite()
                    && inner_cone_angle >= 0.0
                    && inner_cone_angle <= outer_cone_angle
                    && outer_cone_angle > 0.0
                    && outer_cone_angle <= std::f32::consts::FRAC_PI_2;
                if !ok {
                    return Err(bad(
                        "spot",
                        format!(
                            "cone angles must satisfy 0 ≤ innerConeAngle ≤ outerConeAngle ≤ π/2 with outerConeAngle > 0, got inner {inner_cone_angle}, outer {outer_cone_angle}"
                        ),
                    ));
                }
                PunctualKind::Spot {
                    cos_inner: inner_cone_angle.cos(),
                    cos_outer: outer_cone_angle.cos(),
                }
            }
        };
        let direction = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
        if direction == Vec3::ZERO || !direction.is_finite() {
            return Err(bad(
                "node",
                "has a degenerate transform (no direction)".into(),
            ));
        }
        Ok(PunctualLight {
            kind,
            position: world.transform_point3(Vec3::ZERO),
            direction,
            intensity: color * intensity,
            range: if kind == PunctualKind::Directional {
                None
            } else {
                range
            },
        })
    }

    /// Checks an accessor's component type, dimensions and non-zero count.
    fn check_accessor(
        &self,
        mesh: &gltf::Mesh,
        a: &gltf::Accessor,
        what: &str,
        types: &[DataType],
        dims: &[Dimensions],
    ) -> Result<()> {
        if !types.contains(&a.data_type()) || !dims.contains(&a.dimensions()) {
            return Err(self.mesh_error(
                mesh,
                format!(
                    "{what} accessor has type {:?} {:?}, expected one of {types:?} {dims:?}",
                    a.data_type(),
                    a.dimensions()
                ),
            ));
        }
        if a.count() == 0 {
            return Err(self.mesh_error(mesh, format!("{what} accessor is empty")));
        }
        if a.view().is_none() && a.sparse().is_none() {
            return Err(self.mesh_error(mesh, format!("{what} accessor has no buffer view")));
        }
        Ok(())
    }

    fn material(&mut self, m: &gltf::Material) -> Result<Material> {
        let name = m
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("#{}", m.index().unwrap_or(usize::MAX)));
        let pbr = m.pbr_metallic_roughness();
        let [r, g, b, a] = pbr.base_color_factor();
        let mut out = Material {
            name: name.clone(),
            base_color: Vec3::new(r, g, b),
            base_color_texture: self.texture_ref(pbr.base_color_texture(), true)?,
            metallic: pbr.metallic_factor(),
            roughness: pbr.roughness_factor(),
            metallic_roughness_texture: self
                .texture_ref(pbr.metallic_roughness_texture(), false)?,
            emissive: Vec3::from(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0),
            emissive_texture: self.texture_ref(m.emissive_texture(), true)?,
            double_sided: m.double_sided(),
            alpha: a,
            alpha_mode: match m.alpha_mode() {
                gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
                gltf::material::AlphaMode::Mask => AlphaMode::Mask,
                gltf::material::AlphaMode::Blend => AlphaMode::Blend,
            },
            alpha_cutoff: m.alpha_cutoff().unwrap_or(0.5),
            ..Material::default()
        };
        if let Some(n) = m.normal_texture() {
            let tex = n.texture();
            out.normal_texture = self.texture_ref_of(&tex, n.tex_coord(), None, false)?;
            out.normal_scale = n.scale();
        }
        if out.alpha_mode == AlphaMode::Blend {
            self.warn(format!(
                "material `{name}`: alphaMode BLEND is rendered as coverage (MASK with alphaCutoff {}): a path tracer has no draw order to blend in",
                out.alpha_cutoff
            ));
        }
        if let Some(t) = m.transmission() {
            out.transmission = t.transmission_factor();
            out.transmission_texture = self.texture_ref(t.transmission_texture(), false)?;
        }
        if let Some(ior) = m.ior() {
            out.ior = ior;
        }
        if let Some(s) = m.specular() {
            out.specular = s.specular_factor();
            out.specular_texture = self.texture_ref(s.specular_texture(), false)?;
            out.specular_color = Vec3::from(s.specular_color_factor());
            out.specular_color_texture = self.texture_ref(s.specular_color_texture(), true)?;
        }
        let finite = out.base_color.is_finite()
            && out.emissive.is_finite()
            && out.specular_color.is_finite()
            && [
                out.metallic,
                out.roughness,
                out.transmission,
                out.specular,
                out.ior,
                out.normal_scale,
                out.alpha,
                out.alpha_cutoff,
            ]
            .iter()
            .all(|v| v.is_finite());
        if !finite {
            return Err(self.invalid(format!("material `{name}` has a non-finite parameter")));
        }
        if out.emissive.min_element() < 0.0 {
            return Err(self.invalid(format!("material `{name}` has negative emission")));
        }
        if out.ior < 1.0 {
            // KHR_materials_ior allows 0 as a legacy "infinitely dense" value; no physical
            // dielectric has an IOR below 1 here.
            self.warn(format!(
                "material `{name}`: ior {} below 1 replaced by the default 1.5",
                out.ior
            ));
            out.ior = 1.5;
        }
        Ok(out)
    }

    /// A material's texture, loaded (and sRGB-decoded for colour textures) on first use.
    fn texture_ref(
        &mut self,
        info: Option<gltf::texture::Info>,
        srgb: bool,
    ) -> Result<Option<TextureRef>> {
        let Some(info) = info else { return Ok(None) };
        let mut tex_coord = info.tex_coord();
        let transform = info.texture_transform().map(|t| {
            if let Some(tc) = t.tex_coord() {
                tex_coord = tc;
            }
            UvTransform {
                offset: Vec2::from(t.offset()),
                rotation: t.rotation(),
                scale: Vec2::from(t.scale()),
            }
        });
        self.texture_ref_of(&info.texture(), tex_coord, transform, srgb)
    }

    /// The reference to `tex` read through coordinate set `tex_coord` (0 or 1: sets beyond
    /// `TEXCOORD_1` fall back to 0 with a warning).
    fn texture_ref_of(
        &mut self,
        tex: &gltf::Texture,
        mut tex_coord: u32,
        transform: Option<UvTransform>,
        srgb: bool,
    ) -> Result<Option<TextureRef>> {
        if tex_coord > 1 {
            self.warn(format!(
                "texture {} uses TEXCOORD_{tex_coord}; only TEXCOORD_0 and TEXCOORD_1 are loaded, using TEXCOORD_0 instead",
                tex.index()
            ));
            tex_coord = 0;
        }
        let key = (tex.index(), srgb);
        let index = match self.texture_keys.get(&key) {
            Some(&i) => i,
            None => {
                let texture = self.decode_texture(tex, srgb)?;
                let i = self.textures.len() as u32;
                self.textures.push(texture);
                self.texture_keys.insert(key, i);
                i
            }
        };
        Ok(Some(TextureRef {
            texture: index,
            transform,
            tex_coord,
        }))
    }

    fn decode_texture(&mut self, tex: &gltf::Texture, srgb: bool) -> Result<Texture> {
        let image = tex.source();
        let index = image.index();
        let uri = match image.source() {
            gltf::image::Source::Uri { uri, .. } if uri.starts_with("data:") => "data URI".into(),
            gltf::image::Source::Uri { uri, .. } => uri.to_string(),
            gltf::image::Source::View { .. } => "embedded in a buffer view".to_string(),
        };
        let err = |message: String| SceneError::Texture {
            path: self.path.clone(),
            index,
            uri: uri.clone(),
            message,
        };
        if !self.images.contains_key(&index) {
            if let gltf::image::Source::Uri { uri, .. } = image.source()
                && !uri.starts_with("data:")
            {
                let file = self.base.join(percent_decode(uri));
                if !file.is_file() {
                    return Err(err(format!("image file {} not found", file.display())));
                }
            }
            let buffers = &self.buffers;
            // Buffer-view images: check the range before the gltf crate slices it.
            if let gltf::image::Source::View { view, .. } = image.source() {
                let ok = buffers
                    .get(view.buffer().index())
                    .is_some_and(|b| view.offset() + view.length() <= b.0.len());
                if !ok {
                    return Err(err("image buffer view lies outside its buffer".into()));
                }
            }
            let data = gltf::image::Data::from_source(image.source(), Some(&self.base), buffers)
                .map_err(|e| err(format!("cannot decode image: {e}")))?;
            self.images.insert(index, data);
        }
        let data = &self.images[&index];
        let texels =
            image_texels(data, srgb).ok_or_else(|| err("unsupported pixel format".into()))?;
        let mut texture = Texture::new(data.width, data.height, texels).ok_or_else(|| {
            err(format!(
                "image of size {}×{} is unusable",
                data.width, data.height
            ))
        })?;
        let sampler = tex.sampler();
        let wrap = |w: gltf::texture::WrappingMode| match w {
            gltf::texture::WrappingMode::ClampToEdge => WrapMode::ClampToEdge,
            gltf::texture::WrappingMode::MirroredRepeat => WrapMode::MirroredRepeat,
            gltf::texture::WrappingMode::Repeat => WrapMode::Repeat,
        };
        texture.wrap_s = wrap(sampler.wrap_s());
        texture.wrap_t = wrap(sampler.wrap_t());
        texture.nearest = sampler.mag_filter() == Some(gltf::texture::MagFilter::Nearest);
        Ok(texture)
    }
}

/// Converts decoded image data to linear RGBA texels (missing channels: G = B = R for
/// grey images, A = 1). Colour data is sRGB-decoded when `srgb`; alpha never is.
fn image_texels(data: &gltf::image::Data, srgb: bool) -> Option<Vec<Vec4>> {
    use gltf::image::Format;
    let (channels, bytes_per) = match data.format {
        Format::R8 => (1, 1),
        Format::R8G8 => (2, 1),
        Format::R8G8B8 => (3, 1),
        Format::R8G8B8A8 => (4, 1),
        Format::R16 => (1, 2),
        Format::R16G16 => (2, 2),
        Format::R16G16B16 => (3, 2),
        Format::R16G16B16A16 => (4, 2),
        Format::R32G32B32FLOAT => (3, 4),
        Format::R32G32B32A32FLOAT => (4, 4),
    };
    let n = data.width as usize * data.height as usize;
    if data.pixels.len() < n * channels * bytes_per {
        return None;
    }
    let is_float = matches!(
        data.format,
        Format::R32G32B32FLOAT | Format::R32G32B32A32FLOAT
    );
    let value = |i: usize| -> f32 {
        let o = i * bytes_per;
        match bytes_per {
            1 => data.pixels[o] as f32 / 255.0,
            2 => u16::from_le_bytes([data.pixels[o], data.pixels[o + 1]]) as f32 / 65535.0,
            _ => f32::from_le_bytes([
                data.pixels[o],
                data.pixels[o + 1],
                data.pixels[o + 2],
                data.pixels[o + 3],
            ]),
        }
    };
    // 8-bit sRGB decoding through a table.
    let lut: Vec<f32> = (0..256).map(|i| srgb_to_linear(i as f32 / 255.0)).collect();
    let decode = |i: usize| -> f32 {
        if srgb && !is_float {
            if bytes_per == 1 {
                lut[data.pixels[i] as usize]
            } else {
                srgb_to_linear(value(i))
            }
        } else {
            value(i)
        }
    };
    let texels = (0..n)
        .map(|p| {
            let b = p * channels;
            match channels {
                1 => {
                    let v = decode(b);
                    Vec4::new(v, v, v, 1.0)
                }
                2 => {
                    let v = decode(b);
                    Vec4::new(v, v, v, value(b + 1))
                }
                3 => Vec4::new(decode(b), decode(b + 1), decode(b + 2), 1.0),
                _ => Vec4::new(decode(b), decode(b + 1), decode(b + 2), value(b + 3)),
            }
        })
        .map(|t| if t.is_finite() { t } else { Vec4::ZERO })
        .collect();
    Some(texels)
}

impl Scene {
    /// Loads a glTF 2.0 scene (`.gltf` with its buffers and images, or `.glb`).
    pub fn load(path: &Path) -> Result<Scene> {
        load(path)
    }
}

impl AnimatedScene {
    /// Loads a `.gltf` or `.glb` with its animations (a scene without any has none: every
    /// time gives the rest pose).
    pub fn load(path: &Path) -> Result<Self> {
        let (rest, animation) = load_animated(path)?;
        Ok(Self { rest, animation })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_decoding() {
        assert_eq!(percent_decode("a%20b.bin"), "a b.bin");
        assert_eq!(percent_decode("100%"), "100%");
        assert_eq!(percent_decode("x%2"), "x%2");
        assert_eq!(percent_decode("plain.bin"), "plain.bin");
    }
}
