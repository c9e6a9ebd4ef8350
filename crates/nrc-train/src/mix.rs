//! The configuration that chooses producers and mixes them: producer names (`pt`, `pt-sl`,
//! `bt`, `lt`, `sppc`, `mix:pt-sl=0.5,sppc=0.5`), their options, and the mix that splits a
//! frame's budget between them.

use std::fmt;
use std::str::FromStr;

use nrc_render::sampler::Stream;
use nrc_scene::Scene;

use crate::error::TrainError;
use crate::producer::{Produced, Producer, ProducerContext};
use crate::producers::{
    bt::BidirectionalProducer, lt::LightProducer, pt::PathProducer, sppc::SppcProducer,
};

/// Settings of the producers that have any (defaults: the producers' own).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProducerOptions {
    /// Light training: fraction of the budget at uniformly area-sampled surface points.
    pub lt_surface_balance: f32,
    /// Light training: fraction of the budget at camera primary hits.
    pub lt_camera_balance: f32,
    /// SPPC: query balls kept.
    pub sppc_capacity: usize,
    /// SPPC: fraction of the balls replaced each frame.
    pub sppc_replace_fraction: f32,
    /// SPPC: initial radius, as a fraction of the scene bounds' diagonal.
    pub sppc_initial_radius: f32,
    /// SPPC: photon paths per training record.
    pub sppc_photons_per_record: f32,
    /// SPPC: progressive radius reduction α.
    pub sppc_alpha: f32,
    /// SPPC: reject photons whose normal differs from the ball's.
    pub sppc_normal_reject: bool,
}

impl Default for ProducerOptions {
    fn default() -> Self {
        let (lt, sppc) = (LightProducer::default(), SppcProducer::default());
        Self {
            lt_surface_balance: lt.surface_balance,
            lt_camera_balance: lt.camera_balance,
            sppc_capacity: sppc.capacity,
            sppc_replace_fraction: sppc.replace_fraction,
            sppc_initial_radius: sppc.initial_radius,
            sppc_photons_per_record: sppc.photons_per_record,
            sppc_alpha: sppc.alpha,
            sppc_normal_reject: sppc.normal_reject,
        }
    }
}

impl ProducerOptions {
    fn light(&self) -> LightProducer {
        LightProducer {
            surface_balance: self.lt_surface_balance,
            camera_balance: self.lt_camera_balance,
        }
    }

    fn sppc(&self) -> SppcProducer {
        let mut p = SppcProducer::default();
        p.capacity = self.sppc_capacity;
        p.replace_fraction = self.sppc_replace_fraction;
        p.initial_radius = self.sppc_initial_radius;
        p.photons_per_record = self.sppc_photons_per_record;
        p.alpha = self.sppc_alpha;
        p.normal_reject = self.sppc_normal_reject;
        p
    }

    /// Checks every setting, naming the first bad one.
    pub fn validate(&self) -> Result<(), TrainError> {
        self.light().validate()?;
        self.sppc().validate()
    }
}

/// One producer and its settings, as named in a configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProducerKind {
    /// Path tracing; `self_learning` ends training suffixes in the cache.
    Pt { self_learning: bool },
    /// Bidirectional training.
    Bt,
    /// Light training.
    Lt,
    /// Sparse progressive photon collection.
    Sppc,
}

/// A mix of producers with their shares of the record budget (shares sum to 1).
#[derive(Clone, Debug, PartialEq)]
pub struct ProducerSpec {
    pub parts: Vec<(ProducerKind, f32)>,
}

/// The grammar of producer names, for help texts and errors.
pub const PRODUCER_NAMES: &str = "pt (path tracing), pt-sl (path tracing with self-learning), bt (bidirectional), \
     lt (light training), sppc (sparse progressive photon collection), or mix:NAME=SHARE,NAME=SHARE,... \
     (e.g. mix:pt-sl=0.5,sppc=0.5)";

impl ProducerKind {
    fn parse(s: &str) -> Result<Self, TrainError> {
        Ok(match s.trim() {
            "pt" => Self::Pt {
                self_learning: false,
            },
            "pt-sl" => Self::Pt {
                self_learning: true,
            },
            "bt" => Self::Bt,
            "lt" => Self::Lt,
            "sppc" => Self::Sppc,
            other => {
                return Err(TrainError::UnknownProducer {
                    name: other.to_string(),
                    known: PRODUCER_NAMES,
                });
            }
        })
    }

