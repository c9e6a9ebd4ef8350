//! Query prediction: the rays whose first hits become training queries.
//!
//! NRC trains where the next frame will query the cache. Two sources, mixed by a fraction:
//! camera primary hits through jittered tiles (the image cut into `n` near-square tiles, one
//! uniformly placed ray per tile), and the previous frame's inference termination points
//! (re-entered along the segment that reached them, so their training paths continue from
//! the same incoming direction).

use glam::Vec2;
use nrc_render::PixelSampler;
pub use nrc_render::passes::TerminationPoint;
use nrc_render::sampler::Stream;
use nrc_scene::{Camera, Ray};

/// A training path's first segment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StartRay {
    pub ray: Ray,
}

/// `n` camera rays, one per tile of a near-square tiling of the `width × height` image, each at
/// a uniform random position in its tile (stream `seed`).
pub fn camera_tiles(
    camera: &Camera,
    width: u32,
    height: u32,
    n: usize,
    seed: u64,
) -> Vec<StartRay> {
    if n == 0 || width == 0 || height == 0 {
        return Vec::new();
    }
    // Tiles: cols × rows ≥ n with the image's aspect ratio; the first n tiles in a random
    // row-major rotation are used so that every frame covers the image evenly.
    let aspect = width as f64 / height as f64;
    let rows = ((n as f64 / aspect).sqrt().ceil() as usize).max(1);
    let cols = n.div_ceil(rows);
    let tiles = rows * cols;
    let mut s = PixelSampler::new(seed, u64::MAX - 1, 0);
    let offset = (s.next_1d() * tiles as f32) as usize;
    let (tw, th) = (width as f32 / cols as f32, height as f32 / rows as f32);
    (0..n)
        .map(|i| {
            let t = (offset + i) % tiles;
            let (cx, cy) = ((t % cols) as f32, (t / cols) as f32);
            let mut s = PixelSampler::new(seed, i as u64, 1);
            let u = s.next_2d();
            let film = Vec2::new((cx + u.x) * tw, (cy + u.y) * th);
            StartRay {
                ray: camera.generate_ray(film, width, height),
            }
        })
        .collect()
}

/// `n` rays toward termination points chosen uniformly (with replacement) from `points`.
pub fn termination_rays(points: &[TerminationPoint], n: usize, seed: u64) -> Vec<StartRay> {
    if points.is_empty() {
        return Vec::new();
    }
    (0..n)
        .filter_map(|i| {
            let mut s = PixelSampler::new(seed, i as u64, 2);
            let k = ((s.next_1d() * points.len() as f32) as usize).min(points.len() - 1);
            let p = points[k];
            let d = p.to - p.from;
            let len = d.length();
            // Start 1% along the segment: off the previous surface, short of the point.
            (len.is_finite() && len > 0.0).then(|| StartRay {
                ray: Ray::new(p.from + 0.01 * d, d / len),
            })
        })
        .collect()
}

/// The training starts of a frame: `n` rays, a `from_terminations` fraction of them aimed at
/// the previous frame's termination points (when there are any), the rest camera tiles.
pub fn predict(
    camera: &Camera,
    width: u32,
    height: u32,
    previous: &[TerminationPoint],
    from_terminations: f32,
    n: usize,
    seed: u64,
) -> Vec<StartRay> {
    let k = if previous.is_empty() {
        0
    } else {
        ((n as f32 * from_terminations.clamp(0.0, 1.0)).round() as usize).min(n)
    };
    let mut rays = termination_rays(previous, k, Stream::TerminationRays.seed(seed));
    rays.extend(camera_tiles(camera, width, height, n - rays.len(), seed));
    rays
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn tiles_cover_the_image_evenly() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 60.0).unwrap();
        let rays = camera_tiles(&cam, 64, 32, 512, 3);
        assert_eq!(rays.len(), 512);
        // Each quadrant of the image gets a quarter of the rays, within the one-row slack of the
        // tiling.
        let mut quadrants = [0usize; 4];
        for r in &rays {
            let right = r.ray.d.dot(cam.right) > 0.0;
            let up = r.ray.d.dot(cam.up) > 0.0;
            quadrants[right as usize + 2 * up as usize] += 1;
        }
        for q in quadrants {
            assert!((q as i64 - 128).abs() <= 20, "{quadrants:?}");
        }
    }

    #[test]
    fn a_fraction_of_the_starts_aims_at_previous_termination_points() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 60.0).unwrap();
        let points: Vec<TerminationPoint> = (0..10)
            .map(|i| TerminationPoint {
                from: Vec3::new(i as f32, 1.0, 0.0),
                to: Vec3::new(i as f32, 0.0, 0.0),
            })
            .collect();
        let rays = predict(&cam, 32, 32, &points, 0.25, 400, 7);
        assert_eq!(rays.len(), 400);
        // A ray aimed at a termination point starts on its segment and points down (-y); camera
        // rays start at the camera.
        let aimed = rays.iter().filter(|r| r.ray.o != cam.position).count();
        assert_eq!(aimed, 100);
        for r in rays.iter().filter(|r| r.ray.o != cam.position) {
            assert!((r.ray.d - Vec3::new(0.0, -1.0, 0.0)).length() < 1e-6);
            assert!((r.ray.o.y - 0.99).abs() < 1e-6, "{:?}", r.ray.o);
        }
        // Without previous points every start is a camera ray.
        assert!(
            predict(&cam, 32, 32, &[], 0.25, 50, 7)
                .iter()
                .all(|r| r.ray.o == cam.position)
        );
    }
}
