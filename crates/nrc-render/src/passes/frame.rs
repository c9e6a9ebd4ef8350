//! What every pass shares: a frame's input, its output and statistics, the [`RenderPass`]
//! trait, and [`run`], one frame of a pass with its radiance source.

use std::time::Instant;

use glam::{Vec2, Vec3};
use nrc_scene::{Camera, Image, Scene};

use crate::emitters::Supersampled;
use crate::sampler::PixelSequence;
use crate::source::{RadianceQuery, RadianceSource};

/// Where an inference path ended in the source: the vertex and the point the segment reaching
/// it came from (the next frame's training queries re-enter along it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TerminationPoint {
    pub from: Vec3,
    pub to: Vec3,
}

/// What a pass renders this frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameInput<'a> {
    pub scene: &'a Scene,
    pub camera: &'a Camera,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel, at least 1.
    pub spp: u32,
    /// Seed of the frame's random streams: the image is a function of it alone, whatever the
    /// thread count.
    pub seed: u64,
    /// Extra camera rays, their emission only, at each pixel on the outline of an emitter the
    /// camera sees ([`crate::emitters::supersample`]; 0: none). Passes whose camera rays go
    /// through pixel centres (tests at fixed primary rays) take none.
    pub emitter_samples: u32,
    /// Where the frame's camera rays lie in their pixels' sequences ([`PixelSequence`]:
    /// frames of a run stratifying each pixel's footprint together); `None`: independent
    /// offsets from the frame's seed. Passes whose camera rays go through pixel centres ignore
    /// it.
    pub sequence: Option<PixelSequence>,
}

impl FrameInput<'_> {
    /// The camera offset of sample `s` of pixel `pixel` ([`crate::sampler::camera_offset`]).
    pub fn camera_offset(&self, pixel: u64, s: u32, independent: Vec2) -> Vec2 {
        crate::sampler::camera_offset(self.sequence, pixel, s, independent)
    }

    /// The emitters' anti-aliasing of this frame ([`crate::emitters::supersample`] with its
    /// `emitter_samples` and seed) for a pass whose `taken` camera rays a pixel saw `seen`
    /// directly (pixel means, row-major); `None` when the frame takes no extra rays.
    pub fn supersample_emitters(&self, taken: u32, seen: &[Vec3]) -> Option<Supersampled> {
        (self.emitter_samples > 0).then(|| {
            crate::emitters::supersample(
                self.scene,
                self.camera,
                (self.width, self.height),
                self.seed,
                taken,
                self.emitter_samples,
                seen,
                None,
            )
        })
    }
}

/// What a pass counted in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct PassStats {
    /// Camera paths traced (pixels × samples).
    pub paths: u64,
    /// Rays traced (closest-hit and shadow).
    pub rays: u64,
    /// Queries sent to the radiance source.
    pub queries: u64,
    /// Samples whose value was NaN or infinite (counted as black).
    pub invalid_samples: u64,
    /// Milliseconds in the trace phase.
    pub trace_ms: f64,
    /// The frame's phases: the resampling passes' own (zero for the others) and the source's
    /// answers (any pass that asks one).
    pub phases: PhaseTimes,
}

/// Milliseconds per phase of a pass's frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PhaseTimes {
    /// The probe volume's update (its rays traced and blended), for the DDGI passes.
    pub probes_ms: f64,
    /// Camera rays and initial candidates.
    pub candidates_ms: f64,
    pub temporal_ms: f64,
    pub spatial_ms: f64,
    /// Final visibility, shading and the rest of the path.
    pub shading_ms: f64,
    /// The radiance source answering the frame's queries (between trace and resolve; zero
    /// for a pass that asks none).
    pub source_ms: f64,
}

impl PhaseTimes {
    /// Each phase by name, in frame order.
    pub fn named(&self) -> [(&'static str, f64); 6] {
        [
            ("probes", self.probes_ms),
            ("candidates", self.candidates_ms),
            ("temporal", self.temporal_ms),
            ("spatial", self.spatial_ms),
            ("shading", self.shading_ms),
            ("source", self.source_ms),
        ]
    }

    /// `candidates 2.0 ms, temporal 0.5 ms, ...` with the phases that took a twentieth of a
    /// millisecond or more, or `None` for a pass that took none.
    pub fn describe(&self) -> Option<String> {
        let parts: Vec<String> = self
            .named()
            .iter()
            .filter(|(_, ms)| *ms >= 0.05)
            .map(|(n, ms)| format!("{n} {ms:.1} ms"))
            .collect();
        (!parts.is_empty()).then(|| parts.join(", "))
    }

    /// Adds another frame's times to these.
    pub fn add(&mut self, o: &PhaseTimes) {
        self.probes_ms += o.probes_ms;
        self.candidates_ms += o.candidates_ms;
        self.temporal_ms += o.temporal_ms;
        self.spatial_ms += o.spatial_ms;
        self.shading_ms += o.shading_ms;
        self.source_ms += o.source_ms;
    }
}

/// A rendered frame.
#[derive(Clone, Debug)]
pub struct PassOutput {
    /// Per-pixel mean radiance.
    pub image: Image,
    /// Per-pixel sample variance of one sample's estimate, where the pass computes it.
    pub variance: Option<Image>,
    /// Where paths ended in the source (the next frame's training-query prediction).
    pub terminations: Vec<TerminationPoint>,
    pub stats: PassStats,
}

/// An inference pass with its state across frames (see the module documentation).
pub trait RenderPass: Send {
    /// The pass's canonical name (parses back to its spec).
    fn name(&self) -> String;

