//! Checks of a written glTF document against the rules of the glTF 2.0 specification that a
//! hand-written writer can get wrong, done on the files as written (not on the builder):
//! buffer length, 4-byte alignment of views and accessors, accessor bounds, POSITION
//! min/max equal to the data, index ranges, no degenerate triangles, unit normals, declared
//! extensions, no required extensions, readable images, a camera, and well-formed
//! `KHR_lights_punctual` lights.

use std::collections::BTreeSet;
use std::path::Path;

use serde_json::Value;

type Result<T> = std::result::Result<T, String>;

fn get<'a>(v: &'a Value, key: &str) -> Result<&'a Value> {
    v.get(key).ok_or_else(|| format!("missing `{key}`"))
}

fn uint(v: &Value, key: &str) -> Result<usize> {
    get(v, key)?
        .as_u64()
        .map(|x| x as usize)
        .ok_or_else(|| format!("`{key}` is not an unsigned integer"))
}

fn components(kind: &str) -> Result<usize> {
    Ok(match kind {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC3" => 3,
        "VEC4" => 4,
        other => return Err(format!("unexpected accessor type {other}")),
    })
}

/// Typed views of the accessors' data in the buffer.
struct Accessors<'a> {
    json: &'a Value,
    bin: &'a [u8],
}

impl Accessors<'_> {
    fn bytes(&self, index: usize, component_type: u64) -> Result<(&[u8], usize, usize)> {
        let accessor = &self.json["accessors"][index];
        let got = get(accessor, "componentType")?.as_u64().unwrap_or(0);
        if got != component_type {
            return Err(format!(
                "accessor {index}: componentType {got}, expected {component_type}"
            ));
        }
        let size = match component_type {
            5123 => 2,
            5125 | 5126 => 4,
            other => {
                return Err(format!(
                    "accessor {index}: unexpected componentType {other}"
                ));
            }
        };
        let n = components(get(accessor, "type")?.as_str().unwrap_or(""))?;
        let count = uint(accessor, "count")?;
        let offset = accessor
            .get("byteOffset")
            .and_then(Value::as_u64)
            .unwrap_or(0) as usize;
        let view = &self.json["bufferViews"][uint(accessor, "bufferView")?];
        let view_offset = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
        let view_length = uint(view, "byteLength")?;
        if view.get("byteStride").is_some() {
            return Err(format!(
                "accessor {index}: interleaved views are not written by this generator"
            ));
        }
        if !(view_offset + offset).is_multiple_of(size) {
            return Err(format!(
                "accessor {index}: data not aligned to its {size}-byte components"
            ));
        }
        if offset + count * n * size > view_length {
            return Err(format!("accessor {index}: runs past its buffer view"));
        }
        let start = view_offset + offset;
        Ok((&self.bin[start..start + count * n * size], count, n))
    }

    fn floats(&self, index: usize) -> Result<(Vec<f32>, usize, usize)> {
        let (b, count, n) = self.bytes(index, 5126)?;
        Ok((
            b.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            count,
            n,
        ))
    }

    fn indices(&self, index: usize) -> Result<Vec<u32>> {
        let ty = self.json["accessors"][index]["componentType"]
            .as_u64()
            .unwrap_or(0);
        let (b, _, n) = self.bytes(index, ty)?;
        if n != 1 {
            return Err(format!("index accessor {index} is not SCALAR"));
        }
        Ok(match ty {
            5123 => b
                .chunks_exact(2)
                .map(|c| u32::from(u16::from_le_bytes([c[0], c[1]])))
                .collect(),
            _ => b
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        })
    }
}

