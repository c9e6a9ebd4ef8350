//! The training-data producers. Each turns light transport into [`nrc_cache::TrainingBatch`]
//! records (query, outgoing radiance with the query point's own emission excluded).

pub mod bt;
pub mod lt;
pub mod pt;
pub mod sppc;
