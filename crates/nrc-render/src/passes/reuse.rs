//! The reuse driver every resampling pass runs: temporal reuse from the previous frame's
//! reservoirs, spatial reuse from screen neighbours or from the previous frame's world-space
//! hash grid, M-caps, and the merge of reservoirs with the unbiased `1/Z` (Bitterli et al.
//! 2020, Alg. 4–6; Ouyang et al. 2021, Alg. 3–4 and eq. 11 for shifted samples;
//! `world-space-restir-gi.txt`, Alg. 2). A pass says what it resamples by implementing
//! [`Resampling`] for its frame (which vertex of each pixel sample reuses, the sample's target
//! and shift, its visibility test); it keeps its candidates and its shading, and hands the
//! shaded samples to [`super::screen::assemble`].
//!
//! Each step reads one buffer and writes another (`input[i]` → `out[i]`), so a pixel sample's
//! result does not depend on the order of the others; each draws from its own named stream
//! ([`Phase::Temporal`], [`Phase::Spatial`]).

use glam::Vec3;

use super::frame::FrameInput;
use super::hash_grid::{CellRule, HashGrid};
use super::params::{Key, Value};
use super::screen::{GBuffer, MAX, MAX_COUNT, Phase, par_map, stream};
use crate::error::SettingsError;
use crate::path_tracer::PathStats;
use crate::reservoir::Reservoir;
use crate::sampler::PixelSampler;
use crate::transport::Vertex;

/// A reservoir and the counters of the rays spent on it so far.
pub type Slot<S> = (Reservoir<S>, PathStats);

/// One frame of a resampling pass, as the reuse driver sees it.
pub trait Resampling: Sync {
    /// What the pass resamples (a light sample, a reconnection vertex, ...).
    type Sample: Copy + Send + Sync;

    /// The vertex at which pixel sample `i` reuses its neighbours' and its history's
    /// reservoirs (`None`: no reuse there).
    fn receiver(&self, i: usize) -> Option<&Vertex>;

    /// The vertex owning pixel sample `q`'s reservoir when `q` is a screen neighbour (`None`:
    /// `q`'s reservoir is not lent).
    fn donor(&self, q: usize) -> Option<&Vertex>;

    /// `p̂_v(y)`, in the measure the pass's reservoirs at `v` use (0 where `y` brings nothing).
    fn target(&self, v: &Vertex, y: &Self::Sample) -> f32;

    /// The factor carrying a donor's `W` into the receiver's measure (the shift's Jacobian;
    /// 0 where the shift is not defined). 1 for samples whose measure is the same everywhere.
    fn jacobian(&self, _receiver: &Vertex, _donor: &Vertex, _y: &Self::Sample) -> f32 {
        1.0
    }

    /// Whether `v` sees `y`; counts the ray in `stats`.
    fn visible(&self, v: &Vertex, y: &Self::Sample, stats: &mut PathStats) -> bool;

    /// How merges weigh their inputs.
    fn merge(&self) -> Merge;

