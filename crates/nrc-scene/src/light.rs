//! Lights, and the one sampler over all of them.
//!
//! Three kinds of emitter light a scene:
//! - **emissive triangles** (area lights): a point is chosen uniformly on the triangle, so
//!   its density in area measure is `pmf(triangle) / area(triangle)`;
//! - **punctual lights** (`KHR_lights_punctual`: point, spot, directional), delta lights that
//!   next-event estimation samples and BSDF sampling never hits;
//! - **the environment** ([`crate::Environment`]), sampled by its own directional density.
//!
//! [`LightSampler`] chooses among them in proportion to their power, so next-event
//! estimation, the light paths of the training producers and ReSTIR's candidates all draw
//! from the same distribution. Powers are in units of flux/π (the common factor π of a
//! Lambertian emitter left out): a triangle `luminance(Le) · area · sides`, a point light
//! `4 · luminance(I)`, a spot `2 A · luminance(I)` (A from its falloff, below), a directional
//! light `luminance(E) · r²` and the environment `r² ∫ luminance(L) dω / π`, with `r` the
//! radius of the scene's bounding sphere (the flux that crosses the scene, as PBRT counts it).
//!
//! **Units.** glTF gives point and spot intensities in candela and directional ones in lux.
//! The renderer is radiometric in the same arbitrary unit as emission (a material of emissive
//! strength 1 has radiance 1): one candela is a radiant intensity of 1, one lux an irradiance
//! of 1 (no 683 lm/W conversion, the same convention as for emissive strength).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::geometry::{Ray, spawn_ray, spawn_ray_between};
use crate::sampling::{Frame, luminance, sample_concentric_disk, sample_uniform_sphere};

/// The kind of a punctual light, with a spot's cone.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PunctualKind {
    Point,
    /// Cosines of glTF's inner and outer cone angles (`cos_inner ≥ cos_outer`).
    Spot {
        cos_inner: f32,
        cos_outer: f32,
    },
    Directional,
}

/// A `KHR_lights_punctual` light, in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PunctualLight {
    pub kind: PunctualKind,
    /// Position (point and spot lights).
    pub position: Vec3,
    /// Unit direction the light shines toward: the node's −z (spot axis, sun's travel).
    pub direction: Vec3,
    /// Colour × intensity: radiant intensity (point, spot) or irradiance at normal incidence
    /// (directional).
    pub intensity: Vec3,
    /// glTF `range`: beyond it the light is zero, with the specification's smooth window.
    pub range: Option<f32>,
}

impl PunctualLight {
    /// The spot's angular attenuation toward `cos` (cosine from the axis), exactly as the
    /// `KHR_lights_punctual` specification's reference: `saturate((cos − cos_outer) / max(0.001,
    /// cos_inner − cos_outer))²`; 1 for other kinds.
    #[inline]
    pub fn falloff(&self, cos: f32) -> f32 {
        match self.kind {
            PunctualKind::Spot {
                cos_inner,
                cos_outer,
            } => {
                let t = ((cos - cos_outer) / (cos_inner - cos_outer).max(0.001)).clamp(0.0, 1.0);
                t * t
            }
            _ => 1.0,
        }
    }

    /// The specification's range window at distance `d`: `clamp(1 − (d / range)⁴, 0, 1)`.
    #[inline]
    pub fn range_window(&self, d: f32) -> f32 {
        match self.range {
            Some(r) if r > 0.0 => {
                let q = d / r;
                (1.0 - q * q * q * q).clamp(0.0, 1.0)
            }
            _ => 1.0,
        }
    }

    /// Whether the light is at infinity (directional).
    pub fn is_infinite(&self) -> bool {
        self.kind == PunctualKind::Directional
    }

    /// The spot's `∫ falloff dcos` over `[cos_outer, 1]` (2π of it is `∫ falloff dω`), and the
    /// ramp's width `w` and sampled length `len` (see [`PunctualLight::sample_direction`]).
    fn spot_integral(cos_inner: f32, cos_outer: f32) -> (f32, f32, f32) {
        let w = (cos_inner - cos_outer).max(0.001);
        let len = w.min(1.0 - cos_outer).max(0.0);
        let ramp = len * len * len / (3.0 * w * w);
        let flat = (1.0 - cos_outer - w).max(0.0);
        (ramp + flat, w, len)
    }

