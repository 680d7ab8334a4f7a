//! Errors of the numerical core. The binding layer maps them to Python
//! exceptions (ValueError for bad input, SolverError for numerical failure).

use std::fmt;

#[derive(Clone, Debug, PartialEq)]
pub enum SolveError {
    /// A parameter is outside its physical range.
    InvalidParameter {
        name: String,
        value: f64,
        range: String,
    },
    /// A parameter name that the model does not have.
    UnknownParameter(String),
    /// Bad non-parameter input (grid, times, tolerances, measured map).
    InvalidInput(String),
    /// Newton's method failed even at the smallest allowed step.
    NewtonFailure { t: f64, reason: String },
    /// The steady-state shooting did not converge.
    SteadyFailure(String),
    /// The caller's stop flag was set (Ctrl-C in Python): the work was abandoned.
    Interrupted,
    /// An allocation within the size limits (`limits.rs`) was refused.
    OutOfMemory(String),
}

impl fmt::Display for SolveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SolveError::InvalidParameter { name, value, range } => {
                write!(
                    f,
                    "parameter {name} = {value} is out of range: must be {range}"
                )
            }
            SolveError::UnknownParameter(name) => write!(f, "unknown model parameter {name:?}"),
            SolveError::InvalidInput(msg) => write!(f, "{msg}"),
            SolveError::NewtonFailure { t, reason } => {
                write!(f, "time stepper failed at t = {t} s: {reason}")
            }
            SolveError::SteadyFailure(msg) => write!(f, "steady-state solve failed: {msg}"),
            SolveError::Interrupted => write!(f, "interrupted"),
            SolveError::OutOfMemory(msg) => write!(f, "out of memory: {msg}"),
        }
    }
}

impl std::error::Error for SolveError {}

impl SolveError {
    /// True for errors caused by the caller's input (ValueError in Python).
    pub fn is_input_error(&self) -> bool {
        matches!(
            self,
            SolveError::InvalidParameter { .. }
                | SolveError::UnknownParameter(_)
                | SolveError::InvalidInput(_)
        )
    }
}
