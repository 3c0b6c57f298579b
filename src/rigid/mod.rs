//! Rigid bodies with contact and joints (issue 19; course notes sections 5, 13 and 14;
//! Baraff's SIGGRAPH course notes "Rigid body simulation"; Catto's sequential impulses,
//! GDC 2005-2014; Guendelman, Bridson and Fedkiw 2003).
//!
//! A body is a shape (sphere, box, capsule or closed mesh) with a density: its mass and
//! inertia come from [`mass`], its frame is its centre of mass along its principal axes,
//! so the body-frame inertia is diagonal. The state is structure-of-arrays: positions of
//! the centres, unit quaternions, linear and angular velocities (world frame, rad/s), one
//! array each. Static bodies never move; kinematic ones move at their given velocity and
//! push dynamic ones without being pushed back.
//!
//! One step of `dt`:
//! 1. **Collision**: boxes around the bodies (grown by the contact margin), sweep and
//!    prune for the pairs, and contact manifolds from the narrow phase
//!    (`kernels::collide::manifold`): boxes clipped face against face, spheres and
//!    capsules in closed form, hulls by GJK and EPA. Points within the margin but still
//!    apart are *speculative*: they let the bodies close the gap and no more. A pair of
//!    polyhedra whose relative pose has barely moved since its manifold was found keeps
//!    it, moved with the bodies (`contact`).
//! 2. **Velocities**: gravity, and the gyroscopic term as the integrator treats it.
//! 3. **Constraints** ([`RigidSolver`]): sequential impulses (projected Gauss-Seidel on
//!    the accumulated impulses, Catto 2005) over contact manifolds (a normal row with
//!    restitution per point; per manifold two friction rows at its centre clamped to
//!    Coulomb's cone `|λt| <= mu sum λn`, and a twist row about the normal clamped by
//!    `mu sum λn |d|` for points at `d` from the centre, as rapier and bepu) and joint
//!    rows (ball, hinge, fixed, distance), warm-started from the last step's impulses;
//!    position errors removed by split impulses (pseudo-velocities that move the bodies
//!    but add no momentum) or by Baumgarte's velocity bias. The alternatives: one-shot
//!    impulses (no accumulation, no warm start: Baraff's impulse response applied pass by
//!    pass) and penalty springs (as the jello: `k depth n - c vn n` per point). Contact
//!    points are solved four at a time in SIMD batches that keep the sequential order
//!    on every body, so the answer is the sequential one (`batch`).
//! 4. **Positions** by the integrator ([`RigidIntegrator`]).
//!
//! A ball dropped on a slab, stepped from an engine:
//!
//! ```
//! use largestep::rigid::{BodyDesc, Motion, RigidDesc, Shape};
//!
//! let mut d = RigidDesc::default(); // gravity -9.81 along y, sequential impulses
//! d.bodies.push(BodyDesc {
//!     motion: Motion::Static,
//!     ..BodyDesc::new(Shape::Box { half: [5.0, 0.5, 5.0] }, [0.0, -0.5, 0.0])
//! });
//! d.bodies.push(BodyDesc::new(Shape::Sphere { radius: 0.5 }, [0.0, 2.0, 0.0]));
//! let (model, mut state, mut work) = d.build()?;
//! for _ in 0..120 {
//!     model.step(&mut state, &mut work, 1.0 / 60.0)?;
//! }
//! assert!((state.x[1][1] - 0.5).abs() < 0.01); // resting on the slab
//! # Ok::<(), largestep::rigid::RigidError>(())
//! ```

mod batch;
mod contact;
pub mod mass;
pub mod scene;
pub mod sleep;
mod solver;
pub mod witkin;

use crate::io::Mesh;
use crate::validate::ModelError;
use largestep_kernels::collide::bv::Aabb;
use largestep_kernels::collide::grid::SweepAndPrune;
use largestep_kernels::quat::{self, Quat};
use largestep_kernels::rigid;
pub(crate) use largestep_kernels::rigid::{inertia_times, mat_t_vec, mat_vec};
use largestep_kernels::v3::{add, cross, dot, length_and_unit, scale, sub};
use std::sync::Arc;

pub use contact::{ContactDiff, ContactPoint};
pub use mass::MassProperties;

/// A body's shape, in its own frame.
#[derive(Clone, Debug)]
pub enum Shape {
    /// A ball of `radius` (m) about the origin.
    Sphere {
        /// m.
        radius: f64,
    },
    /// A box of half extents (m) about the origin.
    Box {
        /// m.
        half: [f64; 3],
    },
    /// Points within `radius` of the segment from `-half_height` to `half_height` on y.
    Capsule {
        /// m.
        half_height: f64,
        /// m.
        radius: f64,
    },
    /// The solid a closed, outward-oriented triangle mesh bounds (mass properties exact;
    /// it collides as its convex hull).
    Mesh(Arc<Mesh>),
}

impl Shape {
    /// `sphere`, `box`, `capsule` or `mesh`.
    pub fn kind(&self) -> &'static str {
        match self {
            Shape::Sphere { .. } => "sphere",
            Shape::Box { .. } => "box",
            Shape::Capsule { .. } => "capsule",
            Shape::Mesh(_) => "mesh",
        }
    }

    /// Mass properties at `density` (kg/m³), in the shape's frame.
    pub fn mass_properties(&self, density: f64) -> Result<MassProperties, ModelError> {
        Ok(match self {
            Shape::Sphere { radius } => mass::solid_sphere(*radius, density),
            Shape::Box { half } => mass::solid_box(*half, density),
            Shape::Capsule {
                half_height,
                radius,
            } => mass::solid_capsule(*half_height, *radius, density),
            Shape::Mesh(m) => mass::mesh(m, density)?,
        })
    }
}

/// How a body moves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Motion {
    /// Moved by forces and contacts.
    #[default]
    Dynamic,
    /// Never moves (infinite mass).
    Static,
    /// Moves at its given velocities whatever touches it (infinite mass).
    Kinematic,
}

/// One body as the user describes it.
#[derive(Clone, Debug)]
pub struct BodyDesc {
    /// The shape.
    pub shape: Shape,
    /// kg/m³, > 0 (ignored for static and kinematic bodies, which have infinite mass).
    pub density: f64,
    /// Where the shape's origin is (m).
    pub position: [f64; 3],
    /// The shape's orientation (unit quaternion w, x, y, z).
    pub orientation: Quat,
    /// Velocity of the centre of mass (m/s).
    pub velocity: [f64; 3],
    /// Angular velocity (rad/s, world frame).
    pub angular_velocity: [f64; 3],
    /// Dynamic, static or kinematic.
    pub motion: Motion,
}

