//! Procedural textures, encoded as 8-bit RGB PNG. Colour (base-colour) textures store
//! sRGB-encoded values as glTF requires; data textures (metallic-roughness) store linear values.

use glam::Vec3;

/// An 8-bit RGB image, rows from the top.
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

impl Image {
    pub fn from_fn(width: u32, height: u32, mut pixel: impl FnMut(u32, u32) -> [u8; 3]) -> Self {
        let rgb = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .flat_map(|(x, y)| pixel(x, y))
            .collect();
        Self { width, height, rgb }
    }

    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::High);
        let mut writer = encoder.write_header().expect("PNG header into memory");
        writer
            .write_image_data(&self.rgb)
            .expect("PNG data into memory");
        writer.finish().expect("PNG end into memory");
        out
    }
}

/// The sRGB transfer function (IEC 61966-2-1) applied to a linear value, as an 8-bit code.
pub fn srgb_encode(linear: f32) -> u8 {
    let c = linear.clamp(0.0, 1.0);
    let v = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (v * 255.0).round() as u8
}

pub fn srgb_pixel(linear: Vec3) -> [u8; 3] {
    linear.to_array().map(srgb_encode)
}

/// A linear value in [0, 1] as an 8-bit code (for data textures).
pub fn unorm(value: f32) -> u8 {
    (value.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// A square checkerboard base-colour texture: `cells` × `cells` squares of `cell` pixels,
/// alternating linear colours `a` (top-left) and `b`.
pub fn checker(cells: u32, cell: u32, a: Vec3, b: Vec3) -> Image {
    let (pa, pb) = (srgb_pixel(a), srgb_pixel(b));
    Image::from_fn(cells * cell, cells * cell, |x, y| {
        if (x / cell + y / cell).is_multiple_of(2) {
            pa
        } else {
            pb
        }
    })
}
