//! The area-spread heuristic of Müller et al. 2021 ("Real-time Neural Radiance Caching for Path
//! Tracing", §3.3): a path ends in the cache once the footprint its vertices spread over is
//! large enough to blur the cache's own errors.
//!
//! With vertices `x0` (camera or the suffix's start), `x1`, ..., the spread of the path up to
//! `xn` is `a(x1…xn) = (Σ_{i=2..n} √(‖x_{i−1} − x_i‖² / (p(ω_{i−1}) |cos θ_i|)))²` and the
//! reference footprint is `a0 = ‖x0 − x1‖² / (4π |cos θ1|)`. The path terminates at `xn` when
//! `a(x1…xn) > c · a0` (`c = 0.01` in the paper). Delta scattering (infinite density) adds no
//! spread.

/// The running spread of one path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    c: f32,
    a0: Option<f32>,
    sum: f32,
}

impl Spread {
    /// A fresh path with threshold `c`.
    pub fn new(c: f32) -> Self {
        Self {
            c,
            a0: None,
            sum: 0.0,
        }
    }

    /// Adds the segment that reached a vertex: its squared length, the solid-angle density of
    /// its direction at the previous vertex (`None` for the first segment, or for delta
    /// scattering) and the cosine at the new vertex. Returns whether the path should end in the
    /// cache at the new vertex.
    pub fn arrive(&mut self, dist2: f32, pdf: Option<f32>, cos: f32) -> bool {
        let cos = cos.abs().max(1e-4);
        match self.a0 {
            None => {
                self.a0 = Some(dist2 / (4.0 * std::f32::consts::PI * cos));
                false
            }
            Some(a0) => {
                if let Some(p) = pdf.filter(|p| p.is_finite() && *p > 0.0) {
                    self.sum += (dist2 / (p * cos)).sqrt();
                }
                self.sum * self.sum > self.c * a0
            }
        }
    }

    /// Starts a new measurement from the current vertex (training suffixes): the next
    /// segment becomes the reference footprint.
    pub fn restart(&mut self) {
        *self = Self::new(self.c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terminates_when_the_spread_exceeds_c_a0() {
        let mut s = Spread::new(0.01);
        // a0 = 1 / (4π).
        assert!(!s.arrive(1.0, None, 1.0));
        // One diffuse bounce of length 0.1 with pdf 1/π: spread 0.1² π ≈ 0.0314 > 0.01/(4π).
        assert!(s.arrive(0.01, Some(1.0 / std::f32::consts::PI), 1.0));
        // A very sharp lobe spreads little.
        let mut s = Spread::new(0.01);
        s.arrive(1.0, None, 1.0);
        assert!(!s.arrive(0.01, Some(1e6), 1.0));
        // Delta scattering adds nothing.
        assert!(!s.arrive(100.0, None, 1.0));
    }
}
