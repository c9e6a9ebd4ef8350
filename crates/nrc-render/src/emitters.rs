//! The emitter-excluded image: pixels that see an emitter (and their 8 neighbours) left out
//! of the errors, since at low sample counts the emitters' anti-aliasing can dominate every
//! method's error alike.

use nrc_scene::{Image, Scene};

/// Pixels whose footprint sees an emitter (4×4 primary rays per pixel), dilated by one pixel.
pub fn emitter_pixels(scene: &Scene, w: u32, h: u32) -> Vec<bool> {
    let sees = |x: u32, y: u32| {
        (0..16).any(|k| {
            let film = glam::Vec2::new(
                x as f32 + ((k % 4) as f32 + 0.5) / 4.0,
                y as f32 + ((k / 4) as f32 + 0.5) / 4.0,
            );
            let ray = scene.camera.generate_ray(film, w, h);
            scene.intersect(&ray).is_some_and(|hit| {
                scene.emission(&scene.interaction(&ray, &hit)) != glam::Vec3::ZERO
            })
        })
    };
    let direct: Vec<bool> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| sees(x, y))
        .collect();
    let (wi, hi) = (w as i64, h as i64);
    (0..hi)
        .flat_map(|y| (0..wi).map(move |x| (x, y)))
        .map(|(x, y)| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    let (u, v) = (x + dx, y + dy);
                    u >= 0 && v >= 0 && u < wi && v < hi && direct[(v * wi + u) as usize]
                })
            })
        })
        .collect()
}

/// Copies the reference into the excluded pixels (zero error there).
pub fn exclude(image: &mut Image, mask: Option<&[bool]>, reference: &Image) {
    if let Some(mask) = mask {
        for ((p, r), m) in image.data.iter_mut().zip(&reference.data).zip(mask) {
            if *m {
                *p = *r;
            }
        }
    }
}