impl BodyDesc {
    /// A dynamic body of `shape` at `position`, at rest, density 1000 kg/m³.
    pub fn new(shape: Shape, position: [f64; 3]) -> BodyDesc {
        BodyDesc {
            shape,
            density: 1000.0,
            position,
            orientation: quat::IDENTITY,
            velocity: [0.0; 3],
            angular_velocity: [0.0; 3],
            motion: Motion::Dynamic,
        }
    }
}

/// A joint between body `a` and body `b` (or the world, `b = None`), anchors in world
/// coordinates at the start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointDesc {
    /// The first body.
    pub a: usize,
    /// The second body, or the world.
    pub b: Option<usize>,
    /// What it holds.
    pub kind: JointKind,
}

/// What a joint holds (anchors and axes in world coordinates at the start).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum JointKind {
    /// The two bodies share the anchor point (3 rows).
    Ball {
        /// m.
        anchor: [f64; 3],
    },
    /// A ball joint that also keeps the bodies' copies of `axis` aligned (5 rows).
    Hinge {
        /// m.
        anchor: [f64; 3],
        /// Unit or not (normalised).
        axis: [f64; 3],
    },
    /// The bodies keep their relative pose (6 rows).
    Fixed {
        /// m.
        anchor: [f64; 3],
    },
    /// The anchors keep their start distance (1 row).
    Distance {
        /// On body a (m).
        anchor_a: [f64; 3],
        /// On body b or in the world (m).
        anchor_b: [f64; 3],
    },
}

impl JointKind {
    /// `ball`, `hinge`, `fixed` or `distance`.
    pub fn name(&self) -> &'static str {
        match self {
            JointKind::Ball { .. } => "ball",
            JointKind::Hinge { .. } => "hinge",
            JointKind::Fixed { .. } => "fixed",
            JointKind::Distance { .. } => "distance",
        }
    }
}

/// How contacts and joints are resolved (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RigidSolver {
    /// Sequential impulses: accumulated, clamped, warm-started (the default).
    SequentialImpulses,
    /// One-shot impulses per contact, pass after pass, without accumulation or warm start.
    Impulse,
    /// Penalty springs per contact point: stiffness (N/m) and damping (N s/m); `None`
    /// picks each from the lighter body's mass so that a contact rings at 1/20 of the
    /// step rate, critically damped.
    Penalty {
        /// N/m.
        stiffness: Option<f64>,
        /// N s/m.
        damping: Option<f64>,
    },
}

impl RigidSolver {
    /// The scene name.
    pub fn name(&self) -> &'static str {
        match self {
            RigidSolver::SequentialImpulses => "sequential-impulses",
            RigidSolver::Impulse => "impulse",
            RigidSolver::Penalty { .. } => "penalty",
        }
    }
}

/// How the bodies' states advance (see [`RigidDesc::integrator`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RigidIntegrator {
    /// Baraff's state (x, q, P, L) by explicit Euler: positions from the old velocities.
    /// Angular momentum conserved exactly without torque; energy grows.
    ExplicitEuler,
    /// Momenta first, then positions from the new velocities, the angular velocity
    /// `I(q)^-1 L` (the default). Angular momentum conserved exactly without torque.
    SymplecticEuler,
    /// Baraff's state by classical Runge-Kutta over the step (forces constant; contact
    /// impulses applied at its start). Angular momentum conserved exactly without torque.
    Rk4,
    /// Angular velocity in the body frame by one Newton step of backward Euler on Euler's
    /// equations `I w' + w x I w = 0` (Catto, GDC 2015), then symplectic positions:
    /// energy never grows; angular momentum drifts by O(dt²).
    ImplicitGyroscopic,
}

impl RigidIntegrator {
    /// The scene names, in the order of the enum.
    pub const NAMES: [&'static str; 4] = [
        "explicit-euler",
        "symplectic-euler",
        "rk4",
        "implicit-gyroscopic",
    ];

    /// The scene name.
    pub fn name(&self) -> &'static str {
        Self::NAMES[*self as usize]
    }

    /// The integrator of a scene name.
    pub fn from_name(s: &str) -> Option<RigidIntegrator> {
        use RigidIntegrator::*;
        [ExplicitEuler, SymplecticEuler, Rk4, ImplicitGyroscopic]
            .into_iter()
            .find(|m| m.name() == s)
    }
}

/// How position errors (penetration, joint drift) are removed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Correction {
    /// Soft constraints with a relax pass (Catto's soft step, Box2D v3): the error is
    /// removed by an implicit spring-damper, and the velocity it took is relaxed away
    /// (the default).
    Soft,
    /// Split impulses: pseudo-velocities that move the bodies this step only (no energy).
    Split,
    /// Baumgarte: a velocity bias `beta / dt` times the error (adds energy).
    Baumgarte,
}

/// A rigid-body world as described (see the module docs).
#[derive(Clone, Debug)]
pub struct RigidDesc {
    /// The bodies.
    pub bodies: Vec<BodyDesc>,
    /// The joints.
    pub joints: Vec<JointDesc>,
    /// m/s².
    pub gravity: [f64; 3],
    /// Contact and joint solver.
    pub solver: RigidSolver,
    /// How states advance.
    pub integrator: RigidIntegrator,
    /// Solver iterations per step, each a sub-step of `dt / iterations` with one pass
    /// over every row (see `solver`).
    pub iterations: usize,
    /// Coefficient of restitution, 0..=1.
    pub restitution: f64,
    /// Coulomb friction coefficient, >= 0.
    pub friction: f64,
    /// Position correction.
    pub correction: Correction,
    /// Fraction of the position error removed per sub-step, 0..=1 (Baumgarte 0.2, split
    /// 0.8; soft correction sets its own from the contact frequency).
    pub beta: Option<f64>,
    /// Body pairs the broad phase may pass on in a step: each holds up to four contact
    /// points, about 2 kB with the solver's rows. A step with more (bodies started
    /// inside one another, or shapes far larger than their spacing) is refused before
    /// the narrow phase allocates for them.
    pub max_pairs: usize,
    /// Bodies at rest fall asleep and leave the step until touched ([`sleep`]); none
    /// sleep when `None`.
    pub sleep: Option<sleep::Sleep>,
    /// Persistent manifolds: a pair of boxes or hulls keeps its contact points (moved
    /// with the bodies, their depths measured again) instead of running the narrow
    /// phase while the pair's relative pose stays within this fraction of the smaller
    /// body's feature size, and this angle in radians, of the pose they were found at;
    /// 0 finds every manifold afresh each step. In 0..=1; default 0.005, the solver's
    /// slop. Rapier's contact recycling (`contact_recycle_distance`, 5 cm) is about
    /// 0.1 on half-metre boxes: `largestep study rigid-reuse` measures what each
    /// setting saves and how stale it lets the contacts get.
    pub contact_reuse: f64,
}