    /// Power in flux/π units (see the module documentation); `radius` of the scene's bounding
    /// sphere for directional lights.
    pub fn power(&self, radius: f32) -> f32 {
        let i = luminance(self.intensity);
        match self.kind {
            PunctualKind::Point => 4.0 * i,
            PunctualKind::Spot {
                cos_inner,
                cos_outer,
            } => 2.0 * Self::spot_integral(cos_inner, cos_outer).0 * i,
            PunctualKind::Directional => i * radius * radius,
        }
    }

    /// Radiant intensity toward unit direction `w` (from the light), falloff applied.
    #[inline]
    pub fn intensity_toward(&self, w: Vec3) -> Vec3 {
        self.intensity * self.falloff(self.direction.dot(w))
    }

    /// An emission direction of a point or spot light for `u` uniform in `[0, 1)²`, with its
    /// solid-angle density: uniform over the sphere for a point light; for a spot, exactly
    /// proportional to its falloff (cos θ from the axis drawn from the ramp
    /// `((cos − cos_outer)/w)²` or the flat part above it, in proportion to their integrals, φ
    /// uniform), so that `intensity_toward / pdf` is the constant `2π A · I`.
    pub fn sample_direction(&self, u: Vec2) -> Option<(Vec3, f32)> {
        match self.kind {
            PunctualKind::Point => Some((sample_uniform_sphere(u), 0.25 / PI)),
            PunctualKind::Spot {
                cos_inner,
                cos_outer,
            } => {
                let (a, w, len) = Self::spot_integral(cos_inner, cos_outer);
                if a <= 0.0 {
                    return None;
                }
                let ramp = len * len * len / (3.0 * w * w);
                let p_ramp = ramp / a;
                let cos = if u.x < p_ramp {
                    cos_outer + len * (u.x / p_ramp).cbrt()
                } else {
                    let t = (u.x - p_ramp) / (1.0 - p_ramp);
                    (cos_outer + w) + t * (1.0 - cos_outer - w)
                }
                .clamp(-1.0, 1.0);
                let sin = (1.0 - cos * cos).max(0.0).sqrt();
                let (sp, cp) = (2.0 * PI * u.y).sin_cos();
                let local = Vec3::new(sin * cp, sin * sp, cos);
                let d = Frame::from_normal(self.direction).to_world(local);
                let pdf = self.falloff(cos) / (2.0 * PI * a);
                (pdf > 0.0).then_some((d, pdf))
            }
            PunctualKind::Directional => None,
        }
    }

    /// Solid-angle density of [`PunctualLight::sample_direction`] producing `w`.
    pub fn direction_pdf(&self, w: Vec3) -> f32 {
        match self.kind {
            PunctualKind::Point => 0.25 / PI,
            PunctualKind::Spot {
                cos_inner,
                cos_outer,
            } => {
                let a = Self::spot_integral(cos_inner, cos_outer).0;
                if a <= 0.0 {
                    0.0
                } else {
                    self.falloff(self.direction.dot(w)) / (2.0 * PI * a)
                }
            }
            PunctualKind::Directional => 0.0,
        }
    }
}

/// A point sampled on an emissive triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceLightSample {
    /// Position on the light.
    pub p: Vec3,
    /// Unit geometric normal of the light triangle (counter-clockwise winding side).
    pub n: Vec3,
    /// Surface texture coordinates at `p`.
    pub uv: Vec2,
    /// Emitted radiance of the front face at `p` (emissive factor × texture × strength).
    pub le: Vec3,
    /// Whether the back face emits as well (the material is `doubleSided`).
    pub two_sided: bool,
    /// Density of `p` with respect to area: selection probability / triangle area.
    pub pdf_area: f32,
    /// Scene triangle index of the light.
    pub tri: u32,
}

impl SurfaceLightSample {
    /// Radiance leaving the light point toward direction `w` (from the light, any length):
    /// `le` on the emitting side(s), zero otherwise.
    #[inline]
    pub fn le_toward(&self, w: Vec3) -> Vec3 {
        if self.two_sided || self.n.dot(w) > 0.0 {
            self.le
        } else {
            Vec3::ZERO
        }
    }
}

