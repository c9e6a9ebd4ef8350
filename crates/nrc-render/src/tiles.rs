//! Tile scheduling: the image is cut into square tiles that rayon hands to its threads.
//!
//! Tiles keep a thread's pixels close together (coherent rays, warm caches) and are small
//! enough to balance the load when some regions cost more than others. Results are written
//! back by tile position, so the output does not depend on the order tiles finish in.

use rayon::prelude::*;

/// Edge length of a tile in pixels.
pub const TILE_SIZE: u32 = 16;

/// A rectangle of pixels `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tile {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Tile {
    /// Number of pixels in the tile.
    pub fn len(&self) -> usize {
        ((self.x1 - self.x0) * (self.y1 - self.y0)) as usize
    }

    /// Whether the tile holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The tiles covering a `width × height` image, row by row.
pub fn tiles(width: u32, height: u32, size: u32) -> Vec<Tile> {
    let size = size.max(1);
    let mut out = Vec::new();
    for y0 in (0..height).step_by(size as usize) {
        for x0 in (0..width).step_by(size as usize) {
            out.push(Tile {
                x0,
                y0,
                x1: (x0 + size).min(width),
                y1: (y0 + size).min(height),
            });
        }
    }
    out
}

/// Evaluates `pixel(x, y)` for every pixel of a `width × height` image in parallel over
/// tiles (on the current rayon pool) and returns the values in row-major order.
/// `tile_done(tile_pixels)` is called after each tile, from the thread that rendered it
/// (for progress reports).
pub fn map_pixels<T, F, D>(width: u32, height: u32, pixel: F, tile_done: D) -> Vec<T>
where
    T: Send + Copy + Default,
    F: Fn(u32, u32) -> T + Sync,
    D: Fn(usize) + Sync,
{
    let tiles = tiles(width, height, TILE_SIZE);
    let results: Vec<Vec<T>> = tiles
        .par_iter()
        .map(|t| {
            let mut values = Vec::with_capacity(t.len());
            for y in t.y0..t.y1 {
                for x in t.x0..t.x1 {
                    values.push(pixel(x, y));
                }
            }
            tile_done(values.len());
            values
        })
        .collect();
    let mut out = vec![T::default(); width as usize * height as usize];
    for (t, values) in tiles.iter().zip(results) {
        let w = (t.x1 - t.x0) as usize;
        for (row, chunk) in values.chunks_exact(w).enumerate() {
            let start = (t.y0 as usize + row) * width as usize + t.x0 as usize;
            out[start..start + w].copy_from_slice(chunk);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_every_pixel_once() {
        for (w, h) in [(1, 1), (16, 16), (17, 5), (100, 33)] {
            let mut count = vec![0u32; (w * h) as usize];
            for t in tiles(w, h, TILE_SIZE) {
                for y in t.y0..t.y1 {
                    for x in t.x0..t.x1 {
                        count[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(count.iter().all(|&c| c == 1), "{w}x{h}");
        }
    }

    #[test]
    fn map_pixels_is_row_major() {
        let (w, h) = (37, 21);
        let done = std::sync::atomic::AtomicUsize::new(0);
        let v = map_pixels(
            w,
            h,
            |x, y| y * 1000 + x,
            |n| {
                done.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
            },
        );
        for y in 0..h {
            for x in 0..w {
                assert_eq!(v[(y * w + x) as usize], y * 1000 + x);
            }
        }
        assert_eq!(done.into_inner(), (w * h) as usize);
    }
}