    /// The producer with `options`.
    pub fn build(self, options: &ProducerOptions) -> Box<dyn Producer> {
        match self {
            Self::Pt { self_learning } => Box::new(PathProducer::new(self_learning)),
            Self::Bt => Box::new(BidirectionalProducer::default()),
            Self::Lt => Box::new(options.light()),
            Self::Sppc => Box::new(options.sppc()),
        }
    }
}

impl fmt::Display for ProducerKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Pt {
                self_learning: false,
            } => "pt",
            Self::Pt {
                self_learning: true,
            } => "pt-sl",
            Self::Bt => "bt",
            Self::Lt => "lt",
            Self::Sppc => "sppc",
        })
    }
}

impl FromStr for ProducerSpec {
    type Err = TrainError;

    fn from_str(s: &str) -> Result<Self, TrainError> {
        let Some(list) = s.trim().strip_prefix("mix:") else {
            return Ok(Self {
                parts: vec![(ProducerKind::parse(s)?, 1.0)],
            });
        };
        let mut parts = Vec::new();
        for item in list.split(',') {
            let (name, text) = item.split_once('=').ok_or_else(|| TrainError::MixEntry {
                entry: item.to_string(),
                known: PRODUCER_NAMES,
            })?;
            let share = match text.trim().parse::<f32>() {
                Ok(v) if v.is_finite() && v > 0.0 => v,
                _ => {
                    return Err(TrainError::Share {
                        name: name.to_string(),
                        share: text.to_string(),
                    });
                }
            };
            parts.push((ProducerKind::parse(name)?, share));
        }
        if parts.is_empty() {
            return Err(TrainError::EmptyMix {
                known: PRODUCER_NAMES,
            });
        }
        let total: f32 = parts.iter().map(|p| p.1).sum();
        for p in &mut parts {
            p.1 /= total;
        }
        Ok(Self { parts })
    }
}

impl fmt::Display for ProducerSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.parts.as_slice() {
            [(k, _)] => write!(f, "{k}"),
            parts => {
                let items: Vec<String> = parts.iter().map(|(k, s)| format!("{k}={s}")).collect();
                write!(f, "mix:{}", items.join(","))
            }
        }
    }
}

/// The configured producers of a frame, each with its share of the budget.
pub struct ProducerMix {
    parts: Vec<(Box<dyn Producer>, f32)>,
}

impl ProducerMix {
    pub fn new(spec: &ProducerSpec, options: &ProducerOptions) -> Self {
        Self {
            parts: spec
                .parts
                .iter()
                .map(|(k, s)| (k.build(options), *s))
                .collect(),
        }
    }

    /// Whether every producer of the mix can serve `scene`; the first error.
    pub fn check(&self, scene: &Scene) -> Result<(), TrainError> {
        self.parts.iter().try_for_each(|(p, _)| p.check(scene))
    }