/// A sample of the scene's lights, independent of any shading point (so it can be reused
/// across points: ReSTIR's candidates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightSample {
    /// A point on an emissive triangle.
    Surface(SurfaceLightSample),
    /// A punctual light, chosen with probability `pmf`.
    Punctual {
        light: PunctualLight,
        index: u32,
        pmf: f32,
    },
    /// A direction toward the environment (unit, world), its radiance along it, and the
    /// solid-angle density of choosing it (selection probability included).
    Environment { dir: Vec3, le: Vec3, pdf: f32 },
}

/// Light arriving at a shading point from a [`LightSample`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Incident {
    /// Unit direction from the shading point toward the light.
    pub wi: Vec3,
    /// Distance to the light (infinite for directional lights and the environment).
    pub dist: f32,
    /// Incident radiance; for delta lights the radiance-like `I / d²` (point, spot) or `E`
    /// (directional), which the rendering equation's integral turns into a sum.
    pub li: Vec3,
    /// Density of the sample per solid angle at the shading point (selection included); for
    /// delta lights the selection probability.
    pub pdf: f32,
    /// A delta light: no other strategy can find it, so its MIS weight is 1.
    pub delta: bool,
}

/// The start of a light path: where it leaves, in which direction, with what flux weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Emission {
    pub origin: Vec3,
    /// Normal to offset the origin along (zero: not on a surface).
    pub normal: Vec3,
    /// Unit direction of travel.
    pub dir: Vec3,
    /// `Le cos / (p_A p_ω)` (or its delta and infinite-light equivalents): the flux weight of
    /// the path's first segment.
    pub beta: Vec3,
}

impl LightSample {
    /// The point on an emissive triangle, for a surface sample.
    pub fn surface(&self) -> Option<&SurfaceLightSample> {
        match self {
            LightSample::Surface(s) => Some(s),
            _ => None,
        }
    }

    /// Whether the sample is a delta light (point, spot, directional).
    pub fn is_delta(&self) -> bool {
        matches!(self, LightSample::Punctual { .. })
    }

    /// The light arriving at `x` from this sample; `None` where it brings none (behind a
    /// single-sided emitter, outside a spot's cone, beyond a light's range).
    #[inline]
    pub fn incident(&self, x: Vec3) -> Option<Incident> {
        match *self {
            LightSample::Surface(ls) => {
                let to_light = ls.p - x;
                let dist2 = to_light.length_squared();
                let dist = dist2.sqrt();
                let wi = to_light / dist;
                let cos_light = ls.n.dot(-wi).abs();
                let li = ls.le_toward(-wi);
                if ls.pdf_area <= 0.0 || cos_light <= 0.0 || li == Vec3::ZERO || !wi.is_finite() {
                    return None;
                }
                Some(Incident {
                    wi,
                    dist,
                    li,
                    pdf: ls.pdf_area * dist2 / cos_light,
                    delta: false,
                })
            }
            LightSample::Punctual { light, pmf, .. } => {
                if pmf <= 0.0 {
                    return None;
                }
                if light.is_infinite() {
                    return Some(Incident {
                        wi: -light.direction,
                        dist: f32::INFINITY,
                        li: light.intensity,
                        pdf: pmf,
                        delta: true,
                    })
                    .filter(|i| i.li != Vec3::ZERO);
                }
                let to_light = light.position - x;
                let dist2 = to_light.length_squared();
                let dist = dist2.sqrt();
                let wi = to_light / dist;
                let li = light.intensity_toward(-wi) * (light.range_window(dist) / dist2);
                (li != Vec3::ZERO && li.is_finite()).then_some(Incident {
                    wi,
                    dist,
                    li,
                    pdf: pmf,
                    delta: true,
                })
            }
            LightSample::Environment { dir, le, pdf } => {
                (pdf > 0.0 && le != Vec3::ZERO).then_some(Incident {
                    wi: dir,
                    dist: f32::INFINITY,
                    li: le,
                    pdf,
                    delta: false,
                })
            }
        }
    }

