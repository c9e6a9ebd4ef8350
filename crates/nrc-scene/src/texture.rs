//! Image textures: linear RGBA texels, bilinear filtering and glTF wrap modes.
//!
//! Colour textures (base colour, emissive) are sRGB-encoded in glTF and are decoded to
//! linear values once at load time, before filtering, as the glTF specification requires;
//! data textures (metallic-roughness, transmission, specular) are stored as is.

use glam::{Vec2, Vec4};

/// How texture coordinates outside `[0, 1]` map into the image (glTF sampler `wrapS/T`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum WrapMode {
    #[default]
    Repeat,
    ClampToEdge,
    MirroredRepeat,
}

impl WrapMode {
    /// Maps an integer texel coordinate into `[0, n)`.
    #[inline]
    fn apply(self, i: i64, n: i64) -> usize {
        let j = match self {
            WrapMode::Repeat => i.rem_euclid(n),
            WrapMode::ClampToEdge => i.clamp(0, n - 1),
            WrapMode::MirroredRepeat => {
                let period = i.rem_euclid(2 * n);
                if period < n {
                    period
                } else {
                    2 * n - 1 - period
                }
            }
        };
        j as usize
    }
}

/// A 2D texture of linear RGBA texels (row-major, first row at `v = 0` as glTF defines).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    width: u32,
    height: u32,
    texels: Vec<Vec4>,
    pub wrap_s: WrapMode,
    pub wrap_t: WrapMode,
    /// Nearest-texel lookup instead of bilinear filtering (glTF `magFilter` NEAREST).
    pub nearest: bool,
}

impl Texture {
    /// A texture from `width × height` linear texels. Returns `None` when the sizes do not
    /// match or a dimension is zero.
    pub fn new(width: u32, height: u32, texels: Vec<Vec4>) -> Option<Self> {
        (width > 0 && height > 0 && texels.len() == width as usize * height as usize).then_some(
            Self {
                width,
                height,
                texels,
                wrap_s: WrapMode::Repeat,
                wrap_t: WrapMode::Repeat,
                nearest: false,
            },
        )
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// The texel at integer coordinates after wrapping.
    #[inline]
    fn texel(&self, x: i64, y: i64) -> Vec4 {
        let x = self.wrap_s.apply(x, self.width as i64);
        let y = self.wrap_t.apply(y, self.height as i64);
        self.texels[y * self.width as usize + x]
    }

    /// Filtered value at texture coordinates `uv` (texel centres at half-integers).
    /// Non-finite coordinates give the texel at the origin.
    #[inline]
    pub fn sample(&self, uv: Vec2) -> Vec4 {
        let uv = if uv.is_finite() { uv } else { Vec2::ZERO };
        // Keep coordinates in a range where the float→int conversion is exact enough.
        let x = (uv.x as f64 * self.width as f64).clamp(-1e12, 1e12);
        let y = (uv.y as f64 * self.height as f64).clamp(-1e12, 1e12);
        if self.nearest {
            return self.texel(x.floor() as i64, y.floor() as i64);
        }
        let (x, y) = (x - 0.5, y - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let a = self.texel(x0, y0).lerp(self.texel(x0 + 1, y0), fx);
        let b = self.texel(x0, y0 + 1).lerp(self.texel(x0 + 1, y0 + 1), fx);
        a.lerp(b, fy)
    }

    /// Mean of all texels.
    pub fn average(&self) -> Vec4 {
        let sum = self
            .texels
            .iter()
            .fold(glam::DVec4::ZERO, |s, t| s + t.as_dvec4());
        (sum / self.texels.len() as f64).as_vec4()
    }
}

/// A 2D texture-coordinate transform (`KHR_texture_transform`): scale, then rotate
/// (counter-clockwise in UV space as the extension defines), then offset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    pub offset: Vec2,
    pub rotation: f32,
    pub scale: Vec2,
}

impl UvTransform {
    #[inline]
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        let s = uv * self.scale;
        let (sin, cos) = self.rotation.sin_cos();
        // The extension's matrix: [cos, sin; -sin, cos] applied to (u, v).
        Vec2::new(cos * s.x + sin * s.y, -sin * s.x + cos * s.y) + self.offset
    }
}

