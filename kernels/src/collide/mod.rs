//! Collision detection's data structures and tests (course notes, section 14), shared by
//! every domain through `largestep::collide`: bounding volumes ([`bv`]) and the bounding
//! volume hierarchy ([`bvh`]).
//!
//! Unlike the other kernels these own their arrays (a tree is its storage); each keeps
//! its arrays between builds and queries, so a warm rebuild or query of the same size
//! allocates nothing.

pub mod bv;
pub mod bvh;
pub mod ccd;
pub mod grid;
pub mod manifold;
pub mod narrow;
pub mod prox;
pub mod sdf;
