//! CPU (Flex) and wgpu give the same encoding forward and backward, for every encoding.
//!
//! One generic test runs over a list of composite encodings (each kind alone, the hash grid at
//! several feature counts with dense and hashed levels, and both shipped presets). For each,
//! the same raw inputs, table and upstream gradient go through `InputEncoding::encode_tensor`
//! on an autodiff Flex device and on an autodiff wgpu device; the encodings, the gradients
//! w.r.t. the hash table (the custom op's backward: a plain scatter on Flex, a WGSL scatter
//! with compare-and-swap float atomics on wgpu) and the gradients w.r.t. the raw inputs must
//! agree. Both are also checked against the per-sample CPU kernels (`forward_one`,
//! `backward_params_one`), the specification.
//!
//! wgpu runs on whatever adapter exists; in CI that is mesa's lavapipe (software Vulkan). On a
//! machine with no adapter at all the test prints why and passes without comparing.

use burn::tensor::{Device, Tensor, TensorData};
use nrc_cache::config::CompositeConfig;
use nrc_cache::encoding::{EncodingKind, InputEncoding};
use nrc_cache::record::RAW_INPUT_DIMS;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Samples per case: enough for many hash collisions and shared cells in the scatter.
const SAMPLES: usize = 3000;
/// Forward: both backends evaluate the same expressions; only fused multiply-adds differ.
const FORWARD_RTOL: f32 = 1e-5;
/// Backward: the wgpu scatter adds in an arbitrary order (atomics), the CPU in sample order.
const BACKWARD_RTOL: f32 = 1e-4;

/// The encodings under test, as composite configurations over the 14 raw inputs.
fn cases() -> Vec<(&'static str, String)> {
    let grid = |levels: u32, features: u32, log2t: u32, base: f32, scale: f32| {
        format!(
            r#"{{"otype": "HashGrid", "n_dims_to_encode": 3, "n_levels": {levels}, "n_features_per_level": {features},
                "log2_hashmap_size": {log2t}, "base_resolution": {base}, "per_level_scale": {scale}}}"#
        )
    };
    let composite = |nested: &[String]| {
        format!(
            r#"{{"otype": "Composite", "nested": [{}], "pad_to_multiple": 16}}"#,
            nested.join(",")
        )
    };
    let identity = |dims: u32| format!(r#"{{"otype": "Identity", "n_dims_to_encode": {dims}}}"#);
    let preset = |file: &str| {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models")
            .join(file);
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("preset readable"))
                .expect("preset is JSON");
        json["encoding"].to_string()
    };
    vec![
        // Coarse levels dense, fine levels hashed (r³ crosses T = 2^12 at level 3).
        (
            "hash grid F=2",
            composite(&[grid(8, 2, 12, 4.0, 1.6), identity(11)]),
        ),
        (
            "hash grid F=1",
            composite(&[grid(6, 1, 10, 3.0, 2.0), identity(11)]),
        ),
        (
            "hash grid F=4",
            composite(&[grid(5, 4, 11, 8.0, 1.5), identity(11)]),
        ),
        (
            "hash grid F=8",
            composite(&[grid(4, 8, 10, 2.0, 3.0), identity(11)]),
        ),
        (
            "one-blob",
            composite(&[
                r#"{"otype": "OneBlob", "n_dims_to_encode": 4, "n_bins": 8}"#.into(),
                identity(10),
            ]),
        ),
        (
            "one-blob wrapped",
            composite(&[
                r#"{"otype": "OneBlob", "n_dims_to_encode": 4, "n_bins": 5, "wrap": true}"#.into(),
                identity(10),
            ]),
        ),
        (
            "triangle wave",
            composite(&[
                r#"{"otype": "TriangleWave", "n_dims_to_encode": 3, "n_frequencies": 12}"#.into(),
                identity(11),
            ]),
        ),
        (
            "identity (scaled)",
            composite(&[
                r#"{"otype": "Identity", "n_dims_to_encode": 14, "scale": 2.0, "offset": -1.0}"#
                    .into(),
            ]),
        ),
        ("composite: hash-grid preset", preset("nrc-hashgrid.json")),
        (
            "composite: triangle-wave preset",
            preset("nrc-trianglewave.json"),
        ),
    ]
}