    /// Per-frame upkeep before tracing. Default: nothing.
    fn prepare(&mut self, _input: &FrameInput) {}

    /// Forgets the state kept across frames (history, reservoirs), as at the start of an
    /// independent run. Default: nothing (stateless passes).
    fn reset(&mut self) {}

    /// Traces the frame's paths; returns the queries the radiance source must answer.
    fn trace(&mut self, input: &FrameInput) -> Vec<RadianceQuery>;

    /// Combines the answers (one per query of [`RenderPass::trace`], in order) into the frame.
    fn resolve(&mut self, input: &FrameInput, answers: &[Vec3]) -> PassOutput;

    /// Images of the pass's own state after its last frame, for the viewer's debug views
    /// (`nrc view`). Default: none.
    fn debug_views(&self) -> Vec<PassView> {
        Vec::new()
    }
}

/// One image of a pass's state ([`RenderPass::debug_views`]).
#[derive(Clone, Debug)]
pub struct PassView {
    /// Short name, as `nrc view --view` takes it (e.g. `reservoir-m`).
    pub name: &'static str,
    /// A scalar per pixel in the red channel (shown in false colour), else a colour.
    pub scalar: bool,
    pub image: Image,
}

impl PassView {
    /// A colour view of `points` (position, colour) seen through `camera` in a `width × height`
    /// image: a disc of `radius` pixels each, nearer points over farther ones, unoccluded by the
    /// scene (probe and VPL positions).
    pub fn points(
        name: &'static str,
        camera: &Camera,
        width: u32,
        height: u32,
        points: impl IntoIterator<Item = (Vec3, Vec3)>,
        radius: f32,
    ) -> Self {
        let mut image = Image::new(width as usize, height as usize);
        let mut seen: Vec<(f32, glam::Vec2, Vec3)> = points
            .into_iter()
            .filter_map(|(p, c)| {
                let film = camera.project(p, width, height)?;
                Some(((p - camera.position).length(), film, c))
            })
            .collect();
        // Farthest first, so the nearest is drawn last.
        seen.sort_by(|a, b| b.0.total_cmp(&a.0));
        let r = radius.max(0.5);
        for (_, film, colour) in seen {
            let (x0, x1) = (
                (film.x - r).floor().max(0.0) as u32,
                (film.x + r).ceil() as u32,
            );
            let (y0, y1) = (
                (film.y - r).floor().max(0.0) as u32,
                (film.y + r).ceil() as u32,
            );
            for y in y0..y1.min(height) {
                for x in x0..x1.min(width) {
                    let d = glam::Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - film;
                    if d.length() <= r {
                        image.set(x as usize, y as usize, colour);
                    }
                }
            }
        }
        Self {
            name,
            scalar: false,
            image,
        }
    }
}

/// Consecutive frames of one size a pass has rendered since its state was last reset: how
/// many frames its history holds (a resampling pass's history is of the frame's size, and is
/// dropped at a frame of another).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Warmth {
    size: (u32, u32),
    frames: u32,
}

impl Warmth {
    /// Counts a frame of `input`'s size; returns how many frames of that size came before it.
    pub fn count(&mut self, input: &FrameInput) -> u32 {
        let size = (input.width, input.height);
        let before = if size == self.size { self.frames } else { 0 };
        *self = Self {
            size,
            frames: before + 1,
        };
        before
    }

    /// Forgets every frame (the pass's state was reset).
    pub fn reset(&mut self) {
        *self = Self::default();
    }
}

/// One frame of `pass`: prepare, trace, one batch call of `source`, resolve; the trace and
/// source phases timed in the output's statistics.
pub fn run(
    pass: &mut dyn RenderPass,
    input: &FrameInput,
    source: &dyn RadianceSource,
) -> PassOutput {
    pass.prepare(input);
    let t0 = Instant::now();
    let queries = pass.trace(input);
    let trace_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = Instant::now();
    let (answers, source_ms) = if queries.is_empty() {
        (Vec::new(), 0.0)
    } else {
        let a = source.radiance(&queries);
        (a, t1.elapsed().as_secs_f64() * 1e3)
    };
    assert_eq!(
        answers.len(),
        queries.len(),
        "a radiance source answers every query"
    );
    let mut out = pass.resolve(input, &answers);
    out.stats.trace_ms = trace_ms;
    out.stats.phases.source_ms = source_ms;
    out.stats.queries = queries.len() as u64;
    out
}
