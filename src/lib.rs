#![doc = include_str!("../README.md")]
//!
//! See `docs/architecture.md` for the layout and the conventions.
pub use largestep_kernels as kernels;

// Lets files shared with the integration tests (`study/problems.rs`) name the crate the
// same way in both.
extern crate self as largestep;

pub mod machine;
#[cfg(feature = "cli")]
pub mod plot;
pub mod render;
pub mod shapes;

#[cfg(feature = "anim")]
pub mod anim;
#[cfg(feature = "cloth")]
pub mod cloth;
pub mod collide;
#[cfg(feature = "fem")]
pub mod fem;
#[cfg(feature = "fluid")]
pub mod fluid;
pub mod haptics;
pub mod integrate;
pub mod io;
pub mod limits;
pub mod loads;
#[cfg(feature = "mass-spring")]
pub mod mass_spring;
#[cfg(feature = "modal")]
pub mod modal;
#[cfg(feature = "rigid")]
pub mod rigid;
pub mod scene;
pub mod simulation;
pub mod soa;
pub mod solve;
pub mod sparse;
#[cfg(feature = "cli")]
pub mod study;
pub mod validate;