    /// Merges `others` (reservoirs with their owners' vertices) into `own` (the reservoir of
    /// `v`), each shifted by [`Resampling::jacobian`], weighted as [`Resampling::merge`] says
    /// ([`Merge`]). Returns the merged reservoir and whether its sample is `own`'s.
    fn combine(
        &self,
        v: &Vertex,
        own: &Reservoir<Self::Sample>,
        others: &[(Reservoir<Self::Sample>, &Vertex)],
        u: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> (Reservoir<Self::Sample>, bool) {
        if self.merge() == Merge::Pairwise && !others.is_empty() {
            return self.combine_pairwise(v, own, others, u, stats);
        }
        let mut out = Reservoir::new();
        let mut is_own = out.merge(own, own.target, u.next_1d());
        for (o, ov) in others {
            let (t, j) = match &o.sample {
                Some(y) => (self.target(v, y), self.jacobian(v, ov, y)),
                None => (0.0, 0.0),
            };
            if out.merge_shifted(o, t, j, u.next_1d()) {
                is_own = false;
            }
        }
        let z = match out.sample {
            Some(y) if self.merge() != Merge::Biased => {
                let mut z = own.m;
                for (o, ov) in others {
                    if self.jacobian(v, ov, &y) > 0.0
                        && self.target(ov, &y) > 0.0
                        && self.visible(ov, &y, stats)
                    {
                        z += o.m;
                    }
                }
                z
            }
            _ => out.m,
        };
        out.finish(z);
        (out, is_own)
    }

    /// `p̂` of neighbour `o` (owner `ov`) for `y`, carried into the measure of the receiver
    /// `v` (`p̂_o(y) / J`, `J = ∂ω_v/∂ω_o`): the density, up to its normalisation, with which
    /// `o`'s domain produces `y`; and `J`. Zero where the shift is not defined or `p̂_o(y) = 0`,
    /// and, with `test`, where `o`'s owner does not see `y` (a shadow ray, counted in `stats`).
    fn target_from(
        &self,
        v: &Vertex,
        ov: &Vertex,
        y: &Self::Sample,
        test: bool,
        stats: &mut PathStats,
    ) -> (f32, f32) {
        let j = self.jacobian(v, ov, y);
        if j <= 0.0 {
            return (0.0, 0.0);
        }
        let t = self.target(ov, y);
        if t <= 0.0 || (test && !self.visible(ov, y, stats)) {
            return (0.0, j);
        }
        let p = t / j;
        (if p.is_finite() { p } else { 0.0 }, j)
    }

    /// [`Resampling::combine`] with generalised pairwise MIS weights (Bitterli's thesis, 2022,
    /// §9.1.3; Lin et al. 2022, "GRIS", §5): `own` is the canonical input `c` and each of the
    /// `k` others `i` is weighed against it alone, with confidence weights `M`. With
    /// `a_i(y) = M_i p̂_i(y) / (M_i p̂_i(y) + M_c/k · p̂_c(y))` (`p̂_i` in `v`'s measure,
    /// [`Resampling::target_from`]) and each pair's share `b_i = (M_i + M_c/k) / Σ M`, the
    /// weights are `m_i(y) = b_i a_i(y)` and `m_c(y) = Σ_i b_i (1 − a_i(y))`: they sum to 1
    /// wherever `c` can produce `y` and vanish where their own input cannot, so the merge is
    /// unbiased; and a neighbour whose target differs from the receiver's (a diffuse donor's
    /// sample at a glossy receiver, a donor lit where the receiver is dark) gets the weight
    /// its domain deserves instead of 1/Z's equal share, which is what made 1/Z's fireflies.
    /// Each input enters with `m(y) · p̂_c(y) · W · J`, and `W = w_sum / p̂_c(y)`. Costs one
    /// shadow ray per neighbour (the canonical sample seen from its owner), as 1/Z does.
    fn combine_pairwise(
        &self,
        v: &Vertex,
        own: &Reservoir<Self::Sample>,
        others: &[(Reservoir<Self::Sample>, &Vertex)],
        u: &mut PixelSampler,
        stats: &mut PathStats,
    ) -> (Reservoir<Self::Sample>, bool) {
        let k = others.len() as f32;
        let total = own.m + others.iter().map(|(o, _)| o.m).sum::<f32>();
        let c_share = own.m / k;
        let pair = |m_i: f32, p_i: f32, p_c: f32| {
            let a = m_i * p_i;
            let d = a + c_share * p_c;
            if d > 0.0 && d.is_finite() { a / d } else { 0.0 }
        };
        let share = |m_i: f32| (m_i + c_share) / total;
        let mut out = Reservoir::new();
        let mut m_c = 0.0;
        if let Some(y) = &own.sample {
            for (o, ov) in others {
                let (p_i, _) = self.target_from(v, ov, y, true, stats);
                m_c += share(o.m) * (1.0 - pair(o.m, p_i, own.target));
            }
        }
        let mut is_own = out.merge_weighted(own, m_c * own.target * own.w, own.target, u.next_1d());
        for (o, ov) in others {
            let weight = match &o.sample {
                Some(y) => match self.target(v, y) {
                    p_c if p_c > 0.0 => {
                        // `o` found `y` and sees it: no shadow ray for its own density.
                        let (p_i, j) = self.target_from(v, ov, y, false, stats);
                        let m_i = share(o.m) * pair(o.m, p_i, p_c);
                        (m_i * p_c * o.w * j, p_c)
                    }
                    _ => (0.0, 0.0),
                },
                None => (0.0, 0.0),
            };
            if out.merge_weighted(o, weight.0, weight.1, u.next_1d()) {
                is_own = false;
            }
        }
        out.finish_normalised();
        (out, is_own)
    }
}

/// How a merge of reservoirs weighs its inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Merge {
    /// `Z = Σ M`: no visibility rays; biased where the inputs' domains differ.
    Biased,
    /// Unbiased `1/Z` (Bitterli et al. 2020, Alg. 6): `Z` sums the `M` of the inputs whose
    /// owner has a defined shift, `p̂ > 0` for the chosen `y`, and sees it. Every input that
    /// could have produced `y` gets the same share, however unlikely it was to.
    Count,
    /// Unbiased generalised pairwise MIS ([`Resampling::combine_pairwise`]), the default.
    Pairwise,
}

