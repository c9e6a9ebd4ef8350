//! The world-space hash grid of world-space ReSTIR GI (`world-space-restir-gi.txt`, §4.2 and
//! §5.2, eqs. 8–11): path-vertex samples binned by position and normal, so that a vertex can
//! reuse the samples of every path that passed near it, whichever pixel it came from.
//!
//! - **Cell size** (eq. 11): `d_c = d_v · tan(max(fov/R_x, fov · R_x/R_y²) · s)` with `d_v` the
//!   vertex's distance to the camera, `fov` the vertical field of view and `s` the projected
//!   cell size in pixels (the paper: 10 % of the resolution, here `cell_scale · R_x`), then
//!   snapped down to `d_min · 2^k` (`d_min`: 1 % of the scene box's smallest extent, `k ≥ 0`),
//!   so the cell doubles with each doubling of the distance, in steps.
//! - **Key** (eqs. 9–10): the integer cell coordinates `⌊p/d⌋`, the level `k` and the normal
//!   quantised to 3 levels per axis (`d_n = 2`, 2 bits each) hashed together; opposite normals
//!   never share a key. Lookups jitter the position by up to half a cell per axis (§5.3), so
//!   that cell borders do not show.
//! - **Collisions**: the GPU paper hashes keys into a table with linear probing and a checksum.
//!   Here the table is built on the CPU, deterministically: entries are sorted by (key, entry
//!   index), each distinct key becomes one cell (a range of the sorted entries), and cells are
//!   placed in an open-addressing table (slot = a second hash of the key, linear probing) that
//!   stores the full 64-bit key, so a lookup never confuses two cells unless their 64-bit keys
//!   collide. The order inside a cell is the entry order: the same for every thread count.

use glam::{IVec3, Vec3};
use nrc_scene::{Aabb, Camera};

/// Parameters of the cell-size rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellRule {
    pub camera_position: Vec3,
    /// Angle subtended per unit of projected cell size: `max(fov/R_x, fov · R_x/R_y²)`.
    pub angle_per_pixel: f32,
    /// Projected cell size `s`, pixels.
    pub cell_pixels: f32,
    /// The smallest cell, `d_min`.
    pub d_min: f32,
}

impl CellRule {
    /// The rule for a `width × height` frame of `camera` over scene box `bounds`, with the
    /// projected cell size `cell_scale · width` pixels and `d_min = d_min_fraction` times the
    /// box's smallest extent.
    pub fn new(
        camera: &Camera,
        width: u32,
        height: u32,
        bounds: &Aabb,
        cell_scale: f32,
        d_min_fraction: f32,
    ) -> Self {
        let (rx, ry) = (width.max(1) as f32, height.max(1) as f32);
        let ext = bounds.max - bounds.min;
        let smallest = ext.min_element().max(1e-3 * ext.max_element()).max(1e-6);
        Self {
            camera_position: camera.position,
            angle_per_pixel: (camera.fov_y / rx).max(camera.fov_y * rx / (ry * ry)),
            cell_pixels: cell_scale * rx,
            d_min: d_min_fraction * smallest,
        }
    }

    /// Eq. 11 with its snap: the cell size at `p` and its level `k` (`d = d_min · 2^k`).
    #[inline]
    pub fn cell_size(&self, p: Vec3) -> (f32, i32) {
        let d_v = (p - self.camera_position).length();
        let d_c = d_v * (self.angle_per_pixel * self.cell_pixels).tan();
        let k = if d_c > self.d_min && d_c.is_finite() {
            (d_c / self.d_min).log2().floor() as i32
        } else {
            0
        };
        let k = k.clamp(0, 40);
        (self.d_min * (k as f32).exp2(), k)
    }

    /// The key of the cell holding `p` (offset by `jitter` cells, each component in
    /// `[-0.5, 0.5)`) with normal `n`.
    #[inline]
    pub fn key(&self, p: Vec3, n: Vec3, jitter: Vec3) -> u64 {
        let (d, k) = self.cell_size(p);
        let c = ((p / d) + jitter).floor();
        let c = IVec3::new(c.x as i32, c.y as i32, c.z as i32);
        cell_key(c, k, quantise_normal(n))
    }
}

/// Eq. 10: each component of the unit normal `n` mapped from `[-1, 1]` to one of 3 levels
/// (`d_n = 2`), packed 2 bits per axis.
#[inline]
pub fn quantise_normal(n: Vec3) -> u32 {
    let q = |x: f32| ((((x + 1.0) * 0.5) * 2.0).floor() as i32).clamp(0, 2) as u32;
    (q(n.x) << 4) | (q(n.y) << 2) | q(n.z)
}

/// PCG-style 64-bit mix (the hash of eqs. 8–9, `H1`).
#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 33)).wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    z = (z ^ (z >> 33)).wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    z ^ (z >> 33)
}