    /// Runs every producer on its share of `budget` and concatenates the batches (with their
    /// weights).
    pub fn produce(&mut self, ctx: &ProducerContext, budget: usize, seed: u64) -> Produced {
        let mut out = Produced::default();
        let mut left = budget;
        let n = self.parts.len();
        for (i, (producer, share)) in self.parts.iter_mut().enumerate() {
            // The last producer takes what rounding left, so shares sum to the budget.
            let b = if i + 1 == n {
                left
            } else {
                ((budget as f32 * *share).round() as usize).min(left)
            };
            left -= b;
            let p = producer.produce(ctx, b, Stream::Producer(i as u32).seed(seed));
            out.batch.append(p.batch);
            out.stats.add(&p.stats);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use nrc_cache::TrainingBatch;
    use nrc_render::PathTracer;

    use super::*;
    use crate::query::QueryMaker;

    /// A scene of one unlit triangle.
    fn one_triangle() -> Scene {
        Scene::from_description(nrc_scene::SceneDescription {
            positions: vec![glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y],
            triangles: vec![[0, 1, 2]],
            triangle_materials: vec![0],
            triangle_meshes: vec![0],
            mesh_names: vec!["t".into()],
            materials: vec![nrc_scene::Material::default()],
            ..Default::default()
        })
        .unwrap()
    }

    /// A producer of `budget` records weighted `w` (or unweighted).
    struct Weighted(Option<f32>);

    impl Producer for Weighted {
        fn name(&self) -> &str {
            "weighted"
        }
        fn produce(&mut self, _: &ProducerContext, budget: usize, _: u64) -> Produced {
            let batch = TrainingBatch {
                queries: vec![Default::default(); budget],
                targets: vec![[1.0; 3]; budget],
                weights: self.0.map(|w| vec![w; budget]),
            };
            Produced {
                batch,
                stats: Default::default(),
            }
        }
    }

    /// The mix keeps every producer's record weights (it dropped them once).
    #[test]
    fn a_mix_keeps_the_weights_of_its_producers() {
        let scene = one_triangle();
        let queries = QueryMaker::new(&scene.bounds());
        let ctx = ProducerContext {
            scene: &scene,
            camera: &scene.camera,
            cache: &nrc_render::ZeroSource,
            queries: &queries,
            starts: &[],
            tracer: PathTracer::default(),
        };
        let mut mix = ProducerMix {
            parts: vec![
                (Box::new(Weighted(Some(0.25))), 0.5),
                (Box::new(Weighted(None)), 0.25),
                (Box::new(Weighted(Some(3.0))), 0.25),
            ],
        };
        let out = mix.produce(&ctx, 8, 1);
        assert_eq!(out.batch.queries.len(), 8);
        assert_eq!(
            out.batch.weights.as_deref(),
            Some(&[0.25, 0.25, 0.25, 0.25, 1.0, 1.0, 3.0, 3.0][..])
        );
        // Chunks taken for the optimisation steps keep them too.
        let chunk = out.batch.select(&[7, 0, 4]);
        assert_eq!(chunk.weights.as_deref(), Some(&[3.0, 0.25, 1.0][..]));
        let unweighted = ProducerMix {
            parts: vec![(Box::new(Weighted(None)), 1.0)],
        }
        .produce(&ctx, 4, 1);
        assert_eq!(unweighted.batch.weights, None);
    }

    /// Light-path producers serve a scene lit only by the environment (their light paths start
    /// there too) and refuse one that nothing lights; path tracing serves both.
    #[test]
    fn light_path_producers_need_a_light() {
        let mut scene = one_triangle();
        let options = ProducerOptions::default();
        for name in ["bt", "lt", "sppc", "mix:pt-sl=0.5,sppc=0.5"] {
            let mix = ProducerMix::new(&name.parse().unwrap(), &options);
            let e = mix.check(&scene).unwrap_err();
            assert!(matches!(e, TrainError::Unlit { .. }), "{name}: {e}");
            let e = e.to_string();
            assert!(
                e.contains("nothing lights it") && e.contains("pt-sl"),
                "{name}: {e}"
            );
        }
        for name in ["pt", "pt-sl"] {
            let mix = ProducerMix::new(&name.parse().unwrap(), &options);
            assert!(mix.check(&scene).is_ok(), "{name}");
        }
        scene.set_environment(nrc_scene::Environment::constant(glam::Vec3::ONE));
        for name in ["bt", "lt", "sppc", "mix:pt-sl=0.5,sppc=0.5", "pt"] {
            let mix = ProducerMix::new(&name.parse().unwrap(), &options);
            assert!(mix.check(&scene).is_ok(), "{name} under an environment");
        }
    }

    #[test]
    fn specs_parse_and_print() {
        for name in ["pt", "pt-sl", "bt", "lt", "sppc"] {
            assert_eq!(name.parse::<ProducerSpec>().unwrap().to_string(), name);
        }
        let mix: ProducerSpec = "mix:pt-sl=1,sppc=3".parse().unwrap();
        assert_eq!(mix.parts.len(), 2);
        assert!((mix.parts[1].1 - 0.75).abs() < 1e-6);
        for bad in [
            "",
            "ptx",
            "mix:",
            "mix:pt",
            "mix:pt=0",
            "mix:pt=-1",
            "mix:pt=x",
            "mix:foo=1",
        ] {
            assert!(bad.parse::<ProducerSpec>().is_err(), "{bad}");
        }
    }
}
