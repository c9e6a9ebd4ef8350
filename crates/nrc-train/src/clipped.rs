//! The light the loss bound clips, returned where it was clipped.
//!
//! The cache's loss is Huber's beyond a relative residual `k` (`loss.max_relative_error`,
//! `nrc_cache::loss`): a target more than `k · √(lum(y)² + ε)` above the prediction `y` pulls no
//! harder than one at the bound. The bound is relative to the prediction, so it feeds back: a
//! darker cache clips more of the rare bright targets, which darkens it further, down to an
//! equilibrium below the targets' mean (a fifth below it on `ajar` with light tracing;
//! RESULTS.md, "A restart of the rate only for a change that lasts"). Removing the bound
//! removes the bias but lets single fireflies through (the kitchen's first-vertex render 50 %
//! worse in relMSE at a bound of 64).
//!
//! [`ClippedLight`] keeps the bound and returns its light. Before a frame trains, each record's
//! target is clamped where the bound would clip it (at the cache's prediction as the passes
//! read it, in luminance),
//! and the clamped and clipped luminance are summed per bin (a cell of a `grid`³ grid over the
//! scene box, and the normal's dominant axis and sign), the sums decaying by `1 − 1/frames` a
//! frame. Every target of a bin is then scaled by the bin's gain, `1 + clipped / kept`, at most
//! `max_gain`: over a bin and its remembered frames the targets carry the light they carried
//! before the clamp, spread in proportion to the clamped targets instead of in the rare records
//! that brought it. The feedback turns negative: a darker cache clips more, which raises its
//! bin's gain. What remains is a bias *within* a bin (light moved from where the rare targets
//! landed to the rest of the bin) and the gain's cap. A bin holds no direction, so records on
//! glossy surfaces (a specular part smoother than `min_roughness`) are clamped but neither
//! counted nor scaled: the window reflected in the kitchen's counters, returned to every
//! direction, made its first-vertex render 27 % worse in MSE after 512 frames (RESULTS.md,
//! "The light the bound clips").

use glam::Vec3;
use nrc_cache::TrainingBatch;
use nrc_cache::batch::check_record;
use nrc_cache::config::{LossConfig, ReturnClipped};
use nrc_scene::sampling::luminance;

use crate::schedule::bin_of;

/// The per-bin sums of the light kept and clipped by the bound, and the gain they give.
#[derive(Clone, Debug)]
pub struct ClippedLight {
    spec: ReturnClipped,
    /// Remembered luminance of the clamped targets, per bin.
    kept: Vec<f64>,
    /// Remembered luminance clipped off the targets, per bin.
    clipped: Vec<f64>,
}

/// What [`ClippedLight::apply`] did to a frame's records.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClipStats {
    /// Records whose target was clamped at the bound.
    pub clamped: usize,
    /// The records' mean gain, every record counted (1 for those outside the bins; 1 for a
    /// frame without records).
    pub gain: f32,
}

impl ClippedLight {
    /// Empty bins for `spec` (validated with its cache's configuration: `grid` ≥ 1, `frames` ≥ 1).
    pub fn new(spec: &ReturnClipped) -> Self {
        assert!(spec.grid >= 1 && spec.frames >= 1.0, "invalid {spec:?}");
        let bins = (spec.grid as usize).pow(3) * 6;
        Self {
            spec: spec.clone(),
            kept: vec![0.0; bins],
            clipped: vec![0.0; bins],
        }
    }

    /// Its settings.
    pub fn spec(&self) -> &ReturnClipped {
        &self.spec
    }

    /// The gain of bin `b`: `1 + clipped / kept`, at most `max_gain` (1 for a bin that kept
    /// nothing).
    fn gain(&self, b: usize) -> f64 {
        if self.kept[b] > 0.0 {
            (1.0 + self.clipped[b] / self.kept[b]).min(f64::from(self.spec.max_gain))
        } else {
            1.0
        }
    }

    /// Clamps `batch`'s targets at the bound of `loss` around `predictions` (the cache's, one
    /// per record), adds the frame's kept and clipped light to the bins, and scales each target
    /// by its bin's gain. The clamp is on the target's luminance (the loss bounds each channel's
    /// residual, normalised by the prediction's luminance: the two agree for grey targets; a
    /// coloured firefly's clipped channel beyond it is lost as without the return). A record on
    /// a surface with a specular part smoother than `min_roughness` is clamped but takes no part
    /// in the bins: its radiance depends on the direction, which a bin does not hold. Records
    /// the cache drops (`nrc_cache::batch::check_record`: non-finite, negative or above
    /// `max_target`, a bad weight) and those whose prediction is not finite are left alone.
    ///
    /// Panics if `predictions` or the batch's weights are not one per record.
    pub fn apply(
        &mut self,
        batch: &mut TrainingBatch,
        predictions: &[[f32; 3]],
        loss: &LossConfig,
    ) -> ClipStats {
        let n = batch.queries.len();
        assert_eq!(predictions.len(), n, "one prediction per record");
        assert_eq!(batch.targets.len(), n, "one target per record");
        if let Some(w) = &batch.weights {
            assert_eq!(w.len(), n, "one weight per record");
        }
        let decay = 1.0 - 1.0 / f64::from(self.spec.frames);
        for v in self.kept.iter_mut().chain(self.clipped.iter_mut()) {
            *v *= decay;
        }
        let (k, eps) = (f64::from(loss.max_relative_error), f64::from(loss.epsilon));
        let grid = self.spec.grid as usize;
        let mut bins = Vec::with_capacity(n);
        let mut stats = ClipStats::default();
        for (i, (q, y)) in batch.queries.iter().zip(predictions).enumerate() {
            let t = &mut batch.targets[i];
            let w = batch.weights.as_ref().map_or(1.0, |w| w[i]);
            let ly = f64::from(luminance(Vec3::from(*y)));
            if check_record(q, t, w, loss.max_target).is_err() || !ly.is_finite() {
                bins.push(None);
                continue;
            }
            let ly = ly.max(0.0);
            let lt = f64::from(luminance(Vec3::from(*t)));
            let bound = ly + k * (ly * ly + eps).sqrt();
            let clamped = lt > bound;
            if clamped {
                let s = (bound / lt) as f32;
                t.iter_mut().for_each(|c| *c *= s);
                stats.clamped += 1;
            }
            let glossy =
                q.roughness < self.spec.min_roughness && q.specular.iter().any(|&s| s > 0.0);
            if glossy {
                bins.push(None);
                continue;
            }
            let b = bin_of(&q.position, &q.normal, grid);
            let w = f64::from(w);
            self.kept[b] += w * lt.min(bound);
            if clamped {
                self.clipped[b] += w * (lt - bound);
            }
            bins.push(Some(b));
        }
        let mut gains = 0.0;
        for (t, b) in batch.targets.iter_mut().zip(&bins) {
            let g = b.map_or(1.0, |b| self.gain(b));
            if g > 1.0 {
                t.iter_mut().for_each(|c| *c *= g as f32);
            }
            gains += g;
        }
        stats.gain = if bins.is_empty() {
            1.0
        } else {
            (gains / bins.len() as f64) as f32
        };
        stats
    }
}