impl Merge {
    /// The merge of a pass's settings: `-biased`, else pairwise MIS unless `pairwise` is off.
    pub fn of(biased: bool, pairwise: bool) -> Self {
        match (biased, pairwise) {
            (true, _) => Self::Biased,
            (false, true) => Self::Pairwise,
            (false, false) => Self::Count,
        }
    }
}

/// The previous frame of a screen-space pass: its camera rays and final reservoirs.
pub struct History<S> {
    pub g: GBuffer,
    pub res: Vec<Reservoir<S>>,
}

impl<S> History<S> {
    /// The reservoirs' statistics, per pixel over its samples, in red: `reservoir-m`, the mean
    /// `M` (the candidates the final reservoirs stand for, after the M cap); and
    /// `reservoir-contribution`, the mean `W · p̂(y)` of the selected samples (0 for an empty
    /// reservoir): the luminance the resampled sample carries into the pixel (its target
    /// includes the shading) before the final visibility test, large where a pass's fireflies
    /// start. For the viewer
    /// (`nrc view --view`) and `nrc compare --diagnostics`.
    pub fn views(&self) -> Vec<super::frame::PassView> {
        vec![
            self.view("reservoir-m", |r| r.m),
            self.view("reservoir-contribution", |r| {
                if r.sample.is_some() {
                    r.w * r.target
                } else {
                    0.0
                }
            }),
        ]
    }

    fn view(
        &self,
        name: &'static str,
        value: impl Fn(&Reservoir<S>) -> f32,
    ) -> super::frame::PassView {
        let spp = self.g.spp.max(1) as usize;
        let data = self
            .res
            .chunks(spp)
            .map(|r| Vec3::new(r.iter().map(&value).sum::<f32>() / spp as f32, 0.0, 0.0))
            .collect();
        super::frame::PassView {
            name,
            scalar: true,
            image: nrc_scene::Image::from_data(self.g.width as usize, self.g.height as usize, data)
                .unwrap_or_else(|| {
                    nrc_scene::Image::new(self.g.width as usize, self.g.height as usize)
                }),
        }
    }
}

/// Temporal reuse: each receiver merges the previous frame's reservoir at its reprojected
/// pixel sample (similar vertex, [`GBuffer::temporal_neighbour`]), `M` capped at `m_cap`.
/// `recheck`: a sample taken from the history is shadow-tested at the receiver, so that a
/// spatial step after this one lends only samples their owners see.
pub fn temporal<R: Resampling>(
    frame: &R,
    seed: u64,
    history: Option<&History<R::Sample>>,
    m_cap: f32,
    recheck: bool,
    input: &[Slot<R::Sample>],
) -> Vec<Slot<R::Sample>> {
    par_map(input.len(), |i| {
        let (own, mut stats) = input[i];
        let (Some(v), Some(h)) = (frame.receiver(i), history) else {
            return (own, stats);
        };
        let Some((j, pv)) = h.g.temporal_neighbour(v, i) else {
            return (own, stats);
        };
        let mut prev = h.res[j];
        prev.cap(m_cap);
        let mut s = stream(seed, i, Phase::Temporal);
        let (mut r, is_own) = frame.combine(v, &own, &[(prev, pv)], &mut s, &mut stats);
        if recheck
            && !is_own
            && let Some(y) = r.sample
            && !frame.visible(v, &y, &mut stats)
        {
            r.clear_sample();
        }
        (r, stats)
    })
}