impl Default for RigidDesc {
    fn default() -> Self {
        RigidDesc {
            bodies: Vec::new(),
            joints: Vec::new(),
            gravity: [0.0, -9.81, 0.0],
            solver: RigidSolver::SequentialImpulses,
            integrator: RigidIntegrator::SymplecticEuler,
            iterations: 4,
            restitution: 0.0,
            friction: 0.5,
            correction: Correction::Soft,
            beta: None,
            max_pairs: 1 << 20,
            sleep: None,
            contact_reuse: contact::REUSE,
        }
    }
}

/// Why a rigid world cannot be built or stepped.
#[derive(Debug, thiserror::Error)]
pub enum RigidError {
    /// A bad value in the description.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A body's shape or mass properties are unusable.
    #[error("body {body}: {why}")]
    Body {
        /// Index.
        body: usize,
        /// Why.
        why: String,
    },
    /// A joint is unusable.
    #[error("joint {joint}: {why}")]
    Joint {
        /// Index.
        joint: usize,
        /// Why.
        why: String,
    },
    /// More overlapping body pairs than [`RigidDesc::max_pairs`].
    #[error("step {step}: more than {max} body pairs overlap, the most allowed (bodies inside one another, or shapes far larger than their spacing?)")]
    TooManyPairs {
        /// Step.
        step: u64,
        /// The limit.
        max: usize,
    },
    /// The state went non-finite.
    #[error("step {step}: body {body} has a non-finite {what}")]
    NonFinite {
        /// Step number.
        step: u64,
        /// Index.
        body: usize,
        /// `position`, `orientation`, `velocity`.
        what: &'static str,
    },
}

/// A body's collision geometry in its principal frame.
#[derive(Clone, Debug)]
pub(crate) enum Collider {
    Sphere(f64),
    Box([f64; 3]),
    Capsule(f64, f64),
    Hull(std::sync::Arc<[[f64; 3]]>),
}

/// A joint with its anchors in the bodies' frames.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Joint {
    pub a: usize,
    /// `usize::MAX`: the world.
    pub b: usize,
    pub kind: JointKind,
    /// Anchor in a's frame, and in b's (world for the world).
    pub la: [f64; 3],
    pub lb: [f64; 3],
    /// Hinge axis in a's frame and in b's; distance: the rest length in `axis_a[0]`.
    pub axis_a: [f64; 3],
    pub axis_b: [f64; 3],
    /// Fixed: the rest relative rotation `q_a* q_b`.
    pub rel: Quat,
}

/// The immutable model: masses, inertias, colliders, joints.
#[derive(Clone, Debug)]
pub struct Rigid {
    desc: RigidDesc,
    pub(crate) inv_mass: Vec<f64>,
    /// Principal moments (kg m²) and their inverses (0 for static and kinematic bodies).
    pub(crate) inertia: Vec<[f64; 3]>,
    pub(crate) inv_inertia: Vec<[f64; 3]>,
    pub(crate) mass: Vec<f64>,
    pub(crate) colliders: Vec<Collider>,
    /// A mesh body's sharp hull edges in its body frame (empty for the others): what
    /// other systems' triangles must not let through ([`Rigid::obstacles`]).
    hull_edges: Vec<Arc<[[[f64; 3]; 2]]>>,
    /// Radius of a ball about the centre holding the collider (m).
    pub(crate) bound: Vec<f64>,
    /// A length typical of the body's smallest feature (m): margins and slop scale by it.
    pub(crate) size: Vec<f64>,
    /// The shape's frame in the body's: origin and rotation (shape = body offset).
    frame_origin: Vec<[f64; 3]>,
    frame_rot: Vec<Quat>,
    /// The drawn surfaces: every body's vertices in its body frame, one after the other
    /// (body i's from `surface_start[i]`), and their triangles.
    surface_local: Vec<[f64; 3]>,
    surface_start: Vec<usize>,
    surface_triangles: Arc<[[u32; 3]]>,
    pub(crate) joints: Vec<Joint>,
    /// Body pairs a joint connects (no contacts between them), sorted.
    pub(crate) jointed: Vec<(u32, u32)>,
}

/// Positions, orientations and velocities of every body (structure-of-arrays).
#[derive(Clone, Debug, Default)]
pub struct RigidState {
    /// Centres of mass (m).
    pub x: Vec<[f64; 3]>,
    /// Orientations of the principal frames (unit quaternions w, x, y, z).
    pub q: Vec<Quat>,
    /// Velocities of the centres (m/s).
    pub v: Vec<[f64; 3]>,
    /// Angular velocities (rad/s, world frame).
    pub w: Vec<[f64; 3]>,
    /// s.
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    /// Whether each body is asleep (see [`sleep`]; always false without
    /// [`RigidDesc::sleep`]).
    pub asleep: Vec<bool>,
    /// How long each awake dynamic body has moved slower than the sleep thresholds (s).
    pub rest: Vec<f64>,
    /// The island each asleep body fell asleep with (they wake together).
    pub island: Vec<u64>,
}

/// Scratch for stepping, kept between steps (contact impulses for warm starting). A
/// clone keeps the scratch's capacity, so stepping a restored copy allocates no more
/// than stepping the original would.
#[derive(Debug, Default)]
pub struct RigidWork {
    pub(crate) boxes: Vec<Aabb>,
    /// Each body's `|w|` times its bounding radius (m/s), at the step's start.
    pub(crate) spin: Vec<f64>,
    pub(crate) sap: SweepAndPrune,
    pub(crate) pairs: Vec<[u32; 2]>,
    /// Scratch of the pairs' counting sort.
    pub(crate) pair_starts: Vec<u32>,
    pub(crate) pairs_sorted: Vec<[u32; 2]>,
    pub(crate) contacts: Vec<ContactPoint>,
    pub(crate) previous: Vec<ContactPoint>,
    /// The bodies' rotation matrices at the step's start: formed by the collision stage
    /// (which every step runs first), read by it and by the solver.
    pub(crate) rot: Vec<[[f64; 3]; 3]>,
    pub(crate) kept: contact::KeptManifolds,
    pub(crate) kept_next: contact::KeptManifolds,
    pub(crate) solver: solver::SolverWork,
    pub(crate) hulls: Vec<Vec<[f64; 3]>>,
    pub(crate) sleep: sleep::SleepWork,
}

impl Clone for RigidWork {
    fn clone(&self) -> Self {
        RigidWork {
            boxes: self.boxes.clone(),
            spin: self.spin.clone(),
            sap: self.sap.clone(),
            pairs: clone_keeping_capacity(&self.pairs),
            pair_starts: self.pair_starts.clone(),
            pairs_sorted: clone_keeping_capacity(&self.pairs_sorted),
            contacts: clone_keeping_capacity(&self.contacts),
            previous: clone_keeping_capacity(&self.previous),
            rot: self.rot.clone(),
            kept: self.kept.clone(),
            kept_next: self.kept_next.clone(),
            solver: self.solver.clone(),
            hulls: self.hulls.clone(),
            sleep: self.sleep.clone(),
        }
    }
}

