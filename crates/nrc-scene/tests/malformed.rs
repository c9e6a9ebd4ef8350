//! Malformed input gives an error naming the problem, never a panic. Every fixture is built
//! here from bytes and written to a temporary folder.

use std::path::{Path, PathBuf};

use nrc_scene::{Scene, SceneError};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A glTF document with one mesh named `mesh_name` (positions, u16 indices) whose data
/// lives in buffer 0, plus `extra` top-level JSON members (each ending with a comma).
fn document(
    mesh_name: &str,
    positions: &[[f32; 3]],
    indices: &[u16],
    buffer_uri: Option<&str>,
    extra: &str,
) -> (String, Vec<u8>) {
    let mut bin = Vec::new();
    for p in positions {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    let pos_len = bin.len();
    for i in indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let idx_len = bin.len() - pos_len;
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let uri = buffer_uri
        .map(|u| format!(r#""uri": "{u}","#))
        .unwrap_or_default();
    let json = format!(
        r#"{{
  {extra}
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0]}}],
  "nodes": [{{"mesh": 0}}],
  "meshes": [{{"name": "{mesh_name}", "primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1}}]}}],
  "buffers": [{{{uri} "byteLength": {}}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": {pos_len}}},
    {{"buffer": 0, "byteOffset": {pos_len}, "byteLength": {idx_len}}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": {}, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}},
    {{"bufferView": 1, "componentType": 5123, "count": {}, "type": "SCALAR"}}
  ]
}}"#,
        bin.len(),
        positions.len(),
        indices.len()
    );
    (json, bin)
}

/// A `.glb` container of a JSON chunk and a BIN chunk.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b);
    out
}

const QUAD: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
];
const QUAD_INDICES: [u16; 6] = [0, 1, 2, 0, 2, 3];

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn error_of(path: &Path) -> String {
    match Scene::load(path) {
        Ok(_) => panic!("{} loaded but should not", path.display()),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(
            message.contains(p),
            "error `{message}` does not mention `{p}`"
        );
    }
}

#[test]
fn valid_fixtures_load() {
    let dir = tempfile::tempdir().unwrap();
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, None, "");
    let scene = Scene::load(&write(dir.path(), "quad.glb", &glb(&json, &bin))).unwrap();
    assert_eq!(scene.triangle_count(), 2);
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, Some("quad.bin"), "");
    write(dir.path(), "quad.bin", &bin);
    let scene = Scene::load(&write(dir.path(), "quad.gltf", json.as_bytes())).unwrap();
    assert_eq!(scene.triangle_count(), 2);
}

#[test]
fn missing_file() {
    let msg = error_of(Path::new("/nonexistent/folder/scene.glb"));
    assert_mentions(&msg, &["/nonexistent/folder/scene.glb"]);
}

#[test]
fn truncated_glb() {
    let dir = tempfile::tempdir().unwrap();
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, None, "");
    let full = glb(&json, &bin);
    let p = write(dir.path(), "cut.glb", &full[..full.len() - 10]);
    assert_mentions(&error_of(&p), &["cut.glb", "truncated"]);
    let p = write(dir.path(), "tiny.glb", &full[..7]);
    assert_mentions(&error_of(&p), &["tiny.glb", "truncated"]);
    // Every possible truncation is an error, none a panic.
    for len in 0..full.len() {
        let p = write(dir.path(), "any.glb", &full[..len]);
        assert!(
            Scene::load(&p).is_err(),
            "truncated at {len} bytes but loaded"
        );
    }
}

#[test]
fn invalid_json() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "broken.gltf",
        br#"{"asset": {"version": "2.0"}, "meshes": [ }"#,
    );
    assert_mentions(&error_of(&p), &["broken.gltf", "invalid JSON"]);
    let p = write(dir.path(), "empty.gltf", b"");
    assert_mentions(&error_of(&p), &["empty.gltf", "invalid JSON"]);
}

#[test]
fn missing_buffer_file() {
    let dir = tempfile::tempdir().unwrap();
    let (json, _) = document("quad", &QUAD, &QUAD_INDICES, Some("geometry_data.bin"), "");
    let p = write(dir.path(), "scene.gltf", json.as_bytes());
    let msg = error_of(&p);
    assert_mentions(&msg, &["scene.gltf", "geometry_data.bin"]);
    // A buffer file shorter than its declared length.
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, Some("short.bin"), "");
    write(dir.path(), "short.bin", &bin[..bin.len() / 2]);
    let p = write(dir.path(), "short.gltf", json.as_bytes());
    assert_mentions(&error_of(&p), &["short.bin", "truncated buffer"]);
}

#[test]
fn nan_positions() {
    let dir = tempfile::tempdir().unwrap();
    let mut pos = QUAD;
    pos[2][1] = f32::NAN;
    let (json, bin) = document("wonky_mesh", &pos, &QUAD_INDICES, None, "");
    let p = write(dir.path(), "nan.glb", &glb(&json, &bin));
    assert_mentions(&error_of(&p), &["nan.glb", "wonky_mesh", "NaN"]);
    pos[2][1] = f32::INFINITY;
    let (json, bin) = document("inf_mesh", &pos, &QUAD_INDICES, None, "");
    let p = write(dir.path(), "inf.glb", &glb(&json, &bin));
    assert_mentions(&error_of(&p), &["inf_mesh", "non-finite"]);
}

