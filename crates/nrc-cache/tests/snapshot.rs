//! Snapshots: bit-identical round trip; truncated, corrupted, foreign and mismatched files are
//! rejected with messages saying so.

use nrc_cache::config::NestedEncoding;
use nrc_cache::{
    CacheConfig, CacheDevice, CacheError, CacheQuery, ComputePath, RadianceCache, SceneBox,
    TrainingBatch,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn config() -> CacheConfig {
    let mut c = CacheConfig::hash_grid_preset();
    if let Some(NestedEncoding::HashGrid {
        log2_hashmap_size, ..
    }) = c.encoding.nested.first_mut()
    {
        *log2_hashmap_size = 14;
    }
    c
}

fn batch(n: usize, seed: u64) -> TrainingBatch {
    let mut r = Pcg64Mcg::seed_from_u64(seed);
    let queries: Vec<CacheQuery> = (0..n)
        .map(|_| CacheQuery {
            position: [r.random(), r.random(), r.random()],
            direction: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
            ],
            normal: [0.0, 0.0, 1.0],
            roughness: 0.3,
            diffuse: [0.6, 0.5, 0.4],
            specular: [0.04; 3],
        })
        .collect();
    let targets = queries
        .iter()
        .map(|q| [q.position[0] + 0.1, q.position[1] + 0.1, 0.5])
        .collect();
    TrainingBatch {
        queries,
        targets,
        weights: None,
    }
}

fn trained(path: ComputePath) -> RadianceCache {
    let scene = SceneBox {
        min: [-1.0, -2.0, -3.0],
        max: [4.0, 5.0, 6.0],
    };
    let mut cache = RadianceCache::with_path(config(), scene, CacheDevice::Cpu, path).unwrap();
    for i in 0..3 {
        cache.train(&batch(1024, i), 4).unwrap();
    }
    cache
}

fn message(e: CacheError) -> String {
    match e {
        CacheError::Snapshot { message, .. } => message,
        other => panic!("expected a snapshot error, got {other:?}"),
    }
}

