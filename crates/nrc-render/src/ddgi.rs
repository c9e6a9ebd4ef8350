//! A DDGI probe volume (Majercik et al. 2019, "Dynamic Diffuse Global Illumination with
//! Ray-Traced Irradiance Fields", as the seed paper `ddgi-resampling.txt` §2–3 uses it): a grid
//! of probes over the scene box, each holding irradiance and the first two moments of the
//! distance to the nearest surface, per direction, in octahedral maps.
//!
//! - **Storage**: per probe an `n × n` irradiance map (default 8) and an `m × m` moments map
//!   (default 16), each with a one-texel border copied from the texels across the octahedral
//!   seam, so that bilinear lookups near an edge blend the right neighbours.
//! - **Update** (one call per frame): [`ProbeVolume::rays`] rays on a spherical Fibonacci set turned
//!   by a random rotation each frame; each ray's radiance from the chosen [`ProbeRadiance`];
//!   each irradiance texel blends `π Σ max(0, n·ω) L / Σ max(0, n·ω)` into its history with
//!   weight `1 − hysteresis`, each moments texel `(d, d²)` with weights `max(0, n·ω)^sharpness`.
//!   A probe's first updates are a running mean (weight `1/(k+1)` for its `k`-th, until that
//!   falls below `1 − hysteresis`): with the hysteresis alone its first rays, which see only
//!   the emission the empty volume lets through, would weigh `hysteresis^k` for `k` updates.
//! - **Sizing** ([`ProbeVolume::for_frame`]): where the settings leave the counts and rays
//!   open, the volume holds as many probes as the frame's probe-ray budget refreshes within
//!   [`DdgiSettings::sweep`] frames ([`auto_counts`], at most [`MAX_AUTO_PROBES`]) and each
//!   update takes the next probes in turn (RTXGI and its successors schedule probe updates
//!   too). Denser probes are less biased; a static scene loses nothing, a change of lighting
//!   reaches a probe up to a sweep later.
//! - **Query** ([`ProbeVolume::irradiance`]): the 8 probes around the point (offset along the
//!   normal and toward the viewer, §3.5), weighted by trilinear interpolation, wrap shading
//!   `((1 + cos)/2)² + 0.2` and the Chebyshev visibility bound from the moments (cubed, small
//!   weights crushed), normalised. As a [`RadianceSource`] the volume answers `ρ/π · E`.
//!
//! Probes sit at cell centres (`origin + (i + ½) · spacing`), so none lies on the box's faces.
//!
//! Two options of the DDGI paper's successors (RTXGI), off by default (`../shared/PASSES.md`:
//! the seed paper cites them, it does not specify them):
//! - **relocation** moves a probe out of geometry (more than a quarter of its rays hit back
//!   faces: it steps through the closest one, plus half the minimum front-face distance) or
//!   away from a front face closer than a tenth of the smallest spacing, at most 0.45 of a
//!   cell from its grid point; the rays trace from the moved probe and queries use its place.
//! - **classification** switches off a probe that sits inside geometry or whose rays find no
//!   front face inside its eight cells (no shading point there can need it): it is not
//!   blended, queries skip it (unless all eight are off), and it traces an eighth of the rays,
//!   enough to switch it back on.

use std::f32::consts::PI;

use glam::{UVec3, Vec2, Vec3};
use nrc_scene::{Aabb, Ray, Scene, bsdf::Bsdf};
use rayon::prelude::*;

use crate::error::VolumeError;
use crate::path_tracer::{PathStats, PathTracer};
use crate::sampler::PixelSampler;
use crate::source::{RadianceQuery, RadianceSource};
use crate::transport::{Arrival, PathWalk, Vertex};

/// What a probe ray brings back from its hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProbeRadiance {
    /// Eq. 4 (DDGI): the diffuse reflection of direct light at the hit plus the volume's own
    /// diffuse radiance there; the probes converge to indirect-only irradiance.
    Indirect,
    /// Eq. 5 (DDGI+): emission at the hit plus the volume's own radiance there; the probes
    /// converge to the full irradiance.
    Full,
    /// Beyond the paper: emission at the hit plus a radiance source's answer there (the
    /// neural cache feeding the probes, `ddgi-nrc-*`).
    Source,
}

/// A frame's probe rays between [`ProbeVolume::trace_rays`] and [`ProbeVolume::blend`].
#[derive(Clone, Debug, Default)]
pub struct ProbeRays {
    /// The first probe traced; the probes traced follow it in index order (wrapping).
    first: usize,
    /// Per probe traced, per ray: direction, radiance so far, hit distance.
    rays: Vec<Vec<(Vec3, Vec3, f32)>>,
    /// The queries a radiance source must answer, and the (probe's place among those traced,
    /// ray) each belongs to.
    pub queries: Vec<RadianceQuery>,
    slots: Vec<(u32, u32)>,
    /// Per probe traced, what its rays found (relocation and classification).
    geometry: Vec<ProbeGeometry>,
    pub stats: PathStats,
}

/// What one probe's rays found around it.
#[derive(Clone, Copy, Debug)]
struct ProbeGeometry {
    rays: u32,
    back_faces: u32,
    /// Distance and direction of the closest back-face and front-face hits.
    closest_back: (f32, Vec3),
    closest_front: (f32, Vec3),
    /// A front face inside the probe's eight cells.
    front_in_cells: bool,
}

impl Default for ProbeGeometry {
    fn default() -> Self {
        Self {
            rays: 0,
            back_faces: 0,
            closest_back: (f32::INFINITY, Vec3::ZERO),
            closest_front: (f32::INFINITY, Vec3::ZERO),
            front_in_cells: false,
        }
    }
}

