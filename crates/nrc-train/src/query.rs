//! Surface points as cache queries.

use glam::Vec3;
use nrc_cache::{CacheQuery, SceneBox};
use nrc_render::RadianceQuery;
use nrc_scene::{bsdf::Bsdf, geometry::Aabb, interaction::SurfaceInteraction};

/// Builds [`CacheQuery`]s for one scene: positions normalised to the scene's box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QueryMaker {
    pub scene_box: SceneBox,
}

impl QueryMaker {
    /// The box of the scene's geometry, padded by 1% of its largest extent on every side (so
    /// surfaces on the boundary are not at the edge of the encoding) and never flat.
    pub fn new(bounds: &Aabb) -> Self {
        let ext = (bounds.max - bounds.min).max_element();
        let pad = if ext.is_finite() && ext > 0.0 {
            0.01 * ext
        } else {
            1.0
        };
        let min = bounds.min - Vec3::splat(pad);
        let max = bounds.max + Vec3::splat(pad);
        Self {
            scene_box: SceneBox {
                min: min.to_array(),
                max: max.to_array(),
            },
        }
    }

    /// The query for the radiance leaving `si` toward `si.wo`: position, direction, shading
    /// normal, and the BSDF's roughness and reflectances (the inputs of the reflectance
    /// factorisation).
    pub fn query(&self, si: &SurfaceInteraction, bsdf: &Bsdf) -> CacheQuery {
        self.query_toward(si, bsdf, si.wo)
    }

    /// The query for the radiance leaving `si` toward `wo` (unit, world space).
    pub fn query_toward(&self, si: &SurfaceInteraction, bsdf: &Bsdf, wo: Vec3) -> CacheQuery {
        self.cache_query(&RadianceQuery::at(si, bsdf, wo))
    }

    /// A world-space radiance query as the cache's record: its position normalised to the box.
    pub fn cache_query(&self, q: &RadianceQuery) -> CacheQuery {
        CacheQuery {
            position: self.scene_box.normalize(q.position.to_array()),
            direction: q.direction.to_array(),
            normal: q.normal.to_array(),
            roughness: q.roughness,
            diffuse: q.diffuse.to_array(),
            specular: q.specular.to_array(),
        }
    }
}

/// RGB array to vector.
#[inline]
pub fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}
