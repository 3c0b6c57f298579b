//! One door for every domain: the [`Simulation`] interface that scenes, the CLI, studies
//! and embedding engines talk to, and [`MechSimulation`], the generic simulation of any
//! mechanical model.
//!
//! A simulation owns its model (shared, immutable), its state and its scratch buffers,
//! and steps itself: a model's own contacts, constraints, prescribed motion and step-size
//! control happen *inside* [`Simulation::step`], so an embedder never has to know to call
//! something after it. Around the step it reports energy and solver statistics, says what
//! a frame writes ([`FrameData`]), lists the stages it built and left out (`largestep run
//! --explain`) and gives the scenery to draw.
//!
//! Mechanical domains (mass-spring, cloth, and FEM next) implement [`MechModel`]: the
//! model's data computed once by its builder, with forces and Jacobians taking `&self`
//! and a separate `Work` of scratch buffers. [`MechSimulation`] composes such a model with
//! an integrator ([`crate::integrate::MechStepper`]), its state, its contacts
//! ([`crate::collide::VertexContacts`]) and step-size control ([`StepControl`]).

mod mech;
pub mod path;

pub use mech::{MechModel, MechSimulation, StepControl};

use crate::integrate::{IntegrateError, StepInfo};
use crate::io::{Mesh, MeshRef};

/// One stage of a simulation: built or left out, and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stage {
    /// What it is.
    pub name: &'static str,
    /// Whether it was built.
    pub built: bool,
    /// Size when built, reason when left out.
    pub detail: String,
}

/// The name of the Newton-iteration stage, built by implicit integrators that iterate
/// (left out by the linearised step): the run summary names iterations by it.
pub const NEWTON_STAGE: &str = "Newton iteration";

impl Stage {
    /// The constraint contacts with `obstacles` (`collide::VertexContacts`), or why they
    /// are left out.
    pub fn obstacle_contacts(obstacles: &[crate::collide::Obstacle]) -> Stage {
        if obstacles.is_empty() {
            Stage::left_out("collision structures", "the scene has no colliders")
        } else {
            let kinds: Vec<&str> = obstacles.iter().map(|o| o.kind()).collect();
            Stage::built(
                "obstacle contacts (constraint filter + position correction)",
                kinds.join(", "),
            )
        }
    }

    /// A stage built, with what it holds.
    pub fn built(name: &'static str, detail: impl Into<String>) -> Stage {
        Stage {
            name,
            built: true,
            detail: detail.into(),
        }
    }

    /// A stage left out, with why.
    pub fn left_out(name: &'static str, why: impl Into<String>) -> Stage {
        Stage {
            name,
            built: false,
            detail: why.into(),
        }
    }

    /// The constraint filter's fixed vertices: pinned, prescribed, massless.
    pub fn pinned(count: usize) -> Stage {
        if count > 0 {
            Stage::built(
                "pinned-particle filter",
                format!("{count} pinned particles"),
            )
        } else {
            Stage::left_out("pinned-particle filter", "nothing is pinned")
        }
    }

    /// [`Stage::built`] when `built`, else [`Stage::left_out`].
    pub fn new(name: &'static str, built: bool, detail: impl Into<String>) -> Stage {
        Stage {
            name,
            built,
            detail: detail.into(),
        }
    }
}

/// Kinetic and potential energy (J).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Energy {
    /// Kinetic energy (J).
    pub kinetic: f64,
    /// Potential energy of the conservative forces (J); 0 when the model has none.
    pub potential: f64,
    /// Work done on the system since the start by loads without a potential (wind, force
    /// fields), J: a stable run's total energy changes by this much less what damping,
    /// friction and contacts take.
    pub external_work: f64,
}

impl Energy {
    /// Kinetic plus potential (J).
    pub fn total(&self) -> f64 {
        self.kinetic + self.potential
    }
}

