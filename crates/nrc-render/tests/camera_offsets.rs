//! Camera offsets from a per-pixel Owen-scrambled Sobol sequence (`nrc_render::PixelSequence`,
//! `nrc compare --camera-offsets sobol`): the passes of a run that take consecutive points of
//! it stay unbiased per pixel, and their mean has less variance than independent passes' where
//! the image varies within a pixel (an emitter's edges, the light it throws). The controls: a
//! sequence that does not advance between passes loses the gain, and one whose scramble is
//! not renewed per run is biased (every run shares its offsets' error).

mod common;

use common::{per_pixel_z, render_scene, window};
use glam::Vec3;
use nrc_render::passes::{self, FrameInput, PassSpec};
use nrc_render::{PathTracer, PixelSequence, RenderSettings, ZeroSource, pass_seed, render};
use nrc_scene::{Image, Scene};

const W: u32 = 20;
const H: u32 = 16;
const REF_SPP: u32 = 8192;
const RUNS: u32 = 128;
/// Passes of one sample a pixel in a run.
const PASSES: u32 = 8;

/// The emission seen and the direct light (depth 2).
fn tracer() -> PathTracer {
    PathTracer {
        max_depth: 2,
        ..PathTracer::default()
    }
}

/// How a run's passes place their camera rays.
#[derive(Clone, Copy, Debug)]
enum Offsets {
    Independent,
    /// Pass `p` at point `p` of the run's sequence (what `nrc compare` does).
    Sobol,
    /// The control: every pass at point 0.
    Stuck,
    /// The control: the same scramble in every run.
    SharedScramble,
}

/// `RUNS` runs, each the mean of `PASSES` one-sample passes.
fn runs(scene: &Scene, offsets: Offsets) -> Vec<Image> {
    (0..RUNS)
        .map(|r| {
            let run_seed = pass_seed(31, r);
            mean_of_passes(|p| {
                let sequence = match offsets {
                    Offsets::Independent => None,
                    Offsets::Sobol => Some(PixelSequence {
                        seed: run_seed,
                        first: p,
                    }),
                    Offsets::Stuck => Some(PixelSequence {
                        seed: run_seed,
                        first: 0,
                    }),
                    Offsets::SharedScramble => Some(PixelSequence { seed: 5, first: p }),
                };
                let settings = RenderSettings {
                    width: W,
                    height: H,
                    spp: 1,
                    seed: pass_seed(run_seed, p),
                    variance: false,
                    sequence,
                };
                render(scene, &scene.camera, &tracer(), &settings, &|_| {}).mean
            })
        })
        .collect()
}

/// The mean of `PASSES` images, pass `p` the image `pass(p)`.
fn mean_of_passes(mut pass: impl FnMut(u32) -> Image) -> Image {
    let mut sum = vec![Vec3::ZERO; (W * H) as usize];
    for p in 0..PASSES {
        for (s, v) in sum.iter_mut().zip(&pass(p).data) {
            *s += *v / PASSES as f32;
        }
    }
    Image::from_data(W as usize, H as usize, sum).unwrap()
}

