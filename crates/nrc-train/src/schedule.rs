//! The online loop's control: noticing that the scene changed under the cache.
//!
//! **The change score** ([`ChangeMonitor`]). Before a frame trains, the cache (its inference
//! weights, the ones the passes read) predicts radiance at the frame's training queries. The
//! residuals `d = lum(target) − lum(prediction)` of 1-spp targets are noisy, and where the
//! cache is biased (still learning, or blurred where the scene has detail) they have a mean
//! that is not zero, but that mean moves slowly while the scene stays as it is. After a light
//! moves or a material changes it jumps: up where the radiance rose, down where it fell. The
//! records are binned by where they are (an 8³ grid over the scene box, times the normal's
//! dominant axis), and each bin's mean residual this frame is compared with the bin's recent
//! history by Welch's t²; their standardised sum is the score, ≈ N(0, 1) while nothing changes
//! and growing with the records in the bins a change touched.
//!
//! **The detector** ([`ChangeDetector`]) compares each score with the scores' own running
//! level and spread, and calls a change when one stands far above them; the recovery that
//! follows lasts until the score is back at its level. What the online loop does about a
//! change is [`crate::online`]'s business (the cache infers from its training weights while
//! it recovers, [`nrc_cache::RadianceCache::set_follow`]; the hash cache forgets most of its
//! cells' samples, [`nrc_cache::HashCache::forget`]: [`nrc_cache::Cache::begin_recovery`]; and
//! once the change is confirmed a frame later, the learning rate's decay restarts:
//! [`nrc_cache::Cache::confirm_change`]).

use glam::Vec3;
use nrc_cache::TrainingBatch;
use nrc_scene::sampling::luminance;

/// Bins with fewer records (this frame, and in the bin's history) give no statistic.
pub const MIN_BIN_RECORDS: f64 = 4.0;
/// A bin's `t²` counts at most this much (see [`ChangeMonitor::score`]).
pub const BIN_CAP: f64 = 16.0;
/// Cells per axis of the binning grid.
const GRID: usize = 8;
/// Weight a bin's history keeps per frame (the history spans about 1/(1 − λ) = 5 frames).
pub const HISTORY_DECAY: f64 = 0.8;

/// How far a frame's training targets are from the cache's predictions, beyond their noise.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChangeScore {
    /// `(Σt² − B)/√(2B)` over the bins with enough records (0 with none).
    pub z: f32,
    /// Bins that gave a statistic.
    pub bins: u32,
}

/// Records, sum and sum of squares of residuals.
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    n: f64,
    sum: f64,
    sum2: f64,
}

impl Moments {
    fn add(&mut self, d: f64) {
        self.n += 1.0;
        self.sum += d;
        self.sum2 += d * d;
    }

    fn mean(&self) -> f64 {
        self.sum / self.n
    }

    /// Variance of the mean (the sample variance over `n`), at least `floor`.
    fn var_of_mean(&self, floor: f64) -> f64 {
        let m = self.mean();
        ((self.sum2 / self.n - m * m).max(0.0) / self.n).max(floor)
    }
}

/// The change score of successive frames: each frame's residuals, bin by bin, against the
/// bin's recent history (the bins of the last frames, decayed by [`HISTORY_DECAY`] a frame).
/// Comparing with the history instead of with zero cancels the cache's persistent bias (a
/// blurred caustic, a region still being learnt), which would otherwise make the score as
/// noisy as it is large.
#[derive(Clone, Debug)]
pub struct ChangeMonitor {
    history: Vec<Moments>,
}

impl Default for ChangeMonitor {
    fn default() -> Self {
        Self {
            history: vec![Moments::default(); GRID * GRID * GRID * 6],
        }
    }
}

