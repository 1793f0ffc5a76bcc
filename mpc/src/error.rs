//! Why an MPC cannot be set up.

use crate::layout::Rows;
use crate::model;
use protocol::MAX_HORIZON;

/// Why an MPC cannot be set up for a configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MpcError {
    #[error("terminal weight: {0}")]
    Dare(#[from] model::DareError),
    #[error("horizon {0} is outside 1..={MAX_HORIZON}")]
    Horizon(usize),
    #[error("clarabel refused the conic program ({0:?})")]
    Solver(Rows),
}

/// The horizon an MPC can be set up with: `1..=MAX_HORIZON` (the scenario's validator
/// holds it too; an MPC set up from an unvalidated scenario checks it here).
pub fn check_horizon(horizon: usize) -> Result<(), MpcError> {
    if horizon == 0 || horizon > MAX_HORIZON {
        return Err(MpcError::Horizon(horizon));
    }
    Ok(())
}