impl ProbeGeometry {
    fn back_fraction(&self) -> f32 {
        self.back_faces as f32 / self.rays.max(1) as f32
    }
}

/// Probe rays per frame per pixel of the frame where the rays are sized to it: the seed
/// paper's 16 × 8 × 16 probes of 256 rays at 1920 × 1080 (`ddgi-resampling.txt` §4), 0.25.
/// At 256 rays on this project's 2 cores the probe update of a 160 × 90 kitchen frame cost
/// more than a path-traced sample (RESULTS.md, "Where a pass's frame time goes").
pub const PROBE_RAYS_PER_PIXEL: f64 = 0.25;

/// The most rays per probe a frame-sized count takes: the paper's (and RTXGI's) 256.
const MAX_AUTO_RAYS: u32 = 256;

/// The fewest: enough directions for the 8 × 8 irradiance map to see every texel's hemisphere.
const MIN_AUTO_RAYS: u32 = 32;

/// [`PROBE_RAYS_PER_PIXEL`] of `pixels` over `probes`, rounded up to a multiple of 32, in
/// `[MIN_AUTO_RAYS, MAX_AUTO_RAYS]`.
pub fn auto_rays(pixels: u64, probes: usize) -> u32 {
    let per_probe = ray_budget(pixels) / probes.max(1) as f64;
    let rounded = (per_probe / 32.0).ceil() * 32.0;
    rounded.clamp(MIN_AUTO_RAYS as f64, MAX_AUTO_RAYS as f64) as u32
}

/// The probe rays a frame of `pixels` affords: [`PROBE_RAYS_PER_PIXEL`] of them.
fn ray_budget(pixels: u64) -> f64 {
    PROBE_RAYS_PER_PIXEL * pixels as f64
}

/// The most probes a frame-sized volume holds: 4,096 (16 MB of maps). On the Country Kitchen
/// the probes' spacing was the bias of DDGI resampling: 144 probes (8 along its longest axis)
/// left bias² at 18 % of the pass's MSE, 4,096 took it to within its noise of zero
/// (RESULTS.md, "Cheaper world-space ReSTIR GI frames, and what DDGI resampling's bias is").
/// The seed paper's scenes use 2,048 (16 × 8 × 16, `ddgi-resampling.txt` §4).
pub const MAX_AUTO_PROBES: usize = 4096;

/// The fewest probes a frame-sized volume holds (a 2 × 2 × 2 grid).
const MIN_AUTO_PROBES: usize = 8;

/// The probe counts for a scene box of extent `ext` and a frame of `pixels`: as many probes
/// as the frame's ray budget ([`PROBE_RAYS_PER_PIXEL`]) updates at 32 rays each within
/// `sweep` frames, at most [`MAX_AUTO_PROBES`], in cells as near cubic as the box allows (at
/// least 2 per axis).
pub fn auto_counts(ext: Vec3, pixels: u64, sweep: u32) -> UVec3 {
    let per_frame = (ray_budget(pixels) / MIN_AUTO_RAYS as f64).floor().max(1.0);
    let target =
        (per_frame * f64::from(sweep.max(1))).clamp(MIN_AUTO_PROBES as f64, MAX_AUTO_PROBES as f64);
    let ext = ext.max(Vec3::splat(ext.max_element() * 1e-3));
    let volume = f64::from(ext.x) * f64::from(ext.y) * f64::from(ext.z);
    let mut side = (volume / target).cbrt() as f32;
    if !(side > 0.0 && side.is_finite()) {
        return UVec3::splat(2);
    }
    // Rounding per axis can overshoot the target: widen the cells until it fits.
    loop {
        let c = (ext / side).round().max(Vec3::splat(2.0)).as_uvec3();
        if (c.x as usize) * (c.y as usize) * (c.z as usize) <= target as usize
            || c == UVec3::splat(2)
        {
            return c;
        }
        side *= 1.02;
    }
}

/// Above this fraction of back-face hits a probe is inside geometry (RTXGI's threshold).
const INSIDE_FRACTION: f32 = 0.25;

/// The volume's parameters (defaults: RTXGI's and the paper's).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DdgiSettings {
    /// Probes per axis; `None`: where the rays are open too, sized to the frame by
    /// [`ProbeVolume::for_frame`] ([`auto_counts`]: as many as the frame's ray budget refreshes
    /// within [`DdgiSettings::sweep`] frames, at most [`MAX_AUTO_PROBES`]); otherwise 8 along
    /// the longest axis (at least 2 along each).
    pub counts: Option<UVec3>,
    /// Where the counts and the rays are both left open: the most frames a probe waits for its
    /// next update. A frame-sized volume updates the probes its ray budget affords, in turn;
    /// static scenes lose nothing (each update still blends 32 rays or more), a change of the
    /// lighting reaches a probe up to this many frames later.
    pub sweep: u32,
    /// Rays per probe and frame; `None`: sized to the frame the volume serves
    /// ([`ProbeVolume::fit_rays_to_frame`], [`PROBE_RAYS_PER_PIXEL`]), 256 until it is told.
    pub rays_per_probe: Option<u32>,
    pub hysteresis: f32,
    /// Interior texels per side of the irradiance and moments maps.
    pub irradiance_texels: u32,
    pub moment_texels: u32,
    /// Exponent of the cosine weight of the moments update.
    pub depth_sharpness: f32,
    /// Query offsets along the normal and toward the viewer, in units of the smallest spacing.
    pub normal_bias: f32,
    pub view_bias: f32,
    pub radiance: ProbeRadiance,
    /// Probe relocation (see the module's notes).
    pub relocate: bool,
    /// Probe classification (see the module's notes).
    pub classify: bool,
    /// §3.3's attenuation of the emission probe rays find (the paper's slider `s`; 0: off):
    /// see [`ProbeVolume::emission_attenuation`].
    pub attenuation: f32,
}