#[test]
fn sobol_offsets_are_unbiased_per_pixel_and_stratify_a_runs_passes() {
    let scene = window();
    let reference = render_scene(&scene, &tracer(), W, H, REF_SPP, 4242);
    let ref_var = reference.variance.expect("variance at 8192 spp");

    let sobol = runs(&scene, Offsets::Sobol);
    let (worst, beyond, bound) = per_pixel_z(&sobol, &reference.mean, &ref_var, REF_SPP);
    eprintln!("sobol: worst |z| {worst:.2} (bound {bound:.2}), {beyond} beyond");
    assert_eq!(
        beyond, 0,
        "sobol offsets: worst |z| {worst:.2} against {bound:.2}"
    );

    let shared = runs(&scene, Offsets::SharedScramble);
    let (worst_shared, beyond_shared, _) = per_pixel_z(&shared, &reference.mean, &ref_var, REF_SPP);
    eprintln!("shared scramble (control): worst |z| {worst_shared:.2}, {beyond_shared} beyond");
    assert!(
        beyond_shared > 0,
        "a scramble shared by every run should show its offsets' error (worst |z| {worst_shared:.2})"
    );

    let (v_sobol, v_indep, v_stuck) = (
        common::summed_variance(&sobol),
        common::summed_variance(&runs(&scene, Offsets::Independent)),
        common::summed_variance(&runs(&scene, Offsets::Stuck)),
    );
    eprintln!(
        "variance of a run: sobol {v_sobol:.4}, independent {v_indep:.4}, stuck {v_stuck:.4}"
    );
    assert!(
        v_sobol < 0.45 * v_indep,
        "sobol {v_sobol:.4} against independent {v_indep:.4}"
    );
    assert!(
        v_stuck > 2.0 * v_indep,
        "a sequence stuck at one point should not stratify: {v_stuck:.4} against {v_indep:.4}"
    );
}

/// A `W × H` frame of one sample a pixel through `scene`'s camera.
fn frame_input(
    scene: &Scene,
    seed: u64,
    emitter_samples: u32,
    sequence: Option<PixelSequence>,
) -> FrameInput<'_> {
    FrameInput {
        scene,
        camera: &scene.camera,
        width: W,
        height: H,
        spp: 1,
        seed,
        emitter_samples,
        sequence,
    }
}

/// One frame of a fresh `spec` pass with the frame seed fixed and the camera offsets' sequence
/// `sequence`.
fn frame_of(scene: &Scene, spec: &str, sequence: Option<PixelSequence>) -> Image {
    let spec: PassSpec = spec.parse().unwrap();
    let mut pass = spec.build(&tracer());
    let input = frame_input(scene, 77, 0, sequence);
    passes::run(pass.as_mut(), &input, &ZeroSource).image
}

/// Every pass that jitters its camera rays takes them from the frame's sequence (another
/// scramble: another image; the same: the same bits), and a pass told not to jitter (rays
/// through pixel centres) ignores it.
#[test]
fn every_jittering_pass_takes_its_camera_rays_from_the_sequence() {
    let scene = window();
    let a = Some(PixelSequence { seed: 1, first: 0 });
    let b = Some(PixelSequence { seed: 2, first: 0 });
    for spec in [
        "pt",
        "cache-first",
        "cache",
        "ddgi-secondary",
        "restir-di",
        "restir-gi",
        "wsrestir-gi",
        "ddgi-restir",
        "nrc-restir",
        "ir",
    ] {
        let first = frame_of(&scene, spec, a);
        assert_eq!(
            first.data,
            frame_of(&scene, spec, a).data,
            "{spec}: not reproducible"
        );
        assert_ne!(
            first.data,
            frame_of(&scene, spec, b).data,
            "{spec}: ignores the sequence"
        );
        assert_ne!(
            first.data,
            frame_of(&scene, spec, None).data,
            "{spec}: ignores the sequence"
        );
    }
    for spec in [
        "restir-di:jitter=0",
        "wsrestir-gi:jitter=0",
        "ddgi-restir:jitter=0",
    ] {
        assert_eq!(
            frame_of(&scene, spec, a).data,
            frame_of(&scene, spec, b).data,
            "{spec}: rays through pixel centres moved"
        );
    }
}

/// `RUNS` runs of world-space ReSTIR GI (`split` camera rays a pixel sample, `keep_own` its
/// split's negative control, `emitter_samples` outline rays a frame), each the mean of
/// `PASSES` frames of a fresh pass, frame `p` at point `p` of the run's sequence.
fn split_runs(scene: &Scene, split: u32, keep_own: bool, emitter_samples: u32) -> Vec<Image> {
    use nrc_render::passes::RestirGiSettings;
    let spec: PassSpec = format!("wsrestir-gi:split={split}").parse().unwrap();
    let mut settings = *spec.get::<RestirGiSettings>().unwrap();
    settings.split_keeps_own = keep_own;
    let spec = PassSpec::from(settings);
    (0..RUNS)
        .map(|r| {
            let run_seed = pass_seed(47, r);
            let mut pass = spec.build(&tracer());
            mean_of_passes(|p| {
                let sequence = PixelSequence {
                    seed: run_seed,
                    first: p,
                };
                let input = frame_input(
                    scene,
                    pass_seed(run_seed, p),
                    emitter_samples,
                    Some(sequence),
                );
                passes::run(pass.as_mut(), &input, &ZeroSource).image
            })
        })
        .collect()
}