impl ChangeMonitor {
    /// The score of `batch` against the cache's `predictions` at its queries (the first
    /// `predictions.len()` records are used), then the frame joins the history. For each bin
    /// with enough records now and in its history, Welch's statistic
    /// `t² = (mean_now − mean_history)² / (var_now/n_now + var_history/n_history)` (≈ χ²₁ when
    /// nothing changed); the score standardises their sum over the `B` bins,
    /// `z = (Σt² − B)/√(2B)` (≈ N(0, 1)). Each bin's `t²` is capped at [`BIN_CAP`]: a change
    /// moves the radiance of a region, many bins at once, while a burst of caustic paths in
    /// one frame moves one or two bins a lot (uncapped, `caustics` with `pt` called 11 changes
    /// in 1,000 still frames, its score's 99th percentile at 21; capped, none, at 7.5, and the
    /// lamp's jump in `cornell-box-jump` still scores 67 against a level of 5–11).
    pub fn score(&mut self, batch: &TrainingBatch, predictions: &[[f32; 3]]) -> ChangeScore {
        let mut now = vec![Moments::default(); self.history.len()];
        for ((q, t), y) in batch.queries.iter().zip(&batch.targets).zip(predictions) {
            let d = f64::from(luminance(Vec3::from(*t)) - luminance(Vec3::from(*y)));
            if d.is_finite() {
                now[bin_of(&q.position, &q.normal, GRID)].add(d);
            }
        }
        let (mut total, mut bins) = (0.0f64, 0u32);
        for (h, f) in self.history.iter_mut().zip(&now) {
            if f.n >= MIN_BIN_RECORDS && h.n >= MIN_BIN_RECORDS {
                // A floor on the variances: a bin whose residuals are all alike (a black
                // region, exactly predicted) says nothing.
                let floor = 1e-12 * (1.0 + f.mean().abs() + h.mean().abs());
                let var = f.var_of_mean(floor) + h.var_of_mean(floor);
                total += ((f.mean() - h.mean()).powi(2) / var).min(BIN_CAP);
                bins += 1;
            }
            h.n = HISTORY_DECAY * h.n + f.n;
            h.sum = HISTORY_DECAY * h.sum + f.sum;
            h.sum2 = HISTORY_DECAY * h.sum2 + f.sum2;
        }
        if bins == 0 {
            return ChangeScore::default();
        }
        let b = f64::from(bins);
        ChangeScore {
            z: ((total - b) / (2.0 * b).sqrt()) as f32,
            bins,
        }
    }
}

/// The bin of a query: its cell of the `grid`³ grid over the scene box (positions normalised
/// to it), and its normal's dominant axis and sign; `grid³ · 6` bins.
pub(crate) fn bin_of(position: &[f32; 3], normal: &[f32; 3], grid: usize) -> usize {
    let cell = position.iter().fold(0usize, |c, p| {
        c * grid + ((p.clamp(0.0, 1.0) * grid as f32) as usize).min(grid - 1)
    });
    let n = Vec3::from(*normal);
    let a = n.abs();
    let face = if a.x >= a.y && a.x >= a.z {
        usize::from(n.x < 0.0)
    } else if a.y >= a.z {
        2 + usize::from(n.y < 0.0)
    } else {
        4 + usize::from(n.z < 0.0)
    };
    cell * 6 + face
}

/// Frames the detector watches before it may report a change (its level must settle first).
pub const WARM_UP_FRAMES: u32 = 8;
/// Weight of a new frame in the detector's running level and spread.
const SMOOTHING: f32 = 0.2;
/// A change is a score above the running level by this many spreads ...
pub const CHANGE_SPREADS: f32 = 4.0;
/// ... and by at least this much (the score's own scale: ≈ N(0, 1) for an unbiased cache).
pub const CHANGE_MIN_RISE: f32 = 8.0;
/// Recovery lasts at least this many frames ...
pub const RECOVERY_MIN_FRAMES: u32 = 4;
/// ... and at most this many.
pub const RECOVERY_MAX_FRAMES: u32 = 64;

/// What the detector made of a frame's score.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Learning the score's level (the first frames, and after a recovery).
    #[default]
    Watching,
    /// The score is at its level: nothing changed.
    Settled,
    /// The score jumped this frame: the scene changed under the cache.
    Changed,
    /// The frame after a change, the score still up: the change is real, not one frame's
    /// outlier (a burst of caustic paths): the cache's learning rate restarts
    /// ([`nrc_cache::Cache::confirm_change`]). A recovering frame otherwise. (A non-finite
    /// score is not counted as a frame: after one, the confirmation waits for the next.)
    Confirmed,
    /// Since a change, until the score is back at its level before it.
    Recovering,
    /// The score came back this frame: the recovery ends.
    Recovered,
}

impl Phase {
    /// The phase's name, as the statistics write it.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Watching => "watching",
            Phase::Settled => "settled",
            Phase::Changed => "changed",
            Phase::Confirmed => "confirmed",
            Phase::Recovering => "recovering",
            Phase::Recovered => "recovered",
        }
    }
}

