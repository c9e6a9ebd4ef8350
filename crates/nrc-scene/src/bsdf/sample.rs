//! What sampling a BSDF returns, shared by every variant.

use glam::Vec3;

/// One sampled scattering direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    /// Sampled direction (local frame), pointing away from the surface.
    pub wi: Vec3,
    /// Throughput weight: `f(wo, wi) |cos θi| / pdf(wo, wi)` for non-delta samples; for a
    /// delta sample, the delta lobe's weight divided by the probability of choosing it.
    pub weight: Vec3,
    /// Solid-angle density of `wi` for non-delta samples (equal to `Bsdf::pdf(wo, wi)`);
    /// for delta samples the discrete probability of the chosen delta event (MIS must give
    /// delta samples weight 1).
    pub pdf: f32,
    /// The sample came from a Dirac delta lobe (mirror or smooth refraction).
    pub delta: bool,
}
