//! The path tracer's settings (depth limit, Russian roulette, light strategy) and the counters
//! a path adds to: what every walk reads, below the walk itself ([`crate::transport`]) and the
//! estimators built on it ([`crate::path_tracer`]).

/// Which estimators of direct illumination a path uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightStrategy {
    /// NEE and BSDF sampling combined by multiple importance sampling (the default).
    #[default]
    Mis,
    /// BSDF sampling alone: emitters count only when a scattered ray hits them (NEE off).
    BsdfOnly,
    /// NEE alone: emitters hit by rays scattered from non-delta surfaces are ignored (they
    /// are accounted for by the light sample). Emitters seen by the camera or through delta
    /// scattering still count, as no light sample can reach them.
    LightOnly,
}

/// Settings of the path tracer (per-path behaviour, not the image).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PathTracer {
    /// Maximum number of path segments, Mitsuba's convention: 1 = emitters seen directly,
    /// 2 = plus direct illumination, ... `0` or negative: unlimited (Russian roulette ends
    /// paths).
    pub max_depth: i32,
    /// Depth (in scattering events) from which Russian roulette may end a path; Mitsuba's
    /// `rr_depth` (default 5).
    pub rr_depth: u32,
    /// Estimators of direct illumination.
    pub strategy: LightStrategy,
    /// More BSDF samples of the direct light at a glossy first vertex of a walk (roughness below
    /// [`GLOSSY_ROUGHNESS`], not a pure delta), one segment each: a camera path's primary vertex,
    /// and equally the first hit of a walk a pass or producer starts elsewhere (a DDGI probe's
    /// ray, a light-tracing producer's record), weighed against NEE by MIS
    /// with the counts (Veach 1997, §9.2): a narrow lobe reflecting a bright emitter is found
    /// by BSDF samples alone, and each costs one ray, no further path. 0: none (with
    /// [`LightStrategy::Mis`] only).
    pub glossy_samples: u32,
    /// Light samples of next-event estimation at a walk's first vertex (at least 1; the same
    /// first vertices as [`PathTracer::glossy_samples`], whatever their roughness), weighed
    /// against BSDF sampling by MIS with the counts (Veach 1997, §9.2): where the first
    /// vertex's direct light is most of the noise (a window seen past its frame and blinds),
    /// more shadow rays and no more paths. Later vertices take the walk's own count (1, or a
    /// pass's [`crate::transport::PathWalk::with_light_samples`], whichever is larger here).
    pub direct_samples: u32,
    /// The extra samples of a vertex stratified together ([`PathTracer::glossy_samples`]:
    /// directions over a grid of cells, lobe choices over strata; [`PathTracer::direct_samples`]:
    /// light choices over strata, points over cells; on by default); off: independent samples,
    /// the baseline the tests compare with.
    pub stratified: bool,
}

/// Below this roughness a walk's first vertex takes [`PathTracer::glossy_samples`] (the threshold
/// of the `-diffuse` termination too, 0.3).
pub const GLOSSY_ROUGHNESS: f32 = 0.3;
/// `--glossy-samples` at most.
pub const MAX_GLOSSY_SAMPLES: u32 = 64;
/// `--direct-samples` at most.
pub const MAX_DIRECT_SAMPLES: u32 = 64;

impl Default for PathTracer {
    fn default() -> Self {
        Self {
            max_depth: -1,
            rr_depth: 5,
            strategy: LightStrategy::Mis,
            glossy_samples: 0,
            direct_samples: 1,
            stratified: true,
        }
    }
}

/// Counters a path adds to (for rays/s statistics).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PathStats {
    /// Closest-hit rays traced.
    pub closest_rays: u64,
    /// Shadow (occlusion) rays traced.
    pub shadow_rays: u64,
}

impl PathStats {
    /// All rays traced.
    pub fn rays(&self) -> u64 {
        self.closest_rays + self.shadow_rays
    }

    /// Adds another set of counters to this one.
    pub fn add(&mut self, o: &PathStats) {
        self.closest_rays += o.closest_rays;
        self.shadow_rays += o.shadow_rays;
    }
}

impl PathTracer {
    /// The maximum number of segments as an unsigned bound (`u32::MAX` for unlimited): the
    /// one place where `max_depth` is interpreted.
    pub fn segment_limit(&self) -> u32 {
        if self.max_depth <= 0 {
            u32::MAX
        } else {
            self.max_depth as u32
        }
    }
}