/// A copy of `v` with room for as many items as `v` has room for.
pub(crate) fn clone_keeping_capacity<T: Clone>(v: &Vec<T>) -> Vec<T> {
    let mut out = Vec::with_capacity(v.capacity());
    out.extend_from_slice(v);
    out
}

impl RigidWork {
    /// The contact points of the last step or [`Rigid::find_contacts`], sorted by body
    /// pair, with the impulses the step gave them.
    pub fn contacts(&self) -> &[ContactPoint] {
        &self.contacts
    }
}

/// What one step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RigidStepInfo {
    /// Contact points (speculative ones included).
    pub contacts: usize,
    /// Body pairs the broad phase passed on.
    pub pairs: usize,
    /// Deepest penetration at the start of the step (m).
    pub max_depth: f64,
    /// Contact points that matched last step's (warm-started).
    pub warm: usize,
    /// Pairs whose manifold was kept from an earlier step and moved with the bodies
    /// (their relative pose had barely changed) instead of found again.
    pub reused: usize,
}

impl RigidDesc {
    /// Checks the description and computes the model, its state and its work.
    pub fn build(&self) -> Result<(Rigid, RigidState, RigidWork), RigidError> {
        let n = self.bodies.len();
        let finite3 = |v: [f64; 3]| v.iter().all(|x| x.is_finite());
        if !finite3(self.gravity) {
            return Err(RigidError::Model(ModelError::Value {
                item: "gravity",
                index: self
                    .gravity
                    .iter()
                    .position(|x| !x.is_finite())
                    .unwrap_or(0),
                field: "gravity",
                value: f64::NAN,
                why: "must be finite",
            }));
        }
        let check01 = |v: f64, field: &'static str, hi: f64| {
            if v.is_finite() && (0.0..=hi).contains(&v) {
                Ok(())
            } else {
                Err(RigidError::Model(ModelError::Value {
                    item: "rigid",
                    index: 0,
                    field,
                    value: v,
                    why: if hi == 1.0 {
                        "must be in 0..=1"
                    } else {
                        "must be finite and >= 0"
                    },
                }))
            }
        };
        check01(self.restitution, "restitution", 1.0)?;
        check01(self.friction, "friction", f64::INFINITY)?;
        check01(self.contact_reuse, "contact_reuse", 1.0)?;
        if let Some(b) = self.beta {
            check01(b, "beta", 1.0)?;
        }
        if self.iterations == 0 {
            return Err(RigidError::Model(ModelError::Value {
                item: "rigid",
                index: 0,
                field: "iterations",
                value: 0.0,
                why: "must be >= 1",
            }));
        }
        if let RigidSolver::Penalty { stiffness, damping } = self.solver {
            for (v, f) in [(stiffness, "stiffness"), (damping, "damping")] {
                if let Some(v) = v {
                    check01(v, f, f64::INFINITY)?;
                }
            }
        }
        let mut m = Rigid {
            desc: self.clone(),
            inv_mass: Vec::with_capacity(n),
            inertia: Vec::with_capacity(n),
            inv_inertia: Vec::with_capacity(n),
            mass: Vec::with_capacity(n),
            colliders: Vec::with_capacity(n),
            hull_edges: Vec::with_capacity(n),
            bound: Vec::with_capacity(n),
            size: Vec::with_capacity(n),
            frame_origin: Vec::with_capacity(n),
            frame_rot: Vec::with_capacity(n),
            surface_local: Vec::new(),
            surface_start: vec![0],
            surface_triangles: Vec::new().into(),
            joints: Vec::new(),
            jointed: Vec::new(),
        };
        let mut s = RigidState::default();
        let mut surface_triangles: Vec<[u32; 3]> = Vec::new();
        for (i, b) in self.bodies.iter().enumerate() {
            let bad = |why: String| RigidError::Body { body: i, why };
            let surface = body_surface(b).map_err(bad)?;
            let dynamic = b.motion == Motion::Dynamic;
            if dynamic && !(b.density.is_finite() && b.density > 0.0) {
                return Err(bad(format!(
                    "density must be a finite number > 0, not {}",
                    b.density
                )));
            }
            let q_user = quat::normalize(b.orientation).ok_or_else(|| {
                bad(format!(
                    "orientation {:?} is zero or not finite",
                    b.orientation
                ))
            })?;
            for (v, what) in [
                (b.position, "position"),
                (b.velocity, "velocity"),
                (b.angular_velocity, "angular velocity"),
            ] {
                if !finite3(v) {
                    return Err(bad(format!("{what} {v:?} is not finite")));
                }
            }
            let mp = b
                .shape
                .mass_properties(if dynamic { b.density } else { 1.0 });
            let mp = mp.map_err(|e| bad(e.to_string()))?;
            if dynamic && !(mp.mass > 0.0 && mp.mass.is_finite()) {
                return Err(bad(format!("mass {} kg is not positive", mp.mass)));
            }
            // Principal axes: I = R diag(d) Rᵀ.
            let t = mp.inertia;
            let (d, r) = largestep_kernels::fem_diag::sym_eig3::<f64>([
                t[0][0], t[0][1], t[0][2], t[1][1], t[1][2], t[2][2],
            ]);
            let rot = [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]];
            let q_principal = quat::from_matrix(rot);
            // Shape frame -> body frame: p_body = Rpᵀ (p_shape - c).
            let to_body = |p: [f64; 3]| quat::rotate_inv(q_principal, sub(p, mp.center));
            let collider = match &b.shape {
                Shape::Sphere { radius } => Collider::Sphere(*radius),
                Shape::Box { half } => Collider::Box(*half),
                Shape::Capsule {
                    half_height,
                    radius,
                } => Collider::Capsule(*half_height, *radius),
                Shape::Mesh(mesh) => Collider::Hull(
                    (0..mesh.positions.len() / 3)
                        .map(|v| to_body(Mesh::as_ref(mesh).vertex(v)))
                        .collect(),
                ),
            };
            // Analytic shapes are already principal and centred: keep their axes exact.
            let (q_principal, collider) = match collider {
                Collider::Hull(h) => (q_principal, Collider::Hull(h)),
                c => (quat::IDENTITY, c),
            };
            let moments = if matches!(b.shape, Shape::Mesh(_)) {
                d
            } else {
                [t[0][0], t[1][1], t[2][2]]
            };
            // The drawn surface in the body frame.
            let ns = surface.positions.len() / 3;
            let first = m.surface_local.len() as u32;
            for v in 0..ns {
                let p = surface.as_ref().vertex(v);
                m.surface_local.push(match &collider {
                    Collider::Hull(_) => to_body(p),
                    _ => p,
                });
            }
            surface_triangles.extend(surface.triangles.iter().map(|t| t.map(|k| k + first)));
            m.surface_start.push(m.surface_local.len());
            let (bound, size) = match &collider {
                Collider::Sphere(r) => (*r, *r),
                Collider::Box(h) => (
                    (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt(),
                    h[0].min(h[1]).min(h[2]),
                ),
                Collider::Capsule(hh, r) => (hh + r, *r),
                Collider::Hull(p) => {
                    let bound = p.iter().map(|v| dot(*v, *v)).fold(0.0, f64::max).sqrt();
                    let smallest = moments.iter().fold(f64::INFINITY, |a, &b| a.min(b));
                    // The radius of gyration about the stiffest axis, as a feature size.
                    let rg = (smallest / mp.mass.max(f64::MIN_POSITIVE)).sqrt();
                    (bound, rg.min(bound))
                }
            };
            if !(size > 0.0 && bound.is_finite()) {
                return Err(bad("the shape has no extent".into()));
            }
            m.hull_edges.push(match (&b.shape, &collider) {
                (Shape::Mesh(mesh), Collider::Hull(points)) => {
                    Arc::from(hull_edges(points, &mesh.triangles))
                }
                _ => Arc::from([]),
            });
            m.colliders.push(collider);
            m.bound.push(bound);
            m.size.push(size);
            if dynamic {
                m.mass.push(mp.mass);
                m.inv_mass.push(1.0 / mp.mass);
                m.inertia.push(moments);
                m.inv_inertia.push(moments.map(|i| 1.0 / i));
            } else {
                m.mass.push(f64::INFINITY);
                m.inv_mass.push(0.0);
                m.inertia.push([f64::INFINITY; 3]);
                m.inv_inertia.push([0.0; 3]);
            }
            // The body's frame: centre x = position + R_user c, orientation q_user q_p.
            let q = quat::mul(q_user, q_principal);
            s.x.push(add(b.position, quat::rotate(q_user, mp.center)));
            s.q.push(q);
            let (v, w) = if b.motion == Motion::Static {
                ([0.0; 3], [0.0; 3])
            } else {
                (b.velocity, b.angular_velocity)
            };
            s.v.push(v);
            s.w.push(w);
            s.asleep.push(false);
            s.rest.push(0.0);
            s.island.push(0);
            // Shape origin in body frame: Rpᵀ (0 - c); shape rotation in body frame: Rpᵀ.
            m.frame_origin.push(to_body([0.0; 3]));
            m.frame_rot.push(quat::conj(q_principal));
        }
        m.surface_triangles = surface_triangles.into();
        for (k, j) in self.joints.iter().enumerate() {
            m.joints.push(joint(k, j, &m, &s)?);
            let jb = j.b.map_or(u32::MAX, |b| b as u32);
            let p = (j.a.min(jb as usize) as u32, j.a.max(jb as usize) as u32);
            if jb != u32::MAX {
                m.jointed.push(p);
            }
        }
        m.jointed.sort_unstable();
        m.jointed.dedup();
        let w = RigidWork {
            hulls: m
                .colliders
                .iter()
                .map(|c| match c {
                    Collider::Hull(h) => Vec::with_capacity(h.len()),
                    _ => Vec::new(),
                })
                .collect(),
            ..RigidWork::default()
        };
        Ok((m, s, w))
    }
}