impl Default for DdgiSettings {
    fn default() -> Self {
        Self {
            counts: None,
            sweep: 16,
            rays_per_probe: None,
            hysteresis: 0.97,
            irradiance_texels: 8,
            moment_texels: 16,
            depth_sharpness: 50.0,
            normal_bias: 0.1,
            view_bias: 0.1,
            radiance: ProbeRadiance::Full,
            relocate: false,
            classify: false,
            attenuation: 0.0,
        }
    }
}

/// Octahedral encoding of a unit direction into `[-1, 1]²` (the +z hemisphere inside the
/// diamond `|u| + |v| ≤ 1`, the −z one folded over its edges).
#[inline]
pub fn oct_encode(d: Vec3) -> Vec2 {
    let p = Vec2::new(d.x, d.y) / (d.x.abs() + d.y.abs() + d.z.abs());
    if d.z < 0.0 {
        let s = Vec2::new(p.x.signum(), p.y.signum());
        (Vec2::ONE - Vec2::new(p.y.abs(), p.x.abs())) * s
    } else {
        p
    }
}

/// The inverse of [`oct_encode`].
#[inline]
pub fn oct_decode(e: Vec2) -> Vec3 {
    let z = 1.0 - e.x.abs() - e.y.abs();
    let mut p = e;
    if z < 0.0 {
        let s = Vec2::new(e.x.signum(), e.y.signum());
        p = (Vec2::ONE - Vec2::new(e.y.abs(), e.x.abs())) * s;
    }
    Vec3::new(p.x, p.y, z).normalize()
}

/// One probe's octahedral map of `n × n` interior texels with a one-texel border, row-major
/// `(n + 2)²`, texel `(i, j)` of the interior at index `(j + 1)(n + 2) + i + 1`.
#[derive(Clone, Copy, Debug)]
struct OctMap {
    n: u32,
}

/// A probe's rays' directions by component, for [`OctMap::blend`].
#[derive(Default)]
struct RayColumns {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

impl RayColumns {
    fn fill(&mut self, rays: &[(Vec3, Vec3, f32)]) {
        self.x.clear();
        self.y.clear();
        self.z.clear();
        for (d, _, _) in rays {
            self.x.push(d.x);
            self.y.push(d.y);
            self.z.push(d.z);
        }
    }

    /// `max(0, n · d)^exponent` for every ray `d` into `out`, 0 where the cosine is not
    /// positive; `base` is scratch. An integral exponent below 1024 by repeated squaring, bit
    /// for bit `f32::powi`'s (whose library call cost a sixth of a DDGI frame), any other by
    /// `powf`.
    fn weights(&self, n: Vec3, exponent: f32, out: &mut Vec<f32>, base: &mut Vec<f32>) {
        base.clear();
        base.extend(
            self.x
                .iter()
                .zip(&self.y)
                .zip(&self.z)
                .map(|((&x, &y), &z)| n.x * x + n.y * y + n.z * z)
                .map(|c| if c > 0.0 { c } else { 0.0 }),
        );
        out.clear();
        if exponent.fract() != 0.0 || !(0.0..1024.0).contains(&exponent) {
            out.extend(
                base.iter()
                    .map(|&c| if c > 0.0 { c.powf(exponent) } else { 0.0 }),
            );
            return;
        }
        let mut m = exponent as u32;
        if m == 0 {
            out.extend(base.iter().map(|&c| if c > 0.0 { 1.0 } else { 0.0 }));
            return;
        }
        out.extend(base.iter().map(|&c| if m & 1 == 1 { c } else { 1.0 }));
        loop {
            m >>= 1;
            if m == 0 {
                break;
            }
            for b in base.iter_mut() {
                *b *= *b;
            }
            if m & 1 == 1 {
                for (o, &b) in out.iter_mut().zip(base.iter()) {
                    *o *= b;
                }
            }
        }
    }
}

impl OctMap {
    fn side(&self) -> usize {
        self.n as usize + 2
    }

    fn len(&self) -> usize {
        self.side() * self.side()
    }

    /// Octahedral coordinates of the centre of texel `(x, y)` of the bordered map (border
    /// texels lie outside `[-1, 1]²`).
    fn coords(&self, x: usize, y: usize) -> Vec2 {
        let n = self.n as f32;
        Vec2::new(
            (x as f32 - 0.5) / n * 2.0 - 1.0,
            (y as f32 - 0.5) / n * 2.0 - 1.0,
        )
    }

    /// The interior texel a border texel copies: the octahedral wrap mirrors a coordinate
    /// beyond an edge back inside and flips the other one.
    fn wrapped(&self, x: usize, y: usize) -> usize {
        let n = self.n as usize;
        let (mut i, mut j) = (x as i64 - 1, y as i64 - 1);
        let last = n as i64 - 1;
        if i < 0 || i > last {
            i = i.clamp(0, last);
            j = last - j;
        }
        if j < 0 || j > last {
            j = j.clamp(0, last);
            i = last - i;
        }
        let (i, j) = (i.clamp(0, last) as usize, j.clamp(0, last) as usize);
        (j + 1) * self.side() + i + 1
    }

    /// Whether texel `(x, y)` is in the border.
    fn is_border(&self, x: usize, y: usize) -> bool {
        x == 0 || y == 0 || x == self.side() - 1 || y == self.side() - 1
    }