#[test]
fn degenerate_triangles_are_dropped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    // Two good triangles, a repeated-vertex one, a collinear one, an exact duplicate point.
    let mut pos = QUAD.to_vec();
    pos.push([2.0, 0.0, 0.0]);
    let idx: Vec<u16> = vec![0, 1, 2, 0, 2, 3, 1, 1, 2, 0, 1, 4, 3, 3, 3];
    let (json, bin) = document("quad", &pos, &idx, None, "");
    let scene = Scene::load(&write(dir.path(), "degen.glb", &glb(&json, &bin))).unwrap();
    assert_eq!(scene.triangle_count(), 2);
    assert_eq!(scene.degenerate_dropped(), 3);
    assert!(scene.summary().to_string().contains("3 degenerate"));
    // Queries work on the remaining triangles.
    let ray = nrc_scene::Ray::new(glam::Vec3::new(0.5, 0.25, 1.0), -glam::Vec3::Z);
    assert!((scene.intersect(&ray).unwrap().t - 1.0).abs() < 1e-6);
    // Only degenerate triangles: nothing to render.
    let (json, bin) = document("flat", &pos, &[1, 1, 2, 0, 1, 4], None, "");
    let msg = error_of(&write(dir.path(), "allflat.glb", &glb(&json, &bin)));
    assert_mentions(&msg, &["allflat.glb", "no triangles"]);
}

#[test]
fn unsupported_required_extension() {
    let dir = tempfile::tempdir().unwrap();
    let ext = r#""extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"],"#;
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, None, ext);
    let p = write(dir.path(), "draco.glb", &glb(&json, &bin));
    let e = Scene::load(&p).unwrap_err();
    assert!(matches!(e, SceneError::UnsupportedExtension { .. }));
    assert_mentions(
        &e.to_string(),
        &["draco.glb", "KHR_draco_mesh_compression", "required"],
    );
    // Merely used, unknown extensions are ignored with a warning.
    let ext = r#""extensionsUsed": ["EXT_made_up_extension"],"#;
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, None, ext);
    let scene = Scene::load(&write(dir.path(), "used.glb", &glb(&json, &bin))).unwrap();
    assert!(
        scene
            .warnings()
            .iter()
            .any(|w| w.contains("EXT_made_up_extension"))
    );
    // Supported extensions may be required.
    let ext =
        r#""extensionsUsed": ["KHR_materials_ior"], "extensionsRequired": ["KHR_materials_ior"],"#;
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, None, ext);
    assert!(Scene::load(&write(dir.path(), "ior.glb", &glb(&json, &bin))).is_ok());
}

#[test]
fn indices_out_of_range() {
    let dir = tempfile::tempdir().unwrap();
    let (json, bin) = document("holey", &QUAD, &[0, 1, 9], None, "");
    let msg = error_of(&write(dir.path(), "oob.glb", &glb(&json, &bin)));
    assert_mentions(&msg, &["holey", "out of range"]);
}

#[test]
fn wrong_accessor_type() {
    let dir = tempfile::tempdir().unwrap();
    let (json, bin) = document("typed", &QUAD, &QUAD_INDICES, None, "");
    // POSITION declared as VEC2.
    let json = json.replacen(
        r#""count": 4, "type": "VEC3""#,
        r#""count": 4, "type": "VEC2""#,
        1,
    );
    let msg = error_of(&write(dir.path(), "vec2.glb", &glb(&json, &bin)));
    assert_mentions(&msg, &["typed", "POSITION"]);
}

#[test]
fn accessor_outside_buffer() {
    let dir = tempfile::tempdir().unwrap();
    let (json, bin) = document("greedy", &QUAD, &QUAD_INDICES, None, "");
    // More vertices than the buffer view holds.
    let json = json.replacen(
        r#""count": 4, "type": "VEC3""#,
        r#""count": 400, "type": "VEC3""#,
        1,
    );
    let msg = error_of(&write(dir.path(), "big.glb", &glb(&json, &bin)));
    assert_mentions(&msg, &["big.glb"]);
}

#[test]
fn missing_texture_image() {
    let dir = tempfile::tempdir().unwrap();
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, None, "");
    let json = json
        .replacen(
            r#""scene": 0,"#,
            r#""scene": 0,
  "images": [{"uri": "albedo_missing.png"}],
  "textures": [{"source": 0}],
  "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],"#,
            1,
        )
        .replacen(r#""indices": 1}"#, r#""indices": 1, "material": 0}"#, 1);
    let msg = error_of(&write(dir.path(), "tex.glb", &glb(&json, &bin)));
    assert_mentions(&msg, &["tex.glb", "albedo_missing.png"]);
    // A present but undecodable image.
    write(dir.path(), "albedo_missing.png", b"not a png at all");
    let msg = error_of(&dir.path().join("tex.glb"));
    assert_mentions(&msg, &["albedo_missing.png", "decode"]);
}

/// Random byte corruption of a valid file: loading may succeed or fail, but never panics
/// and every success yields finite geometry.
#[test]
fn corrupted_bytes_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let (json, bin) = document("quad", &QUAD, &QUAD_INDICES, None, "");
    let full = glb(&json, &bin);
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let (mut ok, mut err) = (0, 0);
    for _ in 0..2000 {
        let mut bytes = full.clone();
        for _ in 0..rng.random_range(1..4) {
            let i = rng.random_range(0..bytes.len());
            bytes[i] = rng.random();
        }
        let p = write(dir.path(), "corrupt.glb", &bytes);
        match Scene::load(&p) {
            Ok(s) => {
                ok += 1;
                assert!(s.bounds().min.is_finite() && s.bounds().max.is_finite());
            }
            Err(e) => {
                err += 1;
                assert!(!e.to_string().is_empty());
            }
        }
    }
    println!("{ok} corrupted files loaded, {err} rejected");
    assert!(err > 0);
}
