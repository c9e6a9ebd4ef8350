//! k-nearest-neighbour distances among points in space, for density estimation on surfaces
//! (the VPL densities of instant radiosity, Hedman et al. eq. 7: `p(y) ≈ k / (N π r_k(y)²)`,
//! the `k` nearest neighbours assumed to lie on one plane with `y`, as photon mapping does).
//!
//! A uniform grid over the points' bounds with cells about two mean spacings wide on a surface
//! (`√(A/N)`, `A` the bounds' surface area as a stand-in for the surfaces'), searched in rings
//! of cells until the `k`-th distance found is closer than any unsearched cell.

use std::collections::HashMap;

use glam::{IVec3, Vec3};

/// Points indexed for nearest-neighbour queries.
pub struct PointGrid {
    points: Vec<Vec3>,
    min: Vec3,
    cell: f32,
    cells: HashMap<IVec3, Vec<u32>>,
    /// The largest ring worth searching (the grid's extent in cells).
    max_ring: i32,
}

impl PointGrid {
    /// The grid over `points` (none may be non-finite).
    pub fn new(points: &[Vec3]) -> Self {
        let (min, max) = points
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        let ext = if points.is_empty() {
            Vec3::ONE
        } else {
            (max - min).max(Vec3::splat(1e-6))
        };
        let area = 2.0 * (ext.x * ext.y + ext.y * ext.z + ext.z * ext.x);
        let cell = (2.0 * (area / points.len().max(1) as f32).sqrt())
            .max(ext.max_element() / 1024.0)
            .max(1e-6);
        let mut cells: HashMap<IVec3, Vec<u32>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            cells
                .entry(((*p - min) / cell).floor().as_ivec3())
                .or_default()
                .push(i as u32);
        }
        let max_ring = (ext.max_element() / cell).ceil() as i32 + 1;
        Self {
            points: points.to_vec(),
            min,
            cell,
            cells,
            max_ring,
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The squared distance from `q` to its `k`-th nearest point, point `exclude` left out
    /// (a point is not its own neighbour); infinite when fewer than `k` points remain.
    pub fn kth_distance2(&self, q: Vec3, k: usize, exclude: Option<usize>) -> f32 {
        let k = k.max(1);
        let centre = ((q - self.min) / self.cell).floor().as_ivec3();
        // The k smallest squared distances so far, ascending.
        let mut best: Vec<f32> = Vec::with_capacity(k + 1);
        for ring in 0..=self.max_ring {
            for dz in -ring..=ring {
                for dy in -ring..=ring {
                    for dx in -ring..=ring {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                            continue;
                        }
                        let Some(list) = self.cells.get(&(centre + IVec3::new(dx, dy, dz))) else {
                            continue;
                        };
                        for &i in list {
                            if Some(i as usize) == exclude {
                                continue;
                            }
                            let d2 = (self.points[i as usize] - q).length_squared();
                            if best.len() < k || d2 < best[k - 1] {
                                let at = best.partition_point(|&b| b <= d2);
                                best.insert(at, d2);
                                best.truncate(k);
                            }
                        }
                    }
                }
            }
            // Points in later rings lie at least `ring · cell` away.
            let reach = ring as f32 * self.cell;
            if best.len() == k && best[k - 1] <= reach * reach {
                break;
            }
        }
        if best.len() == k {
            best[k - 1]
        } else {
            f32::INFINITY
        }
    }

    /// Eq. 7 of Hedman et al.: the density (per unit area) of `n` points at `q` from its
    /// `k`-th nearest neighbour, `k / (n π r_k²)`.
    pub fn density(&self, q: Vec3, k: usize, n: usize, exclude: Option<usize>) -> f32 {
        let r2 = self.kth_distance2(q, k, exclude);
        if r2 > 0.0 && r2.is_finite() {
            k as f32 / (n.max(1) as f32 * std::f32::consts::PI * r2)
        } else if r2 == 0.0 {
            f32::INFINITY
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::PixelSampler;

    #[test]
    fn nearest_distances_match_brute_force() {
        let mut s = PixelSampler::new(3, 0, 0);
        let pts: Vec<Vec3> = (0..500)
            .map(|_| Vec3::new(s.next_1d(), s.next_1d() * 0.1, s.next_1d()))
            .collect();
        let grid = PointGrid::new(&pts);
        for q in 0..50 {
            for k in [1, 3, 8] {
                let mut d: Vec<f32> = pts
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| *i != q)
                    .map(|(_, p)| (*p - pts[q]).length_squared())
                    .collect();
                d.sort_by(f32::total_cmp);
                assert_eq!(grid.kth_distance2(pts[q], k, Some(q)), d[k - 1]);
            }
        }
        assert_eq!(grid.kth_distance2(Vec3::ZERO, 501, None), f32::INFINITY);
    }
}

/// Eq. 7 on uniform points of a plane (issue 19): for a Poisson process of density `ρ`,
/// `N π r_k² ρ` is Gamma(k, 1), so the mean of `1/p̂` is exactly `1/ρ` (the area) and the mean of
/// `p̂` is `k/(k − 1) · ρ`. 4096 uniform points on the unit square, queried at those at least
/// 0.1 from its edges (no neighbour missing beyond an edge).
#[cfg(test)]
mod density_tests {
    use super::*;
    use crate::sampler::PixelSampler;

    #[test]
    fn knn_density_of_uniform_points_on_a_plane_is_one_over_the_area() {
        let n = 4096;
        let mut s = PixelSampler::new(7, 0, 0);
        let pts: Vec<Vec3> = (0..n)
            .map(|_| Vec3::new(s.next_1d(), 0.25, s.next_1d()))
            .collect();
        let grid = PointGrid::new(&pts);
        for k in [1usize, 8] {
            let (mut inv, mut direct, mut m) = (0.0f64, 0.0f64, 0);
            for (i, p) in pts.iter().enumerate() {
                if p.x < 0.1 || p.x > 0.9 || p.z < 0.1 || p.z > 0.9 {
                    continue;
                }
                let d = f64::from(grid.density(*p, k, n, Some(i)));
                inv += 1.0 / d;
                direct += d;
                m += 1;
            }
            let (inv, direct) = (inv / m as f64, direct / m as f64);
            println!("k = {k}: mean 1/p = {inv:.4} (area 1), mean p = {direct:.4}");
            // The mean of 1/p over m queries has a standard error of about 1/√(k·m) (a
            // Gamma(k)/k variable per query; neighbouring queries share points, which this
            // ignores): within 4 of them.
            let bound = 4.0 / ((k * m) as f64).sqrt();
            assert!(
                (inv - 1.0).abs() < bound,
                "k = {k}: mean 1/p {inv}, bound {bound}"
            );
            if k > 1 {
                let expected = k as f64 / (k as f64 - 1.0);
                assert!(
                    (direct / expected - 1.0).abs() < 0.05,
                    "k = {k}: mean p {direct}"
                );
            }
            // Negative control: a wrong point count (as if the VPL budget, not the points
            // present, were eq. 7's I) doubles 1/p and must fail the same bound.
            let wrong: f64 = pts
                .iter()
                .enumerate()
                .filter(|(_, p)| p.x >= 0.1 && p.x <= 0.9 && p.z >= 0.1 && p.z <= 0.9)
                .map(|(i, p)| 1.0 / f64::from(grid.density(*p, k, 2 * n, Some(i))))
                .sum::<f64>()
                / m as f64;
            assert!(
                (wrong - 1.0).abs() >= bound,
                "k = {k}: a wrong count passed ({wrong})"
            );
        }
    }
}
