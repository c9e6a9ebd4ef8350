//! A pass as named on the command line and in run files: [`PassSpec`], the settings of one
//! registered [`PassKind`] behind the [`PassConfig`] trait. Each pass file declares its kind
//! (its names, what it is, how its names parse) and its settings; the registry in
//! [`super`] lists the kinds and parses names, and nothing else names a pass.

use std::any::Any;
use std::fmt;
use std::sync::Arc;

use super::frame::RenderPass;
use super::params::{self, Param, Params};
use crate::error::{PassError, SettingsError};
use crate::path_tracer::PathTracer;

/// A family of passes: its names, and how a name with its parameters becomes settings.
pub struct PassKind {
    /// The grammar of its names before any parameters, e.g. `restir-di[-biased]`.
    pub grammar: &'static str,
    /// What it does, in a sentence.
    pub about: &'static str,
    /// `nrc compare` takes it as a method by its pass name (at 1 spp; a cache it reads is
    /// trained online by `pt-sl`).
    pub method: bool,
    /// Its variants without parameters (for help and tests).
    pub variants: fn() -> Vec<PassSpec>,
    /// The pass `name` (with its parameters), or `None` when `name` is not of this kind.
    pub parse: fn(&str) -> Option<Result<PassSpec, PassError>>,
}

/// A pass's settings: everything needed to name it and build its state.
pub trait PassConfig: Any + Send + Sync + fmt::Debug {
    fn kind(&self) -> &'static PassKind;
    /// The canonical name (parses back to equal settings).
    fn name(&self) -> String;
    /// The pass's state, with `tracer`'s depth limit and Russian roulette.
    fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass>;
    /// The pass keeps state across frames (history, reservoirs, probes): it gets warm-up
    /// frames and a [`RenderPass::reset`] per independent run.
    fn is_stateful(&self) -> bool {
        false
    }
    /// The pass asks a radiance source for something.
    fn uses_source(&self) -> bool {
        false
    }
    /// Bytes the pass holds per pixel sample of a frame: a screen-space pass keeps the state
    /// of all of a frame's samples at once (G-buffer, paths, reservoirs), so `spp` multiplies
    /// it; 0 for a pass that streams its pixels in tiles. Measured as the growth of the peak
    /// resident size per added sample on the kitchen at 640 × 360 (BENCHMARKS.md, "Memory a
    /// pass holds per pixel sample"), rounded up.
    fn state_bytes_per_sample(&self) -> u64;
    /// Its `KEY=VALUE` parameters and their values.
    fn params(&self) -> Vec<Param> {
        Vec::new()
    }
}

/// A pass and its settings (see the module documentation). Equal when their canonical names
/// are.
#[derive(Clone)]
pub struct PassSpec(Arc<dyn PassConfig>);

impl<T: PassConfig> From<T> for PassSpec {
    fn from(config: T) -> Self {
        Self(Arc::new(config))
    }
}

impl PassSpec {
    /// The settings, when they are of type `T`.
    pub fn get<T: PassConfig>(&self) -> Option<&T> {
        let any: &dyn Any = &*self.0;
        any.downcast_ref()
    }

    pub fn kind(&self) -> &'static PassKind {
        self.0.kind()
    }

    pub fn build(&self, tracer: &PathTracer) -> Box<dyn RenderPass> {
        self.0.build(tracer)
    }

    pub fn is_stateful(&self) -> bool {
        self.0.is_stateful()
    }

    pub fn uses_source(&self) -> bool {
        self.0.uses_source()
    }

    pub fn state_bytes_per_sample(&self) -> u64 {
        self.0.state_bytes_per_sample()
    }

    pub fn params(&self) -> Vec<Param> {
        self.0.params()
    }
}

/// The pass `name`: the base name `base` (before any `:`) is one of `variants`, whose settings
/// then take the parameters after the colon and must pass `validate`; `None` when the base
/// name is none of them.
pub fn parse_variant<N, S>(
    name: &str,
    variants: &[(N, S)],
    validate: fn(&S) -> Result<(), SettingsError>,
) -> Option<Result<PassSpec, PassError>>
where
    N: AsRef<str>,
    S: PassConfig + Params + Clone,
{
    let (base, rest) = name.split_once(':').unwrap_or((name, ""));
    let (_, defaults) = variants.iter().find(|(v, _)| v.as_ref() == base)?;
    let mut settings = defaults.clone();
    Some(
        params::set(name, &mut settings, rest)
            .and_then(|()| {
                validate(&settings).map_err(|source| PassError::Invalid {
                    pass: name.to_string(),
                    source,
                })
            })
            .map(|()| settings.into()),
    )
}

impl PartialEq for PassSpec {
    fn eq(&self, other: &Self) -> bool {
        self.0.name() == other.0.name()
    }
}

impl fmt::Debug for PassSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "PassSpec({})", self.0.name())
    }
}

impl fmt::Display for PassSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0.name())
    }
}

impl serde::Serialize for PassSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}