/// Spatial reuse in screen space: each receiver merges the reservoirs of up to `k` similar
/// pixel samples in a disc of `radius` pixels ([`GBuffer::neighbours`]), read from `input`.
pub fn spatial<R: Resampling>(
    frame: &R,
    g: &GBuffer,
    seed: u64,
    k: u32,
    radius: f32,
    input: &[Slot<R::Sample>],
) -> Vec<Slot<R::Sample>> {
    par_map(input.len(), |i| {
        let (own, mut stats) = input[i];
        let (Some(v), Some(p)) = (frame.receiver(i), g.primary[i].as_ref()) else {
            return (own, stats);
        };
        if k == 0 {
            return (own, stats);
        }
        let mut s = stream(seed, i, Phase::Spatial);
        let mut near = Vec::with_capacity(k as usize);
        g.neighbours(i, p, k, radius, &mut s, &mut near);
        let others: Vec<_> = near
            .iter()
            .filter_map(|&q| Some((input[q].0, frame.donor(q)?)))
            .collect();
        if others.is_empty() {
            return (own, stats);
        }
        let (r, _) = frame.combine(v, &own, &others, &mut s, &mut stats);
        (r, stats)
    })
}

/// A reservoir in the world-space grid, with its owner vertex and whether the owner's path
/// reached it from the camera directly (receivers with a depth limit reuse only such entries
/// when they are primary too: the radiance a sample carries depends on the segments left).
#[derive(Clone, Copy, Debug)]
pub struct Entry<S> {
    pub owner: Vertex,
    pub res: Reservoir<S>,
    pub primary: bool,
}

/// Cosine of the largest angle between a receiver's normal and a grid entry owner's
/// (`world-space-restir-gi.txt`, §5.3: 15°).
pub const GRID_NORMAL_COS: f32 = 0.966;

/// A frame's reservoirs in the world-space hash grid ([`super::hash_grid`]), read by the next
/// frame's spatial reuse.
pub struct WorldHistory<S> {
    grid: HashGrid,
    entries: Vec<Entry<S>>,
    rule: CellRule,
}

impl<S> WorldHistory<S> {
    /// The grid of `entries`, each keyed at its owner by the cell rule of the frame `input`
    /// (projected cell size `cell_scale` of the width, smallest cell `d_min` of the scene's
    /// smallest extent: eq. 11).
    pub fn build(input: &FrameInput, entries: Vec<Entry<S>>, cell_scale: f32, d_min: f32) -> Self {
        let rule = CellRule::new(
            input.camera,
            input.width,
            input.height,
            &input.scene.bounds(),
            cell_scale,
            d_min,
        );
        let keys: Vec<u64> = entries
            .iter()
            .map(|e| rule.key(e.owner.si.p, e.owner.si.ns, Vec3::ZERO))
            .collect();
        let grid = HashGrid::build(&keys);
        Self {
            grid,
            entries,
            rule,
        }
    }

    /// The entries, in the order they were built (for refreshing their samples).
    pub fn entries_mut(&mut self) -> &mut [Entry<S>] {
        &mut self.entries
    }

    pub fn entries(&self) -> &[Entry<S>] {
        &self.entries
    }

    /// The entries' buffer, for the next frame's grid to reuse.
    pub fn into_entries(self) -> Vec<Entry<S>> {
        self.entries
    }
}

