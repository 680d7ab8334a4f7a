//! granseg's numerical core: the segregation-diffusion model of docs/model.md,
//! its implicit adaptive stepper, the direct steady-state solve and the
//! parallel sweep. Pure Rust; the PyO3 layer lives in `bindings.rs` behind
//! the `python` feature, so `cargo test` and `cargo bench` need no Python.
//! The pressure-coupled Newton matrix (`pressure_coupled`, faer's sparse LU)
//! is behind the `pressure-coupled` feature: the bindings do not use it.

// The kernels index several slices (a band, its right-hand side, a Jacobian's row) with one
// loop variable; zipped iterators over three or four of them read worse than the index.
#![allow(clippy::needless_range_loop)]

pub mod banded;
pub mod error;
pub mod exact_jacobian;
pub mod flux;
pub mod laws;
pub mod layers;
pub mod limits;
pub mod model;
pub mod params;
#[cfg(feature = "pressure-coupled")]
pub mod pressure_coupled;
pub mod rosenbrock;
pub mod sensitivity;
pub mod steady;
pub mod stepper;
pub mod sweep;
pub mod tridiag;

#[cfg(feature = "python")]
mod bindings;

pub use error::SolveError;
pub use params::Params;
pub use stepper::{integrate, simulate, Stats, Tolerances};
