//! The environment: radiance arriving from infinitely far away, seen by every ray that leaves
//! the scene. Either a constant (the former background colour, now the trivial environment)
//! or an equirectangular HDR image (`.exr` or `.hdr`), scaled by an intensity and rotated
//! about the up axis (+y, glTF's up).
//!
//! **Mapping** (Mitsuba 3's `envmap` convention, so that the same file renders the same in
//! both): a world direction `d` (rotated back by the environment's rotation) has
//! `u = atan2(d.x, −d.z) / 2π` (wrapped into `[0, 1)`) and `v = acos(d.y) / π`; row 0 of the
//! image is the zenith. The radiance is the texel's value (nearest texel: the radiance is
//! piecewise constant exactly as the sampling density is).
//!
//! **Importance sampling** (PBRT 4th ed. §12.5.2): a piecewise-constant 2D distribution over
//! the texels with weights `luminance × sin θ` (θ at the row's centre). A point `(u, v)` of
//! density `p(u, v)` maps to a direction of solid-angle density `p(u, v) / (2π² sin θ)`.
//! A constant environment is sampled uniformly over the sphere.

use std::f32::consts::PI;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

use crate::error::{Result, SceneError};
use crate::sampling::{Distribution2D, luminance, sample_uniform_sphere, uniform_sphere_pdf};

/// An equirectangular radiance image with its sampling distribution.
#[derive(Clone, Debug)]
struct EnvMap {
    source: PathBuf,
    width: usize,
    height: usize,
    /// Row-major linear RGB, row 0 at the zenith.
    texels: Vec<Vec3>,
    distribution: Distribution2D,
    /// `∫ luminance(L) dω` over the sphere (before the intensity).
    luminance_integral: f64,
    /// A content key of the texels (for reference-store keys).
    digest: u64,
}

/// Radiance from infinitely far away.
#[derive(Clone, Debug)]
pub struct Environment {
    map: Option<EnvMap>,
    /// Constant radiance (when there is no map) or the map's scale.
    scale: Vec3,
    /// Rotation about +y, radians: a map direction `d` appears in the world at `R_y(θ) d`.
    rotation: f32,
    cos_rot: f32,
    sin_rot: f32,
}

impl Default for Environment {
    /// Black: no light from outside the scene.
    fn default() -> Self {
        Self::constant(Vec3::ZERO)
    }
}

impl Environment {
    /// A constant radiance from every direction.
    pub fn constant(radiance: Vec3) -> Self {
        Self {
            map: None,
            scale: radiance.max(Vec3::ZERO),
            rotation: 0.0,
            cos_rot: 1.0,
            sin_rot: 0.0,
        }
    }

    /// An environment image (`.exr` or `.hdr`) scaled by `intensity` and rotated by
    /// `rotate_degrees` about +y. A width other than twice the height is allowed (the
    /// mapping stretches it) and reported in the returned warning.
    pub fn load(
        path: &Path,
        intensity: f32,
        rotate_degrees: f32,
    ) -> Result<(Self, Option<String>)> {
        if !(intensity.is_finite() && intensity >= 0.0) {
            return Err(SceneError::Invalid {
                path: path.into(),
                message: format!(
                    "environment intensity must be finite and non-negative, got {intensity}"
                ),
            });
        }
        if !rotate_degrees.is_finite() {
            return Err(SceneError::Invalid {
                path: path.into(),
                message: format!("environment rotation must be finite, got {rotate_degrees}"),
            });
        }
        let (width, height, texels) = read_radiance_image(path)?;
        Self::from_texels(path, width, height, texels, intensity, rotate_degrees)
    }

