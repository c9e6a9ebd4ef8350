//! Budgets and the frame loop of the comparison harness.
//!
//! A method's unit of work is an **estimate**: one independent estimate of the frame at the
//! method's stated samples per pixel (its random streams chosen by a seed). [`render_frame`]
//! averages estimates until the [`Budget`] is spent:
//!
//! - [`Budget::Passes`]`(n)` (equal samples): exactly `n` estimates, so `pt-4spp` at 2 holds 8
//!   samples per pixel; methods stating the same samples per pixel get the same count.
//! - [`Budget::Time`]`(t)` (equal time): estimates follow each other while finishing one more
//!   is predicted to end nearer the budget than stopping now (predicted with the mean time so
//!   far, i.e. another starts while `elapsed + mean/2 ≤ t`). At least one is made, even if it
//!   alone exceeds the budget. **Tolerance:** the frame's wall time is within one estimate of
//!   the budget, `|elapsed − t| ≤` [`Frame::longest_pass`] (with steady times, within half of
//!   one); the last estimate is always kept whole, never cut or weighted.

use std::fmt;
use std::time::{Duration, Instant};

use glam::{DVec3, Vec3};
use nrc_scene::{Camera, Image, Scene};

use nrc_render::passes::{PassView, PhaseTimes};
use nrc_render::{PixelSequence, pass_seed};

use crate::error::HarnessError;

/// One independent estimate of the frame by a method.
#[derive(Clone, Debug)]
pub struct Estimate {
    /// Per-pixel mean radiance of the pass.
    pub image: Image,
    /// Samples whose estimate was NaN or infinite (counted as black).
    pub invalid_samples: u64,
    /// Stateful methods: frames of this size the method's state rendered before this one
    /// since it was last reset (how warm its history was).
    pub warm_frames: Option<u32>,
    /// Rays the pass traced, closest-hit and shadow (a trained cache's producer not included).
    pub rays: u64,
    /// The pass's phase times ([`PhaseTimes`]).
    pub phases: PhaseTimes,
}

/// A rendering method with its state (for the path tracer, just its settings; for cache-based
/// methods, the cache they train and query). Methods render on the current rayon pool.
pub trait Method: Send {
    /// The method's canonical name.
    fn name(&self) -> &str;

    /// Samples per pixel of one pass.
    fn samples_per_pass(&self) -> u32;

    /// Gets ready to render `width × height` frames from `camera` (cache methods train here);
    /// called once, untimed, before the first measured frame. An error names what is wrong.
    fn prepare(
        &mut self,
        _scene: &Scene,
        _camera: &Camera,
        _width: u32,
        _height: u32,
    ) -> Result<(), HarnessError> {
        Ok(())
    }

    /// Whether [`Method::prepare`] already rendered at the comparison's size (so thread pool
    /// and caches are warm, and an untimed start-up frame of another size would only shrink a
    /// stateful pass's history). Default: no.
    fn warm_after_prepare(&self) -> bool {
        false
    }

    /// Starts independent run `run` (seeded `seed`), untimed: a stateful method forgets the
    /// state of the previous run (a pass's history, a trained cache) and builds it afresh, with
    /// the same warm-up for every run, so that runs are independent estimates. Called before
    /// every run, after [`Method::prepare`]. Default: nothing (stateless methods).
    fn restart(
        &mut self,
        _scene: &Scene,
        _camera: &Camera,
        _width: u32,
        _height: u32,
        _run: u32,
        _seed: u64,
    ) -> Result<(), HarnessError> {
        Ok(())
    }

    /// Renders one pass of `width × height` pixels from `camera`; `seed` chooses the random
    /// streams, so passes with different seeds are independent estimates; `sequence`, where
    /// given, places the pass's camera rays ([`nrc_render::FrameInput::sequence`]).
    fn render_estimate(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        height: u32,
        seed: u64,
        sequence: Option<PixelSequence>,
    ) -> Estimate;

    /// The images of its pass's state after its last frame (a resampling pass's reservoir
    /// statistics, probes, VPLs: [`nrc_render::passes::RenderPass::debug_views`]), for
    /// `nrc compare --diagnostics`. Default: none.
    fn debug_views(&self) -> Vec<PassView> {
        Vec::new()
    }
}

/// How much a frame may spend.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Budget {
    /// Exactly this many passes (equal samples per pixel for methods of equal pass size).
    Passes(u32),
    /// Wall-clock time (equal time); see the module documentation for the stopping rule.
    Time(Duration),
}

impl Budget {
    /// Equal time (`equal_time_ms`) or equal samples (`equal_passes`): exactly one, checked.
    pub fn from_limits(
        equal_time_ms: Option<f64>,
        equal_passes: Option<u32>,
    ) -> Result<Self, HarnessError> {
        match (equal_time_ms, equal_passes) {
            (Some(ms), None) if ms.is_finite() && ms > 0.0 && ms <= 3.6e6 => {
                Ok(Budget::Time(Duration::from_secs_f64(ms * 1e-3)))
            }
            (Some(ms), None) => Err(HarnessError::bounds(
                "--equal-time",
                "be between 0 and one hour in milliseconds",
                ms,
            )),
            (None, Some(0)) => Err(HarnessError::bounds("--equal-spp", "be at least 1", 0)),
            (None, Some(n)) => Ok(Budget::Passes(n)),
            _ => Err(HarnessError::BudgetChoice),
        }
    }
}

