//! Configuration parsing, validation messages, presets and scene sizing.

use nrc_cache::config::NestedEncoding;
use nrc_cache::model::ModelLayout;
use nrc_cache::{CacheConfig, CacheError, SceneBox};

fn preset_json() -> serde_json::Value {
    serde_json::from_str(include_str!("../../../models/nrc-hashgrid.json")).unwrap()
}

fn field_of(result: Result<CacheConfig, CacheError>) -> (String, String) {
    match result {
        Err(CacheError::Config { field, message }) => (field, message),
        other => panic!("expected a configuration error, got {other:?}"),
    }
}

#[test]
fn presets_parse_and_have_the_documented_shape() {
    let h = CacheConfig::hash_grid_preset();
    let g = h.hash_grid().expect("hash grid preset has a grid");
    assert_eq!(
        (
            g.n_levels,
            g.n_features_per_level,
            g.log2_hashmap_size,
            g.base_resolution
        ),
        (16, 2, 19, 16.0)
    );
    assert_eq!(h.network.n_hidden_layers, 3);
    let t = CacheConfig::triangle_wave_preset();
    assert!(t.hash_grid().is_none());
    assert!(t.encoding.nested.iter().any(|n| matches!(
        n,
        NestedEncoding::TriangleWave {
            n_frequencies: 12,
            ..
        }
    )));
    assert!(
        t.encoding
            .nested
            .iter()
            .any(|n| matches!(n, NestedEncoding::OneBlob { wrap: true, .. }))
    );
    assert_eq!(t.network.n_hidden_layers, 5);
    // Round trip through JSON.
    assert_eq!(CacheConfig::from_json_str(&h.to_json()).unwrap(), h);
    // Both presets' encodings pad to 64 network inputs.
    assert_eq!(ModelLayout::new(&h).encoding.padded_dims, 64);
    assert_eq!(ModelLayout::new(&t).encoding.padded_dims, 64);
}

#[test]
fn out_of_range_values_name_the_field() {
    let cases: [(&str, serde_json::Value, &str); 16] = [
        (
            "/encoding/nested/0/n_levels",
            0.into(),
            "encoding.nested[0].n_levels",
        ),
        (
            "/encoding/nested/0/log2_hashmap_size",
            30.into(),
            "encoding.nested[0].log2_hashmap_size",
        ),
        (
            "/encoding/nested/0/n_features_per_level",
            3.into(),
            "encoding.nested[0].n_features_per_level",
        ),
        (
            "/encoding/nested/1/n_bins",
            0.into(),
            "encoding.nested[1].n_bins",
        ),
        ("/network/n_neurons", 128.into(), "network.n_neurons"),
        (
            "/network/n_hidden_layers",
            0.into(),
            "network.n_hidden_layers",
        ),
        ("/loss/epsilon", (-1.0).into(), "loss.epsilon"),
        (
            "/loss/return_clipped/grid",
            0.into(),
            "loss.return_clipped.grid",
        ),
        (
            "/loss/return_clipped/frames",
            0.5.into(),
            "loss.return_clipped.frames",
        ),
        (
            "/loss/return_clipped/max_gain",
            0.9.into(),
            "loss.return_clipped.max_gain",
        ),
        (
            "/loss/return_clipped/min_roughness",
            (-1.0).into(),
            "loss.return_clipped.min_roughness",
        ),
        ("/optimizer/decay", 1.5.into(), "optimizer.decay"),
        (
            "/optimizer/nested/nested/learning_rate",
            0.0.into(),
            "optimizer.nested.nested.learning_rate",
        ),
        (
            "/optimizer/nested/decay_base",
            1.5.into(),
            "optimizer.nested.decay_base",
        ),
        (
            "/optimizer/nested/decay_interval",
            0.into(),
            "optimizer.nested.decay_interval",
        ),
        (
            "/optimizer/nested/decay_end",
            10.into(),
            "optimizer.nested.decay_end",
        ),
    ];
    for (pointer, value, field) in cases {
        let mut v = preset_json();
        // A valid return of the clipped light (the presets' may change).
        v["loss"]["return_clipped"] =
            serde_json::json!({"grid": 16, "frames": 64, "max_gain": 4, "min_roughness": 0.7});
        *v.pointer_mut(pointer)
            .unwrap_or_else(|| panic!("{pointer}")) = value;
        let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
        assert_eq!(f, field, "{pointer}: {m}");
        assert!(!m.is_empty());
    }
}

