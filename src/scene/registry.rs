//! The one registry of domains: the only place in `scene/` that names one.
//!
//! Adding a domain is a folder (`src/<domain>/` with its `scene.rs`) and one line here.

use super::{Context, Scene, SceneError};
use crate::limits::Limits;
use crate::simulation::Simulation;
use std::path::Path;

/// A domain a scene can hold: the top-level table it owns and the function that builds its
/// simulation from that table.
pub struct Domain {
    /// The scene table (`cloth` for `[cloth]`).
    pub table: &'static str,
    /// Builds the system from the table (errors located in the scene file).
    pub build: fn(&Context<'_>) -> Result<Box<dyn Simulation>, SceneError>,
}

/// A file format that is a whole scene of its own, chosen by extension.
pub struct Format {
    /// The file extension, lower case, without the dot.
    pub extension: &'static str,
    /// Reads the file into a scene within the limits.
    pub load: fn(&Path, &Limits) -> Result<Scene, SceneError>,
}

/// The domains, in the order a scene's systems are built and stepped: rigid bodies
/// first, so that the systems they are moving obstacles for see them where they are at
/// the end of the step.
pub const DOMAINS: &[Domain] = &[
    #[cfg(feature = "rigid")]
    Domain {
        table: "rigid",
        build: crate::rigid::scene::build,
    },
    #[cfg(feature = "mass-spring")]
    Domain {
        table: "mass_spring",
        build: crate::mass_spring::scene::build,
    },
    #[cfg(feature = "cloth")]
    Domain {
        table: "cloth",
        build: crate::cloth::scene::build,
    },
    #[cfg(feature = "fem")]
    Domain {
        table: "fem",
        build: crate::fem::scene::build,
    },
    #[cfg(feature = "fluid")]
    Domain {
        table: "fluid",
        build: crate::fluid::scene::build,
    },
    #[cfg(feature = "anim")]
    Domain {
        table: "anim",
        build: crate::anim::scene::build,
    },
    #[cfg(feature = "modal")]
    Domain {
        table: "sound",
        build: crate::modal::scene::build,
    },
];

/// Scene files other than TOML.
pub const FORMATS: &[Format] = &[
    #[cfg(feature = "mass-spring")]
    Format {
        extension: "w",
        load: crate::mass_spring::world::load_scene,
    },
];