/// What one backend computed for one case.
struct Outcome {
    encoded: Vec<f32>,
    table_grad: Vec<f32>,
    input_grad: Vec<f32>,
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("f32 data")
}

/// Encodes on `device` (with autodiff) and back-propagates `⟨upstream, encoding⟩`.
fn run(
    device: &Device,
    encoding: &InputEncoding,
    raw: &[f32],
    table: &[f32],
    upstream: &[f32],
) -> Outcome {
    let device = device.clone().autodiff();
    let n = raw.len() / RAW_INPUT_DIMS;
    let raw = Tensor::<2>::from_data(TensorData::new(raw.to_vec(), [n, RAW_INPUT_DIMS]), &device)
        .require_grad();
    let table_t = (!table.is_empty()).then(|| {
        Tensor::<1>::from_data(TensorData::new(table.to_vec(), [table.len()]), &device)
            .require_grad()
    });
    let upstream = Tensor::<2>::from_data(
        TensorData::new(upstream.to_vec(), [n, encoding.padded_dims]),
        &device,
    );

    let encoded = encoding.encode_tensor(table_t.clone(), raw.clone());
    let mut grads = (encoded.clone() * upstream).sum().backward();
    let input_grad = raw
        .grad_remove(&mut grads)
        .map(values)
        .unwrap_or_else(|| vec![0.0; raw.dims()[0] * RAW_INPUT_DIMS]);
    let table_grad = table_t
        .and_then(|t| t.grad_remove(&mut grads))
        .map(values)
        .unwrap_or_default();
    Outcome {
        encoded: values(encoded),
        table_grad,
        input_grad,
    }
}

/// Largest violation of |a − b| ≤ rtol·max(|a|, |b|) + atol over two arrays, as a multiple of
/// the allowed error (≤ 1 passes). `atol` is rtol times the RMS of `a`: rounding differences
/// scale with the magnitude of the summed terms, not with a result that happens to cancel.
fn worst(a: &[f32], b: &[f32], rtol: f32) -> (f32, usize) {
    worst_beyond(a, b, rtol, &|_| 0.0)
}

/// [`worst`] with `extra(i)` added to element `i`'s absolute tolerance.
fn worst_beyond(a: &[f32], b: &[f32], rtol: f32, extra: &dyn Fn(usize) -> f32) -> (f32, usize) {
    assert_eq!(a.len(), b.len(), "array lengths differ");
    let rms = (a.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>() / a.len().max(1) as f64).sqrt()
        as f32;
    let atol = rtol * rms.max(f32::MIN_POSITIVE);
    let mut worst = (0.0f32, 0usize);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        let allowed = rtol * x.abs().max(y.abs()) + atol + extra(i);
        let ratio = if x.is_finite() && y.is_finite() {
            (x - y).abs() / allowed
        } else {
            f32::INFINITY
        };
        if ratio > worst.0 {
            worst = (ratio, i);
        }
    }
    worst
}

fn check(case: &str, what: &str, a: &[f32], b: &[f32], rtol: f32) {
    check_beyond(case, what, a, b, rtol, &|_| 0.0);
}

fn check_beyond(
    case: &str,
    what: &str,
    a: &[f32],
    b: &[f32],
    rtol: f32,
    extra: &dyn Fn(usize) -> f32,
) {
    let (ratio, i) = worst_beyond(a, b, rtol, extra);
    assert!(
        ratio <= 1.0,
        "{case}: {what} differs at {i}: {} vs {} ({ratio:.2}× the tolerance, rtol {rtol})",
        a[i],
        b[i]
    );
}