#[test]
fn malformed_documents_name_the_field() {
    let mut v = preset_json();
    *v.pointer_mut("/encoding/nested/0/n_levels").unwrap() = "sixteen".into();
    let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert_eq!(f, "encoding.nested[0].n_levels", "{m}");

    let mut v = preset_json();
    *v.pointer_mut("/encoding/nested/0/inference_precision")
        .unwrap() = "f64".into();
    let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert_eq!(f, "encoding.nested[0].inference_precision", "{m}");
    assert!(m.contains("f16"), "the message lists the choices: {m}");

    let mut v = preset_json();
    *v.pointer_mut("/encoding/nested/0/training_precision")
        .unwrap() = "bf16".into();
    let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert_eq!(f, "encoding.nested[0].training_precision", "{m}");
    assert!(m.contains("f32"), "the message lists the choices: {m}");

    let mut v = preset_json();
    v["network"]["n_neuronz"] = 64.into();
    let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert!(f.starts_with("network"), "{f}: {m}");
    assert!(m.contains("n_neuronz"), "{m}");

    let mut v = preset_json();
    v["encoding"]["nested"][1]["otype"] = "Spherical".into();
    let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert!(f.starts_with("encoding.nested[1]"), "{f}: {m}");

    let mut v = preset_json();
    v.as_object_mut().unwrap().remove("loss");
    let (_, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert!(m.contains("loss"), "{m}");

    // The single-valued tags are enums: another value names its field and the choice.
    for (pointer, field, choice) in [
        ("/encoding/otype", "encoding.otype", "Composite"),
        ("/network/otype", "network.otype", "FullyFusedMLP"),
        ("/network/activation", "network.activation", "ReLU"),
        ("/loss/otype", "loss.otype", "RelativeL2Luminance"),
    ] {
        let mut v = preset_json();
        *v.pointer_mut(pointer).unwrap() = "Tanh".into();
        let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
        assert_eq!(f, field, "{m}");
        assert!(m.contains(choice), "{m}");
    }

    let (f, _) = field_of(CacheConfig::from_json_str("{ not json"));
    assert!(!f.is_empty());
}

#[test]
fn the_encodings_must_consume_the_fourteen_raw_inputs() {
    let mut v = preset_json();
    v["encoding"]["nested"].as_array_mut().unwrap().pop();
    let (f, m) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert_eq!(f, "encoding.nested");
    assert!(m.contains("14"), "{m}");

    let mut v = preset_json();
    *v.pointer_mut("/encoding/nested/0/n_dims_to_encode")
        .unwrap() = 2.into();
    let (f, _) = field_of(CacheConfig::from_json_str(&v.to_string()));
    assert_eq!(f, "encoding.nested[0].n_dims_to_encode");
}

#[test]
fn sizing_follows_the_scene_extent() {
    let base = CacheConfig::hash_grid_preset();
    // A 10 × 4 × 2 m scene, 1 cm features: finest resolution 1000 cells along x.
    let scene = SceneBox {
        min: [0.0, 0.0, 0.0],
        max: [10.0, 4.0, 2.0],
    };
    let (c, s) = base.sized_for_scene(&scene, 0.01).unwrap();
    assert_eq!(s.finest_resolution, 1000);
    let g = c.grid_layout().unwrap();
    let finest = g.levels.last().unwrap();
    assert!(
        (finest.scale + 1.0 - 1000.0).abs() < 1.0,
        "finest scale {}",
        finest.scale
    );
    // Surface cells 2·(1000·400 + 400·200 + 200·1000) = 1.36e6 → 2^21, capped by the preset's 2^19.
    assert_eq!(s.log2_hashmap_size, Some(19));
    // A small scene gets a small table.
    let (c2, s2) = base
        .sized_for_scene(
            &SceneBox {
                min: [0.0; 3],
                max: [1.0; 3],
            },
            0.02,
        )
        .unwrap();
    assert_eq!(s2.finest_resolution, 50);
    assert_eq!(s2.log2_hashmap_size, Some(14)); // 2·3·50² = 15000 cells → 2^14
    assert!(s2.param_count < s.param_count);
    assert_eq!(s2.param_count, ModelLayout::new(&c2).param_count());
    // Weights, moments, EMA (16 bytes a parameter), the EMA step per entry, the inference copy.
    assert!((s2.param_count * 18..=s2.param_count * 24).contains(&s2.memory_bytes));
    // Triangle-wave octaves follow the finest feature too.
    let (_, st) = CacheConfig::triangle_wave_preset()
        .sized_for_scene(&scene, 0.01)
        .unwrap();
    assert_eq!(st.n_frequencies, Some(11)); // ceil(log2 1000) + 1
    // Bad input is an error naming it.
    assert!(
        matches!(base.sized_for_scene(&scene, 0.0), Err(CacheError::Config { field, .. }) if field == "min_feature_size")
    );
    assert!(
        matches!(base.sized_for_scene(&SceneBox { min: [0.0; 3], max: [f32::NAN; 3] }, 0.1), Err(CacheError::Config { field, .. }) if field == "scene_box")
    );
}