/// Validates `<dir>/<name>.gltf` and the files it names.
pub fn validate(dir: &Path, name: &str) -> Result<()> {
    let path = dir.join(format!("{name}.gltf"));
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let json: Value =
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let in_doc = |e: String| format!("{}: {e}", path.display());

    if json["asset"]["version"] != "2.0" {
        return Err(in_doc("asset.version is not 2.0".into()));
    }
    if json.get("extensionsRequired").is_some() {
        return Err(in_doc("extensionsRequired is set".into()));
    }
    // No array in the document may be empty.
    for (key, value) in json.as_object().expect("object") {
        if value.as_array().is_some_and(Vec::is_empty) {
            return Err(in_doc(format!("`{key}` is an empty array")));
        }
    }

    let buffer = &json["buffers"][0];
    let bin_path = dir.join(get(buffer, "uri").map_err(in_doc)?.as_str().unwrap_or(""));
    let bin = std::fs::read(&bin_path).map_err(|e| format!("{}: {e}", bin_path.display()))?;
    if uint(buffer, "byteLength").map_err(in_doc)? != bin.len() {
        return Err(in_doc(format!(
            "buffer byteLength differs from the size of {}",
            bin_path.display()
        )));
    }
    for (i, view) in json["bufferViews"]
        .as_array()
        .into_iter()
        .flatten()
        .enumerate()
    {
        let offset = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
        if !offset.is_multiple_of(4) {
            return Err(in_doc(format!("bufferView {i} is not 4-byte aligned")));
        }
        if offset + uint(view, "byteLength").map_err(in_doc)? > bin.len() {
            return Err(in_doc(format!("bufferView {i} runs past the buffer")));
        }
    }

    let acc = Accessors {
        json: &json,
        bin: &bin,
    };
    let mut used = BTreeSet::new();
    for (m, material) in json["materials"]
        .as_array()
        .into_iter()
        .flatten()
        .enumerate()
    {
        if material.get("doubleSided").is_none() {
            return Err(in_doc(format!("material {m} does not state doubleSided")));
        }
        if let Some(f) = material.get("emissiveFactor").and_then(Value::as_array)
            && f.iter()
                .any(|c| !(0.0..=1.0).contains(&c.as_f64().unwrap_or(-1.0)))
        {
            return Err(in_doc(format!(
                "material {m}: emissiveFactor outside [0, 1]"
            )));
        }
        for ext in material
            .get("extensions")
            .and_then(Value::as_object)
            .into_iter()
            .flatten()
        {
            used.insert(ext.0.clone());
        }
    }
    // KHR_lights_punctual: the document's list of lights, referenced by nodes.
    if let Some(lights) = json
        .get("extensions")
        .and_then(|e| e.get("KHR_lights_punctual"))
    {
        used.insert("KHR_lights_punctual".to_owned());
        let lights = get(lights, "lights")
            .map_err(in_doc)?
            .as_array()
            .ok_or_else(|| in_doc("KHR_lights_punctual.lights is not an array".into()))?;
        if lights.is_empty() {
            return Err(in_doc("KHR_lights_punctual.lights is empty".into()));
        }
        for (i, light) in lights.iter().enumerate() {
            let bad = |why: &str| in_doc(format!("KHR_lights_punctual light {i}: {why}"));
            let intensity = light
                .get("intensity")
                .and_then(Value::as_f64)
                .unwrap_or(1.0);
            if !(intensity.is_finite() && intensity >= 0.0) {
                return Err(bad("intensity not finite and non-negative"));
            }
            if let Some(c) = light.get("color").and_then(Value::as_array)
                && (c.len() != 3
                    || c.iter()
                        .any(|c| !(0.0..=1.0).contains(&c.as_f64().unwrap_or(-1.0))))
            {
                return Err(bad("color not three values in [0, 1]"));
            }
            match light.get("type").and_then(Value::as_str) {
                Some("point" | "directional") => {}
                Some("spot") => {
                    let spot = get(light, "spot").map_err(|e| bad(&e))?;
                    let inner = spot
                        .get("innerConeAngle")
                        .and_then(Value::as_f64)
                        .unwrap_or(0.0);
                    let outer = spot
                        .get("outerConeAngle")
                        .and_then(Value::as_f64)
                        .unwrap_or(std::f64::consts::FRAC_PI_4);
                    if !(0.0 <= inner && inner < outer && outer <= std::f64::consts::FRAC_PI_2) {
                        return Err(bad("spot cone angles not 0 ≤ inner < outer ≤ π/2"));
                    }
                }
                _ => return Err(bad("type not point, spot or directional")),
            }
        }
        let mut referenced = vec![false; lights.len()];
        for node in json["nodes"].as_array().into_iter().flatten() {
            if let Some(l) = node.pointer("/extensions/KHR_lights_punctual/light") {
                let l = l
                    .as_u64()
                    .map(|l| l as usize)
                    .filter(|&l| l < lights.len())
                    .ok_or_else(|| in_doc(format!("node light index {l} out of range")))?;
                referenced[l] = true;
            }
        }
        if referenced.contains(&false) {
            return Err(in_doc("a KHR_lights_punctual light is on no node".into()));
        }
    }
    let declared: BTreeSet<String> = json["extensionsUsed"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|e| e.as_str().map(str::to_owned))
        .collect();
    if used != declared {
        return Err(in_doc(format!(
            "extensionsUsed {declared:?} but the document uses {used:?}"
        )));
    }

    for (m, mesh) in json["meshes"].as_array().into_iter().flatten().enumerate() {
        for prim in get(mesh, "primitives")
            .map_err(in_doc)?
            .as_array()
            .into_iter()
            .flatten()
        {
            if prim.get("mode").and_then(Value::as_u64).unwrap_or(4) != 4 {
                return Err(in_doc(format!("mesh {m}: not a triangle list")));
            }
            let attributes = get(prim, "attributes").map_err(in_doc)?;
            let pos_index = uint(attributes, "POSITION").map_err(in_doc)?;
            let (pos, count, n) = acc.floats(pos_index).map_err(in_doc)?;
            if n != 3 {
                return Err(in_doc(format!("mesh {m}: POSITION is not VEC3")));
            }
            let accessor = &json["accessors"][pos_index];
            for (bound, pick) in [("min", f32::min as fn(f32, f32) -> f32), ("max", f32::max)] {
                let stated: Vec<f32> = get(accessor, bound)
                    .map_err(|e| in_doc(format!("mesh {m}: POSITION {e}")))?
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|v| v.as_f64().unwrap_or(f64::NAN) as f32)
                    .collect();
                let start = if bound == "min" {
                    f32::INFINITY
                } else {
                    f32::NEG_INFINITY
                };
                let actual: Vec<f32> = (0..3)
                    .map(|k| {
                        pos.iter()
                            .skip(k)
                            .step_by(3)
                            .fold(start, |a, &b| pick(a, b))
                    })
                    .collect();
                if stated != actual {
                    return Err(in_doc(format!(
                        "mesh {m}: POSITION {bound} {stated:?} differs from the data {actual:?}"
                    )));
                }
            }
            if pos.iter().any(|x| !x.is_finite()) {
                return Err(in_doc(format!("mesh {m}: non-finite position")));
            }
            if let Some(i) = attributes.get("NORMAL").and_then(Value::as_u64) {
                let (normals, c, n) = acc.floats(i as usize).map_err(in_doc)?;
                if c != count || n != 3 {
                    return Err(in_doc(format!(
                        "mesh {m}: NORMAL count or type differs from POSITION"
                    )));
                }
                if normals
                    .chunks_exact(3)
                    .any(|v| ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() > 1e-4)
                {
                    return Err(in_doc(format!("mesh {m}: NORMAL not of unit length")));
                }
            }
            if let Some(i) = attributes.get("TEXCOORD_0").and_then(Value::as_u64) {
                let (_, c, n) = acc.floats(i as usize).map_err(in_doc)?;
                if c != count || n != 2 {
                    return Err(in_doc(format!(
                        "mesh {m}: TEXCOORD_0 count or type differs from POSITION"
                    )));
                }
            }
            let indices = acc
                .indices(uint(prim, "indices").map_err(in_doc)?)
                .map_err(in_doc)?;
            if !indices.len().is_multiple_of(3) || indices.iter().any(|&i| i as usize >= count) {
                return Err(in_doc(format!(
                    "mesh {m}: index count not a multiple of 3 or index out of range"
                )));
            }
            let p = |i: u32| glam::Vec3::from_slice(&pos[3 * i as usize..3 * i as usize + 3]);
            for t in indices.chunks_exact(3) {
                if (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0])).length() == 0.0 {
                    return Err(in_doc(format!("mesh {m}: degenerate triangle {t:?}")));
                }
            }
        }
    }

    for image in json["images"].as_array().into_iter().flatten() {
        let file = dir.join(get(image, "uri").map_err(in_doc)?.as_str().unwrap_or(""));
        let decoder = png::Decoder::new(std::io::BufReader::new(
            std::fs::File::open(&file).map_err(|e| format!("{}: {e}", file.display()))?,
        ));
        decoder
            .read_info()
            .map_err(|e| format!("{}: {e}", file.display()))?;
    }
    let has_camera = json["nodes"]
        .as_array()
        .into_iter()
        .flatten()
        .any(|n| n.get("camera").is_some());
    if !has_camera {
        return Err(in_doc("no camera node".into()));
    }

    // And the gltf crate (the loader's parser) must accept it, with its own validation.
    gltf::import(&path).map_err(|e| format!("{}: gltf crate: {e}", path.display()))?;
    Ok(())
}
