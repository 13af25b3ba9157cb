//! Structured interior-point solver (placeholder, see below).

use super::{QpError, QpSolution, QpSolver, StageQp};

/// Options of [`StructuredSolver`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StructuredOptions {}

/// Structured solver.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StructuredSolver {
    /// Options.
    pub options: StructuredOptions,
}

impl QpSolver for StructuredSolver {
    fn name(&self) -> &'static str {
        "structured"
    }
    fn solve(&self, _qp: &StageQp, _warm_start: Option<&QpSolution>) -> Result<QpSolution, QpError> {
        Err(QpError::Numerical("not implemented".into()))
    }
}