    /// An environment from row-major linear RGB texels (row 0 at the zenith).
    pub fn from_texels(
        source: &Path,
        width: usize,
        height: usize,
        texels: Vec<Vec3>,
        intensity: f32,
        rotate_degrees: f32,
    ) -> Result<(Self, Option<String>)> {
        let invalid = |message: String| SceneError::Invalid {
            path: source.into(),
            message,
        };
        if width == 0 || height == 0 || texels.len() != width * height {
            return Err(invalid(format!(
                "environment image is empty or its size is wrong ({width}×{height}, {} texels)",
                texels.len()
            )));
        }
        if let Some(i) = texels.iter().position(|t| !t.is_finite()) {
            return Err(invalid(format!(
                "environment image holds a non-finite value (NaN or infinite) at texel ({}, {})",
                i % width,
                i / width
            )));
        }
        if let Some(i) = texels.iter().position(|t| t.min_element() < 0.0) {
            return Err(invalid(format!(
                "environment image holds a negative value at texel ({}, {})",
                i % width,
                i / width
            )));
        }
        let warning = (width != 2 * height).then(|| {
            format!(
                "environment image {} is {width}×{height}, not 2:1 as an equirectangular map is; it is stretched over the sphere",
                source.display()
            )
        });
        let mut weights = Vec::with_capacity(texels.len());
        let mut integral = 0.0f64;
        let d_phi = 2.0 * std::f64::consts::PI / width as f64;
        for y in 0..height {
            let theta0 = std::f64::consts::PI * y as f64 / height as f64;
            let theta1 = std::f64::consts::PI * (y + 1) as f64 / height as f64;
            let sin_mid = (PI * (y as f32 + 0.5) / height as f32).sin();
            // Exact solid angle of a texel of this row.
            let omega = d_phi * (theta0.cos() - theta1.cos());
            for x in 0..width {
                let l = luminance(texels[y * width + x]);
                weights.push(l * sin_mid);
                integral += l as f64 * omega;
            }
        }
        let distribution = Distribution2D::new(&weights, width, height);
        let digest = texels.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, t| {
            [t.x, t.y, t.z].iter().fold(h, |h, c| {
                (h ^ c.to_bits() as u64).wrapping_mul(0x0000_0100_0000_01b3)
            })
        });
        let rotation = rotate_degrees.to_radians();
        Ok((
            Self {
                map: Some(EnvMap {
                    source: source.into(),
                    width,
                    height,
                    texels,
                    distribution,
                    luminance_integral: integral,
                    digest,
                }),
                scale: Vec3::splat(intensity),
                rotation,
                cos_rot: rotation.cos(),
                sin_rot: rotation.sin(),
            },
            warning,
        ))
    }

    /// The constant radiance (or the map's scale).
    pub fn scale(&self) -> Vec3 {
        self.scale
    }

    /// One line for summaries and cache keys.
    pub fn describe(&self) -> String {
        let v = self.scale;
        match &self.map {
            None => format!("constant ({:.4}, {:.4}, {:.4})", v.x, v.y, v.z),
            Some(m) => format!(
                "{} ({}×{}), intensity {:.4}, rotated {:.2}°",
                m.source.display(),
                m.width,
                m.height,
                v.x,
                self.rotation.to_degrees()
            ),
        }
    }

    /// A key that changes whenever the radiance in any direction changes.
    pub fn content_key(&self) -> String {
        let bits = |v: Vec3| {
            format!(
                "{:08x}{:08x}{:08x}",
                v.x.to_bits(),
                v.y.to_bits(),
                v.z.to_bits()
            )
        };
        match &self.map {
            None => format!("constant {}", bits(self.scale)),
            Some(m) => format!(
                "map {}x{} {:016x} scale {} rot {:08x}",
                m.width,
                m.height,
                m.digest,
                bits(self.scale),
                self.rotation.to_bits()
            ),
        }
    }

    /// `∫ luminance(L(ω)) dω` over the sphere.
    pub fn luminance_integral(&self) -> f64 {
        let s = luminance(self.scale) as f64;
        match &self.map {
            None => s * 4.0 * std::f64::consts::PI,
            Some(m) => s * m.luminance_integral,
        }
    }

    /// World direction → map direction (undo the rotation about +y).
    #[inline]
    fn to_map(&self, d: Vec3) -> Vec3 {
        Vec3::new(
            self.cos_rot * d.x - self.sin_rot * d.z,
            d.y,
            self.sin_rot * d.x + self.cos_rot * d.z,
        )
    }

    /// Map direction → world direction.
    #[inline]
    fn to_world(&self, d: Vec3) -> Vec3 {
        Vec3::new(
            self.cos_rot * d.x + self.sin_rot * d.z,
            d.y,
            -self.sin_rot * d.x + self.cos_rot * d.z,
        )
    }

    /// Radiance arriving along `-d`, i.e. seen looking in world direction `d` (unit).
    #[inline]
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        match &self.map {
            None => self.scale,
            Some(m) => {
                let uv = direction_to_uv(self.to_map(d));
                let x = ((uv.x * m.width as f32) as usize).min(m.width - 1);
                let y = ((uv.y * m.height as f32) as usize).min(m.height - 1);
                self.scale * m.texels[y * m.width + x]
            }
        }
    }

    /// A direction toward the environment (unit, world) for `u` uniform in `[0, 1)²`, with
    /// its solid-angle density; `None` where the density is zero or undefined (the poles).
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, f32)> {
        match &self.map {
            None => Some((sample_uniform_sphere(u), uniform_sphere_pdf())),
            Some(m) => {
                let (uv, p) = m.distribution.sample(u);
                let sin_theta = (PI * uv.y).sin();
                if p <= 0.0 || sin_theta <= 0.0 {
                    return None;
                }
                Some((
                    self.to_world(uv_to_direction(uv)),
                    p / (2.0 * PI * PI * sin_theta),
                ))
            }
        }
    }

    /// Solid-angle density with which [`Environment::sample`] produces world direction `d`.
    #[inline]
    pub fn pdf(&self, d: Vec3) -> f32 {
        match &self.map {
            None => uniform_sphere_pdf(),
            Some(m) => {
                let uv = direction_to_uv(self.to_map(d));
                let sin_theta = (PI * uv.y).sin();
                if sin_theta <= 0.0 {
                    return 0.0;
                }
                m.distribution.pdf(uv) / (2.0 * PI * PI * sin_theta)
            }
        }
    }
}

