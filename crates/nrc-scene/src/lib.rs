//! Scene description for the neural radiance cache: geometry, materials (closed enums),
//! lights, camera, glTF loading, BVH ray queries, sampling and images.
//!
//! The entry point is [`Scene::load`]; a scene answers closest-hit and occlusion queries
//! ([`Scene::intersect`], [`Scene::occluded`]), describes hit points
//! ([`Scene::interaction`], [`Scene::pbr`], [`Scene::emission`]) and samples its lights:
//! emissive triangles, punctual lights and the environment ([`Scene::sample_light`],
//! [`Scene::light_pdf_area`], [`Scene::environment_light_pdf`]).
//!
//! ```
//! use glam::Vec3;
//! use nrc_scene::{Material, Ray, Scene, SceneDescription};
//!
//! // One emissive triangle facing +z (scenes usually come from `Scene::load("x.glb")`).
//! let scene = Scene::from_description(SceneDescription {
//!     positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
//!     triangles: vec![[0, 1, 2]],
//!     triangle_materials: vec![0],
//!     materials: vec![Material { emissive: Vec3::splat(2.0), ..Material::default() }],
//!     ..SceneDescription::default()
//! })?;
//! let ray = Ray::new(Vec3::new(0.25, 0.25, 1.0), -Vec3::Z);
//! let hit = scene.intersect(&ray).expect("the ray hits the triangle");
//! let si = scene.interaction(&ray, &hit);
//! assert_eq!(hit.t, 1.0);
//! assert_eq!(si.ng, Vec3::Z);
//! assert_eq!(scene.emission(&si), Vec3::splat(2.0)); // seen from the front
//! assert_eq!(scene.light_count(), 1);
//! // A ray leaving the surface does not hit it again.
//! assert!(scene.intersect(&si.spawn_ray(Vec3::new(0.3, 0.1, 1.0).normalize())).is_none());
//! # Ok::<(), nrc_scene::SceneError>(())
//! ```

pub mod accel;
pub mod animation;
pub mod bsdf;
pub mod camera;
pub mod cpu;
pub mod environment;
pub mod error;
pub mod geometry;
pub mod gltf_load;
pub mod image;
pub mod interaction;
pub mod light;
pub mod light_tree;
pub mod material;
pub mod sampling;
pub mod scene;
pub mod tangents;
pub mod testing;
pub mod texture;

pub use accel::Hit;
pub use animation::AnimatedScene;
pub use bsdf::PbrParams;
pub use camera::{Camera, CameraError};
pub use environment::Environment;
pub use error::SceneError;
pub use geometry::{Aabb, Ray, offset_ray_origin, spawn_ray, spawn_ray_between, spawn_ray_to};
pub use image::Image;
pub use interaction::SurfaceInteraction;
pub use light::{
    Incident, LightContext, LightSample, LightSampler, LightSamplerKind, LightSource, PunctualKind,
    PunctualLight, SurfaceLightSample,
};
pub use light_tree::{LightBounds, LightTree};
pub use material::{AlphaMode, Material};
pub use scene::{Scene, SceneDescription, SceneSummary};
pub use texture::{Texture, TextureRef, WrapMode};