#[test]
fn cpu_and_wgpu_give_the_same_forward_and_backward() {
    let wgpu = match nrc_cache::gpu::wgpu_device() {
        Ok(device) => device,
        Err(why) => {
            nrc_scene::testing::skipped(
                "cpu_and_wgpu_give_the_same_forward_and_backward",
                &why.to_string(),
            );
            return;
        }
    };
    for info in nrc_cache::gpu::adapters() {
        println!(
            "wgpu adapter: {} ({:?}, {:?})",
            info.name, info.device_type, info.backend
        );
    }
    let flex = Device::flex();
    let mut rng = Pcg64Mcg::seed_from_u64(0x5eed_b0c5);

    for (case, json) in cases() {
        let config: CompositeConfig =
            serde_json::from_str(&json).unwrap_or_else(|e| panic!("{case}: {e}"));
        let encoding = InputEncoding::new(&config);
        let dims = encoding.padded_dims;

        // Inputs in [0, 1] (positions, angles, roughness, reflectances); a table with values of
        // order one so that the interpolation sums are not dominated by rounding; an arbitrary
        // upstream gradient.
        let raw: Vec<f32> = (0..SAMPLES * RAW_INPUT_DIMS)
            .map(|_| rng.random::<f32>())
            .collect();
        let table: Vec<f32> = (0..encoding.param_count())
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let upstream: Vec<f32> = (0..SAMPLES * dims)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();

        let cpu = run(&flex, &encoding, &raw, &table, &upstream);
        let gpu = run(&wgpu, &encoding, &raw, &table, &upstream);

        // The specification: per-sample CPU kernels.
        let mut spec_encoded = vec![0f32; SAMPLES * dims];
        let mut spec_grad = vec![0f32; table.len()];
        for ((x, out), up) in raw
            .chunks_exact(RAW_INPUT_DIMS)
            .zip(spec_encoded.chunks_exact_mut(dims))
            .zip(upstream.chunks_exact(dims))
        {
            encoding.forward_one(&table, x, out);
            if let Some((grid, part)) = encoding.grid() {
                let d = &up[part.out_offset..part.out_offset + part.out_dims];
                grid.backward_params_one([x[0], x[1], x[2]], d, &mut spec_grad);
            }
        }
        check(
            case,
            "forward, Flex vs specification",
            &spec_encoded,
            &cpu.encoded,
            FORWARD_RTOL,
        );
        // A GPU compiler may contract the cell position x·s + 0.5 into one fused multiply-add
        // (NVIDIA's Vulkan driver does; the CPU kernels round the product first). A trilinear
        // weight factor then differs by up to one ulp of x·s_l + 0.5, a corner's weight (three
        // factors in [0, 1]) by 3 such ulps: an output by that times the largest difference of
        // two table values (2·max|T|), a table entry's gradient by that times the |upstream| of
        // every sample whose corner it is.
        let ulp = |scale: f32| f32::EPSILON * (scale + 0.5).log2().floor().exp2();
        let contraction = encoding.grid().map_or(0.0, |(grid, _)| {
            let finest = grid.levels.iter().map(|l| l.scale).fold(0.0f32, f32::max);
            let max_table = table.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            3.0 * ulp(finest) * 2.0 * max_table
        });
        let mut contraction_grad = vec![0f32; table.len()];
        if let Some((grid, part)) = encoding.grid() {
            let f = grid.features();
            for (x, up) in raw
                .chunks_exact(RAW_INPUT_DIMS)
                .zip(upstream.chunks_exact(dims))
            {
                let d = &up[part.out_offset..part.out_offset + part.out_dims];
                for (l, level) in grid.levels.iter().enumerate() {
                    let corners = grid.corners(level, [x[0], x[1], x[2]]);
                    for index in corners.index {
                        for j in 0..f {
                            contraction_grad[index as usize * f + j] +=
                                3.0 * ulp(level.scale) * d[l * f + j].abs();
                        }
                    }
                }
            }
        }
        check_beyond(
            case,
            "forward, wgpu vs Flex",
            &cpu.encoded,
            &gpu.encoded,
            FORWARD_RTOL,
            &|_| contraction,
        );
        check(
            case,
            "table gradient, Flex vs specification",
            &spec_grad,
            &cpu.table_grad,
            BACKWARD_RTOL,
        );
        check_beyond(
            case,
            "table gradient, wgpu vs Flex",
            &cpu.table_grad,
            &gpu.table_grad,
            BACKWARD_RTOL,
            &|i| contraction_grad[i],
        );
        check(
            case,
            "input gradient, wgpu vs Flex",
            &cpu.input_grad,
            &gpu.input_grad,
            BACKWARD_RTOL,
        );

        // The allowances hide no real error: hash-grid outputs off by 1 % of the table's scale,
        // or table gradients 5 % too large, fail.
        if let Some((_, part)) = encoding.grid() {
            let mut off = gpu.encoded.clone();
            for row in off.chunks_exact_mut(dims) {
                row[part.out_offset..part.out_offset + part.out_dims]
                    .iter_mut()
                    .for_each(|v| *v += 0.01);
            }
            let forward = worst_beyond(&cpu.encoded, &off, FORWARD_RTOL, &|_| contraction).0;
            let grads: Vec<f32> = gpu.table_grad.iter().map(|g| g * 1.05).collect();
            let backward = worst_beyond(&cpu.table_grad, &grads, BACKWARD_RTOL, &|i| {
                contraction_grad[i]
            })
            .0;
            assert!(
                forward > 1.0 && backward > 1.0,
                "{case}: the allowances hide a wrong answer ({forward:.2}, {backward:.2} × tolerance)"
            );
        }
        let has_grid = encoding
            .parts
            .iter()
            .any(|p| matches!(p.kind, EncodingKind::HashGrid(_)));
        assert_eq!(
            has_grid,
            !cpu.table_grad.is_empty(),
            "{case}: a table gradient exactly when there is a table"
        );
        if has_grid {
            assert!(
                cpu.table_grad.iter().any(|g| *g != 0.0),
                "{case}: the table gradient is not all zero"
            );
        }
        println!(
            "{case}: {} outputs, {} table gradients agree (forward {:.2}, table grad {:.2}, input grad {:.2} × tolerance)",
            cpu.encoded.len(),
            cpu.table_grad.len(),
            worst_beyond(&cpu.encoded, &gpu.encoded, FORWARD_RTOL, &|_| contraction).0,
            worst_beyond(&cpu.table_grad, &gpu.table_grad, BACKWARD_RTOL, &|i| {
                contraction_grad[i]
            })
            .0,
            worst(&cpu.input_grad, &gpu.input_grad, BACKWARD_RTOL).0,
        );
    }
}