    /// Bilinear lookup at direction `d` of `texels` (this map's layout).
    fn lookup<T>(&self, texels: &[T], d: Vec3) -> T
    where
        T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
    {
        let n = self.n as f32;
        let e = oct_encode(d);
        // Continuous texel coordinates of the bordered map (texel centres at k + 0.5).
        let t = (e + Vec2::ONE) * 0.5 * n + Vec2::splat(1.0) - Vec2::splat(0.5);
        let t = t.clamp(Vec2::ZERO, Vec2::splat(n));
        let (x0, y0) = (t.x.floor() as usize, t.y.floor() as usize);
        let (fx, fy) = (t.x - x0 as f32, t.y - y0 as f32);
        let (x1, y1) = ((x0 + 1).min(self.side() - 1), (y0 + 1).min(self.side() - 1));
        let at = |x: usize, y: usize| texels[y * self.side() + x];
        (at(x0, y0) * ((1.0 - fx) * (1.0 - fy)) + at(x1, y0) * (fx * (1.0 - fy)))
            + (at(x0, y1) * ((1.0 - fx) * fy) + at(x1, y1) * (fx * fy))
    }

    /// Blends one frame's rays `(direction, radiance, distance)` into every interior texel of
    /// `texels` with history weight `h`: the texel gets `Σ w value / Σ w` over the rays, `w` the
    /// cosine between the texel's direction and the ray raised to `exponent` (rays behind it
    /// skip); then the border is filled. The cosines and weights of a texel are computed for
    /// all rays at once from `rays`' directions in columns (a loop the compiler vectorises),
    /// the sums in ray order.
    fn blend<T>(
        &self,
        texels: &mut [T],
        rays: &RayColumns,
        h: f32,
        exponent: f32,
        value: impl Fn(usize) -> T,
        scratch: &mut (Vec<f32>, Vec<f32>),
    ) where
        T: Copy + Default + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
    {
        for y in 1..=self.n as usize {
            for x in 1..=self.n as usize {
                let nt = oct_decode(self.coords(x, y));
                let (weights, base) = scratch;
                rays.weights(nt, exponent, weights, base);
                let (mut sum, mut wsum) = (T::default(), 0.0);
                for (i, &w) in weights.iter().enumerate() {
                    if w > 0.0 {
                        sum = sum + value(i) * w;
                        wsum += w;
                    }
                }
                if wsum > 0.0 {
                    let i = y * self.side() + x;
                    texels[i] = texels[i] * h + sum * ((1.0 - h) / wsum);
                }
            }
        }
        self.fill_border(texels);
    }

