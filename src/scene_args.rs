//! Options shared by the subcommands that load a scene: the scene file, camera overrides
//! and background radiance.

use std::path::PathBuf;

use anyhow::{Context, Result};
use glam::Vec3;
use nrc_scene::{Camera, Scene};

use crate::args::{parse_rgb, parse_vec3};

/// The scene and how to look at it.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene file: glTF 2.0 (`.gltf` with its buffers, or `.glb`).
    #[arg(long)]
    pub scene: PathBuf,

    /// Camera position `x,y,z` (overrides the scene's camera; unset parts keep it).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_pos: Option<Vec3>,

    /// Point the camera looks at, `x,y,z`.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_target: Option<Vec3>,

    /// Camera up direction `x,y,z`.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera_up: Option<Vec3>,

    /// Vertical field of view in degrees.
    #[arg(long)]
    pub fov_y: Option<f32>,

    /// Constant background radiance `r,g,b` (or one number for grey) for rays leaving the
    /// scene. Default: the scene's (black for glTF files).
    #[arg(long, value_parser = parse_rgb)]
    pub background: Option<Vec3>,
}

impl SceneArgs {
    /// Loads the scene and applies the camera and background overrides.
    pub fn load(&self) -> Result<Scene> {
        let mut scene = Scene::load(&self.scene)?;
        scene.camera = self
            .camera(&scene.camera)
            .with_context(|| "invalid camera")?;
        if let Some(b) = self.background {
            scene.background = b;
        }
        Ok(scene)
    }

    /// The scene's camera with the command-line overrides applied.
    fn camera(&self, base: &Camera) -> Result<Camera, nrc_scene::CameraError> {
        if self.camera_pos.is_none()
            && self.camera_target.is_none()
            && self.camera_up.is_none()
            && self.fov_y.is_none()
        {
            return Ok(*base);
        }
        let pos = self.camera_pos.unwrap_or(base.position);
        let target = self.camera_target.unwrap_or(pos + base.forward);
        let up = self.camera_up.unwrap_or(base.up);
        let fov = self.fov_y.unwrap_or(base.fov_y.to_degrees());
        Camera::look_at(pos, target, up, fov)
    }
}
