//! Typed errors of this crate: pass names and their parameters ([`PassError`]), the settings
//! they hold ([`SettingsError`]), probe volumes ([`VolumeError`]) and termination names
//! ([`TerminationError`]). Each displays as the one line the CLI prints after `error:`.

use glam::UVec3;

/// A pass name that does not parse into a pass.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PassError {
    /// No registered pass claims the name.
    #[error("unknown pass `{name}`; known: {known}")]
    UnknownPass { name: String, known: String },
    /// A parameter without `=`.
    #[error("pass `{pass}`: parameter `{text}` is not KEY=VALUE")]
    NotKeyValue { pass: String, text: String },
    /// A value that does not read as its key's kind or lies outside its range.
    #[error("pass `{pass}`: bad value `{value}` for `{key}` ({expected})")]
    BadValue {
        pass: String,
        key: String,
        value: String,
        expected: String,
    },
    /// A parameter given to a pass that takes none.
    #[error("pass `{pass}`: unknown parameter `{key}` (this pass takes no parameters)")]
    NoParameters { pass: String, key: String },
    /// A parameter the pass does not declare.
    #[error("pass `{pass}`: unknown parameter `{key}` (known: {known})")]
    UnknownParameter {
        pass: String,
        key: String,
        known: String,
    },
    /// `KEY=VALUE` parameters given to the cache-terminated passes, whose termination takes its
    /// own after its colon.
    #[error(
        "pass `{pass}`: takes no KEY=VALUE parameters (a termination takes its own after its colon, e.g. cache-bth:8)"
    )]
    TerminationParameters { pass: String },
    /// A termination in a pass's name that does not parse.
    #[error("pass `{pass}`: {source}")]
    Termination {
        pass: String,
        source: TerminationError,
    },
    /// Parameters that parse but cannot work together.
    #[error("pass `{pass}`: {source}")]
    Invalid { pass: String, source: SettingsError },
}

/// A pass's settings that cannot work.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SettingsError {
    /// One setting outside its bounds.
    #[error("{setting} must {bound}, got {got}")]
    OutOfBounds {
        setting: &'static str,
        bound: String,
        got: String,
    },
    /// A combination of settings that cannot work, said in words.
    #[error("{0}")]
    Combination(&'static str),
    /// The probe volume's settings.
    #[error(transparent)]
    Volume(#[from] VolumeError),
}

impl SettingsError {
    /// `setting` outside `bound` ("lie in [0, 1]", "be positive"), with the value it had.
    pub fn bounds(setting: &'static str, bound: impl Into<String>, got: impl ToString) -> Self {
        Self::OutOfBounds {
            setting,
            bound: bound.into(),
            got: got.to_string(),
        }
    }
}

/// A probe volume that cannot be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum VolumeError {
    #[error("ddgi: the scene box is empty or not finite")]
    EmptyBox,
    #[error("ddgi: rays per probe, texels per side and the sweep must be at least 1")]
    Zero,
    #[error("ddgi: at most 16384 rays per probe and 64 texels per side")]
    TooLarge,
    #[error("ddgi: hysteresis must be in [0, 1), got {0}")]
    Hysteresis(f32),
    #[error("ddgi: attenuation must lie in [0, 100], got {0}")]
    Attenuation(f32),
    #[error("ddgi: probe counts {0} must be at least 1 and at most 65536 in all")]
    ProbeCounts(UVec3),
}

/// A termination name that does not parse.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TerminationError {
    #[error("termination `{name}`: the parameter must be a positive number, got `{param}`")]
    BadParameter { name: String, param: String },
    #[error("unknown termination `{name}`; known: {known}")]
    Unknown { name: String, known: &'static str },
}
