//! `nrc compare --sequence` as a library: every method renders every frame of the animated
//! Cornell box against its own reference, and the report holds per-frame errors and the
//! temporal measures.

use nrc_cache::{CacheConfig, CacheDevice};
use nrc_harness::compare::Comparison;
use nrc_harness::methods::CacheMethodSettings;
use nrc_harness::sequence::{Sequence, compare_sequence};
use nrc_harness::{Budget, MethodSpec};
use nrc_render::PathTracer;
use nrc_scene::AnimatedScene;

#[test]
fn a_sequence_reports_every_frame_of_every_method() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/cornell-box-moving.gltf");
    let out = tempfile::tempdir().unwrap();
    let c = Comparison {
        methods: ["ir", "pt-1spp"]
            .iter()
            .map(|m| m.parse::<MethodSpec>().unwrap())
            .collect(),
        budget: Budget::Passes(1),
        width: 16,
        height: 16,
        runs: 1,
        sweep_steps: None,
        flip: false,
        out: out.path().to_path_buf(),
        seed: 1,
        exposure: 0.0,
        exclude_emitters: false,
        diagnostics: false,
        emitter_samples: 0,
        camera_offsets: Default::default(),
        interleave: false,
        tracer: PathTracer::default(),
        cache: CacheMethodSettings::new(CacheConfig::hash_grid_preset(), CacheDevice::Cpu),
        converge: None,
        scene_name: "cornell-box-moving".into(),
        scene_path: path.display().to_string(),
    };
    let animated = AnimatedScene::load(&path).unwrap();
    let pose = |t: f32| Ok(animated.at(t)?);
    let seq = Sequence {
        frames: 4,
        fps: 2.0,
        reference_spp: 16,
        tracked: 64,
        camera_path: None,
    };
    let r = compare_sequence(&c, &seq, (&pose, true), &|_| {}).unwrap();
    assert_eq!(r.rows.len(), 2);
    assert_eq!(r.tracked_pixels, 64);
    for row in &r.rows {
        assert_eq!(row.mape.len(), 4);
        assert_eq!(row.tracked_error.len(), 4);
        assert!(
            row.mape
                .iter()
                .chain(&row.rel_mse)
                .all(|e| e.is_finite() && *e > 0.0)
        );
        assert!(row.mean_abs_error > 0.0 && row.mean_abs_error_change > 0.0);
    }
    for f in ["sequence.md", "sequence.json", "sequence-mape.png"] {
        assert!(out.path().join(f).exists(), "{f}");
    }
    // A sequence of one frame is refused with a message.
    let one = Sequence { frames: 1, ..seq };
    let e = compare_sequence(&c, &one, (&pose, true), &|_| {}).unwrap_err();
    assert!(
        e.to_string().contains("between 2 and 1000000 frames"),
        "{e}"
    );
}
