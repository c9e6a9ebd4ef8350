//! Fly controls: the viewer's camera moved by keys (WASD along the view and sideways, Q/E down
//! and up), turned by the mouse (yaw about the world's up, pitch about the camera's right), with
//! its speed on the wheel; and the camera as a keyframe of the project's camera-path JSON.

use glam::{Quat, Vec3};
use nrc_scene::Camera;

/// The fly camera: the camera itself and how fast it moves.
#[derive(Clone, Copy, Debug)]
pub struct Fly {
    pub camera: Camera,
    /// Metres (scene units) per second.
    pub speed: f32,
}

/// Keys held this frame, as a direction in the camera's frame: x right, y up, z forward.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Held {
    pub right: f32,
    pub up: f32,
    pub forward: f32,
}

impl Held {
    pub fn any(&self) -> bool {
        *self != Self::default()
    }
}

/// Radians of turn per pixel of mouse movement.
pub const LOOK_SENSITIVITY: f32 = 0.004;

/// Speed change per wheel notch.
pub const WHEEL_FACTOR: f32 = 1.25;

/// Pitch is kept this far (radians) from straight up or down, where yaw about the world's up
/// would spin the view.
const PITCH_MARGIN: f32 = 0.02;

impl Fly {
    /// At `camera`, moving a quarter of the scene's largest extent `extent` per second.
    pub fn new(camera: Camera, extent: f32) -> Self {
        let speed = if extent.is_finite() && extent > 0.0 {
            0.25 * extent
        } else {
            1.0
        };
        Self { camera, speed }
    }

    /// Moves by the held keys for `seconds`; whether the camera changed.
    pub fn translate(&mut self, held: Held, seconds: f32) -> bool {
        if !held.any() || !(seconds > 0.0) {
            return false;
        }
        let c = &mut self.camera;
        let step = (c.right * held.right + Vec3::Y * held.up + c.forward * held.forward)
            .normalize_or_zero()
            * self.speed
            * seconds;
        c.position += step;
        step != Vec3::ZERO
    }

    /// Turns by a mouse movement of `(dx, dy)` pixels (right and down); whether the camera
    /// changed. The camera's up becomes the world's up (+Y) projected off the view.
    pub fn look(&mut self, dx: f32, dy: f32) -> bool {
        if dx == 0.0 && dy == 0.0 {
            return false;
        }
        let c = self.camera;
        let yaw = Quat::from_axis_angle(Vec3::Y, -dx * LOOK_SENSITIVITY);
        let forward = yaw * c.forward;
        let right = forward.cross(Vec3::Y).normalize_or_zero();
        if right == Vec3::ZERO {
            return false;
        }
        // The pitch, kept off the poles.
        let pitch_now = forward.y.clamp(-1.0, 1.0).asin();
        let limit = std::f32::consts::FRAC_PI_2 - PITCH_MARGIN;
        let pitch = (pitch_now - dy * LOOK_SENSITIVITY).clamp(-limit, limit) - pitch_now;
        let forward = Quat::from_axis_angle(right, pitch) * forward;
        match Camera::look_at(
            c.position,
            c.position + forward,
            Vec3::Y,
            c.fov_y.to_degrees(),
        ) {
            Ok(turned) => {
                self.camera = turned;
                true
            }
            Err(_) => false,
        }
    }

    /// Scales the speed by wheel `notches` (positive: faster).
    pub fn wheel(&mut self, notches: f32) {
        if notches.is_finite() {
            self.speed = (self.speed * WHEEL_FACTOR.powf(notches)).clamp(1e-4, 1e6);
        }
    }
}

/// `camera` as a keyframe of the camera-path JSON (`nrc train --camera-path`): its position, a
/// target one unit ahead, its up and its field of view in degrees.
pub fn keyframe(camera: &Camera) -> nrc_harness::run::Keyframe {
    nrc_harness::run::Keyframe {
        position: camera.position.to_array(),
        target: (camera.position + camera.forward).to_array(),
        up: Some(camera.up.to_array()),
        fov_y: Some(camera.fov_y.to_degrees()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::look_at(Vec3::ZERO, Vec3::new(0.0, 0.0, -1.0), Vec3::Y, 45.0).unwrap()
    }

    #[test]
    fn keys_move_along_the_view_and_sideways_at_the_speed() {
        let mut fly = Fly::new(camera(), 4.0);
        assert_eq!(fly.speed, 1.0);
        assert!(fly.translate(
            Held {
                forward: 1.0,
                ..Default::default()
            },
            0.5
        ));
        assert!((fly.camera.position - Vec3::new(0.0, 0.0, -0.5)).length() < 1e-6);
        assert!(fly.translate(
            Held {
                right: 1.0,
                ..Default::default()
            },
            1.0
        ));
        assert!((fly.camera.position - Vec3::new(1.0, 0.0, -0.5)).length() < 1e-6);
        assert!(!fly.translate(Held::default(), 1.0), "no key, no move");
        fly.wheel(2.0);
        assert!((fly.speed - 1.5625).abs() < 1e-6);
    }

    #[test]
    fn mouse_turns_and_stops_short_of_the_poles() {
        let mut fly = Fly::new(camera(), 1.0);
        // A quarter turn to the right: forward from -Z to +X.
        assert!(fly.look(std::f32::consts::FRAC_PI_2 / LOOK_SENSITIVITY, 0.0));
        assert!(
            (fly.camera.forward - Vec3::X).length() < 1e-4,
            "{:?}",
            fly.camera.forward
        );
        // Far up: stops short of straight up, and stays a valid camera.
        assert!(fly.look(0.0, -10.0 / LOOK_SENSITIVITY));
        assert!(fly.camera.forward.y < 1.0 - 1e-4 && fly.camera.forward.y > 0.99);
        assert!((fly.camera.up.length() - 1.0).abs() < 1e-4);
        assert!(fly.camera.forward.dot(fly.camera.up).abs() < 1e-4);
    }

    #[test]
    fn keyframe_round_trips_through_the_camera_path_reader() {
        let c = Camera::look_at(
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(0.5, 1.0, 0.0),
            Vec3::Y,
            50.0,
        )
        .unwrap();
        let json = serde_json::to_string(&vec![keyframe(&c)]).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("path.json");
        std::fs::write(&path, json).unwrap();
        let back = nrc_harness::run::camera_path(Some(&path), &camera(), 1).unwrap()[0];
        assert!((back.position - c.position).length() < 1e-5);
        assert!((back.forward - c.forward).length() < 1e-5);
        assert!((back.fov_y - c.fov_y).abs() < 1e-5);
    }
}