/// Where a run's frames put their camera rays in each pixel (`nrc compare --camera-offsets`).
#[derive(
    clap::ValueEnum,
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum CameraOffsets {
    /// Each pass's offsets independent of the others' (uniform random in the pixel).
    #[default]
    Independent,
    /// The passes of a run take consecutive points of one Owen-scrambled Sobol sequence per
    /// pixel ([`nrc_render::PixelSequence`]), scrambled anew for each run: every offset still
    /// uniform in the pixel, so each pass stays unbiased, and a run's passes stratify the
    /// pixel's footprint together.
    Sobol,
}

/// What to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRequest {
    pub width: u32,
    pub height: u32,
    /// Seed of the frame; pass `p` uses [`pass_seed`]`(seed, p)`.
    pub seed: u64,
    pub budget: Budget,
    /// Where the passes put their camera rays in each pixel: with [`CameraOffsets::Sobol`],
    /// pass `p` takes the points `p · samples per pass, …` of each pixel's sequence seeded by
    /// `seed`.
    pub offsets: CameraOffsets,
}

/// A rendered frame: the average of its passes, and what it cost.
#[derive(Clone, Debug)]
pub struct Frame {
    pub image: Image,
    /// Passes averaged.
    pub passes: u32,
    /// Samples per pixel in the frame (passes × samples per pass).
    pub samples_per_pixel: u64,
    /// Wall time of the whole frame (passes and averaging).
    pub elapsed: Duration,
    /// The longest pass, measured between consecutive budget checks (so it includes any
    /// overhead between passes); the equal-time tolerance.
    pub longest_pass: Duration,
    /// Samples whose estimate was NaN or infinite (counted as black).
    pub invalid_samples: u64,
    /// The first pass's [`Estimate::warm_frames`].
    pub warm_frames: Option<u32>,
    /// Rays of all passes ([`Estimate::rays`]).
    pub rays: u64,
    /// Phase times summed over the passes.
    pub phases: PhaseTimes,
}

/// Why a frame could not be rendered.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BudgetError(pub String);

impl fmt::Display for BudgetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BudgetError {}