/// Map direction (unit) → `(u, v)` in `[0, 1)²`.
#[inline]
pub fn direction_to_uv(d: Vec3) -> Vec2 {
    let mut u = d.x.atan2(-d.z) * (0.5 / PI);
    if u < 0.0 {
        u += 1.0;
    }
    let v = d.y.clamp(-1.0, 1.0).acos() / PI;
    Vec2::new(
        u.min(1.0 - f32::EPSILON / 2.0),
        v.min(1.0 - f32::EPSILON / 2.0),
    )
}

/// `(u, v)` → map direction (unit).
#[inline]
pub fn uv_to_direction(uv: Vec2) -> Vec3 {
    let (sin_phi, cos_phi) = (2.0 * PI * uv.x).sin_cos();
    let (sin_theta, cos_theta) = (PI * uv.y).sin_cos();
    Vec3::new(sin_phi * sin_theta, cos_theta, -cos_phi * sin_theta)
}

/// Reads an HDR image (`.exr` or Radiance `.hdr`) as row-major linear RGB.
fn read_radiance_image(path: &Path) -> Result<(usize, usize, Vec<Vec3>)> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("exr") => {
            let image = crate::image::Image::read_exr(path)?;
            Ok((image.width, image.height, image.data))
        }
        Some("hdr") => {
            let err = |message: String| SceneError::Invalid {
                path: path.into(),
                message,
            };
            let file = std::fs::File::open(path).map_err(|e| SceneError::Io {
                path: path.into(),
                source: e,
            })?;
            let decoder = image::codecs::hdr::HdrDecoder::new(std::io::BufReader::new(file))
                .map_err(|e| err(format!("not a readable Radiance HDR image: {e}")))?;
            let img = image::DynamicImage::from_decoder(decoder)
                .map_err(|e| err(format!("not a readable Radiance HDR image: {e}")))?
                .into_rgb32f();
            let (w, h) = (img.width() as usize, img.height() as usize);
            let texels = img
                .pixels()
                .map(|p| Vec3::new(p.0[0], p.0[1], p.0[2]))
                .collect();
            Ok((w, h, texels))
        }
        _ => Err(SceneError::Invalid {
            path: path.into(),
            message: "an environment image must be .exr or .hdr".into(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapping_round_trips() {
        for i in 0..200 {
            let u = Vec2::new(
                (i as f32 * 0.618_034) % 1.0,
                (i as f32 * 0.414_213 + 0.01) % 1.0,
            );
            let d = uv_to_direction(u);
            let back = direction_to_uv(d);
            assert!((back - u).abs().max_element() < 1e-4, "{u} {back}");
        }
        // Mitsuba's convention: u = 0 looks down −z, v = 0 is +y.
        assert!((uv_to_direction(Vec2::new(0.0, 0.5)) - Vec3::NEG_Z).length() < 1e-6);
        assert!((uv_to_direction(Vec2::new(0.25, 0.5)) - Vec3::X).length() < 1e-6);
    }

    #[test]
    fn rotation_moves_the_map() {
        // One bright texel column at u = 0 (looking down −z), rotated 90° about +y.
        let (w, h) = (8, 4);
        let texels = (0..w * h)
            .map(|i| if i % w == 0 { Vec3::ONE } else { Vec3::ZERO })
            .collect();
        let (env, warning) =
            Environment::from_texels(Path::new("t.exr"), w, h, texels, 1.0, 90.0).unwrap();
        assert!(warning.is_none());
        // R_y(90°) takes −z to −x.
        let seen = env.radiance(Vec3::new(-1.0, 0.0, -0.01).normalize());
        assert_eq!(seen, Vec3::ONE);
        assert_eq!(env.radiance(Vec3::NEG_Z), Vec3::ZERO);
        let (d, pdf) = env.sample(Vec2::new(0.3, 0.6)).unwrap();
        assert!(d.x < -0.5 && pdf > 0.0 && (env.pdf(d) - pdf).abs() < 1e-3 * pdf);
    }

    #[test]
    fn bad_texels_are_refused() {
        let p = Path::new("sky.exr");
        let nan = vec![Vec3::ONE, Vec3::new(f32::NAN, 0.0, 0.0)];
        let e = Environment::from_texels(p, 2, 1, nan, 1.0, 0.0).unwrap_err();
        assert!(
            e.to_string().contains("non-finite") && e.to_string().contains("sky.exr"),
            "{e}"
        );
        let neg = vec![Vec3::ONE, Vec3::splat(-1.0)];
        assert!(Environment::from_texels(p, 2, 1, neg, 1.0, 0.0).is_err());
        let (_, warning) = Environment::from_texels(p, 3, 1, vec![Vec3::ONE; 3], 1.0, 0.0).unwrap();
        assert!(warning.unwrap().contains("not 2:1"));
    }
}
