//! The pinhole (perspective) camera.
//!
//! Conventions follow glTF: the camera looks down its local −Z axis with +Y up and +X to the
//! right; the vertical field of view is fixed and the horizontal one follows the image's
//! aspect ratio (the glTF `aspectRatio` is informative only; the render resolution decides).

use glam::{Mat4, Vec2, Vec3};

use crate::geometry::{Aabb, Ray};

/// A perspective camera: position, orthonormal orientation and vertical field of view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: Vec3,
    /// Unit viewing direction (the camera's −Z axis).
    pub forward: Vec3,
    /// Unit right vector (the camera's +X axis).
    pub right: Vec3,
    /// Unit up vector (the camera's +Y axis), orthogonal to `forward` and `right`.
    pub up: Vec3,
    /// Vertical field of view in radians.
    pub fov_y: f32,
}

/// Why a camera description is unusable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CameraError(pub String);

impl std::fmt::Display for CameraError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for CameraError {}

impl Camera {
    /// A camera at `position` looking at `target`, with `up` giving the upward direction
    /// (need not be orthogonal to the view direction) and a vertical field of view in
    /// degrees. Errors for coincident points, `up` parallel to the view direction, a field
    /// of view outside (0°, 180°), or non-finite input.
    pub fn look_at(
        position: Vec3,
        target: Vec3,
        up: Vec3,
        fov_y_degrees: f32,
    ) -> Result<Self, CameraError> {
        if !(position.is_finite() && target.is_finite() && up.is_finite()) {
            return Err(CameraError(
                "camera position, target and up must be finite".into(),
            ));
        }
        if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
            return Err(CameraError(format!(
                "vertical field of view {fov_y_degrees}° is outside (0°, 180°)"
            )));
        }
        let forward = (target - position).normalize_or_zero();
        if forward == Vec3::ZERO {
            return Err(CameraError("camera position and target coincide".into()));
        }
        let right = forward.cross(up).normalize_or_zero();
        if right == Vec3::ZERO || forward.cross(up.normalize_or_zero()).length() < 1e-6 {
            return Err(CameraError(
                "camera up vector is zero or parallel to the viewing direction".into(),
            ));
        }
        Ok(Self {
            position,
            forward,
            right,
            up: right.cross(forward),
            fov_y: fov_y_degrees.to_radians(),
        })
    }

    /// A camera placed by a node's world transform (glTF convention: looking down local
    /// −Z, +Y up). Scale and shear are removed by orthonormalising the axes.
    pub fn from_world_matrix(world: &Mat4, fov_y_radians: f32) -> Result<Self, CameraError> {
        let position = world.w_axis.truncate();
        let forward = (-world.z_axis.truncate()).normalize_or_zero();
        let up = world.y_axis.truncate();
        if !(fov_y_radians > 0.0 && fov_y_radians < std::f32::consts::PI) {
            return Err(CameraError(format!(
                "camera yfov {fov_y_radians} rad is outside (0, π)"
            )));
        }
        Self::look_at(position, position + forward, up, fov_y_radians.to_degrees())
    }

    /// A camera that frames the box `bounds`: looking down −Z at its centre from the +Z
    /// side, far enough away that its bounding sphere fits in the vertical field of view.
    pub fn framing(bounds: &Aabb) -> Self {
        const FOV_Y_DEGREES: f32 = 45.0;
        let fallback = (Vec3::ZERO, 1.0);
        let (center, radius) = if bounds.is_empty() || !bounds.extent().is_finite() {
            fallback
        } else {
            (bounds.center(), (0.5 * bounds.extent().length()).max(1e-3))
        };
        let place = |(center, radius): (Vec3, f32)| {
            let distance = radius / (0.5 * FOV_Y_DEGREES.to_radians()).sin();
            Self::look_at(center + Vec3::Z * distance, center, Vec3::Y, FOV_Y_DEGREES)
        };
        // Bounds so large that the camera position overflows get the unit framing.
        place((center, radius))
            .or_else(|_| place(fallback))
            .expect("the unit framing camera is well formed")
    }

    /// The primary ray through film position `film` (pixel coordinates: `x` right in
    /// `[0, width]`, `y` down in `[0, height]`, sub-pixel jitter included) of a
    /// `width × height` image. The direction is unit length.
    #[inline]
    pub fn generate_ray(&self, film: Vec2, width: u32, height: u32) -> Ray {
        let aspect = width as f32 / height as f32;
        let tan_half = (0.5 * self.fov_y).tan();
        let ndc_x = 2.0 * film.x / width as f32 - 1.0;
        let ndc_y = 1.0 - 2.0 * film.y / height as f32;
        let d =
            self.forward + self.right * (ndc_x * tan_half * aspect) + self.up * (ndc_y * tan_half);
        Ray::new(self.position, d.normalize())
    }

    /// The film position (as [`Camera::generate_ray`] takes it) at which `p` is seen, or `None`
    /// where `p` is behind the camera or outside the `width × height` image: the inverse of
    /// `generate_ray` (reprojection into a previous frame's camera).
    #[inline]
    pub fn project(&self, p: Vec3, width: u32, height: u32) -> Option<Vec2> {
        let v = p - self.position;
        let z = v.dot(self.forward);
        if !(z > 0.0) {
            return None;
        }
        let aspect = width as f32 / height as f32;
        let tan_half = (0.5 * self.fov_y).tan();
        let ndc_x = v.dot(self.right) / (z * tan_half * aspect);
        let ndc_y = v.dot(self.up) / (z * tan_half);
        let film = Vec2::new(
            0.5 * (ndc_x + 1.0) * width as f32,
            0.5 * (1.0 - ndc_y) * height as f32,
        );
        (film.x >= 0.0 && film.y >= 0.0 && film.x < width as f32 && film.y < height as f32)
            .then_some(film)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_pixel_looks_at_target_and_corners_span_fov() {
        let cam = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO, Vec3::Y, 60.0).unwrap();
        let r = cam.generate_ray(Vec2::new(50.0, 25.0), 100, 50);
        assert!((r.d - (-Vec3::new(1.0, 2.0, 3.0)).normalize()).length() < 1e-6);
        let top = cam.generate_ray(Vec2::new(50.0, 0.0), 100, 50);
        let angle = top.d.dot(cam.forward).acos().to_degrees();
        assert!((angle - 30.0).abs() < 1e-3, "half vertical fov {angle}");
        assert!(top.d.dot(cam.up) > 0.0, "film y=0 is the top row");
        let left = cam.generate_ray(Vec2::new(0.0, 25.0), 100, 50);
        assert!(left.d.dot(cam.right) < 0.0);
    }

    #[test]
    fn project_inverts_generate_ray() {
        let cam = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO, Vec3::Y, 50.0).unwrap();
        for film in [
            Vec2::new(10.5, 7.25),
            Vec2::new(99.0, 49.0),
            Vec2::new(0.1, 30.0),
        ] {
            let r = cam.generate_ray(film, 100, 50);
            let back = cam.project(r.o + r.d * 3.7, 100, 50).unwrap();
            assert!((back - film).length() < 1e-3, "{film} -> {back}");
        }
        assert_eq!(
            cam.project(Vec3::new(2.0, 4.0, 6.0), 100, 50),
            None,
            "behind"
        );
        let r = cam.generate_ray(Vec2::new(50.0, 25.0), 100, 50);
        let off = r.o + r.d * 2.0 + cam.right * 100.0;
        assert_eq!(cam.project(off, 100, 50), None, "outside the image");
    }

    #[test]
    fn gltf_identity_node_looks_down_minus_z() {
        let cam = Camera::from_world_matrix(&Mat4::IDENTITY, 1.0).unwrap();
        assert_eq!(cam.forward, -Vec3::Z);
        assert_eq!(cam.up, Vec3::Y);
        assert_eq!(cam.right, Vec3::X);
    }

    #[test]
    fn bad_cameras_are_errors() {
        assert!(Camera::look_at(Vec3::ZERO, Vec3::ZERO, Vec3::Y, 45.0).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::Y, Vec3::Y, 45.0).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::X, Vec3::Y, 0.0).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::X, Vec3::Y, f32::NAN).is_err());
    }
}
