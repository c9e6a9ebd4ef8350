//! Typed errors of this crate: producer names and mixes that do not parse, settings out of
//! their bounds, producers that cannot serve a scene. Each displays as the one line the CLI
//! prints after `error:`.

/// An error of the producers or the online loop's settings.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TrainError {
    /// A producer name that names no producer.
    #[error("unknown producer `{name}`; known: {known}")]
    UnknownProducer { name: String, known: &'static str },
    /// A mix entry without `=`.
    #[error("mix entry `{entry}` needs NAME=SHARE; {known}")]
    MixEntry { entry: String, known: &'static str },
    /// A mix share that is not a positive number.
    #[error("share `{share}` of `{name}` must be a positive number")]
    Share { name: String, share: String },
    /// `mix:` with nothing after it.
    #[error("an empty mix; {known}")]
    EmptyMix { known: &'static str },
    /// One setting outside its bounds.
    #[error("{setting} must {bound}, got {got}")]
    OutOfBounds {
        setting: String,
        bound: &'static str,
        got: String,
    },
    /// A producer of light paths on a scene that nothing lights.
    #[error(
        "producer {producer} cannot serve this scene: nothing lights it (no emissive triangle, punctual light or environment), so its light paths have nowhere to start; use pt or pt-sl instead"
    )]
    Unlit { producer: String },
}

impl TrainError {
    /// `setting` outside `bound` ("lie in [0, 1]", "be at least 1"), with the value it had.
    pub fn bounds(setting: impl Into<String>, bound: &'static str, got: impl ToString) -> Self {
        Self::OutOfBounds {
            setting: setting.into(),
            bound,
            got: got.to_string(),
        }
    }
}