/// A split's extra camera rays (`wsrestir-gi:split=3`) in a run whose frames stratify each
/// pixel (`--camera-offsets sobol`): each extra ray takes its frame's point of a sequence of
/// its own, and what it sees directly joins the G-buffer's emission, weighed by rays (the
/// outline's supersampled mean counting for its rays). At depth 2 in [`window`] (the emission
/// seen and the direct light, both split) the runs match the footprint reference per pixel,
/// with outline rays and without, and their variance is below 0.4× the pass's without the
/// split (without outline rays; measured 0.35 when written, 0.27 with 4 outline rays; the build
/// before, whose extra rays were independent of the sequence and whose seen emission was the
/// G-buffer ray's alone, gave 0.93 and fails). Negative control: the path's own gathered
/// light kept whole beside the split's mean is biased and fails (the image's mean).
#[test]
fn split_camera_rays_stratify_with_the_runs_frames_and_see_the_emitters() {
    let scene = window();
    let reference = render_scene(&scene, &tracer(), W, H, REF_SPP, 4243);
    let ref_var = reference.variance.expect("variance at 8192 spp");
    let plain = common::summed_variance(&split_runs(&scene, 1, false, 0));
    for emitter_samples in [0, 4] {
        let runs = split_runs(&scene, 3, false, emitter_samples);
        let (worst, beyond, bound) = per_pixel_z(&runs, &reference.mean, &ref_var, REF_SPP);
        let ratio = common::summed_variance(&runs) / plain;
        eprintln!(
            "split=3, {emitter_samples} outline rays: worst |z| {worst:.2} (bound {bound:.2}), \
             {beyond} beyond; variance {ratio:.3}× the pass's without the split"
        );
        assert_eq!(beyond, 0, "worst |z| {worst:.2} against {bound:.2}");
        assert!(ratio < 0.4, "variance {ratio:.3}× without the split");
    }
    // The image's mean, which the control's bias moves too.
    let z = image_mean_z(&split_runs(&scene, 3, false, 0), &reference.mean, &ref_var);
    let z_kept = image_mean_z(&split_runs(&scene, 3, true, 0), &reference.mean, &ref_var);
    eprintln!("the image's mean: z {z:.2}; own light kept whole (control) z {z_kept:.2}");
    assert!(z.abs() < 4.0, "the image's mean: z {z:.2}");
    assert!(z_kept.abs() > 4.0, "the control passed: z {z_kept:.2}");
}

/// The z-score of the image's mean over `runs` (all pixels and channels) against the
/// reference's, the reference's own variance of the mean (its per-sample variance over
/// `REF_SPP`, summed over pixels as independent) included.
fn image_mean_z(runs: &[Image], reference: &Image, ref_var: &Image) -> f64 {
    let cells = (reference.data.len() * 3) as f64;
    let mean_of = |img: &Image| {
        img.data
            .iter()
            .map(|p| (p.x + p.y + p.z) as f64)
            .sum::<f64>()
            / cells
    };
    let means: Vec<f64> = runs.iter().map(mean_of).collect();
    let n = means.len() as f64;
    let m = means.iter().sum::<f64>() / n;
    let var = means.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
    let ref_se2 = ref_var
        .data
        .iter()
        .map(|p| (p.x + p.y + p.z) as f64)
        .sum::<f64>()
        / (cells * cells * REF_SPP as f64);
    (m - mean_of(reference)) / (var / n + ref_se2).sqrt()
}