/// What a simulation writes per frame.
///
/// Meshes are what the mechanical domains write; grids are what fluids write (the
/// runner draws their slices and renders their density); skeletons (characters) will be
/// a variant of their own. Sound is not per frame: a system hands its whole sound over
/// through [`Simulation::audio`].
#[derive(Clone, Debug)]
#[non_exhaustive]
pub enum FrameData<'a> {
    /// Vertices with surface triangles, segments (springs, chains), both, or neither
    /// (points).
    Mesh(MeshRef<'a>),
    /// Fields on a grid of cells.
    Grid(GridRef<'a>),
}

/// A field on a grid's cells (one value per cell, x fastest), and what it means, which
/// says how it is drawn.
#[derive(Clone, Copy, Debug)]
pub enum GridField<'a> {
    /// Velocity at cell centres, component-major (3 x cells), m/s: drawn as its
    /// magnitude.
    Speed(&'a [f64]),
    /// Vorticity (1/s): the z component in 2-D (signed), the magnitude in 3-D.
    Vorticity(&'a [f64]),
    /// Smoke density (volume-rendered in 3-D, a grey map in 2-D).
    Density(&'a [f64]),
}

/// A grid of `cells` cubes of side `h` from `origin`, with its fields.
#[derive(Clone, Debug)]
pub struct GridRef<'a> {
    /// Cells along x, y, z (z = 1: 2-D).
    pub cells: [usize; 3],
    /// Cell side (m).
    pub h: f64,
    /// Lower corner (m).
    pub origin: [f64; 3],
    /// Solid cells, if any.
    pub solid: Option<&'a [bool]>,
    /// The fields.
    pub fields: Vec<GridField<'a>>,
}

impl<'a> FrameData<'a> {
    /// The mesh of a mesh frame; an empty mesh for a grid.
    pub fn mesh(&self) -> MeshRef<'a> {
        match self {
            FrameData::Mesh(m) => *m,
            FrameData::Grid(_) => MeshRef {
                positions: &[],
                triangles: &[],
                segments: &[],
            },
        }
    }
}

/// The impulses a system's obstacles gave its vertices over its last step
/// ([`Simulation::contact_impulses`]), for listeners such as modal sound.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ContactImpulses {
    /// When the step began (s).
    pub time: f64,
    /// Its length (s).
    pub dt: f64,
    /// Vertices of the system.
    pub vertex_count: usize,
    /// `(vertex, impulse)` (N s), in the system's initial frame: turned back by the
    /// rotation that best fits the body's present positions to its initial ones, so a
    /// listener holding the body's modes at rest reads them in the modes' frame.
    pub impulses: Vec<(u32, [f64; 3])>,
    /// Rigid bodies of the system (0 for systems of vertices).
    pub bodies: usize,
    /// The impulses each rigid body took at its contact points over the step.
    pub points: Vec<BodyImpulse>,
}

/// An impulse a rigid body took at a contact point over a step ([`ContactImpulses`]), in
/// the body's shape frame: the frame its shape was described in (a box or sphere centred
/// on its origin, a mesh in its file's coordinates times its scale), so a listener
/// holding modes of the same shape at rest reads them in the modes' frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BodyImpulse {
    /// The body's index in its system.
    pub body: u32,
    /// The contact point (m, shape frame, at the body's pose after the step).
    pub point: [f64; 3],
    /// The impulse on the body (N s, shape frame).
    pub impulse: [f64; 3],
}

/// Sound a system made ([`Simulation::audio`]).
#[derive(Clone, Copy, Debug)]
pub struct Audio<'a> {
    /// One value per sample (arbitrary units: the runner scales the file).
    pub samples: &'a [f64],
    /// Samples per second.
    pub sample_rate: u32,
}

/// A table a system writes a block of rows to at every frame (`bodies.csv` of rigid
/// bodies): its file name in the output folder and its header line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameTable {
    /// File name (CSV).
    pub file: &'static str,
    /// The header line, without its newline.
    pub header: &'static str,
}

