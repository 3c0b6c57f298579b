//! # largestep
//!
//! Data-oriented kernels for physically based animation and simulation. See
//! `docs/architecture.md` for the layout and the conventions.
pub use largestep_kernels as kernels;

pub mod machine;

pub mod soa;
pub mod sparse;
pub mod solve;
pub mod integrate;
#[cfg(feature = "mass-spring")]
pub mod mass_spring;
pub mod io;
#[cfg(feature = "mass-spring")]
pub mod scene;
#[cfg(feature = "cli")]
pub mod study;
