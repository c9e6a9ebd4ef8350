//! Reservoirs and resampled importance sampling (RIS), generic over the sample type: the core
//! of ReSTIR (Bitterli et al. 2020; the seed paper `world-space-restir-gi.txt`, §3, eqs. 3–6,
//! and its Alg. 1 for streaming).
//!
//! A reservoir keeps one sample `y` out of a stream of candidates, each taken with probability
//! proportional to its resampling weight `w`, together with the weights' sum and the number
//! of candidates `M` it stands for. With target function `p̂`, the selected sample's
//! *unbiased contribution weight* is `W = w_sum / (Z p̂(y))`, where `Z` is `M` for plain RIS
//! (candidates `x_i ~ p_i`, `w_i = p̂(x_i)/p_i(x_i)`, eq. 5) and, when reservoirs of other
//! pixels or frames are merged, the count of candidates whose domain could have produced `y`
//! (Bitterli et al. 2020, eq. 16, Alg. 6) — or `Σ M` in the biased mode. `f(y) W` then
//! estimates `∫ f`.
//!
//! Candidates drawn from several strategies `t` (light sampling, BSDF sampling) use the
//! balance-heuristic weight `w = p̂(x) / Σ_t M_t p_t(x)` with `M` already folded in: such
//! reservoirs are finished with [`Reservoir::finish_normalised`] (`Z = 1`).

/// One reservoir: the selected sample, its target value, the weight sum, the candidate count
/// and (once finished) the unbiased contribution weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reservoir<T> {
    /// The selected sample (`None`: no candidate with positive weight yet).
    pub sample: Option<T>,
    /// Target function value `p̂(y)` of the selected sample at the reservoir's owner.
    pub target: f32,
    /// Sum of the resampling weights streamed in.
    pub w_sum: f32,
    /// Candidates this reservoir stands for (a real number: M-capping scales it).
    pub m: f32,
    /// Unbiased contribution weight `W` of the sample (valid after a `finish`).
    pub w: f32,
}

impl<T> Default for Reservoir<T> {
    fn default() -> Self {
        Self {
            sample: None,
            target: 0.0,
            w_sum: 0.0,
            m: 0.0,
            w: 0.0,
        }
    }
}

impl<T: Copy> Reservoir<T> {
    /// An empty reservoir.
    pub fn new() -> Self {
        Self::default()
    }

    /// Streams one candidate in with resampling weight `weight` and target value `target`
    /// (`p̂` at this reservoir's owner); `u` uniform in `[0, 1)` decides whether it replaces
    /// the selected sample (with probability `weight / w_sum`). Counts one candidate.
    /// Non-positive or non-finite weights are counted but never selected. Returns whether it
    /// was selected.
    #[inline]
    pub fn update(&mut self, sample: T, weight: f32, target: f32, u: f32) -> bool {
        self.m += 1.0;
        self.offer(sample, weight, target, u)
    }

    /// [`Reservoir::update`] without counting a candidate (merging counts `M` itself).
    #[inline]
    fn offer(&mut self, sample: T, weight: f32, target: f32, u: f32) -> bool {
        if !(weight > 0.0 && weight.is_finite()) {
            return false;
        }
        self.w_sum += weight;
        if u * self.w_sum < weight {
            self.sample = Some(sample);
            self.target = target;
            true
        } else {
            false
        }
    }

    /// Merges `other` (a finished reservoir of another pixel or frame) into this one: its
    /// sample enters with weight `p̂_here(y) · W · M`, where `target_here` is `p̂_here(y)`, the
    /// target at *this* reservoir's owner (the Jacobian of a shift between the two domains
    /// already folded in, for GI); `M` adds up. Returns whether its sample was selected.
    #[inline]
    pub fn merge(&mut self, other: &Reservoir<T>, target_here: f32, u: f32) -> bool {
        self.merge_shifted(other, target_here, 1.0, u)
    }

    /// [`Reservoir::merge`] of a sample shifted from the other reservoir's domain into this
    /// one's: `jacobian` is `|∂y_here/∂y_there|` (for GI reconnection, the ratio of solid
    /// angles, [`crate::passes::restir_gi::reconnection_jacobian`]), which carries the other
    /// reservoir's `W` into this domain's measure (Ouyang et al. 2021, eq. 11; Lin et al. 2022).
    #[inline]
    pub fn merge_shifted(
        &mut self,
        other: &Reservoir<T>,
        target_here: f32,
        jacobian: f32,
        u: f32,
    ) -> bool {
        self.m += other.m;
        match other.sample {
            Some(s) => self.offer(
                s,
                target_here * jacobian * other.w * other.m,
                target_here,
                u,
            ),
            None => false,
        }
    }

    /// Merges `other` with a resampling weight the caller computed (generalised RIS:
    /// `m(y) · p̂_here(y) · W · J`, the MIS weight `m` holding the confidence); `M` adds up.
    /// Finish with [`Reservoir::finish_normalised`]. Returns whether its sample was selected.
    #[inline]
    pub fn merge_weighted(
        &mut self,
        other: &Reservoir<T>,
        weight: f32,
        target_here: f32,
        u: f32,
    ) -> bool {
        self.m += other.m;
        match other.sample {
            Some(s) => self.offer(s, weight, target_here, u),
            None => false,
        }
    }

    /// Finishes with `W = w_sum / (z · p̂(y))`: `z = M` for plain RIS and biased merging, the
    /// count of candidates whose domains hold `y` for unbiased merging. Zero without a sample
    /// or where `z` or `p̂(y)` is not positive.
    #[inline]
    pub fn finish(&mut self, z: f32) {
        let d = z * self.target;
        self.w = if self.sample.is_some() && d > 0.0 && d.is_finite() {
            self.w_sum / d
        } else {
            0.0
        };
        if !self.w.is_finite() {
            self.w = 0.0;
        }
    }

    /// Finishes a reservoir whose candidate weights already hold the `1/M` (balance-heuristic
    /// RIS over several strategies): `W = w_sum / p̂(y)`.
    #[inline]
    pub fn finish_normalised(&mut self) {
        self.finish(1.0);
    }

    /// Caps the candidate count at `m_max` (the history's weight in temporal reuse), scaling
    /// `w_sum` with it so that `W` is unchanged.
    #[inline]
    pub fn cap(&mut self, m_max: f32) {
        if self.m > m_max && m_max > 0.0 {
            self.w_sum *= m_max / self.m;
            self.m = m_max;
        }
    }

    /// Drops the sample (visibility reuse: a sample found occluded at its owner lights
    /// nothing there), keeping `M`.
    #[inline]
    pub fn clear_sample(&mut self) {
        self.sample = None;
        self.w = 0.0;
        self.target = 0.0;
        self.w_sum = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capping_keeps_the_contribution_weight() {
        let mut r = Reservoir::new();
        for i in 0..50 {
            r.update(i, 1.0 + i as f32, 2.0, 0.37);
        }
        r.finish(r.m);
        let w = r.w;
        r.cap(10.0);
        assert_eq!(r.m, 10.0);
        let mut r2 = r;
        r2.finish(r2.m);
        assert!((r2.w - w).abs() <= 1e-5 * w, "{} vs {w}", r2.w);
    }

    #[test]
    fn bad_weights_are_never_selected() {
        let mut r = Reservoir::new();
        for w in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert!(!r.update(1u8, w, 1.0, 0.0));
        }
        assert_eq!(r.sample, None);
        assert_eq!(r.m, 4.0);
        r.finish(r.m);
        assert_eq!(r.w, 0.0);
    }
}
