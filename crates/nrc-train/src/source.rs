//! A trained cache (neural or hash, [`nrc_cache::Cache`]) as a [`RadianceSource`]: the adapter between the passes' world-space
//! queries and the cache's box-normalised [`nrc_cache::CacheQuery`] records.

use glam::Vec3;
use nrc_cache::{Cache, CacheQuery};
use nrc_render::{RadianceQuery, RadianceSource};

use crate::query::QueryMaker;

/// A trained cache answering radiance queries (its EMA weights, one inference call per batch).
#[derive(Clone, Copy)]
pub struct CacheSource<'a> {
    pub cache: &'a Cache,
    /// The scene box the cache's positions are normalised to.
    pub queries: QueryMaker,
}

impl<'a> CacheSource<'a> {
    /// The cache with its own scene box.
    pub fn new(cache: &'a Cache) -> Self {
        Self {
            cache,
            queries: QueryMaker {
                scene_box: cache.scene_box(),
            },
        }
    }
}

impl RadianceSource for CacheSource<'_> {
    fn radiance(&self, queries: &[RadianceQuery]) -> Vec<Vec3> {
        let records: Vec<CacheQuery> = queries
            .iter()
            .map(|q| self.queries.cache_query(q))
            .collect();
        self.cache
            .infer(&records)
            .into_iter()
            .map(Vec3::from_array)
            .collect()
    }
}
