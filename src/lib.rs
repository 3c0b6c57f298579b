#![doc = include_str!("../README.md")]
//!
//! See `docs/architecture.md` for the layout and the conventions.
pub use largestep_kernels as kernels;

pub mod machine;
#[cfg(feature = "cli")]
pub mod plot;
pub mod render;

pub mod cloth;
pub mod integrate;
pub mod io;
#[cfg(feature = "mass-spring")]
pub mod mass_spring;
#[cfg(feature = "mass-spring")]
pub mod scene;
pub mod soa;
pub mod solve;
pub mod sparse;
#[cfg(feature = "cli")]
pub mod study;