    /// The shadow ray from surface point `x` (geometric normal `ng`) toward the light of
    /// `incident` (from [`LightSample::incident`] at `x`).
    #[inline]
    pub fn shadow_ray(&self, x: Vec3, ng: Vec3, incident: &Incident) -> Ray {
        match *self {
            LightSample::Surface(ls) => spawn_ray_between(x, ng, ls.p, ls.n),
            LightSample::Punctual { light, .. } if !light.is_infinite() => {
                crate::geometry::spawn_ray_to(x, ng, light.position)
            }
            _ => spawn_ray(x, ng, incident.wi),
        }
    }

    /// The first segment of a light path from this sample: `u_side` picks the face of a
    /// two-sided emitter, `u_dir` the direction (cosine-distributed from a triangle, by
    /// [`PunctualLight::sample_direction`] from a point or spot) or, for lights at infinity,
    /// the origin on a disc of radius `radius` perpendicular to the travel direction, facing
    /// the bounding sphere (centre `center`) from outside (PBRT's construction: density
    /// `1/(π r²)` per unit area).
    pub fn emit(&self, u_side: f32, u_dir: Vec2, center: Vec3, radius: f32) -> Option<Emission> {
        let disc = |travel: Vec3| {
            let frame = Frame::from_normal(travel);
            let d = sample_concentric_disk(u_dir) * radius;
            center - travel * radius + frame.to_world(Vec3::new(d.x, d.y, 0.0))
        };
        let area = PI * radius * radius;
        let e = match *self {
            LightSample::Surface(ls) => {
                let (n, side_pdf) = if ls.two_sided {
                    (if u_side < 0.5 { ls.n } else { -ls.n }, 0.5)
                } else {
                    (ls.n, 1.0)
                };
                let local = crate::sampling::sample_cosine_hemisphere(u_dir);
                let dir = Frame::from_normal(n).to_world(local);
                let le = ls.le_toward(dir);
                if local.z <= 0.0 || ls.pdf_area <= 0.0 || le == Vec3::ZERO {
                    return None;
                }
                // β = Le cos / (p_A · cos/π · side_pdf).
                Emission {
                    origin: ls.p,
                    normal: ls.n,
                    dir,
                    beta: le * (PI / (ls.pdf_area * side_pdf)),
                }
            }
            LightSample::Punctual { light, pmf, .. } => {
                if pmf <= 0.0 {
                    return None;
                }
                if light.is_infinite() {
                    Emission {
                        origin: disc(light.direction),
                        normal: Vec3::ZERO,
                        dir: light.direction,
                        beta: light.intensity * (area / pmf),
                    }
                } else {
                    let (dir, pdf) = light.sample_direction(u_dir)?;
                    Emission {
                        origin: light.position,
                        normal: Vec3::ZERO,
                        dir,
                        beta: light.intensity_toward(dir) / (pmf * pdf),
                    }
                }
            }
            LightSample::Environment { dir, le, pdf } => {
                if pdf <= 0.0 {
                    return None;
                }
                Emission {
                    origin: disc(-dir),
                    normal: Vec3::ZERO,
                    dir: -dir,
                    beta: le * (area / pdf),
                }
            }
        };
        (e.beta.is_finite() && e.beta.max_element() > 0.0).then_some(e)
    }
}

/// The point a light is chosen for: its position and unit shading normal (zero where there is
/// no surface). The light tree ([`crate::light_tree`]) chooses by it; the power sampler ignores it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightContext {
    pub p: Vec3,
    pub n: Vec3,
}

impl LightContext {
    /// A shading point `p` with shading normal `n`.
    pub fn new(p: Vec3, n: Vec3) -> Self {
        Self { p, n }
    }
}

/// How next-event estimation and the resampling passes' light candidates choose a light.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightSamplerKind {
    /// In proportion to power, the same everywhere.
    #[default]
    Power,
    /// By the light tree: power, distance and orientation toward the shading point.
    Tree,
}

impl std::str::FromStr for LightSamplerKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "power" => Ok(Self::Power),
            "tree" => Ok(Self::Tree),
            _ => Err(format!("unknown light sampler `{s}` (power or tree)")),
        }
    }
}