/// Eq. 9: the cell coordinates, the level and the quantised normal hashed in a chain.
#[inline]
pub fn cell_key(c: IVec3, level: i32, normal: u32) -> u64 {
    let h = mix(c.z as u32 as u64);
    let h = mix(h ^ (c.y as u32 as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let h = mix(h ^ (c.x as u32 as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    let h = mix(h ^ (level as u32 as u64).wrapping_mul(0xA24B_AED4_963E_E407));
    mix(h ^ (normal as u64 + 1).wrapping_mul(0x9FB2_1C65_1E98_DF25))
}

const EMPTY: u32 = u32::MAX;

/// The grid: cells of entry indices, found by key.
#[derive(Clone, Debug, Default)]
pub struct HashGrid {
    /// Open-addressing table: the cell index in each slot, or `EMPTY`.
    slots: Vec<u32>,
    /// Per cell: its key and its range in `order`.
    cells: Vec<(u64, u32, u32)>,
    /// Entry indices, sorted by (key, index).
    order: Vec<u32>,
    /// The slot hash the table was built with (`None`: the default).
    slot_hash: Option<fn(u64) -> u64>,
}

impl HashGrid {
    /// The grid over entries `0..keys.len()`, entry `i` in the cell of `keys[i]`.
    pub fn build(keys: &[u64]) -> Self {
        Self::build_with(keys, mix)
    }

    /// [`HashGrid::build`] with another slot hash (tests force collisions with it).
    pub fn build_with(keys: &[u64], slot_hash: fn(u64) -> u64) -> Self {
        let mut sorted: Vec<(u64, u32)> = keys
            .iter()
            .enumerate()
            .map(|(i, &k)| (k, i as u32))
            .collect();
        sorted.sort_unstable();
        let mut cells = Vec::new();
        let mut start = 0;
        for i in 1..=sorted.len() {
            if i == sorted.len() || sorted[i].0 != sorted[start].0 {
                cells.push((sorted[start].0, start as u32, (i - start) as u32));
                start = i;
            }
        }
        let size = (2 * cells.len()).next_power_of_two().max(16);
        let mut slots = vec![EMPTY; size];
        for (c, &(key, _, _)) in cells.iter().enumerate() {
            let mut s = (slot_hash(key) as usize) & (size - 1);
            while slots[s] != EMPTY {
                s = (s + 1) & (size - 1);
            }
            slots[s] = c as u32;
        }
        Self {
            slots,
            cells,
            order: sorted.into_iter().map(|(_, i)| i).collect(),
            slot_hash: Some(slot_hash),
        }
    }

    /// The entries in the cell of `key` (empty where no entry has it).
    pub fn find(&self, key: u64) -> &[u32] {
        if self.slots.is_empty() {
            return &[];
        }
        let size = self.slots.len();
        let hash = self.slot_hash.unwrap_or(mix);
        let mut s = (hash(key) as usize) & (size - 1);
        loop {
            let c = self.slots[s];
            if c == EMPTY {
                return &[];
            }
            let (k, begin, count) = self.cells[c as usize];
            if k == key {
                return &self.order[begin as usize..(begin + count) as usize];
            }
            s = (s + 1) & (size - 1);
        }
    }

    /// Cells in the grid.
    pub fn cell_count(&self) -> usize {
        self.cells.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rule() -> CellRule {
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0).unwrap();
        let bounds = Aabb {
            min: Vec3::splat(-1.0),
            max: Vec3::splat(1.0),
        };
        CellRule::new(&camera, 128, 128, &bounds, 0.1, 0.01)
    }

    #[test]
    fn a_points_key_is_stable_inside_its_cell_and_opposite_normals_separate() {
        let r = rule();
        let p = Vec3::new(0.1234, -0.271, 0.05);
        let (d, _) = r.cell_size(p);
        let corner = (p / d).floor() * d;
        let n = Vec3::new(0.3, 0.9, 0.3).normalize();
        let key = r.key(p, n, Vec3::ZERO);
        for f in [0.01f32, 0.3, 0.6, 0.99] {
            let q = corner + Vec3::splat(f * d);
            assert_eq!(r.cell_size(q).1, r.cell_size(p).1, "same level");
            assert_eq!(r.key(q, n, Vec3::ZERO), key, "inside the cell at {f}");
        }
        assert_ne!(
            r.key(corner + Vec3::splat(1.01 * d), n, Vec3::ZERO),
            key,
            "next cell"
        );
        assert_ne!(r.key(p, -n, Vec3::ZERO), key, "opposite normal");
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            assert_ne!(quantise_normal(axis), quantise_normal(-axis));
        }
    }

    #[test]
    fn the_cell_size_doubles_where_eq_11_says() {
        let r = rule();
        let (d0, k0) = r.cell_size(r.camera_position + Vec3::new(0.0, 0.0, -1.0));
        assert!((d0 - r.d_min * (k0 as f32).exp2()).abs() < 1e-6);
        // d_c grows linearly with distance; the snapped size is d_min 2^⌊log2(d_c/d_min)⌋.
        for dist in [0.5f32, 1.0, 2.0, 3.0, 4.0, 8.0, 16.0] {
            let (d, k) = r.cell_size(r.camera_position + Vec3::new(0.0, 0.0, -dist));
            let d_c = dist * (r.angle_per_pixel * r.cell_pixels).tan();
            let expect = (d_c / r.d_min).log2().floor().max(0.0) as i32;
            assert_eq!(k, expect, "distance {dist}");
            assert!(
                d <= d_c.max(r.d_min) * 1.0001 && (d_c < r.d_min || 2.0 * d > d_c),
                "distance {dist}: {d} vs {d_c}"
            );
        }
        let (_, k1) = r.cell_size(r.camera_position + Vec3::new(0.0, 0.0, -3.0));
        let (_, k2) = r.cell_size(r.camera_position + Vec3::new(0.0, 0.0, -6.0));
        assert_eq!(k2, k1 + 1, "twice the distance, twice the cell");
    }

    #[test]
    fn every_entry_is_found_under_forced_collisions() {
        let keys: Vec<u64> = (0..200u64).map(|i| mix(i % 37)).collect();
        for grid in [HashGrid::build(&keys), HashGrid::build_with(&keys, |_| 0)] {
            assert_eq!(grid.cell_count(), 37);
            for (i, &k) in keys.iter().enumerate() {
                let cell = grid.find(k);
                assert!(cell.contains(&(i as u32)), "entry {i}");
                assert!(cell.iter().all(|&j| keys[j as usize] == k));
                assert!(cell.windows(2).all(|w| w[0] < w[1]), "entry order");
            }
            assert!(grid.find(mix(1000)).is_empty(), "a key not in the grid");
        }
    }
}