/// Spatial reuse in world space (`world-space-restir-gi.txt`, Alg. 2): each receiver (`at(i)`:
/// its vertex and whether it is the primary one) merges up to `samples` entries of the
/// previous frame's grid cell around it (the position jittered by up to half a cell; a random
/// offset and a fixed stride through the cell), those whose owner's normal is within 15° and,
/// unless `unlimited` path length, whose `primary` matches the receiver's, `M` capped at
/// `m_cap`.
#[allow(clippy::too_many_arguments)]
pub fn world_spatial<'a, R: Resampling>(
    frame: &R,
    at: impl Fn(usize) -> Option<(&'a Vertex, bool)> + Sync,
    seed: u64,
    history: Option<&WorldHistory<R::Sample>>,
    samples: u32,
    m_cap: f32,
    unlimited: bool,
    input: &[Slot<R::Sample>],
) -> Vec<Slot<R::Sample>> {
    par_map(input.len(), |i| {
        let (own, mut stats) = input[i];
        let Some((v, primary)) = at(i) else {
            return (own, stats);
        };
        let mut s = stream(seed, i, Phase::Spatial);
        let mut others = Vec::new();
        if let Some(h) = history {
            others.reserve(samples as usize);
            let jitter = Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) - Vec3::splat(0.5);
            let cell = h.grid.find(h.rule.key(v.si.p, v.si.ns, jitter));
            let count = cell.len();
            if count > 0 && samples > 0 {
                let step = count.div_ceil(samples as usize).max(1);
                let off = ((s.next_1d() * step as f32) as usize).min(step - 1);
                for k in (0..count).step_by(step) {
                    let e = &h.entries[cell[(k + off) % count] as usize];
                    let same_budget = unlimited || e.primary == primary;
                    if same_budget && e.owner.si.ns.dot(v.si.ns) >= GRID_NORMAL_COS {
                        let mut res = e.res;
                        res.cap(m_cap);
                        others.push((res, &e.owner));
                    }
                }
            }
        }
        if others.is_empty() {
            return (own, stats);
        }
        let (r, _) = frame.combine(v, &own, &others, &mut s, &mut stats);
        (r, stats)
    })
}

/// The key choosing pairwise MIS over 1/Z for unbiased merges ([`Merge`]).
pub(super) fn visit_pairwise(f: &mut dyn FnMut(&Key, &mut dyn Value), pairwise: &mut bool) {
    let key = Key::new(
        "pairwise",
        "unbiased merges by pairwise MIS (0: 1/Z, an equal share for every input)",
    );
    f(&key, pairwise);
}

/// The keys of the screen-space reuse every resampling pass of the primary vertex shares:
/// `k` neighbours in a disc of `radius` pixels, the history's `mcap`, `temporal`, and
/// `pairwise`.
pub(super) fn visit_reuse(
    f: &mut dyn FnMut(&Key, &mut dyn Value),
    neighbours: &mut u32,
    radius: &mut f32,
    m_cap: &mut f32,
    temporal: &mut bool,
    pairwise: &mut bool,
) {
    let k = Key::new("k", "spatial neighbours (0: no spatial reuse)");
    f(&k.range(0.0, MAX), neighbours);
    let r = Key::new("radius", "radius of the spatial neighbourhood, pixels");
    f(&r.range(0.0, f64::INFINITY), radius);
    let mcap = Key::new(
        "mcap",
        "the history's M capped at this multiple of the candidates",
    );
    f(&mcap.positive(f64::INFINITY), m_cap);
    f(
        &Key::new("temporal", "reuse the previous frame's reservoirs"),
        temporal,
    );
    visit_pairwise(f, pairwise);
}

/// The bounds every resampling pass puts on its reuse settings (`counts`: its candidate and
/// neighbour counts; absurd values would be loops per pixel).
pub(super) fn validate_reuse(counts: &[u32], radius: f32, m_cap: f32) -> Result<(), SettingsError> {
    let max = MAX_COUNT;
    if let Some(c) = counts.iter().find(|&&c| c > max) {
        return Err(SettingsError::bounds(
            "candidate and neighbour counts",
            format!("be at most {max}"),
            c,
        ));
    }
    if !(radius >= 0.0 && radius.is_finite()) {
        return Err(SettingsError::bounds(
            "spatial radius",
            "be finite and ≥ 0",
            radius,
        ));
    }
    if !(m_cap > 0.0 && m_cap.is_finite()) {
        return Err(SettingsError::bounds("M-cap", "be positive", m_cap));
    }
    Ok(())
}