#[test]
fn round_trip_is_bit_identical_and_training_continues_identically() {
    for path in [ComputePath::Fused, ComputePath::CustomOps] {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("cache.nrc");
        let mut a = trained(path);
        a.save(&file).unwrap();
        let mut b = RadianceCache::load(&file, CacheDevice::Cpu).unwrap();
        b.set_path(path).unwrap();
        assert_eq!(b.step_count(), a.step_count());
        assert_eq!(b.scene_box(), a.scene_box());
        assert_eq!(b.config(), a.config());
        let probe = batch(500, 99).queries;
        let (ya, yb) = (a.infer(&probe), b.infer(&probe));
        for (x, y) in ya.iter().zip(&yb) {
            assert_eq!(
                x.map(f32::to_bits),
                y.map(f32::to_bits),
                "{path}: reloaded cache answers differently"
            );
        }
        assert_eq!(a.host_state(), b.host_state());
        // Both continue identically (Adam moments and step count were saved too). The preset's
        // training forward reads a half copy of the table: the reloaded cache builds it from the
        // weights, the original kept it up to date step by step, so this also checks the two
        // copies agree.
        let next = batch(1024, 7);
        let (sa, sb) = (a.train(&next, 2).unwrap(), b.train(&next, 2).unwrap());
        assert_eq!(sa.loss.to_bits(), sb.loss.to_bits());
        assert_eq!(a.weights(), b.weights());
        // No temporary file is left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}

#[test]
fn damaged_foreign_and_mismatched_files_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cache.nrc");
    trained(ComputePath::Fused).save(&file).unwrap();
    let bytes = std::fs::read(&file).unwrap();

    // Truncated: tensor data cut short, and header cut short.
    for keep in [bytes.len() - 100, 20, 4] {
        let f = dir.path().join(format!("truncated-{keep}.nrc"));
        std::fs::write(&f, &bytes[..keep]).unwrap();
        let m = message(RadianceCache::load(&f, CacheDevice::Cpu).unwrap_err());
        assert!(
            m.contains("truncated") || m.contains("not a safetensors"),
            "{keep}: {m}"
        );
    }

    // Corrupted: one flipped bit in the tensor data.
    let mut corrupt = bytes.clone();
    let at = corrupt.len() - 1000;
    corrupt[at] ^= 0x10;
    let f = dir.path().join("corrupt.nrc");
    std::fs::write(&f, &corrupt).unwrap();
    let m = message(RadianceCache::load(&f, CacheDevice::Cpu).unwrap_err());
    assert!(m.contains("checksum"), "{m}");

    // Foreign: a text file, and a safetensors file without the cache's metadata.
    let f = dir.path().join("foreign.txt");
    std::fs::write(&f, "hello, this is not a snapshot at all").unwrap();
    message(RadianceCache::load(&f, CacheDevice::Cpu).unwrap_err());
    let data = [1f32, 2.0, 3.0];
    let view = safetensors::tensor::TensorView::new(
        safetensors::Dtype::F32,
        vec![3],
        bytemuck::cast_slice(&data),
    )
    .unwrap();
    let other = safetensors::tensor::serialize(vec![("weights", view)], None).unwrap();
    let f = dir.path().join("other.safetensors");
    std::fs::write(&f, other).unwrap();
    let m = message(RadianceCache::load(&f, CacheDevice::Cpu).unwrap_err());
    assert!(m.contains("not an nrc-cache snapshot"), "{m}");

    // Mismatched: loading against a different configuration names the section.
    let mut other_config = config();
    other_config.network.n_hidden_layers = 2;
    let m =
        message(RadianceCache::load_matching(&file, &other_config, CacheDevice::Cpu).unwrap_err());
    assert!(m.contains("network"), "{m}");
    assert!(RadianceCache::load_matching(&file, &config(), CacheDevice::Cpu).is_ok());

    // Inconsistent: metadata claiming another configuration than the tensors fit.
    // (The metadata JSON sits escaped inside the header: `n_hidden_layers\":3`.)
    let needle = br#"n_hidden_layers\":3"#;
    let mut swapped = bytes.clone();
    let pos = swapped
        .windows(needle.len())
        .position(|w| w == needle)
        .expect("metadata holds the config");
    swapped[pos + needle.len() - 1] = b'4';
    let f = dir.path().join("inconsistent.nrc");
    std::fs::write(&f, &swapped).unwrap();
    let m = message(RadianceCache::load(&f, CacheDevice::Cpu).unwrap_err());
    assert!(m.contains("shape"), "{m}");

    // Missing file: an I/O error naming the path.
    assert!(matches!(
        RadianceCache::load(&dir.path().join("absent.nrc"), CacheDevice::Cpu),
        Err(CacheError::Io { .. })
    ));
}

/// Weights set from outside take effect in the next step, also in the half-precision copy the
/// preset's training forward reads: a cache given new weights trains exactly as one loaded
/// from a snapshot holding them (which builds its copy afresh).
#[test]
fn set_weights_reaches_the_training_forward() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cache.nrc");
    let mut a = trained(ComputePath::Fused);
    let (grid, mlp) = a.weights();
    let grid: Vec<f32> = grid.iter().map(|w| 2.0 * w + 1e-3).collect();
    a.set_weights(grid, mlp).unwrap();
    a.save(&file).unwrap();
    let mut b = RadianceCache::load(&file, CacheDevice::Cpu).unwrap();
    b.set_path(ComputePath::Fused).unwrap();
    let next = batch(1024, 11);
    let (sa, sb) = (a.train(&next, 2).unwrap(), b.train(&next, 2).unwrap());
    assert_eq!(sa.first_loss.to_bits(), sb.first_loss.to_bits());
    assert_eq!(sa.loss.to_bits(), sb.loss.to_bits());
    assert_eq!(a.weights(), b.weights());
}