impl std::fmt::Display for LightSamplerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Power => "power",
            Self::Tree => "tree",
        })
    }
}

/// What a [`LightSampler`] entry stands for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LightSource {
    /// An emissive scene triangle.
    Triangle(u32),
    /// A punctual light, by index.
    Punctual(u32),
    /// The environment.
    Environment,
}

/// Selection of lights in proportion to their power (see the module documentation).
///
/// The table stores the cumulative distribution for sampling and, per scene triangle, the area
/// density for multiple importance sampling.
#[derive(Clone, Debug, Default)]
pub struct LightSampler {
    entries: Vec<LightSource>,
    /// Cumulative power, normalised so the last entry is 1.
    cdf: Vec<f32>,
    /// Selection probability of each entry.
    pmf: Vec<f32>,
    /// Per scene triangle: selection probability / area (0 for triangles that never emit).
    pdf_area: Vec<f32>,
    /// The light triangles, in increasing order.
    tris: Vec<u32>,
    env_pmf: f32,
    total_power: f64,
}

impl LightSampler {
    /// Builds the sampler for a scene of `n_triangles` triangles from the emissive ones,
    /// `(triangle index, area, power)`, the punctual lights' powers and the environment's.
    /// Entries with zero or non-finite power or area are skipped.
    pub fn new(
        n_triangles: usize,
        triangles: &[(u32, f32, f32)],
        punctual: &[f32],
        environment: f32,
    ) -> Self {
        let ok = |x: f32| x > 0.0 && x.is_finite();
        let mut tris: Vec<(u32, f32, f32)> = triangles
            .iter()
            .copied()
            .filter(|&(_, area, power)| ok(area) && ok(power))
            .collect();
        tris.sort_by_key(|l| l.0);
        tris.dedup_by_key(|l| l.0);
        let mut entries: Vec<(LightSource, f32)> = tris
            .iter()
            .map(|&(t, _, p)| (LightSource::Triangle(t), p))
            .collect();
        entries.extend(
            punctual
                .iter()
                .enumerate()
                .filter(|&(_, &p)| ok(p))
                .map(|(i, &p)| (LightSource::Punctual(i as u32), p)),
        );
        if ok(environment) {
            entries.push((LightSource::Environment, environment));
        }
        let total: f64 = entries.iter().map(|l| l.1 as f64).sum();
        let mut sampler = Self {
            pdf_area: vec![0.0; n_triangles],
            tris: tris.iter().map(|t| t.0).collect(),
            total_power: total,
            ..Self::default()
        };
        let mut acc = 0.0f64;
        for &(source, power) in &entries {
            let p = power as f64 / total;
            acc += power as f64;
            sampler.entries.push(source);
            sampler.pmf.push(p as f32);
            sampler.cdf.push((acc / total) as f32);
            if source == LightSource::Environment {
                sampler.env_pmf = p as f32;
            }
        }
        for (&(tri, area, _), &p) in tris.iter().zip(&sampler.pmf) {
            sampler.pdf_area[tri as usize] = (p as f64 / area as f64) as f32;
        }
        if let Some(last) = sampler.cdf.last_mut() {
            *last = 1.0;
        }
        sampler
    }

    /// Number of lights (emissive triangles, punctual lights and the environment with
    /// non-zero power).
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when nothing lights the scene.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Sum of the lights' powers (flux/π units).
    pub fn total_power(&self) -> f64 {
        self.total_power
    }

    /// Chooses a light with `u` uniform in `[0, 1)`: `(light, probability)`.
    #[inline]
    pub fn select(&self, u: f32) -> Option<(LightSource, f32)> {
        if self.entries.is_empty() {
            return None;
        }
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .min(self.entries.len() - 1);
        Some((self.entries[i], self.pmf[i]))
    }

    /// Selection probability of scene triangle `tri` (0 for non-lights).
    #[inline]
    pub fn pmf(&self, tri: u32) -> f32 {
        match self.tris.binary_search(&tri) {
            Ok(i) => self.pmf[i],
            Err(_) => 0.0,
        }
    }

