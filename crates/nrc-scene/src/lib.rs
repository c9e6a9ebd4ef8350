//! Scene description for the neural radiance cache: geometry, materials (closed enums),
//! lights, camera, glTF loading, BVH ray queries, sampling and images.
//!
//! The entry point is [`Scene::load`]; a scene answers closest-hit and occlusion queries
//! ([`Scene::intersect`], [`Scene::occluded`]), describes hit points
//! ([`Scene::interaction`], [`Scene::pbr`], [`Scene::emission`]) and samples its area
//! lights ([`Scene::sample_light`], [`Scene::light_pdf_area`]).

pub mod accel;
pub mod bsdf;
pub mod camera;
pub mod error;
pub mod geometry;
pub mod gltf_load;
pub mod image;
pub mod interaction;
pub mod light;
pub mod material;
pub mod sampling;
pub mod scene;
pub mod texture;

pub use accel::Hit;
pub use bsdf::PbrParams;
pub use camera::{Camera, CameraError};
pub use error::SceneError;
pub use geometry::{Aabb, Ray, offset_ray_origin, spawn_ray, spawn_ray_between, spawn_ray_to};
pub use image::Image;
pub use interaction::SurfaceInteraction;
pub use light::{LightSample, LightSampler};
pub use material::Material;
pub use scene::{Scene, SceneDescription, SceneSummary};
pub use texture::{Texture, TextureRef, WrapMode};