/// A material's reference to a texture of the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into the scene's textures.
    pub texture: u32,
    /// Optional `KHR_texture_transform`.
    pub transform: Option<UvTransform>,
    /// Which texture coordinate set it reads (`TEXCOORD_0` or `TEXCOORD_1`).
    pub tex_coord: u32,
}

impl TextureRef {
    /// The texture coordinates to look up for the surface's coordinate sets `uvs`.
    #[inline]
    pub fn uv(&self, uvs: &[Vec2; 2]) -> Vec2 {
        let uv = uvs[(self.tex_coord as usize).min(1)];
        match &self.transform {
            Some(t) => t.apply(uv),
            None => uv,
        }
    }
}

/// The sRGB electro-optical transfer function: encoded value in `[0, 1]` to linear.
#[inline]
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB opto-electronic transfer function: linear value in `[0, 1]` to encoded.
#[inline]
pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.0031308 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> Texture {
        // 2×1: black, white.
        Texture::new(2, 1, vec![Vec4::ZERO, Vec4::ONE]).unwrap()
    }

    #[test]
    fn bilinear_interpolates_between_texel_centres() {
        let t = checker();
        assert_eq!(t.sample(Vec2::new(0.25, 0.5)), Vec4::ZERO);
        assert_eq!(t.sample(Vec2::new(0.75, 0.5)), Vec4::ONE);
        let mid = t.sample(Vec2::new(0.5, 0.5));
        assert!((mid - Vec4::splat(0.5)).abs().max_element() < 1e-6);
    }

    #[test]
    fn wrap_modes() {
        let mut t = checker();
        // u = 0: halfway between texel 0 and (wrapped) texel −1.
        t.wrap_s = WrapMode::Repeat;
        assert!((t.sample(Vec2::new(0.0, 0.5)).x - 0.5).abs() < 1e-6);
        assert_eq!(t.sample(Vec2::new(1.25, 0.5)), Vec4::ZERO);
        t.wrap_s = WrapMode::ClampToEdge;
        assert_eq!(t.sample(Vec2::new(-3.0, 0.5)), Vec4::ZERO);
        assert_eq!(t.sample(Vec2::new(3.0, 0.5)), Vec4::ONE);
        t.wrap_s = WrapMode::MirroredRepeat;
        assert_eq!(t.sample(Vec2::new(1.25, 0.5)), Vec4::ONE);
        assert_eq!(t.sample(Vec2::new(1.75, 0.5)), Vec4::ZERO);
        // Non-finite coordinates read at the origin: with mirroring, texel 0 on both sides.
        assert_eq!(t.sample(Vec2::new(f32::NAN, 0.5)), Vec4::ZERO);
        t.wrap_s = WrapMode::Repeat;
        assert_eq!(t.sample(Vec2::new(f32::INFINITY, 0.5)).x, 0.5);
    }

    #[test]
    fn texture_transform_follows_the_extension_matrix() {
        // KHR_texture_transform: uv' = T · R · S · uv with R = [cos sin; −sin cos].
        let t = UvTransform {
            offset: Vec2::new(0.5, 0.25),
            rotation: std::f32::consts::FRAC_PI_2,
            scale: Vec2::new(2.0, 3.0),
        };
        let uv = t.apply(Vec2::new(1.0, 1.0));
        // S: (2, 3); R(π/2): (cos·2 + sin·3, −sin·2 + cos·3) = (3, −2); T: (3.5, −1.75).
        assert!((uv - Vec2::new(3.5, -1.75)).length() < 1e-5, "{uv}");
        let mut r = TextureRef {
            texture: 0,
            transform: None,
            tex_coord: 0,
        };
        let sets = [Vec2::new(0.3, 0.7), Vec2::new(0.9, 0.1)];
        assert_eq!(r.uv(&sets), sets[0]);
        r.tex_coord = 1;
        assert_eq!(r.uv(&sets), sets[1]);
    }

    #[test]
    fn srgb_round_trip() {
        for i in 0..=255 {
            let c = i as f32 / 255.0;
            assert!((linear_to_srgb(srgb_to_linear(c)) - c).abs() < 1e-5);
        }
        assert!((srgb_to_linear(0.5) - 0.21404).abs() < 1e-4);
    }
}
