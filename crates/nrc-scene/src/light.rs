//! Area lights: every triangle whose material emits is a light. Lights are chosen in
//! proportion to their emitted power, then a point is chosen uniformly on the triangle,
//! so the density of a light point in area measure is `pmf(triangle) / area(triangle)`.

use glam::{Vec2, Vec3};

/// A point sampled on an emissive triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSample {
    /// Position on the light.
    pub p: Vec3,
    /// Unit geometric normal of the light triangle (counter-clockwise winding side).
    pub n: Vec3,
    /// Surface texture coordinates at `p`.
    pub uv: Vec2,
    /// Emitted radiance of the front face at `p` (emissive factor × texture × strength).
    /// Use [`LightSample::le_toward`] for the radiance leaving toward a shading point.
    pub le: Vec3,
    /// Whether the back face emits as well (the material is `doubleSided`).
    pub two_sided: bool,
    /// Density of `p` with respect to area: selection probability / triangle area.
    pub pdf_area: f32,
    /// Scene triangle index of the light.
    pub tri: u32,
}

impl LightSample {
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

/// Selection of emissive triangles in proportion to their power.
///
/// The power of a triangle is `luminance(mean Le) × area × (2 if two-sided)` (the common
/// factor π of a Lambertian emitter is left out). The table stores the cumulative
/// distribution for sampling and, per scene triangle, the area density for multiple
/// importance sampling.
#[derive(Clone, Debug, Default)]
pub struct LightSampler {
    /// Scene triangle index of each light.
    tris: Vec<u32>,
    /// Cumulative power, normalised so the last entry is 1.
    cdf: Vec<f32>,
    /// Selection probability of each light.
    pmf: Vec<f32>,
    /// Per scene triangle: selection probability / area (0 for triangles that never emit).
    pdf_area: Vec<f32>,
    total_power: f64,
}

impl LightSampler {
    /// Builds the sampler for a scene of `n_triangles` triangles from the emissive ones:
    /// `(triangle index, area, power)`. Entries with zero or non-finite power or area are
    /// skipped.
    pub fn new(n_triangles: usize, emitters: &[(u32, f32, f32)]) -> Self {
        let mut lights: Vec<(u32, f32, f32)> = emitters
            .iter()
            .copied()
            .filter(|&(_, area, power)| {
                area > 0.0 && power > 0.0 && area.is_finite() && power.is_finite()
            })
            .collect();
        lights.sort_by_key(|l| l.0);
        lights.dedup_by_key(|l| l.0);
        let total: f64 = lights.iter().map(|l| l.2 as f64).sum();
        let mut tris = Vec::with_capacity(lights.len());
        let mut cdf = Vec::with_capacity(lights.len());
        let mut pmf = Vec::with_capacity(lights.len());
        let mut pdf_area = vec![0.0; n_triangles];
        let mut acc = 0.0f64;
        for &(tri, area, power) in &lights {
            let p = power as f64 / total;
            acc += power as f64;
            tris.push(tri);
            pmf.push(p as f32);
            cdf.push((acc / total) as f32);
            pdf_area[tri as usize] = (p / area as f64) as f32;
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        Self {
            tris,
            cdf,
            pmf,
            pdf_area,
            total_power: total,
        }
    }

    /// Number of lights (emissive triangles with non-zero power).
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// True when the scene has no emissive triangle.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Sum of the lights' powers (luminance × area, ×2 for two-sided).
    pub fn total_power(&self) -> f64 {
        self.total_power
    }

    /// Chooses a light with `u` uniform in `[0, 1)`: `(scene triangle index, probability)`.
    #[inline]
    pub fn select(&self, u: f32) -> Option<(u32, f32)> {
        if self.tris.is_empty() {
            return None;
        }
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .min(self.tris.len() - 1);
        Some((self.tris[i], self.pmf[i]))
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

    /// The lights' scene triangle indices, in increasing order.
    pub fn triangles(&self) -> &[u32] {
        &self.tris
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selection_follows_power() {
        let s = LightSampler::new(5, &[(1, 2.0, 1.0), (3, 1.0, 3.0), (4, 1.0, 0.0)]);
        assert_eq!(s.len(), 2);
        assert_eq!(s.select(0.0), Some((1, 0.25)));
        assert_eq!(s.select(0.2499), Some((1, 0.25)));
        assert_eq!(s.select(0.25), Some((3, 0.75)));
        assert_eq!(s.select(0.9999999), Some((3, 0.75)));
        assert_eq!(s.pmf(3), 0.75);
        assert_eq!(s.pmf(4), 0.0);
        assert!((s.pdf_area(1) - 0.125).abs() < 1e-7);
        assert_eq!(s.pdf_area(0), 0.0);
        assert_eq!(s.pdf_area(99), 0.0);
    }
}
