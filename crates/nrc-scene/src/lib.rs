//! Scene description for the neural radiance cache: geometry, materials (closed enums),
//! lights, camera, glTF loading, BVH ray queries, sampling and images.

pub mod bsdf;
pub mod sampling;