/// Renders one frame of `method` within `request.budget`: passes with seeds
/// [`pass_seed`]`(request.seed, 0, 1, …)`, averaged with equal weights.
pub fn render_frame(
    method: &mut dyn Method,
    scene: &Scene,
    camera: &Camera,
    request: &FrameRequest,
) -> Result<Frame, BudgetError> {
    let (w, h) = (request.width, request.height);
    if w == 0 || h == 0 {
        return Err(BudgetError(format!("image size {w}x{h} is empty")));
    }
    match request.budget {
        Budget::Passes(0) => return Err(BudgetError("a frame needs at least one pass".into())),
        Budget::Time(t) if t.is_zero() => {
            return Err(BudgetError("the time budget must be positive".into()));
        }
        _ => {}
    }
    let start = Instant::now();
    let mut sum = vec![DVec3::ZERO; w as usize * h as usize];
    let mut passes = 0u32;
    let mut invalid_samples = 0;
    let mut longest_pass = Duration::ZERO;
    let mut last_check = Duration::ZERO;
    let mut warm_frames = None;
    let mut rays = 0;
    let mut phases = PhaseTimes::default();
    loop {
        let sequence = (request.offsets == CameraOffsets::Sobol).then(|| PixelSequence {
            seed: request.seed,
            first: passes.wrapping_mul(method.samples_per_pass()),
        });
        let pass = method.render_estimate(
            scene,
            camera,
            w,
            h,
            pass_seed(request.seed, passes),
            sequence,
        );
        if passes == 0 {
            warm_frames = pass.warm_frames;
        }
        for (s, p) in sum.iter_mut().zip(&pass.image.data) {
            *s += p.as_dvec3();
        }
        invalid_samples += pass.invalid_samples;
        rays += pass.rays;
        phases.add(&pass.phases);
        passes += 1;
        let now = start.elapsed();
        longest_pass = longest_pass.max(now - last_check);
        last_check = now;
        let more = match request.budget {
            Budget::Passes(n) => passes < n,
            // Another pass ends nearer the budget than stopping now when
            // now + mean ≤ budget + (budget − now), i.e. now + mean/2 ≤ budget.
            Budget::Time(budget) => now + (now / passes) / 2 <= budget,
        };
        if !more {
            break;
        }
    }
    let scale = 1.0 / passes as f64;
    let data: Vec<Vec3> = sum.iter().map(|s| (*s * scale).as_vec3()).collect();
    let image = Image::from_data(w as usize, h as usize, data).expect("one value per pixel");
    Ok(Frame {
        image,
        passes,
        samples_per_pixel: passes as u64 * method.samples_per_pass() as u64,
        elapsed: start.elapsed(),
        longest_pass,
        invalid_samples,
        warm_frames,
        rays,
        phases,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A method whose passes are constant images worth `pass index + 1` and take a fixed time.
    struct Fake {
        passes: u32,
        sleep: Duration,
        /// The camera offsets' sequence each pass was given.
        sequences: Vec<Option<PixelSequence>>,
    }

    impl Fake {
        fn new(sleep: Duration) -> Self {
            Self {
                passes: 0,
                sleep,
                sequences: Vec::new(),
            }
        }
    }

    impl Method for Fake {
        fn name(&self) -> &str {
            "fake"
        }
        fn samples_per_pass(&self) -> u32 {
            3
        }
        fn render_estimate(
            &mut self,
            _: &Scene,
            _: &Camera,
            width: u32,
            height: u32,
            _: u64,
            sequence: Option<PixelSequence>,
        ) -> Estimate {
            std::thread::sleep(self.sleep);
            self.sequences.push(sequence);
            self.passes += 1;
            constant_estimate(width, height, self.passes as f32)
        }
    }

    /// An estimate whose every pixel is `value`.
    pub(crate) fn constant_estimate(width: u32, height: u32, value: f32) -> Estimate {
        let n = (width * height) as usize;
        let image =
            Image::from_data(width as usize, height as usize, vec![Vec3::splat(value); n]).unwrap();
        Estimate {
            image,
            invalid_samples: 0,
            warm_frames: None,
            rays: 0,
            phases: PhaseTimes::default(),
        }
    }

    /// One triangle and nothing else (for methods that do not trace it).
    pub(crate) fn empty_scene() -> Scene {
        Scene::from_description(nrc_scene::SceneDescription {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]],
            triangle_materials: vec![0],
            triangle_meshes: vec![0],
            mesh_names: vec!["t".into()],
            materials: vec![nrc_scene::Material::default()],
            ..Default::default()
        })
        .unwrap()
    }

    #[test]
    fn equal_passes_average_all_passes() {
        let scene = empty_scene();
        let mut m = Fake::new(Duration::ZERO);
        let req = FrameRequest {
            width: 2,
            height: 3,
            seed: 1,
            budget: Budget::Passes(4),
            offsets: CameraOffsets::Independent,
        };
        let f = render_frame(&mut m, &scene, &scene.camera, &req).unwrap();
        assert_eq!((f.passes, f.samples_per_pixel), (4, 12));
        // Mean of 1, 2, 3, 4.
        assert!(f.image.data.iter().all(|p| *p == Vec3::splat(2.5)));
        let bad = FrameRequest {
            budget: Budget::Passes(0),
            ..req
        };
        assert!(render_frame(&mut m, &scene, &scene.camera, &bad).is_err());
    }

    /// The stopping rule's guarantee, |elapsed − budget| ≤ longest pass, with passes of
    /// several sizes relative to the budget (including one pass longer than the budget).
    #[test]
    fn equal_time_stops_within_one_pass_of_the_budget() {
        let scene = empty_scene();
        for (sleep_ms, budget_ms) in [(2u64, 30u64), (7, 30), (40, 30)] {
            let mut m = Fake::new(Duration::from_millis(sleep_ms));
            let budget = Duration::from_millis(budget_ms);
            let req = FrameRequest {
                width: 2,
                height: 2,
                seed: 1,
                budget: Budget::Time(budget),
                offsets: CameraOffsets::Independent,
            };
            let f = render_frame(&mut m, &scene, &scene.camera, &req).unwrap();
            let diff = f.elapsed.abs_diff(budget);
            assert!(diff <= f.longest_pass, "{sleep_ms} ms passes: {f:?}");
            assert!(f.longest_pass >= Duration::from_millis(sleep_ms));
            assert_eq!(f.samples_per_pixel, 3 * f.passes as u64);
            if sleep_ms > budget_ms {
                assert_eq!(f.passes, 1);
            }
        }
    }

    /// With Sobol offsets pass `p` of a frame takes its pixels' points from `p × samples per
    /// pass` of the sequence seeded by the frame's seed (so a run's passes continue one
    /// sequence); with independent offsets none is given.
    #[test]
    fn sobol_offsets_continue_one_sequence_over_the_passes() {
        let scene = empty_scene();
        for offsets in [CameraOffsets::Sobol, CameraOffsets::Independent] {
            let mut m = Fake::new(Duration::ZERO);
            let req = FrameRequest {
                width: 2,
                height: 2,
                seed: 11,
                budget: Budget::Passes(4),
                offsets,
            };
            render_frame(&mut m, &scene, &scene.camera, &req).unwrap();
            let want: Vec<Option<PixelSequence>> = (0..4)
                .map(|p| {
                    (offsets == CameraOffsets::Sobol).then_some(PixelSequence {
                        seed: 11,
                        first: 3 * p,
                    })
                })
                .collect();
            assert_eq!(m.sequences, want, "{offsets:?}");
        }
    }

    #[test]
    fn pass_seeds_differ() {
        let mut seen = std::collections::HashSet::new();
        for seed in 0..64 {
            for pass in 0..64 {
                assert!(seen.insert(pass_seed(seed, pass)));
            }
        }
    }
}
