//! Inference passes: the techniques that turn a scene, a camera and (for most) a radiance
//! source into a frame. One file per technique, each a state struct kept across frames with
//! named phases, in the manner of kajiya's renderers:
//!
//! 1. [`RenderPass::prepare`]: per-frame upkeep before tracing (history buffers, probe or
//!    light updates);
//! 2. [`RenderPass::trace`]: the frame's paths, up to the points where they want far-field
//!    radiance; returns those queries;
//! 3. the radiance source answers every query of the frame in one batch ([`run`] does this);
//! 4. [`RenderPass::resolve`]: the answers combined into the image.
//!
//! A pass is chosen by a [`PassSpec`], which parses from the command line (`--pass NAME`) and
//! from JSON (the same name as a string). **Adding a technique**: one file here with its
//! settings (a [`PassConfig`] whose parameters are declared once as [`params::Params`]), its
//! [`PassKind`] named `KIND`, its state struct and its [`RenderPass`] implementation; then its
//! module's name in the `passes!` list below. Parsing, printing, `--pass`'s help, `nrc
//! compare`'s method names and the registry tests then reach it.
//!
//! Passes know nothing of burn: the cache reaches them as a [`RadianceSource`](crate::source::RadianceSource).

/// The registered passes: each module is declared here and its `KIND` listed in [`REGISTRY`],
/// in the order names are tried (and help is printed).
macro_rules! passes {
    ($($pass:ident),* $(,)?) => {
        $(pub mod $pass;)*
        /// Every pass kind, in the order [`PassSpec`]'s parser tries them.
        pub static REGISTRY: &[&PassKind] = &[$(&$pass::KIND),*];
    };
}

passes!(
    path_traced,
    cache_terminated,
    restir_di,
    restir_gi,
    ddgi_terminated,
    ddgi_restir,
    instant_radiosity,
);

pub mod frame;
pub mod hash_grid;
pub mod params;
pub mod reuse;
pub mod screen;
pub mod spec;
pub mod split;

use std::str::FromStr;

pub use cache_terminated::{
    CacheTerminatedPass, CacheTerminatedSettings, TERMINATION_NAMES, Termination,
};
pub use ddgi_restir::{DdgiRestirPass, DdgiRestirSettings, SurfaceLight};
pub use ddgi_terminated::{DdgiTerminatedPass, DdgiTerminatedSettings};
pub use frame::{
    FrameInput, PassOutput, PassStats, PassView, PhaseTimes, RenderPass, TerminationPoint, Warmth,
    run,
};
pub use instant_radiosity::{InstantRadiosityPass, IrSettings, VplMode};
pub use path_traced::{PathTracedPass, PathTracedSettings};
pub use restir_di::{RestirDiPass, RestirDiSettings};
pub use restir_gi::{GiReuse, RestirGiPass, RestirGiSettings};
pub use spec::{PassConfig, PassKind, PassSpec};

use crate::error::PassError;
use params::Param;

/// The registered kind that claims `name`, and what it made of it.
pub fn find(name: &str) -> Option<(&'static PassKind, Result<PassSpec, PassError>)> {
    let name = name.trim();
    REGISTRY
        .iter()
        .find_map(|kind| (kind.parse)(name).map(|r| (*kind, r)))
}

impl FromStr for PassSpec {
    type Err = PassError;

    fn from_str(s: &str) -> Result<Self, PassError> {
        match find(s) {
            Some((_, r)) => r,
            None => Err(PassError::UnknownPass {
                name: s.trim().to_string(),
                known: names(),
            }),
        }
    }
}

impl<'de> serde::Deserialize<'de> for PassSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

impl Default for PassSpec {
    /// Paths ending in the cache by the spread heuristic, with NEE.
    fn default() -> Self {
        CacheTerminatedSettings::default().into()
    }
}

/// The grammar of every pass name, on one line (errors).
pub fn names() -> String {
    REGISTRY
        .iter()
        .map(|k| {
            let params = (k.variants)().iter().any(|v| !v.params().is_empty());
            format!("{}{}", k.grammar, if params { "[:PARAMS]" } else { "" })
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// Every pass with its parameters, their defaults and ranges (`--pass`'s help).
pub fn help() -> String {
    let mut out = String::from(
        "The inference pass, with parameters after a colon (NAME:KEY=VALUE,KEY=VALUE):\n",
    );
    for kind in REGISTRY {
        out.push_str(&format!("\n{}: {}\n", kind.grammar, kind.about));
        // Variants that take the same keys share one list.
        let mut groups: Vec<(Vec<String>, Vec<Param>)> = Vec::new();
        for v in (kind.variants)() {
            let p = v.params();
            match groups.iter_mut().find(|(_, q)| *q == p) {
                Some((names, _)) => names.push(v.to_string()),
                None => groups.push((vec![v.to_string()], p)),
            }
        }
        let listed = groups.iter().filter(|(_, p)| !p.is_empty()).count();
        for (names, p) in groups.iter().filter(|(_, p)| !p.is_empty()) {
            if listed > 1 {
                out.push_str(&format!("  {}:\n", names.join(", ")));
            }
            out.push_str(&params::help(p));
        }
    }
    out
}

#[cfg(test)]
mod registry_tests;