    /// Copies every border texel from the interior texel it wraps to.
    fn fill_border<T: Copy>(&self, texels: &mut [T]) {
        let s = self.side();
        for y in 0..s {
            for x in 0..s {
                if self.is_border(x, y) {
                    texels[y * s + x] = texels[self.wrapped(x, y)];
                }
            }
        }
    }
}

/// The probe volume: its grid and each probe's maps.
#[derive(Clone, Debug)]
pub struct ProbeVolume {
    pub settings: DdgiSettings,
    /// Rays per probe and frame: the settings' count, or the one sized to the frame.
    pub rays: u32,
    pub counts: UVec3,
    pub origin: Vec3,
    pub spacing: Vec3,
    irradiance_map: OctMap,
    moment_map: OctMap,
    /// Per probe, `(n + 2)²` irradiance texels.
    irradiance: Vec<Vec3>,
    /// Per probe, `(m + 2)²` texels of (mean distance, mean squared distance).
    moments: Vec<Vec2>,
    /// Probes traced and blended per update: all of them, unless the volume was sized to a
    /// frame whose ray budget updates them in turn ([`DdgiSettings::sweep`]).
    per_update: usize,
    /// The first probe of the next update.
    cursor: usize,
    /// Whether the counts were sized to a frame (then updates may take the probes in turn).
    frame_sized: bool,
    /// Per probe: its relocation offset from its grid point, whether it is on, how many
    /// updates it has blended (its `k`-th blends with weight `min(hysteresis, k / (k + 1))` on
    /// its history: a running mean until the hysteresis takes over, so a young probe is not
    /// held to its first, one-bounce rays), and the back-face fraction of its last rays.
    offsets: Vec<Vec3>,
    active: Vec<bool>,
    updates: Vec<u32>,
    back_fraction: Vec<f32>,
}

/// A sphere point of the spherical Fibonacci set of `n` points.
#[inline]
fn fibonacci(i: u32, n: u32) -> Vec3 {
    let golden = PI * (3.0 - 5f32.sqrt());
    let z = 1.0 - (2.0 * i as f32 + 1.0) / n as f32;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = golden * i as f32;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// A uniformly random rotation from three uniform numbers (Shoemake's quaternion).
fn random_rotation(u: Vec3) -> glam::Quat {
    let (a, b) = ((1.0 - u.x).sqrt(), u.x.sqrt());
    let (t1, t2) = (2.0 * PI * u.y, 2.0 * PI * u.z);
    glam::Quat::from_xyzw(a * t1.sin(), a * t1.cos(), b * t2.sin(), b * t2.cos()).normalize()
}

impl ProbeVolume {
    /// An empty volume over `bounds`.
    pub fn new(bounds: &Aabb, settings: DdgiSettings) -> Result<Self, VolumeError> {
        Self::build(bounds, settings, None)
    }

    /// A volume over `bounds` serving frames of `pixels`: where the settings leave both the
    /// counts and the rays open, counts from [`auto_counts`] (a count or a ray count in the
    /// settings is kept); rays from [`ProbeVolume::fit_rays_to_frame`]. The counts stay those
    /// of this first frame's size; later frames refit only the rays and the probes an update
    /// takes.
    pub fn for_frame(
        bounds: &Aabb,
        settings: DdgiSettings,
        pixels: u64,
    ) -> Result<Self, VolumeError> {
        let sized = (settings.counts.is_none() && settings.rays_per_probe.is_none())
            .then(|| auto_counts(bounds.max - bounds.min, pixels, settings.sweep));
        let mut v = Self::build(bounds, settings, sized)?;
        v.fit_rays_to_frame(pixels);
        Ok(v)
    }

    fn build(
        bounds: &Aabb,
        settings: DdgiSettings,
        sized: Option<UVec3>,
    ) -> Result<Self, VolumeError> {
        let ext = bounds.max - bounds.min;
        if !(ext.is_finite() && ext.max_element() > 0.0) {
            return Err(VolumeError::EmptyBox);
        }
        if settings.rays_per_probe == Some(0)
            || settings.sweep == 0
            || settings.irradiance_texels == 0
            || settings.moment_texels == 0
        {
            return Err(VolumeError::Zero);
        }
        if settings.rays_per_probe.is_some_and(|r| r > 1 << 14)
            || settings.irradiance_texels.max(settings.moment_texels) > 64
        {
            return Err(VolumeError::TooLarge);
        }
        if !(0.0..1.0).contains(&settings.hysteresis) {
            return Err(VolumeError::Hysteresis(settings.hysteresis));
        }
        if !(settings.attenuation >= 0.0 && settings.attenuation <= 100.0) {
            return Err(VolumeError::Attenuation(settings.attenuation));
        }
        let counts = settings.counts.or(sized).unwrap_or_else(|| {
            let longest = ext.max_element();
            let c = (ext / longest * 8.0).round();
            UVec3::new(c.x as u32, c.y as u32, c.z as u32).max(UVec3::splat(2))
        });
        if counts.min_element() == 0
            || counts.x as u64 * counts.y as u64 * counts.z as u64 > 1 << 16
        {
            // 2^16 probes of the default maps hold about 280 MB.
            return Err(VolumeError::ProbeCounts(counts));
        }
        let spacing = ext / counts.as_vec3();
        let n = (counts.x * counts.y * counts.z) as usize;
        let irradiance_map = OctMap {
            n: settings.irradiance_texels,
        };
        let moment_map = OctMap {
            n: settings.moment_texels,
        };
        Ok(Self {
            settings,
            rays: settings.rays_per_probe.unwrap_or(MAX_AUTO_RAYS),
            counts,
            origin: bounds.min,
            spacing,
            irradiance_map,
            moment_map,
            irradiance: vec![Vec3::ZERO; n * irradiance_map.len()],
            moments: vec![Vec2::ZERO; n * moment_map.len()],
            per_update: n,
            cursor: 0,
            frame_sized: sized.is_some(),
            offsets: vec![Vec3::ZERO; n],
            active: vec![true; n],
            updates: vec![0; n],
            back_fraction: vec![0.0; n],
        })
    }

    /// Sizes the rays per probe to a frame of `pixels` where the settings leave them to the
    /// volume: [`PROBE_RAYS_PER_PIXEL`] of the frame's pixels spread over the probes, in
    /// multiples of 32 between 32 and 256. A count set in the settings is kept. A volume whose
    /// counts were sized to a frame ([`ProbeVolume::for_frame`]) and whose rays are open also
    /// updates only the probes the budget affords at that count, in turn, but every probe at
    /// least once in [`DdgiSettings::sweep`] updates.
    pub fn fit_rays_to_frame(&mut self, pixels: u64) {
        if self.settings.rays_per_probe.is_some() {
            return;
        }
        let n = self.probe_count();
        if !self.frame_sized {
            self.rays = auto_rays(pixels, n);
            return;
        }
        // Rounded down here: every probe at the rays the budget gives each, or, where that is
        // under the floor, the probes the budget affords at the floor.
        let budget = ray_budget(pixels);
        let each = ((budget / n as f64 / 32.0).floor() * 32.0) as u32;
        self.rays = each.clamp(MIN_AUTO_RAYS, MAX_AUTO_RAYS);
        let affordable = (budget / f64::from(self.rays)).floor() as usize;
        let sweep = self.settings.sweep.max(1) as usize;
        self.per_update = affordable.max(n.div_ceil(sweep)).clamp(1, n);
    }

    /// Probes traced and blended per update ([`ProbeVolume::fit_rays_to_frame`]).
    pub fn per_update(&self) -> usize {
        self.per_update
    }

    /// Updates probe `p` has blended (0: its maps are empty, queries skip it).
    pub fn probe_updates(&self, p: usize) -> u32 {
        self.updates[p]
    }

    /// Probes in the volume.
    pub fn probe_count(&self) -> usize {
        (self.counts.x * self.counts.y * self.counts.z) as usize
    }

    /// Position of probe `(i, j, k)`.
    pub fn probe_position(&self, c: UVec3) -> Vec3 {
        self.origin + (c.as_vec3() + Vec3::splat(0.5)) * self.spacing
    }

    /// Where probe `p` is: its grid point plus its relocation offset.
    pub fn probe_origin(&self, p: usize) -> Vec3 {
        self.probe_position(self.coords_of(p)) + self.offsets[p]
    }

    /// Whether probe `p` is on (always, without classification).
    pub fn probe_active(&self, p: usize) -> bool {
        self.active[p]
    }

    /// The fraction of probe `p`'s last rays that hit back faces.
    pub fn probe_back_fraction(&self, p: usize) -> f32 {
        self.back_fraction[p]
    }

    fn index(&self, c: UVec3) -> usize {
        ((c.z * self.counts.y + c.y) * self.counts.x + c.x) as usize
    }

    fn coords_of(&self, p: usize) -> UVec3 {
        let (cx, cy) = (self.counts.x as usize, self.counts.y as usize);
        UVec3::new(
            (p % cx) as u32,
            ((p / cx) % cy) as u32,
            (p / (cx * cy)) as u32,
        )
    }

    /// Probe `p`'s irradiance texels (bordered layout).
    pub fn probe_irradiance(&self, p: usize) -> &[Vec3] {
        let l = self.irradiance_map.len();
        &self.irradiance[p * l..(p + 1) * l]
    }

    /// Probe `p`'s moments texels (bordered layout).
    pub fn probe_moments(&self, p: usize) -> &[Vec2] {
        let l = self.moment_map.len();
        &self.moments[p * l..(p + 1) * l]
    }

    /// The irradiance stored by probe `p` for normal `n` (bilinear in its map).
    pub fn probe_irradiance_toward(&self, p: usize, n: Vec3) -> Vec3 {
        self.irradiance_map.lookup(self.probe_irradiance(p), n)
    }

    /// The directions of probe `p`'s interior irradiance texels and their values.
    pub fn irradiance_texels(&self, p: usize) -> Vec<(Vec3, Vec3)> {
        let m = self.irradiance_map;
        let t = self.probe_irradiance(p);
        let mut out = Vec::new();
        for y in 1..=m.n as usize {
            for x in 1..=m.n as usize {
                out.push((oct_decode(m.coords(x, y)), t[y * m.side() + x]));
            }
        }
        out
    }

    /// Whether every border texel of every map equals the interior texel it wraps to.
    pub fn borders_are_wrapped(&self) -> bool {
        let check = |map: OctMap, len: usize, eq: &dyn Fn(usize, usize) -> bool| {
            (0..self.probe_count()).all(|p| {
                let s = map.side();
                (0..s).all(|y| {
                    (0..s).all(|x| {
                        !map.is_border(x, y) || eq(p * len + y * s + x, p * len + map.wrapped(x, y))
                    })
                })
            })
        };
        check(self.irradiance_map, self.irradiance_map.len(), &|a, b| {
            self.irradiance[a] == self.irradiance[b]
        }) && check(self.moment_map, self.moment_map.len(), &|a, b| {
            self.moments[a] == self.moments[b]
        })
    }

    /// The query point offset off the surface (§3.5): along the normal and toward the viewer.
    fn biased_point(&self, x: Vec3, n: Vec3, wo: Vec3) -> Vec3 {
        let s = self.spacing.min_element();
        x + (n * self.settings.normal_bias + wo * self.settings.view_bias) * s
    }

    /// The probes around `x` (normal `n`, viewer direction `wo`) and their normalised weights
    /// (trilinear × wrap shading × Chebyshev visibility).
    pub fn probe_weights(&self, x: Vec3, n: Vec3, wo: Vec3) -> Vec<(usize, f32)> {
        let q = self.biased_point(x, n, wo);
        let g = ((q - self.origin) / self.spacing - Vec3::splat(0.5))
            .clamp(Vec3::ZERO, (self.counts - UVec3::ONE).as_vec3());
        let base = g
            .floor()
            .min((self.counts.saturating_sub(UVec3::splat(2))).as_vec3())
            .max(Vec3::ZERO);
        let alpha = (g - base).clamp(Vec3::ZERO, Vec3::ONE);
        let base = base.as_uvec3();
        let mut out = Vec::with_capacity(8);
        let mut total = 0.0;
        // Classification: the probes that are off count only where all eight are; so do the
        // probes not updated yet (their maps are empty).
        let usable = |p: usize| self.active[p] && self.updates[p] > 0;
        let all_off = (0..8u32).all(|corner| {
            let off = UVec3::new(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            !usable(self.index((base + off).min(self.counts - UVec3::ONE)))
        });
        for corner in 0..8u32 {
            let off = UVec3::new(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            let c = (base + off).min(self.counts - UVec3::ONE);
            let p = self.index(c);
            if !usable(p) && !all_off {
                continue;
            }
            let to_probe = self.probe_origin(p) - q;
            let dist = to_probe.length().max(1e-6);
            let dir = to_probe / dist;
            let tri = Vec3::select(off.cmpeq(UVec3::ONE), alpha, Vec3::ONE - alpha);
            let trilinear = tri.x * tri.y * tri.z;
            let wrap = (0.5 * (1.0 + dir.dot(n))).powi(2) + 0.2;
            let l = self.moment_map.len();
            let m = self
                .moment_map
                .lookup(&self.moments[p * l..(p + 1) * l], -dir);
            let mut visibility = 1.0;
            if dist > m.x && self.updates[p] > 0 {
                let var = (m.y - m.x * m.x).abs().max(1e-8);
                let d = dist - m.x;
                visibility = (var / (var + d * d)).max(0.0).powi(3);
            }
            let mut w = wrap * visibility.max(0.05);
            // Crush tiny weights (RTXGI): they only add leaks.
            if w < 0.2 {
                w = w * w * w / (0.2 * 0.2);
            }
            w *= trilinear;
            if w > 0.0 {
                out.push((p, w));
                total += w;
            }
        }
        if total > 0.0 {
            for e in &mut out {
                e.1 /= total;
            }
        }
        out
    }

    /// Irradiance at surface point `x` with normal `n`, seen from direction `wo`.
    pub fn irradiance(&self, x: Vec3, n: Vec3, wo: Vec3) -> Vec3 {
        self.probe_weights(x, n, wo)
            .into_iter()
            .map(|(p, w)| self.probe_irradiance_toward(p, n) * w)
            .sum()
    }

    /// One update: every probe of the update ([`ProbeVolume::per_update`] of them, in turn)
    /// traces its rays and blends them in. `seed` chooses the frame's
    /// rotations and light samples; the result does not depend on the thread count. Returns
    /// the rays traced. With [`ProbeRadiance::Source`] nothing answers the rays' queries here
    /// (they bring back emission only): use [`ProbeVolume::trace_rays`] and
    /// [`ProbeVolume::blend`] with a radiance source between them.
    pub fn update(&mut self, scene: &Scene, seed: u64) -> PathStats {
        let rays = self.trace_rays(scene, seed);
        let stats = rays.stats;
        let answers = vec![Vec3::ZERO; rays.queries.len()];
        self.blend(rays, &answers);
        stats
    }

    /// The first half of an update: the rays of the update's probes traced and their radiance
    /// found, except (for [`ProbeRadiance::Source`]) the reflected radiance at the hits, left as
    /// queries for a radiance source.
    pub fn trace_rays(&self, scene: &Scene, seed: u64) -> ProbeRays {
        let n_rays = self.rays;
        let radiance = self.settings.radiance;
        let this = self;
        // Per probe: each ray's direction, radiance and hit distance, and its query if any.
        type Traced = (
            Vec<(Vec3, Vec3, f32)>,
            Vec<(u32, RadianceQuery)>,
            ProbeGeometry,
            PathStats,
        );
        let (n, first) = (self.probe_count(), self.cursor);
        let traced: Vec<Traced> = (0..self.per_update)
            .into_par_iter()
            .map(|i| {
                let p = (first + i) % n;
                let mut s = PixelSampler::new(seed, p as u64, 0);
                let rot = random_rotation(Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()));
                let origin = this.probe_origin(p);
                let grid_point = this.probe_position(this.coords_of(p));
                let max_dist = 1.5 * this.spacing.length();
                let mut stats = PathStats::default();
                let mut queries = Vec::new();
                // A probe that is off traces an eighth of the rays (to be switched back on).
                let n_rays = if this.active[p] {
                    n_rays
                } else {
                    (n_rays / 8).max(1)
                };
                let mut geo = ProbeGeometry {
                    rays: n_rays,
                    ..Default::default()
                };
                let rays = (0..n_rays)
                    .map(|r| {
                        let d = rot * fibonacci(r, n_rays);
                        let ray = Ray::new(origin, d);
                        stats.closest_rays += 1;
                        let Some(hit) = scene.intersect(&ray) else {
                            let le = if radiance == ProbeRadiance::Indirect {
                                Vec3::ZERO
                            } else {
                                scene.environment().radiance(d)
                            };
                            return (d, le, max_dist);
                        };
                        let si = scene.interaction(&ray, &hit);
                        let v = Vertex::new(scene, &si, si.wo);
                        let back_face = si.ng.dot(si.wo) < 0.0
                            && !scene.materials()[si.material as usize].double_sided;
                        if back_face {
                            geo.back_faces += 1;
                            if hit.t < geo.closest_back.0 {
                                geo.closest_back = (hit.t, d);
                            }
                        } else {
                            if hit.t < geo.closest_front.0 {
                                geo.closest_front = (hit.t, d);
                            }
                            let rel = (si.p - grid_point).abs();
                            geo.front_in_cells |= rel.cmplt(this.spacing).all();
                        }
                        let l = match radiance {
                            ProbeRadiance::Source => {
                                queries.push((r, v.query()));
                                scene.emission(&si)
                            }
                            _ => this.ray_radiance(scene, &v, radiance, &mut s, &mut stats),
                        };
                        let l = if this.settings.attenuation > 0.0
                            && radiance != ProbeRadiance::Indirect
                        {
                            l - scene.emission(&si) * (1.0 - this.emission_attenuation(p, d, hit.t))
                        } else {
                            l
                        };
                        // Back faces (inside geometry) shorten the distance (RTXGI).
                        let dist = if back_face {
                            0.2 * hit.t
                        } else {
                            hit.t.min(max_dist)
                        };
                        (d, l, dist)
                    })
                    .collect();
                (rays, queries, geo, stats)
            })
            .collect();
        let mut out = ProbeRays {
            first,
            ..Default::default()
        };
        for (i, (rays, queries, geo, st)) in traced.into_iter().enumerate() {
            out.stats.add(&st);
            out.geometry.push(geo);
            for (r, q) in queries {
                out.slots.push((i as u32, r));
                out.queries.push(q);
            }
            out.rays.push(rays);
        }
        out
    }

    /// The second half of an update: `answers` (one per query of `rays`, the reflected
    /// radiance at each hit) added to their rays' radiance, and each traced probe's rays
    /// blended into its maps with the hysteresis.
    pub fn blend(&mut self, mut rays: ProbeRays, answers: &[Vec3]) {
        assert_eq!(
            answers.len(),
            rays.slots.len(),
            "one answer per probe query"
        );
        for (&(p, r), a) in rays.slots.iter().zip(answers) {
            if a.is_finite() {
                rays.rays[p as usize][r as usize].1 += *a;
            }
        }
        let (im, mm) = (self.irradiance_map, self.moment_map);
        let hysteresis = self.settings.hysteresis;
        let sharp = self.settings.depth_sharpness;
        let (n, first, traced) = (self.probe_count(), rays.first, rays.rays.len());
        // Per probe, in parallel (each probe's texels are its own); only the probes traced.
        self.irradiance
            .par_chunks_mut(im.len())
            .zip(self.moments.par_chunks_mut(mm.len()))
            .zip(self.active.par_iter().zip(self.updates.par_iter_mut()))
            .enumerate()
            .for_each_init(
                || (RayColumns::default(), (Vec::new(), Vec::new())),
                |(columns, scratch), (p, ((irr, mom), (&active, updates)))| {
                    let i = (p + n - first) % n;
                    if !active || i >= traced {
                        return;
                    }
                    let rays = &rays.rays[i];
                    let k = *updates as f32;
                    let h = hysteresis.min(k / (k + 1.0));
                    *updates += 1;
                    columns.fill(rays);
                    im.blend(irr, columns, h, 1.0, |i| rays[i].1 * PI, scratch);
                    let moments = |i: usize| {
                        let d = rays[i].2;
                        Vec2::new(d, d * d)
                    };
                    mm.blend(mom, columns, h, sharp, moments, scratch);
                },
            );
        self.cursor = (first + traced) % n;
        self.relocate_and_classify(first, &rays.geometry);
    }

    /// Relocation and classification from the rays' findings, `geometry[i]` probe
    /// `first + i`'s (see the module's notes).
    fn relocate_and_classify(&mut self, first: usize, geometry: &[ProbeGeometry]) {
        let min_front = 0.1 * self.spacing.min_element();
        let limit = 0.45 * self.spacing;
        let n = self.probe_count();
        for (i, g) in geometry.iter().enumerate() {
            let p = (first + i) % n;
            let inside = g.back_fraction() > INSIDE_FRACTION;
            self.back_fraction[p] = g.back_fraction();
            if self.settings.relocate {
                let mut off = self.offsets[p];
                if inside && g.closest_back.0.is_finite() {
                    off += g.closest_back.1 * (g.closest_back.0 + 0.5 * min_front);
                } else if !inside && g.closest_front.0 < min_front {
                    off -= g.closest_front.1 * (min_front - g.closest_front.0);
                }
                self.offsets[p] = off.clamp(-limit, limit);
            }
            if self.settings.classify {
                self.active[p] = !inside && g.front_in_cells;
            }
        }
    }

    /// §3.3: the factor on the emission a ray of probe `p` (direction `d`) finds at distance
    /// `t`. Emission at probe centres is too bright for the surfaces the probe shades, which
    /// lie farther from the light: on average `b` behind the probe, its mean distance toward
    /// `−d` (the moments it already holds) clipped to its eight cells; the factor is the
    /// inverse square law's `(t / (t + s·b))²`, `s` the setting. A heuristic (the paper's own
    /// word), biased either way; 1 before the probe holds any distances.
    pub fn emission_attenuation(&self, p: usize, d: Vec3, t: f32) -> f32 {
        let l = self.moment_map.len();
        let mean = self
            .moment_map
            .lookup(&self.moments[p * l..(p + 1) * l], -d)
            .x;
        let to_cells = (self.spacing / d.abs().max(Vec3::splat(1e-6))).min_element();
        let b = self.settings.attenuation * mean.min(to_cells).max(0.0);
        if b > 0.0 { (t / (t + b)).powi(2) } else { 1.0 }
    }

    /// The radiance a probe ray brings back from vertex `v` (eq. 4 or eq. 5).
    fn ray_radiance(
        &self,
        scene: &Scene,
        v: &Vertex,
        radiance: ProbeRadiance,
        s: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> Vec3 {
        let rho = v.bsdf.diffuse_reflectance();
        let volume = rho / PI * self.irradiance(v.si.p, v.si.ns, v.wo_world);
        match radiance {
            // (`Source` rays take their radiance from the source, never from here.)
            ProbeRadiance::Full | ProbeRadiance::Source => scene.emission(&v.si) + volume,
            ProbeRadiance::Indirect => {
                // T_{f_d} L_e: the direct light reflected by the hit's diffuse part, by NEE
                // and BSDF sampling combined by MIS (NEE alone has unbounded variance where
                // the hit lies next to an emitter).
                let vd = Vertex {
                    bsdf: Bsdf::Diffuse { albedo: rho },
                    ..*v
                };
                let tracer = PathTracer {
                    max_depth: 2,
                    ..Default::default()
                };
                let mut walk = PathWalk::from_vertex(scene, &tracer, 1);
                let mut direct = walk.next_event(scene, &vd, s, stats);
                if walk.scatter(&vd, s).is_some() {
                    direct += walk.throughput()
                        * match walk.arrive(scene, stats) {
                            Arrival::Escaped { le, mis } => le * mis,
                            Arrival::Hit(h) => h.le * h.mis,
                        };
                }
                direct + volume
            }
        }
    }
}

impl RadianceSource for ProbeVolume {
    /// `ρ/π · E` at each query (the diffuse radiance the probes describe).
    fn radiance(&self, queries: &[RadianceQuery]) -> Vec<Vec3> {
        queries
            .par_iter()
            .map(|q| q.diffuse / PI * self.irradiance(q.position, q.normal, q.direction))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blend's weights are `f32::powi`'s to the bit for integral exponents (so the faster
    /// blend renders the same images), `powf`'s otherwise, and zero behind the texel.
    #[test]
    fn blend_weights_are_powi_to_the_bit() {
        let mut s = PixelSampler::new(7, 0, 0);
        let dirs: Vec<Vec3> = (0..512)
            .map(|_| nrc_scene::sampling::sample_uniform_sphere(s.next_2d()))
            .collect();
        let rays: Vec<(Vec3, Vec3, f32)> = dirs.iter().map(|&d| (d, Vec3::ZERO, 1.0)).collect();
        let mut columns = RayColumns::default();
        columns.fill(&rays);
        let n = Vec3::new(0.3, -0.5, 0.81).normalize();
        let (mut out, mut base) = (Vec::new(), Vec::new());
        for exponent in [0.0f32, 1.0, 2.0, 7.0, 50.0, 2.5] {
            columns.weights(n, exponent, &mut out, &mut base);
            for (d, &w) in dirs.iter().zip(&out) {
                let c = n.dot(*d);
                let want = if c <= 0.0 {
                    0.0
                } else if exponent.fract() == 0.0 {
                    c.powi(exponent as i32)
                } else {
                    c.powf(exponent)
                };
                assert_eq!(w.to_bits(), want.to_bits(), "cos {c}, exponent {exponent}");
            }
        }
    }
}