/// The drawn surface of a body's shape, in the shape's frame.
fn body_surface(b: &BodyDesc) -> Result<Mesh, String> {
    let pos = |v: f64, what: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(format!("{what} must be a finite number > 0, not {v}"))
        }
    };
    Ok(match &b.shape {
        Shape::Sphere { radius } => {
            crate::shapes::uv_sphere([0.0; 3], pos(*radius, "the sphere's radius")?, 8, 16)
        }
        Shape::Box { half } => {
            for h in half {
                pos(*h, "each half extent of a box")?;
            }
            faceted_box(*half)
        }
        Shape::Capsule {
            half_height,
            radius,
        } => {
            let r = pos(*radius, "the capsule's radius")?;
            if !(half_height.is_finite() && *half_height >= 0.0) {
                return Err(format!(
                    "the capsule's half height must be finite and >= 0, not {half_height}"
                ));
            }
            crate::shapes::capsule([0.0, -half_height, 0.0], [0.0, *half_height, 0.0], r, 12)
        }
        Shape::Mesh(m) => (**m).clone(),
    })
}

/// A box of half extents `h` drawn with four vertices per face, so that each face shades
/// flat (a shared corner would average three normals and round the box off).
fn faceted_box(h: [f64; 3]) -> Mesh {
    let mut pts = Vec::with_capacity(24);
    let mut tris = Vec::with_capacity(12);
    for axis in 0..3 {
        for sign in [-1.0, 1.0] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = pts.len() as u32;
            for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let mut p = [0.0; 3];
                p[axis] = sign * h[axis];
                p[u] = a * h[u];
                p[v] = b * h[v];
                pts.push(p);
            }
            // Counter-clockwise seen from outside: (u, v, axis) is right-handed.
            if sign > 0.0 {
                tris.push([base, base + 1, base + 2]);
                tris.push([base, base + 2, base + 3]);
            } else {
                tris.push([base, base + 2, base + 1]);
                tris.push([base, base + 3, base + 2]);
            }
        }
    }
    crate::shapes::from_triangles(&pts, &tris)
}