    /// Area density with which [`crate::Scene::sample_light`] produces points on scene
    /// triangle `tri`: selection probability / area (0 for non-lights).
    #[inline]
    pub fn pdf_area(&self, tri: u32) -> f32 {
        self.pdf_area.get(tri as usize).copied().unwrap_or(0.0)
    }

    /// Selection probability of the environment (0 when it is black).
    #[inline]
    pub fn environment_pmf(&self) -> f32 {
        self.env_pmf
    }

    /// The light triangles' scene indices, in increasing order.
    pub fn triangles(&self) -> &[u32] {
        &self.tris
    }

    /// Counts of (emissive triangles, punctual lights, environment 0 or 1).
    pub fn counts(&self) -> (usize, usize, usize) {
        let punctual = self
            .entries
            .iter()
            .filter(|e| matches!(e, LightSource::Punctual(_)))
            .count();
        (self.tris.len(), punctual, (self.env_pmf > 0.0) as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selection_follows_power() {
        let s = LightSampler::new(5, &[(1, 2.0, 1.0), (3, 1.0, 3.0), (4, 1.0, 0.0)], &[], 0.0);
        assert_eq!(s.len(), 2);
        assert_eq!(s.select(0.0), Some((LightSource::Triangle(1), 0.25)));
        assert_eq!(s.select(0.2499), Some((LightSource::Triangle(1), 0.25)));
        assert_eq!(s.select(0.25), Some((LightSource::Triangle(3), 0.75)));
        assert_eq!(s.select(0.9999999), Some((LightSource::Triangle(3), 0.75)));
        assert_eq!(s.pmf(3), 0.75);
        assert_eq!(s.pmf(4), 0.0);
        assert!((s.pdf_area(1) - 0.125).abs() < 1e-7);
        assert_eq!(s.pdf_area(0), 0.0);
        assert_eq!(s.pdf_area(99), 0.0);
    }

    #[test]
    fn selection_spans_every_kind_of_light() {
        let s = LightSampler::new(2, &[(0, 1.0, 1.0)], &[2.0, 0.0], 1.0);
        assert_eq!(s.len(), 3);
        assert_eq!(s.counts(), (1, 1, 1));
        assert_eq!(s.select(0.1), Some((LightSource::Triangle(0), 0.25)));
        assert_eq!(s.select(0.5), Some((LightSource::Punctual(0), 0.5)));
        assert_eq!(s.select(0.9), Some((LightSource::Environment, 0.25)));
        assert_eq!(s.environment_pmf(), 0.25);
        assert_eq!(s.pdf_area(0), 0.25);
    }

    /// A spot's emission sampling gives `intensity_toward / pdf` the same everywhere in the
    /// cone (exact importance sampling of the falloff), and its density integrates to 1.
    #[test]
    fn spot_sampling_is_proportional_to_falloff() {
        let spot = PunctualLight {
            kind: PunctualKind::Spot {
                cos_inner: 0.3f32.cos(),
                cos_outer: 0.6f32.cos(),
            },
            position: Vec3::ZERO,
            direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
            intensity: Vec3::ONE,
            range: None,
        };
        let mut ratio = None;
        for i in 0..500 {
            let u = Vec2::new(
                ((i as f32 + 0.5) * 0.618_034) % 1.0,
                (i as f32 * 0.754_877) % 1.0,
            );
            let (d, pdf) = spot.sample_direction(u).unwrap();
            assert!((spot.direction_pdf(d) - pdf).abs() < 1e-3 * pdf);
            let r = spot.intensity_toward(d).x / pdf;
            let r0 = *ratio.get_or_insert(r);
            assert!((r / r0 - 1.0).abs() < 1e-3, "{r} {r0}");
        }
        // ∫ pdf dω over the sphere by a fine quadrature in cos θ.
        let n = 20_000;
        let integral: f32 = (0..n)
            .map(|k| {
                let c = -1.0 + 2.0 * (k as f32 + 0.5) / n as f32;
                let a = spot.direction;
                let perp = Frame::from_normal(a).to_world(Vec3::X);
                let w = a * c + perp * (1.0 - c * c).sqrt();
                spot.direction_pdf(w) * 2.0 * PI * (2.0 / n as f32)
            })
            .sum();
        assert!((integral - 1.0).abs() < 2e-3, "{integral}");
    }
}
