//! Typed errors of this crate, and of the crates below it as they reach a comparison: a method
//! that cannot be prepared or restarted, arguments that do not parse or are out of bounds.
//! Each displays as the one line the CLI prints after `error:`.

use nrc_cache::CacheError;
use nrc_render::error::{PassError, TerminationError};
use nrc_train::error::TrainError;

/// An error of the harness.
#[derive(Debug, thiserror::Error)]
pub enum HarnessError {
    #[error(transparent)]
    Cache(#[from] CacheError),
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error(transparent)]
    Pass(#[from] PassError),
    #[error(transparent)]
    Termination(#[from] TerminationError),
    /// One setting or argument outside its bounds.
    #[error("{setting} must {bound}, got {got}")]
    OutOfBounds {
        setting: &'static str,
        bound: &'static str,
        got: String,
    },
    /// Neither or both of the comparison's budgets.
    #[error("give exactly one of --equal-time MS and --equal-spp N")]
    BudgetChoice,
    /// Text that should be three comma-separated numbers.
    #[error("expected three comma-separated numbers x,y,z, got `{0}`")]
    NotThreeNumbers(String),
    /// Text that should be a finite number.
    #[error("`{text}` is not a finite number{context}")]
    NotANumber { text: String, context: String },
    /// A setting that cannot be set up for this scene or call (the message says why).
    #[error("{0}")]
    Setup(String),
}

impl HarnessError {
    /// `setting` outside `bound`, with the value it had.
    pub fn bounds(setting: &'static str, bound: &'static str, got: impl ToString) -> Self {
        Self::OutOfBounds {
            setting,
            bound,
            got: got.to_string(),
        }
    }
}
