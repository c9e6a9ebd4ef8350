//! Fresnel reflectance and the mirror/refraction directions of a smooth interface.
//!
//! `eta` is always a *relative* index of refraction: the index of the medium the light
//! enters (the far side of the interface) over the index of the side the direction is on.

use glam::Vec3;

/// Exact unpolarized Fresnel reflectance of a dielectric interface (the average of the
/// s- and p-polarized Fresnel equations). `cos_i` is the cosine between the direction and
/// the interface normal on its side, `eta` the relative index of the far side. A negative
/// `cos_i` means the direction is on the other side: the interface is seen with `1/eta`.
/// Returns 1 under total internal reflection.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let (cos_i, eta) = if cos_i < 0.0 {
        (-cos_i, 1.0 / eta)
    } else {
        (cos_i, eta)
    };
    let cos_i = cos_i.min(1.0);
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_parallel = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perpendicular = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let f = 0.5 * (r_parallel * r_parallel + r_perpendicular * r_perpendicular);
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// The weight `(1 − cos)⁵` of Schlick's 1994 approximation.
#[inline]
pub fn schlick_weight(cos: f32) -> f32 {
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

/// Schlick's approximation `F0 + (1 − F0)(1 − cos)⁵` (reflectance 1 at grazing).
#[inline]
pub fn schlick(f0: Vec3, cos: f32) -> Vec3 {
    f0 + (Vec3::ONE - f0) * schlick_weight(cos)
}

/// Normal-incidence reflectance of a dielectric of relative index `eta`: `((η − 1)/(η + 1))²`.
#[inline]
pub fn f0_from_ior(eta: f32) -> f32 {
    let r = (eta - 1.0) / (eta + 1.0);
    r * r
}

/// Mirror direction of `w` about the unit normal `n` (both pointing away from the surface).
#[inline]
pub fn reflect(w: Vec3, n: Vec3) -> Vec3 {
    2.0 * w.dot(n) * n - w
}

/// Refracted direction of `w` through an interface of unit normal `n` on `w`'s side
/// (`w·n > 0`), by Snell's law with relative index `eta` (far side over `w`'s side).
/// The result points away from the interface on the far side; `None` under total internal
/// reflection.
#[inline]
pub fn refract(w: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = w.dot(n);
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(-w / eta + (cos_i / eta - cos_t) * n)
}