/// The joint of `j` with anchors taken into the bodies' frames at the start.
fn joint(k: usize, j: &JointDesc, m: &Rigid, s: &RigidState) -> Result<Joint, RigidError> {
    let n = s.x.len();
    let bad = |why: String| RigidError::Joint { joint: k, why };
    if j.a >= n {
        return Err(bad(format!(
            "names body {}, but there are only {n} bodies",
            j.a
        )));
    }
    if let Some(b) = j.b {
        if b >= n {
            return Err(bad(format!(
                "names body {b}, but there are only {n} bodies"
            )));
        }
        if b == j.a {
            return Err(bad(format!("joins body {b} to itself")));
        }
    }
    let b = j.b.unwrap_or(usize::MAX);
    if m.inv_mass[j.a] == 0.0 && (b == usize::MAX || m.inv_mass[b] == 0.0) {
        return Err(bad("joins two bodies that cannot move".into()));
    }
    let local = |body: usize, p: [f64; 3]| {
        if body == usize::MAX {
            p
        } else {
            quat::rotate_inv(s.q[body], sub(p, s.x[body]))
        }
    };
    let local_dir = |body: usize, d: [f64; 3]| {
        if body == usize::MAX {
            d
        } else {
            quat::rotate_inv(s.q[body], d)
        }
    };
    let finite = |v: [f64; 3]| v.iter().all(|x| x.is_finite());
    let q_of = |body: usize| {
        if body == usize::MAX {
            quat::IDENTITY
        } else {
            s.q[body]
        }
    };
    let mut out = Joint {
        a: j.a,
        b,
        kind: j.kind,
        la: [0.0; 3],
        lb: [0.0; 3],
        axis_a: [0.0; 3],
        axis_b: [0.0; 3],
        rel: quat::mul(quat::conj(q_of(j.a)), q_of(b)),
    };
    match j.kind {
        JointKind::Ball { anchor } | JointKind::Fixed { anchor } => {
            if !finite(anchor) {
                return Err(bad(format!("anchor {anchor:?} is not finite")));
            }
            out.la = local(j.a, anchor);
            out.lb = local(b, anchor);
        }
        JointKind::Hinge { anchor, axis } => {
            let Some((_, u)) = length_and_unit(axis).filter(|_| finite(anchor) && finite(axis))
            else {
                return Err(bad(format!(
                    "needs a finite anchor and a non-zero axis, not {anchor:?} and {axis:?}"
                )));
            };
            out.la = local(j.a, anchor);
            out.lb = local(b, anchor);
            out.axis_a = local_dir(j.a, u);
            out.axis_b = local_dir(b, u);
        }
        JointKind::Distance { anchor_a, anchor_b } => {
            if !finite(anchor_a) || !finite(anchor_b) {
                return Err(bad("anchors must be finite".into()));
            }
            out.la = local(j.a, anchor_a);
            out.lb = local(b, anchor_b);
            let d = sub(anchor_b, anchor_a);
            out.axis_a = [dot(d, d).sqrt(), 0.0, 0.0];
        }
    }
    Ok(out)
}

impl Rigid {
    /// The description it was built from.
    pub fn desc(&self) -> &RigidDesc {
        &self.desc
    }

    /// Bodies.
    pub fn len(&self) -> usize {
        self.inv_mass.len()
    }

    /// Whether there are no bodies.
    pub fn is_empty(&self) -> bool {
        self.inv_mass.is_empty()
    }

    /// Mass of body `i` (kg; infinite for static and kinematic bodies).
    pub fn mass(&self, i: usize) -> f64 {
        self.mass[i]
    }

    /// Principal moments of inertia of body `i` (kg m²).
    pub fn principal_inertia(&self, i: usize) -> [f64; 3] {
        self.inertia[i]
    }

    /// Whether contacts can happen: two bodies or more, one of them dynamic (else the
    /// collision stage is left out).
    pub fn collides(&self) -> bool {
        self.len() >= 2 && self.inv_mass.iter().any(|&m| m > 0.0)
    }

    /// Whether body `i` is moved by forces.
    pub fn is_dynamic(&self, i: usize) -> bool {
        self.inv_mass[i] > 0.0
    }

    /// The world inverse inertia `R diag(1/I) Rᵀ` of body `i` at the rotation `r`.
    pub(crate) fn inv_inertia_world(&self, i: usize, r: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
        rotate_diag(r, self.inv_inertia[i])
    }

    /// Angular momentum of body `i` (kg m²/s, world).
    pub fn angular_momentum(&self, s: &RigidState, i: usize) -> [f64; 3] {
        if !self.is_dynamic(i) {
            return [0.0; 3];
        }
        inertia_times(&quat::to_matrix(s.q[i]), self.inertia[i], s.w[i])
    }

    /// Kinetic energy (J) of the dynamic bodies.
    pub fn kinetic_energy(&self, s: &RigidState) -> f64 {
        (0..self.len())
            .filter(|&i| self.is_dynamic(i))
            .map(|i| {
                let wb = quat::rotate_inv(s.q[i], s.w[i]);
                let rot: f64 = (0..3).map(|a| self.inertia[i][a] * wb[a] * wb[a]).sum();
                0.5 * (self.mass[i] * dot(s.v[i], s.v[i]) + rot)
            })
            .sum()
    }

    /// Gravitational potential energy (J), zero at the origin.
    pub fn potential_energy(&self, s: &RigidState) -> f64 {
        (0..self.len())
            .filter(|&i| self.is_dynamic(i))
            .map(|i| -self.mass[i] * dot(self.desc.gravity, s.x[i]))
            .sum()
    }

    /// The pose of body `i`'s shape frame (the frame its description was given in):
    /// origin and orientation.
    pub fn shape_pose(&self, s: &RigidState, i: usize) -> ([f64; 3], Quat) {
        (
            add(s.x[i], quat::rotate(s.q[i], self.frame_origin[i])),
            quat::mul(s.q[i], self.frame_rot[i]),
        )
    }

    /// Every body's surface posed, one after the other, then the two anchors of each
    /// distance joint (the strings of a pendulum), as component-major positions (see
    /// [`Rigid::surface_triangles`] and [`Rigid::joint_segments`]).
    pub fn posed_surfaces(&self, s: &RigidState, out: &mut Vec<f64>) {
        let surface = self.surface_local.len();
        let strings = || {
            self.joints
                .iter()
                .filter(|j| matches!(j.kind, JointKind::Distance { .. }))
        };
        let total = surface + 2 * strings().count();
        out.clear();
        out.resize(3 * total, 0.0);
        let mut put = |k: usize, p: [f64; 3]| {
            for a in 0..3 {
                out[a * total + k] = p[a];
            }
        };
        for i in 0..self.len() {
            for k in self.surface_start[i]..self.surface_start[i + 1] {
                put(k, add(s.x[i], quat::rotate(s.q[i], self.surface_local[k])));
            }
        }
        for (k, j) in strings().enumerate() {
            put(surface + 2 * k, add(s.x[j.a], quat::rotate(s.q[j.a], j.la)));
            let b = if j.b == usize::MAX {
                j.lb
            } else {
                add(s.x[j.b], quat::rotate(s.q[j.b], j.lb))
            };
            put(surface + 2 * k + 1, b);
        }
    }

    /// The triangles of [`Rigid::posed_surfaces`].
    pub fn surface_triangles(&self) -> &Arc<[[u32; 3]]> {
        &self.surface_triangles
    }

    /// The segments of [`Rigid::posed_surfaces`]: one per distance joint.
    pub fn joint_segments(&self) -> Vec<[u32; 2]> {
        let surface = self.surface_local.len() as u32;
        let strings = self
            .joints
            .iter()
            .filter(|j| matches!(j.kind, JointKind::Distance { .. }))
            .count() as u32;
        (0..strings)
            .map(|k| [surface + 2 * k, surface + 2 * k + 1])
            .collect()
    }