/// A running simulation of one system (see the module docs).
pub trait Simulation: Send {
    /// Advances by `dt` (s): one step, or several smaller ones when step-size control
    /// halves it, each followed by the model's prescribed motion and contacts. The counts
    /// returned sum over the sub-steps.
    fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError>;
    /// Simulated time (s).
    fn time(&self) -> f64;
    /// Integrator steps taken, sub-steps included.
    fn steps(&self) -> u64;
    /// Kinetic and potential energy now.
    fn energy(&self) -> Energy;
    /// The deepest penetration of the model into an obstacle (m), 0 without obstacles.
    fn max_penetration(&self) -> f64;
    /// What a frame writes now.
    fn frame(&self) -> FrameData<'_>;
    /// The stages built and left out.
    fn stages(&self) -> Vec<Stage>;
    /// Meshes of the fixed scenery (obstacles) for previews; unbounded ones (planes) are
    /// cut to the box `around` (the region the frames show).
    fn scenery(&self, around: ([f64; 3], [f64; 3])) -> Vec<Mesh>;
    /// The integrator's name.
    fn method(&self) -> String;
    /// The linear solver of implicit steps, if any.
    fn linear_solver(&self) -> Option<&'static str>;
    /// `self` as `Any`, to reach the concrete simulation (see
    /// `<dyn Simulation>::downcast_ref`).
    fn as_any(&self) -> &dyn std::any::Any;
    /// What the model found questionable in its input but could run with (nodes no
    /// element uses, say), one line each, for the run summary.
    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }
    /// Starts or stops recording [`Simulation::contact_impulses`] (a listener asked for
    /// them; off by default, since they cost a force evaluation a step). Systems without
    /// contacts ignore it.
    fn record_contact_impulses(&mut self, _on: bool) {}

    /// The contact impulses of the last step, while recording.
    fn contact_impulses(&self) -> Option<&ContactImpulses> {
        None
    }

    /// Whether this system listens to the other systems' contact impulses.
    fn listens(&self) -> bool {
        false
    }

    /// Takes another system's contact impulses of its last step (a listener's; others
    /// ignore them). The error says what does not fit.
    fn listen(&mut self, _impulses: &ContactImpulses) -> Result<(), String> {
        Ok(())
    }

    /// The sound made so far, for systems that make one.
    fn audio(&self) -> Option<Audio<'_>> {
        None
    }

    /// Appends this system's bodies as obstacles for the others to `out`, at their
    /// present poses with their motion (rigid bodies; nothing for the rest).
    fn moving_obstacles(&self, out: &mut Vec<crate::collide::MovingObstacle>) {
        let _ = out;
    }

    /// Whether this system's contacts take other systems' moving obstacles (models
    /// whose contacts are [`crate::collide::VertexContacts`]: the cloth, and the FEM
    /// when it has obstacles of its own).
    fn takes_moving_obstacles(&self) -> bool {
        false
    }

    /// Hands over the other systems' moving obstacles for the next step (one-way: they
    /// feel nothing back).
    fn set_moving_obstacles(&mut self, obstacles: &[crate::collide::MovingObstacle]) {
        let _ = obstacles;
    }

    /// The table this system writes rows to at every frame, if any.
    fn frame_table(&self) -> Option<FrameTable> {
        None
    }

    /// Writes the rows of [`Simulation::frame_table`] for frame `frame` now.
    fn write_frame_rows(&self, frame: usize, w: &mut dyn std::io::Write) -> std::io::Result<()> {
        let _ = (frame, w);
        Ok(())
    }

    /// Whether the system has a volume to write as a frame ([`Simulation::write_volume`]).
    fn has_volume(&self) -> bool {
        false
    }
    /// Writes the system's volume now (a legacy VTK unstructured grid with its fields),
    /// for `[output] frames = "vtk"`.
    fn write_volume(&self, w: &mut dyn std::io::Write, comment: &str) -> std::io::Result<()> {
        let _ = (w, comment);
        Ok(())
    }
}

impl dyn Simulation + '_ {
    /// The concrete simulation, when it is a `T` (for example
    /// `MechSimulation<largestep::cloth::Cloth>`).
    pub fn downcast_ref<T: 'static>(&self) -> Option<&T> {
        self.as_any().downcast_ref()
    }
}