/// The fused MLP op (`nrc_cache::ops::mlp`): tile-fused rayon kernels on Flex, tile-fused WGSL
/// kernels on wgpu. Same weights, inputs and upstream gradient on both; raw outputs, weight
/// gradients and input gradients must agree, for both presets' network shapes and a batch that
/// is not a multiple of the tile.
#[test]
fn avx2_hash_grid_kernel_matches_the_portable_loop() {
    use burn::tensor::f16;
    use nrc_cache::cpu::grid::{Table, encode_tile, encode_tile_portable};
    if !nrc_cache::cpu::gemm::has_avx2_fma() {
        nrc_scene::testing::skipped(
            "avx2_hash_grid_kernel_matches_the_portable_loop",
            "this CPU has no AVX2/FMA, so only the portable loop exists",
        );
        return;
    }
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    for log2t in [12u32, 19] {
        let grid = preset_like_grid(log2t);
        let levels = grid.fast_levels();
        let m = 700;
        let pos = hard_positions(&mut rng, m);
        let d = grid.output_dims();
        for (half, table_stride) in [(false, 2usize), (true, 2), (false, 8)] {
            let table: Vec<f32> = (0..grid.total_entries * table_stride)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let halves: Vec<f16> = table.iter().map(|v| f16::from_f32(*v)).collect();
            let view = if half {
                Table::F16(&halves)
            } else {
                Table::F32(&table, table_stride)
            };
            let run = |avx: bool| {
                let mut out = vec![0f32; m * (d + 3)];
                let p = |i: usize| [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]];
                if avx {
                    encode_tile(&grid, &levels, view, m, p, &mut out, d + 3, 3);
                } else {
                    encode_tile_portable(&levels, 2, view, m, p, &mut out, d + 3, 3);
                }
                out
            };
            let (a, b) = (run(true), run(false));
            assert!(a.iter().any(|v| *v != 0.0));
            for (i, (x, y)) in a.iter().zip(&b).enumerate() {
                assert_eq!(
                    x.to_bits(),
                    y.to_bits(),
                    "log2T {log2t}, stride {table_stride}, half {half}, value {i}: {x} vs {y}"
                );
            }
        }
    }
}