    /// Appends every body but the meshes to `out` as an obstacle for other systems (cloth,
    /// FEM) at its present pose, with its motion: spheres, capsules, and boxes as oriented boxes.
    /// Mesh bodies are left out (they collide as hulls here; other systems would need a
    /// distance field of them).
    pub fn obstacles(&self, s: &RigidState, out: &mut Vec<crate::collide::MovingObstacle>) {
        use crate::collide::{MovingObstacle, Obstacle};
        for i in 0..self.len() {
            // The poses the contact stage collides them at.
            let shape = match &self.colliders[i] {
                Collider::Sphere(r) => Obstacle::Sphere {
                    center: s.x[i],
                    radius: *r,
                },
                Collider::Capsule(hh, r) => {
                    let [a, b] = contact::segment(s, i, *hh);
                    Obstacle::Capsule { a, b, radius: *r }
                }
                Collider::Box(h) => {
                    let p = contact::box_pose(s, &quat::to_matrix(s.q[i]), i, *h);
                    Obstacle::Oriented {
                        center: p.center,
                        axes: p.axes,
                        half: p.half,
                    }
                }
                Collider::Hull(points) => {
                    // The hull's frame is the body's principal frame.
                    let r = quat::to_matrix(s.q[i]);
                    Obstacle::Hull {
                        points: points.clone(),
                        edges: self.hull_edges[i].clone(),
                        center: s.x[i],
                        axes: columns(&r),
                    }
                }
            };
            out.push(MovingObstacle {
                shape,
                center: s.x[i],
                velocity: s.v[i],
                angular_velocity: s.w[i],
            });
        }
    }

    /// The collision stage alone: the contact points of the present state (speculative
    /// ones within the margin a step of `dt` needs) into `w`, read back by
    /// [`RigidWork::contacts`]. [`Rigid::step`] runs it first.
    pub fn find_contacts(
        &self,
        s: &RigidState,
        w: &mut RigidWork,
        dt: f64,
    ) -> Result<RigidStepInfo, RigidError> {
        contact::collide(self, s, w, dt)
    }

    /// Advances `s` by `dt` (s): collision, velocities, constraints, positions (module
    /// docs). An error names the body whose state went non-finite; `s` is then as the
    /// step left it.
    pub fn step(
        &self,
        s: &mut RigidState,
        w: &mut RigidWork,
        dt: f64,
    ) -> Result<RigidStepInfo, RigidError> {
        let mut info = contact::collide(self, s, w, dt)?;
        if self.desc.sleep.is_some() && sleep::wake_touched(self, s, &w.contacts, &mut w.sleep) {
            // The woken islands' own contacts were left out while they slept.
            info = contact::collide_again(self, s, w, dt);
        }
        solver::step(self, s, w, dt);
        s.time += dt;
        s.steps += 1;
        sleep::settle(self, s, &w.contacts, &mut w.sleep, dt);
        for i in 0..self.len() {
            let what = if !s.x[i].iter().all(|v| v.is_finite()) {
                "position"
            } else if !s.q[i].iter().all(|v| v.is_finite()) {
                "orientation"
            } else if !s.v[i].iter().chain(&s.w[i]).all(|v| v.is_finite()) {
                "velocity"
            } else {
                continue;
            };
            return Err(RigidError::NonFinite {
                step: s.steps,
                body: i,
                what,
            });
        }
        Ok(info)
    }
}

impl Rigid {
    /// Body `i`'s velocities over a sub-step `h` before the constraints: gravity, and the
    /// gyroscopic term where the integrator treats it here.
    pub(crate) fn advance_velocity(
        &self,
        i: usize,
        q: Quat,
        v: &mut [f64; 3],
        w: &mut [f64; 3],
        h: f64,
    ) {
        if !self.is_dynamic(i) {
            return;
        }
        *v = add(*v, scale(self.desc.gravity, h));
        if self.desc.integrator == RigidIntegrator::ImplicitGyroscopic {
            *w = implicit_gyroscopic(self.inertia[i], q, *w, h);
        }
    }

    /// Body `i`'s position over a sub-step `h` by the integrator, from the velocities the
    /// constraints left, plus the split impulses' pseudo-velocities `pv`, `pw`. `rot` is
    /// the rotation matrix of the body's orientation, before and after (the solver keeps
    /// it from sub-step to sub-step rather than form it from the quaternion again).
    pub(crate) fn advance_position(
        &self,
        s: &mut RigidState,
        i: usize,
        h: f64,
        (pv, pw): ([f64; 3], [f64; 3]),
        rot: &mut [[f64; 3]; 3],
    ) {
        let d = &self.desc;
        if d.bodies[i].motion == Motion::Static {
            return;
        }
        match (self.is_dynamic(i), d.integrator) {
            (true, RigidIntegrator::SymplecticEuler) => {
                // L = I(q0) w is what the solver left; q advances by I(q0)^-1 L = w,
                // and w is re-read from L at the new orientation.
                let p = rigid::symplectic(
                    s.x[i],
                    rot,
                    s.q[i],
                    (s.v[i], s.w[i]),
                    (pv, pw),
                    (self.inertia[i], self.inv_inertia[i]),
                    h,
                );
                (s.x[i], s.q[i], s.w[i], *rot) = (p.x, p.q, p.w, p.rot);
            }
            (true, RigidIntegrator::ExplicitEuler | RigidIntegrator::Rk4) => {
                // Back to the velocities at the sub-step's start (plus the impulses).
                let v_start = sub(s.v[i], scale(d.gravity, h));
                let l = inertia_times(rot, self.inertia[i], s.w[i]);
                let (x, q, v) = if d.integrator == RigidIntegrator::Rk4 {
                    rk4(self, i, s.x[i], s.q[i], v_start, l, h)
                } else {
                    (
                        add(s.x[i], scale(v_start, h)),
                        quat::integrate(s.q[i], s.w[i], h),
                        s.v[i],
                    )
                };
                s.x[i] = add(x, scale(pv, h));
                s.q[i] = quat::integrate(q, pw, h);
                s.v[i] = v;
                *rot = quat::to_matrix(s.q[i]);
                s.w[i] = inertia_times(rot, self.inv_inertia[i], l);
            }
            // Implicit gyroscopic (w already advanced) and kinematic bodies.
            _ => {
                s.x[i] = add(s.x[i], scale(add(s.v[i], pv), h));
                s.q[i] = quat::integrate(s.q[i], add(s.w[i], pw), h);
                *rot = quat::to_matrix(s.q[i]);
            }
        }
    }
}

/// `R diag(d) Rᵀ` for the rotation `r`.
fn rotate_diag(r: &[[f64; 3]; 3], d: [f64; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in i..3 {
            let v = r[i][0] * d[0] * r[j][0] + r[i][1] * d[1] * r[j][1] + r[i][2] * d[2] * r[j][2];
            out[i][j] = v;
            out[j][i] = v;
        }
    }
    out
}