/// Tells a change in the scene from the noise of the change score ([`ChangeMonitor::score`]): a
/// running level (exponential average) and spread (mean absolute deviation × 1.25, σ for a
/// normal score) of the scores; a score above the level by [`CHANGE_SPREADS`] spreads and at
/// least [`CHANGE_MIN_RISE`] is a change. The recovery that follows ends when the score is back
/// within two spreads of the level it had before the change (at least [`RECOVERY_MIN_FRAMES`],
/// at most [`RECOVERY_MAX_FRAMES`] frames); then the detector learns the level anew. A change
/// whose next score has not come back is confirmed ([`Phase::Confirmed`]).
#[derive(Clone, Debug, Default)]
pub struct ChangeDetector {
    level: f32,
    spread: f32,
    seen: u32,
    /// Frames into the recovery, and the level and spread before the change.
    recovery: Option<(u32, f32, f32)>,
}

impl ChangeDetector {
    /// Reads one frame's score.
    pub fn observe(&mut self, z: f32) -> Phase {
        if !z.is_finite() {
            return if self.recovery.is_some() {
                Phase::Recovering
            } else {
                Phase::Watching
            };
        }
        if let Some((frames, level, spread)) = &mut self.recovery {
            *frames += 1;
            let back = z <= *level + 2.0 * *spread;
            if *frames == 1 && !back {
                return Phase::Confirmed;
            }
            if (*frames >= RECOVERY_MIN_FRAMES && back) || *frames >= RECOVERY_MAX_FRAMES {
                let spread = *spread;
                self.recovery = None;
                self.level = z;
                self.spread = spread;
                self.seen = 1;
                return Phase::Recovered;
            }
            return Phase::Recovering;
        }
        if self.seen == 0 {
            (self.level, self.spread, self.seen) = (z, 0.0, 1);
            return Phase::Watching;
        }
        let rise = z - self.level;
        if self.seen >= WARM_UP_FRAMES && rise > (CHANGE_SPREADS * self.spread).max(CHANGE_MIN_RISE)
        {
            self.recovery = Some((0, self.level, self.spread));
            return Phase::Changed;
        }
        self.level += SMOOTHING * rise;
        self.spread += SMOOTHING * (1.25 * rise.abs() - self.spread);
        self.seen += 1;
        if self.seen > WARM_UP_FRAMES {
            Phase::Settled
        } else {
            Phase::Watching
        }
    }

    /// Whether the score has settled at its level (watched long enough, no recovery).
    pub fn settled(&self) -> bool {
        self.recovery.is_none() && self.seen > WARM_UP_FRAMES
    }

    /// Whether a recovery is under way.
    pub fn recovering(&self) -> bool {
        self.recovery.is_some()
    }
}

/// Frames a run under a time budget takes to warm up (its first frames pay for allocations
/// and the cost fits have not seen enough frames): the budget is judged after them.
pub const BUDGET_WARM_UP_FRAMES: usize = 10;
/// Fewest training records a frame under a time budget produces.
pub const MIN_BUDGET_RECORDS: usize = 256;
/// Most training records a frame under a time budget produces (NRC's 2^16 on a GPU).
pub const MAX_BUDGET_RECORDS: usize = 1 << 16;
/// Share of the budget a frame spends while the cache is settled (the whole budget while it
/// warms up or recovers from a change). Not tuned: half, so that a settled cache leaves the
/// frame time to rendering and a change can still double the spend.
pub const SETTLED_SHARE: f64 = 0.5;
/// Weight each earlier frame keeps per frame in the cost fits (about ten frames' memory).
const COST_DECAY: f64 = 0.9;

/// A cost `a + b·x` in milliseconds fitted to the recent frames by least squares, weighted
/// by [`COST_DECAY`] per frame of age, with the running mean absolute residual.
#[derive(Clone, Copy, Debug, Default)]
struct CostLine {
    w: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
    /// Mean absolute residual.
    dev: f64,
}

impl CostLine {
    fn observe(&mut self, x: f64, y: f64) {
        if !(x.is_finite() && y.is_finite() && x >= 0.0 && y >= 0.0) {
            return;
        }
        if self.w > 0.0 {
            let (a, b) = self.fit();
            self.dev = COST_DECAY * self.dev + (1.0 - COST_DECAY) * (y - a - b * x).abs();
        } else {
            self.dev = 0.25 * y;
        }
        for s in [
            &mut self.w,
            &mut self.sx,
            &mut self.sy,
            &mut self.sxx,
            &mut self.sxy,
        ] {
            *s *= COST_DECAY;
        }
        self.w += 1.0;
        self.sx += x;
        self.sy += y;
        self.sxx += x * x;
        self.sxy += x * y;
    }