/// The hash-grid preset's levels with table size 2^`log2t`.
fn preset_like_grid(log2t: u32) -> nrc_cache::encoding::hash_grid::HashGrid {
    use nrc_cache::encoding::hash_grid::{HashGrid, HashGridParams};
    HashGrid::new(HashGridParams {
        n_levels: 16,
        n_features_per_level: 2,
        log2_hashmap_size: log2t,
        base_resolution: 16.0,
        per_level_scale: 1.38191,
        inference_precision: Default::default(),
        training_precision: Default::default(),
    })
}

/// `m` random positions (`[m][3]`), the first three on faces of the cube, outside it and NaN.
fn hard_positions(rng: &mut Pcg64Mcg, m: usize) -> Vec<f32> {
    let mut pos: Vec<f32> = (0..3 * m).map(|_| rng.random::<f32>()).collect();
    pos[..9].copy_from_slice(&[0.0, 1.0, 1.0, 1.0, 0.0, 1.0, -0.5, 2.0, f32::NAN]);
    pos
}

/// The batch gradient scatter (per level, software-pipelined) gives the same bits as
/// scattering one sample at a time with the scalar reference, including
/// positions on the faces of the cube, outside it and NaN, and a batch that is not a multiple
/// of eight; also with every sample at one point, which overflows the first try's bins on the
/// hashed levels (redone with counted bins).
#[test]
fn batch_hash_grid_scatter_matches_the_per_sample_reference() {
    use nrc_cache::cpu::grid::backward_table;
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    for log2t in [12u32, 19] {
        let grid = preset_like_grid(log2t);
        let m = 700;
        let mut pos = hard_positions(&mut rng, m);
        // Clustered samples, so that entries collect several contributions.
        for v in pos[300..600].iter_mut() {
            *v = 0.5 + 0.01 * *v;
        }
        let one_point: Vec<f32> = (0..m).flat_map(|_| [0.3, 0.6, 0.7]).collect();
        let levels = grid.levels.len();
        let dense_multi_bin = grid
            .levels
            .iter()
            .filter(|l| l.dense && l.entries as usize > nrc_cache::cpu::grid::BIN_ENTRIES)
            .count();
        for (what, pos) in [("spread", pos), ("one point", one_point)] {
            let d = grid.output_dims();
            let dout: Vec<f32> = (0..m * d).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut batch = vec![0f32; grid.total_entries * 2];
            backward_table(&grid, &pos, &dout, &mut batch);
            let mut reference = vec![0f32; grid.total_entries * 2];
            for i in 0..m {
                grid.backward_params_one(
                    [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]],
                    &dout[i * d..(i + 1) * d],
                    &mut reference,
                );
            }
            assert!(batch.iter().filter(|v| **v != 0.0).count() > 100);
            let (binned, counted) = binned_gradient(&grid, &pos, &dout);
            // Dense levels of several bins always count; so do hashed levels where the cluster
            // overflows a bin (the coarser ones), and at one point every hashed level of several
            // bins; at log2T 12 every level is one bin.
            let multi_bin = grid
                .levels
                .iter()
                .filter(|l| l.entries as usize > nrc_cache::cpu::grid::BIN_ENTRIES)
                .count();
            let expected = match what {
                "spread" => dense_multi_bin..multi_bin,
                _ => multi_bin..multi_bin + 1,
            };
            assert!(
                expected.contains(&counted) || (multi_bin == 0 && counted == 0),
                "log2T {log2t}, {what}: {counted} of {levels} levels counted, not {expected:?}"
            );
            for (i, ((x, y), z)) in batch.iter().zip(&reference).zip(&binned).enumerate() {
                assert_eq!(
                    x.to_bits(),
                    y.to_bits(),
                    "log2T {log2t}, {what}, value {i}: {x} vs {y}"
                );
                assert_eq!(
                    z.to_bits(),
                    y.to_bits(),
                    "log2T {log2t}, {what}, binned value {i}: {z} vs {y}"
                );
            }
        }
        if log2t == 19 {
            assert!(
                dense_multi_bin > 0,
                "the preset has dense levels of several bins"
            );
        }
    }
}