/// The columns of the rotation `r`: the body's axes in the world.
pub(crate) fn columns(r: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|k| [r[0][k], r[1][k], r[2][k]])
}

/// One Newton step of backward Euler on `I w' + w x I w = 0` in the body frame (Catto
/// 2015): `(I + dt (skew(w) I - skew(I w))) dw = -dt w x I w`.
fn implicit_gyroscopic(inertia: [f64; 3], q: Quat, w: [f64; 3], dt: f64) -> [f64; 3] {
    let wb = quat::rotate_inv(q, w);
    let iw = [inertia[0] * wb[0], inertia[1] * wb[1], inertia[2] * wb[2]];
    let f = scale(cross(wb, iw), dt);
    let skew = |a: [f64; 3]| [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]];
    let (sw, siw) = (skew(wb), skew(iw));
    let mut j = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            j[r][c] = dt * (sw[r][c] * inertia[c] - siw[r][c]);
        }
        j[r][r] += inertia[r];
    }
    let m = nalgebra::Matrix3::from_fn(|r, c| j[r][c]);
    let rhs = nalgebra::Vector3::new(-f[0], -f[1], -f[2]);
    let dw = m.lu().solve(&rhs).map_or([0.0; 3], |x| [x[0], x[1], x[2]]);
    quat::rotate(q, add(wb, dw))
}

/// Classical Runge-Kutta on Baraff's `(x, q, P/m, L)` of body `i` under gravity and no
/// torque over `dt`: `x' = v`, `q' = 1/2 [0, I(q)^-1 L] q`, `v' = g`, `L' = 0`.
fn rk4(
    m: &Rigid,
    i: usize,
    x: [f64; 3],
    q: Quat,
    v: [f64; 3],
    l: [f64; 3],
    dt: f64,
) -> ([f64; 3], Quat, [f64; 3]) {
    let g = m.desc.gravity;
    let qdot = |q: Quat| {
        let qn = quat::normalize(q).unwrap_or(quat::IDENTITY);
        quat::derivative(q, inertia_times(&quat::to_matrix(qn), m.inv_inertia[i], l))
    };
    let qadd = |q: Quat, d: Quat, h: f64| {
        [
            q[0] + h * d[0],
            q[1] + h * d[1],
            q[2] + h * d[2],
            q[3] + h * d[3],
        ]
    };
    let k1 = qdot(q);
    let k2 = qdot(qadd(q, k1, dt / 2.0));
    let k3 = qdot(qadd(q, k2, dt / 2.0));
    let k4 = qdot(qadd(q, k3, dt));
    let mut qn = q;
    for c in 0..4 {
        qn[c] += dt / 6.0 * (k1[c] + 2.0 * k2[c] + 2.0 * k3[c] + k4[c]);
    }
    let qn = quat::normalize(qn).unwrap_or(q);
    // Constant acceleration: exact.
    let xn = add(add(x, scale(v, dt)), scale(g, 0.5 * dt * dt));
    (xn, qn, add(v, scale(g, dt)))
}

/// The sharp edges of a closed mesh's convex hull (`points`: the mesh's vertices, in
/// order): the mesh edges whose two triangles both lie on the hull (every point on one
/// side of their planes) and meet at more than 20 degrees (a cube's twelve edges, not its faces'
/// diagonals). Left empty for meshes of more than 5e7 point-triangle pairs, whose test
/// would take seconds at build.
fn hull_edges(points: &[[f64; 3]], triangles: &[[u32; 3]]) -> Vec<[[f64; 3]; 2]> {
    if (points.len() as f64) * (triangles.len() as f64) > 5e7 {
        return Vec::new();
    }
    let size = points
        .iter()
        .map(|p| dot(*p, *p))
        .fold(0.0, f64::max)
        .sqrt();
    let at = |i: u32| points.get(i as usize).copied();
    // Each triangle's unit normal, when every point lies on one side of its plane (on
    // the side its normal points away from, for an outward wound mesh; either side
    // serves, as long as the winding is consistent).
    let on_hull: Vec<Option<[f64; 3]>> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = [at(t[0])?, at(t[1])?, at(t[2])?];
            let (_, n) = length_and_unit(cross(sub(b, a), sub(c, a)))?;
            let tol = 1e-9 * size;
            let side = |sign: f64| points.iter().all(|p| sign * dot(n, sub(*p, a)) <= tol);
            (side(1.0) || side(-1.0)).then_some(n)
        })
        .collect();
    let cos_20 = 20f64.to_radians().cos();
    let mut edges = Vec::new();
    for pair in crate::io::edge_uses(triangles).chunk_by(|a, b| a.0 == b.0) {
        let [(e, f), (_, g)] = pair else {
            continue; // an open or non-manifold edge: the mesh check reports those
        };
        if let (Some(m), Some(n), Some(p), Some(q)) = (on_hull[*f], on_hull[*g], at(e[0]), at(e[1]))
        {
            if dot(m, n) < cos_20 {
                edges.push([p, q]);
            }
        }
    }
    edges
}

#[cfg(test)]
mod tests {
    use super::hull_edges;

    /// A cube meshed with two triangles a face has its twelve edges as sharp hull edges
    /// (not the faces' diagonals); a dent in a face (a vertex pushed in, off the hull)
    /// takes that face's triangles, and the edges they held, off the hull.
    #[test]
    fn a_cube_mesh_has_twelve_sharp_hull_edges() {
        let cube = crate::shapes::cuboid([-0.3; 3], [0.3; 3]);
        let points: Vec<[f64; 3]> = (0..cube.positions.len() / 3)
            .map(|v| cube.as_ref().vertex(v))
            .collect();
        let edges = hull_edges(&points, &cube.triangles);
        assert_eq!(edges.len(), 12);
        for [a, b] in &edges {
            let d: Vec<f64> = (0..3).map(|k| (b[k] - a[k]).abs()).collect();
            // Along one axis, the cube's side long.
            assert_eq!(d.iter().filter(|&&c| c > 1e-12).count(), 1, "{a:?} {b:?}");
            assert!(d.iter().any(|&c| (c - 0.6).abs() < 1e-12));
        }
        // Wound the other way round: the same edges.
        let inward: Vec<[u32; 3]> = cube.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect();
        assert_eq!(hull_edges(&points, &inward).len(), 12);
        // The dent: one corner pulled in to the centre. Its three faces' triangles that
        // use it leave the hull.
        let mut dented = points.clone();
        dented[0] = [0.0; 3];
        let fewer = hull_edges(&dented, &cube.triangles);
        assert!(fewer.len() < 12, "{}", fewer.len());
    }
}