    /// `(a, b)`, both ≥ 0; all of the cost per unit of `x` while the frames' `x` hardly vary.
    fn fit(&self) -> (f64, f64) {
        let spread = self.w * self.sxx - self.sx * self.sx;
        let proportional = (
            0.0,
            if self.sx > 0.0 {
                self.sy / self.sx
            } else {
                0.0
            },
        );
        if spread <= 1e-3 * self.w * self.sxx {
            return proportional;
        }
        let b = (self.w * self.sxy - self.sx * self.sy) / spread;
        let a = (self.sy - b * self.sx) / self.w;
        if a < 0.0 || b < 0.0 {
            proportional
        } else {
            (a, b)
        }
    }
}

/// Chooses a frame's training records so that producing and training them fits a time budget
/// (NVIDIA's NRC SDK fixes a per-frame training budget; this one adapts the records to it).
///
/// The cost of a frame is modelled as `a_p + b_p·records` for producing (with the change
/// score's prediction) and `a_t + b_t·records·steps` for training, each line fitted to the
/// recent frames (weighted least squares: the fixed parts are the per-frame work that does not grow with
/// the records, such as preparing the inference weights). A frame plans its records so that
/// the two lines plus twice their mean absolute residuals fit what it spends:
/// [`SETTLED_SHARE`] of the budget while the cache is settled, all of it otherwise, changing
/// by at most a factor of two from one frame to the next. The first frame is not measured (it
/// pays for allocations: 93 ms for 4,096 records on `ajar` against 7 ms for 2,048 in the next,
/// which as a point of the fit held the records at the minimum for 20 frames); the second and
/// third take the starting records and half of them, so that the fit sees two sizes.
#[derive(Clone, Debug)]
pub struct TrainBudget {
    budget_ms: f64,
    /// Records of the first frame (before any cost is measured).
    first_records: usize,
    produce: CostLine,
    train: CostLine,
    /// Frames seen, and the records of the last.
    frames: u32,
    last_records: usize,
}

/// One frame's plan.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FramePlan {
    /// Records to produce.
    pub records: usize,
    /// Milliseconds the frame may spend on them.
    pub spend_ms: f64,
}

impl TrainBudget {
    /// A budget of `budget_ms` per frame (finite and > 0), starting at `first_records`.
    pub fn new(budget_ms: f64, first_records: usize) -> Self {
        Self {
            budget_ms,
            first_records: first_records.clamp(MIN_BUDGET_RECORDS, MAX_BUDGET_RECORDS),
            produce: CostLine::default(),
            train: CostLine::default(),
            frames: 0,
            last_records: first_records,
        }
    }

    pub fn budget_ms(&self) -> f64 {
        self.budget_ms
    }

    /// The records of the next frame, which takes `steps` steps on each record and finds the
    /// cache `settled` or not.
    pub fn plan(&self, steps: u32, settled: bool) -> FramePlan {
        let spend_ms = self.budget_ms * if settled { SETTLED_SHARE } else { 1.0 };
        let records = match self.frames {
            0 | 1 => self.first_records,
            2 => self.first_records / 2,
            _ => {
                let ((ap, bp), (at, bt)) = (self.produce.fit(), self.train.fit());
                let fixed = ap + at + 2.0 * (self.produce.dev + self.train.dev);
                let per_record = bp + f64::from(steps) * bt;
                let fit = if per_record > 0.0 {
                    ((spend_ms - fixed).max(0.0) / per_record) as usize
                } else {
                    MAX_BUDGET_RECORDS
                };
                fit.clamp(self.last_records / 2, self.last_records.saturating_mul(2))
            }
        };
        FramePlan {
            records: records.clamp(MIN_BUDGET_RECORDS, MAX_BUDGET_RECORDS),
            spend_ms,
        }
    }

    /// Learns from a frame that produced `records` in `produce_ms` and trained them `steps`
    /// times in `train_ms`.
    pub fn observe(&mut self, records: usize, steps: u32, produce_ms: f64, train_ms: f64) {
        if records == 0 {
            return;
        }
        self.frames += 1;
        self.last_records = records;
        if self.frames == 1 {
            return;
        }
        self.produce.observe(records as f64, produce_ms);
        self.train
            .observe((records * steps as usize) as f64, train_ms);
    }
}