/// The table gradient as the training step forms it: level by level with
/// [`nrc_cache::cpu::grid::scatter_binned`], each bin copied out and cleared as the sparse
/// update does; checks that every entry with a nonzero gradient is marked referenced (a
/// referenced entry's sum may be zero: corners with weight zero on the cube's faces). Also
/// returns how many levels were redone with counted bins.
fn binned_gradient(
    grid: &nrc_cache::encoding::hash_grid::HashGrid,
    pos: &[f32],
    dout: &[f32],
) -> (Vec<f32>, usize) {
    use nrc_cache::cpu::grid::{BinScratch, scatter_binned};
    let m = pos.len() / 3;
    let d = grid.output_dims();
    let padded = m.next_multiple_of(8);
    let axes: Vec<Vec<f32>> = (0..3)
        .map(|a| {
            let mut v: Vec<f32> = (0..m).map(|i| pos[3 * i + a]).collect();
            v.resize(padded, 0.0);
            v
        })
        .collect();
    let xyz = [&axes[0][..], &axes[1][..], &axes[2][..]];
    let mut out = vec![0f32; grid.total_entries * 2];
    let mut scratch = BinScratch::default();
    for (l, level) in grid.levels.iter().enumerate() {
        let level_dout: Vec<f32> = (0..m)
            .flat_map(|i| [dout[i * d + 2 * l], dout[i * d + 2 * l + 1]])
            .collect();
        let base = level.offset * 2;
        scatter_binned::<2>(
            grid,
            l,
            xyz,
            &level_dout,
            &mut scratch,
            |first, g, touched| {
                for (e, pair) in g.chunks_exact_mut(2).enumerate() {
                    let bit = touched[e / 64] >> (e % 64) & 1 == 1;
                    assert!(bit || pair == [0.0, 0.0], "level {l}, entry {}", first + e);
                    out[base + 2 * (first + e)..][..2].copy_from_slice(pair);
                }
                g.fill(0.0);
                touched.fill(0);
            },
        );
    }
    (out, scratch.counted_levels())
}

/// The per-sample encodings of a whole tile (one-blob a column at a time) give the same bits as
/// the one-sample reference encoding, for both presets, with inputs outside [0,1] and NaN.
#[test]
fn tile_encoding_matches_the_per_row_encoding() {
    use nrc_cache::model::ModelLayout;
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    for config in [
        nrc_cache::CacheConfig::hash_grid_preset(),
        nrc_cache::CacheConfig::triangle_wave_preset(),
    ] {
        let enc = ModelLayout::new(&config).encoding;
        let (m, row_len) = (77, RAW_INPUT_DIMS + 5);
        let mut rows: Vec<f32> = (0..m * row_len)
            .map(|_| rng.random_range(-0.2..1.2))
            .collect();
        rows[3] = f32::NAN;
        rows[row_len + 4] = f32::INFINITY;
        let k = enc.padded_dims;
        let mut tile = vec![7f32; m * k];
        enc.forward_rows_without_grid(&rows, row_len, &mut tile, k);
        let grid_columns = enc.grid().map_or(0..0, |(_, part)| {
            part.out_offset..part.out_offset + part.out_dims
        });
        let table = vec![0f32; enc.grid().map_or(0, |(g, _)| g.param_count())];
        let mut one = vec![0f32; k];
        for (row, t) in rows.chunks_exact(row_len).zip(tile.chunks_exact(k)) {
            enc.forward_one(&table, &row[..RAW_INPUT_DIMS], &mut one);
            for (j, (a, b)) in t.iter().zip(&one).enumerate() {
                if grid_columns.contains(&j) {
                    assert_eq!(*a, 7.0, "grid column {j} written");
                } else {
                    assert_eq!(a.to_bits(), b.to_bits(), "column {j}: {a} vs {b}");
                }
            }
        }
    }
}
