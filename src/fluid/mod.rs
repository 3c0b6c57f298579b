//! Stable fluids on a staggered (MAC) grid: semi-Lagrangian advection, forces, implicit
//! viscosity and a multigrid-preconditioned pressure projection (issue 17; course notes
//! section 16; Stam 1999; Bridson 2015; Fedkiw, Stam and Jensen 2001; McAdams, Sifakis and
//! Teran 2010).
//!
//! The grid has `n[0] x n[1] x n[2]` cubic cells of side `h` (`n[2] = 1`: a 2-D fluid).
//! Velocity components live on the faces normal to them, one flat array each, x fastest
//! (`(n[0] + 1) n[1] n[2]` x-faces, ...); scalars (smoke density, temperature) and the
//! pressure at cell centres. A cell is fluid or solid: solids come from obstacles (a cell
//! whose centre is inside one) and only when the scene has obstacles. Each side of the
//! domain is a no-slip wall, a free-slip wall, open (outflow, `p = 0` beyond it), a lid
//! (a no-slip wall moving in its plane) or periodic ([`Boundary`]).
//!
//! One step of `dt` is split into `ceil(dt max|u| / (cfl h))` sub-steps (at most
//! [`FluidDesc::max_substeps`]); each one:
//! 1. advects velocity and scalars by the velocity at its start (semi-Lagrangian: each
//!    node takes the value at the foot of its back trace, RK2 or RK3, linear or monotone
//!    cubic interpolation, optionally corrected by MacCormack or BFECC);
//! 2. adds forces: a uniform body force, buoyancy `(-alpha d + beta (T - T_amb)) up`
//!    and vorticity confinement `eps h (N x w)` with `N = grad|w| / |grad|w||` (Fedkiw et
//!    al. 2001, section 4), each at cell centres averaged to faces;
//! 3. applies the sources (smoke, heat and velocity in a region);
//! 4. with viscosity nu > 0, solves `(I - nu dt lap) u = u*` per component by Jacobi-
//!    preconditioned CG (no-slip walls by the ghost value `2 U - u`, second order);
//! 5. projects: `A p = -div u / dt` on the fluid cells (`solve::GridPoisson`, multigrid-
//!    preconditioned CG) and `u -= dt grad p` on the free faces, after which the
//!    divergence is the solver's relative tolerance times what it was.
//!
//! Pressure is kinematic (m^2/s^2) inside; [`FluidSim::pressure`] reports it times the
//! density (Pa).

pub mod scene;
pub mod validation;

use crate::collide::Obstacle;
use crate::solve::{CellKind, GridPoisson, PoissonParams, Side, SolveError, SolveInfo};
use crate::validate::{check, ModelError, Rule};
use largestep_kernels::fluid::{self as kf, Field, Velocity};
pub use largestep_kernels::fluid::{Interp, Trace};
use std::time::Instant;

/// What lies beyond one side of the domain.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Boundary {
    /// A no-slip wall (zero velocity).
    #[default]
    Wall,
    /// A free-slip wall (zero normal velocity, no shear).
    Slip,
    /// Open: fluid leaves and enters freely, `p = 0` half a cell outside.
    Open,
    /// A no-slip wall moving in its own plane at this velocity (m/s; the normal part is
    /// ignored): the lid of a driven cavity.
    Lid([f64; 3]),
    /// Periodic: the opposite side continues the domain (both sides must say so).
    Periodic,
}

impl Boundary {
    /// The scene name.
    pub fn name(&self) -> &'static str {
        match self {
            Boundary::Wall => "wall",
            Boundary::Slip => "slip",
            Boundary::Open => "open",
            Boundary::Lid(_) => "lid",
            Boundary::Periodic => "periodic",
        }
    }

    /// Whether the normal velocity on this side is zero.
    fn closed(&self) -> bool {
        matches!(self, Boundary::Wall | Boundary::Slip | Boundary::Lid(_))
    }

    fn side(&self) -> Side {
        match self {
            Boundary::Open => Side::Open,
            Boundary::Periodic => Side::Periodic,
            _ => Side::Wall,
        }
    }
}

/// Error correction of the advection.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Correction {
    /// Plain semi-Lagrangian.
    #[default]
    None,
    /// MacCormack (Selle et al. 2008), limited to the original nodes' range.
    MacCormack,
    /// Back and forth error compensation (Kim et al. 2005), limited likewise.
    Bfecc,
}

/// How fields are advected.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Advection {
    /// Back-trace rule.
    pub trace: Trace,
    /// Interpolation.
    pub interp: Interp,
    /// Error correction.
    pub correction: Correction,
}

impl Default for Advection {
    fn default() -> Self {
        Advection {
            trace: Trace::Rk2,
            interp: Interp::Linear,
            correction: Correction::None,
        }
    }
}

/// Buoyancy of hot smoke (Fedkiw, Stam and Jensen 2001, equation 8).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Buoyancy {
    /// Up (any length; normalised).
    pub up: [f64; 3],
    /// `alpha`: downward acceleration per unit smoke density (m/s^2).
    pub smoke: f64,
    /// `beta`: upward acceleration per kelvin above ambient (m/s^2/K).
    pub heat: f64,
    /// Ambient temperature (K).
    pub ambient: f64,
}

/// A region that emits smoke, heat or velocity (at build, and every sub-step while the
/// time is below `until`).
#[derive(Clone, Debug, PartialEq)]
pub struct Source {
    /// The region: a sphere or a box (cells whose centres are inside).
    pub shape: Obstacle,
    /// Smoke density set there (at least this much), if any.
    pub density: Option<f64>,
    /// Temperature set there (at least this), K.
    pub temperature: Option<f64>,
    /// Velocity set on the region's faces (m/s).
    pub velocity: Option<[f64; 3]>,
    /// Emits while the time is below this (s); 0: only the initial state.
    pub until: f64,
}

/// The velocity at the start.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Initial {
    /// At rest.
    #[default]
    Rest,
    /// The Taylor-Green vortex in x-y, `u = U sin(k x) cos(k y)`, `v = -U cos(k x) sin(k y)`
    /// with `k = 2 pi / L` (L the domain's x length; the domain must be square in x-y):
    /// it satisfies periodic and free-slip sides, and decays as `exp(-2 nu k^2 t)`.
    TaylorGreen {
        /// U (m/s).
        speed: f64,
    },
    /// Uniform velocity (m/s).
    Uniform([f64; 3]),
}

/// An editable fluid description.
#[derive(Clone, Debug, PartialEq)]
pub struct FluidDesc {
    /// Cells along x, y, z (z = 1: 2-D).
    pub cells: [usize; 3],
    /// Cell side (m).
    pub h: f64,
    /// The domain's lower corner (m).
    pub origin: [f64; 3],
    /// Beyond each side: `[axis][0]` low, `[1]` high.
    pub boundaries: [[Boundary; 2]; 3],
    /// Solid obstacles (cells whose centre is inside).
    pub obstacles: Vec<Obstacle>,
    /// Cells made solid besides the obstacles (a voxelised mesh), or none.
    pub solid_cells: Option<Vec<bool>>,
    /// Kinematic viscosity (m^2/s); 0 builds no diffusion solve.
    pub viscosity: f64,
    /// Density (kg/m^3), for pressure and energy.
    pub density: f64,
    /// Uniform body acceleration (m/s^2), gravity on the fluid itself.
    pub force: [f64; 3],
    /// Buoyancy of smoke and heat, if any.
    pub buoyancy: Option<Buoyancy>,
    /// Vorticity confinement strength (dimensionless); 0: none.
    pub vorticity: f64,
    /// Advection scheme.
    pub advection: Advection,
    /// Cells a sub-step may carry the fluid (the CFL number).
    pub cfl: f64,
    /// Most sub-steps per step; a step that needs more is refused with the step that fits.
    pub max_substeps: usize,
    /// The pressure solve.
    pub poisson: PoissonParams,
    /// Sources.
    pub sources: Vec<Source>,
    /// The velocity at the start.
    pub initial: Initial,
}

impl Default for FluidDesc {
    fn default() -> Self {
        FluidDesc {
            cells: [32, 32, 1],
            h: 1.0 / 32.0,
            origin: [0.0; 3],
            boundaries: [[Boundary::Wall; 2]; 3],
            obstacles: Vec::new(),
            solid_cells: None,
            viscosity: 0.0,
            density: 1.0,
            force: [0.0; 3],
            buoyancy: None,
            vorticity: 0.0,
            advection: Advection::default(),
            cfl: 1.0,
            max_substeps: 64,
            poisson: PoissonParams::default(),
            sources: Vec::new(),
            initial: Initial::Rest,
        }
    }
}

/// Fluid failures.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FluidError {
    /// The description is invalid.
    #[error("{0}")]
    Model(#[from] ModelError),
    /// A value became NaN or infinite.
    #[error("step {step}: {field} is not finite at {at}; reduce dt or the forces")]
    NonFinite {
        /// Step (1-based).
        step: u64,
        /// `velocity`, `density`, `temperature`.
        field: &'static str,
        /// Where: the cell or face `(i, j, k)` and component.
        at: String,
    },
    /// A step needs more sub-steps than allowed.
    #[error("step {step}: dt = {dt} s carries the fluid {cells:.1} cells at {speed:.3e} m/s, which needs {needed} sub-steps at CFL {cfl}, more than the {max} allowed: use dt <= {limit:.3e} s or raise max_substeps")]
    Cfl {
        /// Step (1-based).
        step: u64,
        /// The step asked (s).
        dt: f64,
        /// The fastest speed (m/s).
        speed: f64,
        /// Cells it moves in dt.
        cells: f64,
        /// The CFL number.
        cfl: f64,
        /// Sub-steps needed.
        needed: f64,
        /// Sub-steps allowed.
        max: usize,
        /// The largest dt that fits.
        limit: f64,
    },
    /// The pressure or viscosity solve failed.
    #[error("step {step}: the {what} solve failed: {source}")]
    Solve {
        /// Step (1-based).
        step: u64,
        /// `pressure` or `viscosity`.
        what: &'static str,
        /// The solver's error.
        source: SolveError,
    },
}

/// Index of node `c` in a grid of `n` nodes.
#[inline]
fn idx(n: [usize; 3], c: [usize; 3]) -> usize {
    c[0] + n[0] * (c[1] + n[1] * c[2])
}

/// Node `i`'s coordinates in a grid of `n` nodes.
#[inline]
fn coords(n: [usize; 3], i: usize) -> [usize; 3] {
    [i % n[0], (i / n[0]) % n[1], i / (n[0] * n[1])]
}

/// The implicit viscosity operator of one velocity component: for each free face the
/// free neighbours (`u32::MAX` for none), the count of couplings (a fixed neighbour
/// counts 1, a no-slip ghost 2), and `2 U` summed over lid ghosts.
#[derive(Clone, Debug)]
struct Diffusion {
    nbr: Vec<[u32; 6]>,
    degree: Vec<f64>,
    lid: Vec<f64>,
    /// The faces beside a lid (`lid` not zero).
    lid_faces: Vec<u32>,
}

/// A built fluid: the grid, its flags and settings (immutable; see the module docs).
#[derive(Clone, Debug)]
pub struct Fluid {
    desc: FluidDesc,
    dims: usize,
    /// Solid cells, when the scene has obstacles.
    solid: Option<Vec<bool>>,
    /// Per component: faces whose velocity is prescribed (zero: walls, solids) or that
    /// repeat face 0 of a periodic axis.
    fixed: [Vec<bool>; 3],
    /// Per component, listed once at build for `sync_faces`: the fixed faces held at
    /// zero, and the (last, first) face pairs of a periodic axis.
    zero_faces: [Vec<u32>; 3],
    mirror_faces: [Vec<(u32, u32)>; 3],
    /// Per source: its cells.
    source_cells: Vec<Vec<u32>>,
    /// Whether smoke density and temperature are carried.
    has_density: bool,
    has_temperature: bool,
    /// Per component, when viscosity is on.
    diffusion: Option<[Diffusion; 3]>,
}

/// What a step changes.
#[derive(Clone, Debug)]
pub struct FluidState {
    /// Face velocities (m/s) per component (z empty in 2-D).
    pub u: [Vec<f64>; 3],
    /// Smoke density per cell (empty when not carried).
    pub density: Vec<f64>,
    /// Temperature per cell (K; empty when not carried).
    pub temperature: Vec<f64>,
    /// Kinematic pressure of the last projection (m^2/s^2), per cell.
    pub pressure: Vec<f64>,
    /// Time (s).
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    /// Sub-steps taken.
    pub substeps: u64,
    /// Work done on the fluid since the start (J): by forces and sources (the kinetic
    /// energy they add) and by moving lids (their shear stress times their speed).
    pub external_work: f64,
}

/// Scratch buffers (allocated once).
#[derive(Clone, Debug)]
pub struct FluidWork {
    poisson: GridPoisson,
    div: Vec<f64>,
    rhs: Vec<f64>,
    /// Scratch of the corrected advection schemes per component (empty without one).
    tmp: [[Vec<f64>; 2]; 3],
    /// Back-trace feet of one layout (three f32 per node), forwards and backwards (the
    /// second empty without a corrected scheme).
    feet: [Vec<f32>; 2],
    next: [Vec<f64>; 3],
    scalar_tmp: [Vec<f64>; 3],
    force: [Vec<f64>; 3],
    /// CG vectors of the viscosity solve: right side, r, z, p, q.
    cg: [Vec<f64>; 5],
}

/// What a step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FluidStepInfo {
    /// Sub-steps.
    pub substeps: usize,
    /// Pressure CG iterations, summed.
    pub pressure_iterations: usize,
    /// Viscosity CG iterations, summed.
    pub viscosity_iterations: usize,
    /// Last pressure relative residual.
    pub residual: f64,
    /// Wall time of the solves (s).
    pub solve_seconds: f64,
}

/// Bytes a fluid of `cells` cells holds in state and work, for the memory check before
/// allocating: velocities (3 faces) in state, next, tmp and force, scalars, the
/// multigrid hierarchy (about 8 vectors per cell, 1/7 more for the coarse levels) and
/// CG vectors.
pub fn bytes_per_cell(viscosity: bool) -> f64 {
    let velocity = 3.0 * 4.0;
    let scalars = 2.0 * 4.0 + 2.0;
    let poisson = 8.0 * 8.0 / 7.0 + 4.0;
    let cg = if viscosity {
        4.0 + 3.0 * 8.0 / 8.0 * 7.0
    } else {
        4.0
    };
    8.0 * (velocity + scalars + poisson + cg + 2.0)
}

impl FluidDesc {
    /// Cells in the grid.
    pub fn cell_count(&self) -> usize {
        self.cells.iter().product()
    }

    /// Whether the fluid is 2-D (one cell along z).
    pub fn is_2d(&self) -> bool {
        self.cells[2] == 1
    }

    /// Checks the description.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (a, &c) in self.cells.iter().enumerate() {
            if c == 0 || (a < 2 && c < 2) {
                return Err(ModelError::Value {
                    item: "grid",
                    index: a,
                    field: "cells",
                    value: c as f64,
                    why: "needs at least 2 cells along x and y and 1 along z",
                });
            }
        }
        if self
            .cells
            .iter()
            .try_fold(1usize, |a, &b| a.checked_mul(b))
            .is_none_or(|c| c > u32::MAX as usize / 4)
        {
            return Err(ModelError::TooLarge(format!(
                "a grid of {} x {} x {} cells is too large to index",
                self.cells[0], self.cells[1], self.cells[2]
            )));
        }
        check("grid", 0, "h", self.h, Rule::Positive)?;
        for (a, &o) in self.origin.iter().enumerate() {
            check("grid", a, "origin", o, Rule::Coordinate)?;
        }
        check("fluid", 0, "viscosity", self.viscosity, Rule::NonNegative)?;
        check("fluid", 0, "density", self.density, Rule::Positive)?;
        for (a, &f) in self.force.iter().enumerate() {
            check("fluid", a, "force", f, Rule::Finite)?;
        }
        check("fluid", 0, "vorticity", self.vorticity, Rule::NonNegative)?;
        check("fluid", 0, "cfl", self.cfl, Rule::Positive)?;
        if self.max_substeps == 0 {
            return Err(ModelError::Value {
                item: "fluid",
                index: 0,
                field: "max_substeps",
                value: 0.0,
                why: "must be at least 1",
            });
        }
        check(
            "fluid",
            0,
            "tolerance",
            self.poisson.tolerance,
            Rule::Positive,
        )?;
        for a in 0..3 {
            let [lo, hi] = self.boundaries[a];
            if (lo == Boundary::Periodic) != (hi == Boundary::Periodic) {
                return Err(ModelError::Value {
                    item: "boundary",
                    index: a,
                    field: "periodic",
                    value: 0.0,
                    why: "a periodic axis must be periodic on both sides",
                });
            }
            for b in [lo, hi] {
                if let Boundary::Lid(v) = b {
                    for (c, &x) in v.iter().enumerate() {
                        check("boundary", c, "lid velocity", x, Rule::Finite)?;
                    }
                }
            }
        }
        if let Some(b) = &self.buoyancy {
            for (a, &x) in b.up.iter().enumerate() {
                check("buoyancy", a, "up", x, Rule::Finite)?;
            }
            if b.up.iter().all(|&x| x == 0.0) {
                return Err(ModelError::Value {
                    item: "buoyancy",
                    index: 0,
                    field: "up",
                    value: 0.0,
                    why: "must not be the zero vector",
                });
            }
            check("buoyancy", 0, "smoke", b.smoke, Rule::Finite)?;
            check("buoyancy", 0, "heat", b.heat, Rule::Finite)?;
            check("buoyancy", 0, "ambient", b.ambient, Rule::Finite)?;
        }
        let lo = self.origin;
        let hi: [f64; 3] = std::array::from_fn(|a| lo[a] + self.cells[a] as f64 * self.h);
        for (i, o) in self.obstacles.iter().enumerate() {
            o.validate(i)?;
            if !overlaps(o, lo, hi) {
                return Err(ModelError::Element {
                    item: "obstacle",
                    index: i,
                    what: format!(
                        "({}) lies outside the domain [{:?}, {:?}]",
                        o.kind(),
                        lo,
                        hi
                    ),
                });
            }
        }
        if let Some(s) = &self.solid_cells {
            if s.len() != self.cell_count() {
                return Err(ModelError::Length {
                    what: "solid cells",
                    got: s.len(),
                    expected: self.cell_count(),
                    per: "cell",
                });
            }
        }
        for (i, s) in self.sources.iter().enumerate() {
            s.shape.validate(i)?;
            if let Some(d) = s.density {
                check("source", i, "density", d, Rule::Finite)?;
            }
            if let Some(t) = s.temperature {
                check("source", i, "temperature", t, Rule::Finite)?;
            }
            if let Some(v) = s.velocity {
                for &x in &v {
                    check("source", i, "velocity", x, Rule::Finite)?;
                }
            }
            if s.until.is_nan() || s.until < 0.0 {
                return Err(ModelError::Value {
                    item: "source",
                    index: i,
                    field: "until",
                    value: s.until,
                    why: "must be >= 0 (infinite: forever)",
                });
            }
            if !overlaps(&s.shape, lo, hi) {
                return Err(ModelError::Element {
                    item: "source",
                    index: i,
                    what: "lies outside the domain".into(),
                });
            }
        }
        match self.initial {
            Initial::TaylorGreen { speed } => {
                check("initial", 0, "speed", speed, Rule::Finite)?;
            }
            Initial::Uniform(v) => {
                for (a, &x) in v.iter().enumerate() {
                    check("initial", a, "velocity", x, Rule::Finite)?;
                }
            }
            Initial::Rest => {}
        }
        Ok(())
    }

    /// Builds the fluid and its initial state and work.
    pub fn build(&self) -> Result<(Fluid, FluidState, FluidWork), FluidError> {
        self.validate()?;
        let n = self.cells;
        let dims = if self.is_2d() { 2 } else { 3 };
        let cells = self.cell_count();
        let center = |c: usize| -> [f64; 3] {
            let q = coords(n, c);
            std::array::from_fn(|a| self.origin[a] + (q[a] as f64 + 0.5) * self.h)
        };
        let inside = |o: &Obstacle, p: [f64; 3]| o.distance(p).is_some_and(|(d, _)| d < 0.0);
        let solid = if self.obstacles.is_empty() && self.solid_cells.is_none() {
            None
        } else {
            let mut s = self
                .solid_cells
                .clone()
                .unwrap_or_else(|| vec![false; cells]);
            for (c, sc) in s.iter_mut().enumerate() {
                let p = center(c);
                if self.obstacles.iter().any(|o| inside(o, p)) {
                    *sc = true;
                }
            }
            if s.iter().all(|&x| x) {
                return Err(ModelError::Element {
                    item: "obstacle",
                    index: 0,
                    what: "the obstacles fill every cell of the domain".into(),
                }
                .into());
            }
            Some(s)
        };
        let is_solid = |c: [usize; 3]| solid.as_ref().is_some_and(|s| s[idx(n, c)]);
        let fixed: [Vec<bool>; 3] = std::array::from_fn(|a| {
            if a >= dims {
                return Vec::new();
            }
            let mut fnn = n;
            fnn[a] += 1;
            (0..fnn.iter().product())
                .map(|f| {
                    let c = coords(fnn, f);
                    let ia = c[a];
                    let [lo, hi] = self.boundaries[a];
                    if ia == n[a] && hi == Boundary::Periodic {
                        return true; // repeats face 0
                    }
                    if (ia == 0 && lo.closed()) || (ia == n[a] && hi.closed()) {
                        return true;
                    }
                    let mut below = c;
                    let wrap = hi == Boundary::Periodic;
                    let below_ok = if ia > 0 {
                        below[a] = ia - 1;
                        true
                    } else if wrap {
                        below[a] = n[a] - 1;
                        true
                    } else {
                        false
                    };
                    let above_ok = ia < n[a];
                    (below_ok && is_solid(below)) || (above_ok && is_solid(c))
                })
                .collect()
        });
        let source_cells = self
            .sources
            .iter()
            .map(|s| {
                (0..cells)
                    .filter(|&c| inside(&s.shape, center(c)))
                    .map(|c| c as u32)
                    .collect()
            })
            .collect();
        let has_density = self.sources.iter().any(|s| s.density.is_some())
            || self.buoyancy.is_some_and(|b| b.smoke != 0.0);
        let has_temperature = self.sources.iter().any(|s| s.temperature.is_some())
            || self.buoyancy.is_some_and(|b| b.heat != 0.0);
        let per = self.boundaries.map(|b| b[0] == Boundary::Periodic);
        let mut zero_faces: [Vec<u32>; 3] = Default::default();
        let mut mirror_faces: [Vec<(u32, u32)>; 3] = Default::default();
        for a in 0..dims {
            let mut fnn = n;
            fnn[a] += 1;
            for (f, &fx) in fixed[a].iter().enumerate() {
                let c = coords(fnn, f);
                if per[a] && c[a] == n[a] {
                    let mut c0 = c;
                    c0[a] = 0;
                    mirror_faces[a].push((f as u32, idx(fnn, c0) as u32));
                } else if fx {
                    zero_faces[a].push(f as u32);
                }
            }
        }
        let mut fluid = Fluid {
            desc: self.clone(),
            dims,
            solid,
            fixed,
            zero_faces,
            mirror_faces,
            source_cells,
            has_density,
            has_temperature,
            diffusion: None,
        };
        if self.viscosity > 0.0 {
            fluid.diffusion = Some(std::array::from_fn(|a| fluid.diffusion_of(a)));
        }
        let kind: Vec<CellKind> = (0..cells)
            .map(|c| {
                if fluid.solid.as_ref().is_some_and(|s| s[c]) {
                    CellKind::Solid
                } else {
                    CellKind::Fluid
                }
            })
            .collect();
        let sides = self.boundaries.map(|b| b.map(|s| s.side()));
        let poisson =
            GridPoisson::with_sides(n, self.h, kind, sides).map_err(|e| FluidError::Solve {
                step: 0,
                what: "pressure",
                source: e,
            })?;
        let faces = |a: usize| fluid.fixed[a].len();
        let mut state = FluidState {
            u: std::array::from_fn(|a| vec![0.0; faces(a)]),
            density: vec![0.0; if has_density { cells } else { 0 }],
            temperature: vec![
                self.buoyancy.map_or(0.0, |b| b.ambient);
                if has_temperature { cells } else { 0 }
            ],
            pressure: vec![0.0; cells],
            time: 0.0,
            steps: 0,
            substeps: 0,
            external_work: 0.0,
        };
        fluid.initial_velocity(&mut state);
        fluid.apply_sources(&mut state, true);
        let work = FluidWork {
            poisson,
            div: vec![0.0; cells],
            rhs: vec![0.0; cells],
            tmp: std::array::from_fn(|a| {
                let len = if self.advection.correction == Correction::None {
                    0
                } else {
                    faces(a)
                };
                [vec![0.0; len], vec![0.0; len]]
            }),
            next: std::array::from_fn(|a| vec![0.0; faces(a)]),
            feet: {
                let most = (0..dims).map(faces).max().unwrap_or(0).max(cells);
                let back = if self.advection.correction == Correction::None {
                    0
                } else {
                    3 * most
                };
                [vec![0.0; 3 * most], vec![0.0; back]]
            },
            scalar_tmp: std::array::from_fn(|_| vec![0.0; cells]),
            force: std::array::from_fn(|a| {
                let any = self.vorticity > 0.0 || self.buoyancy.is_some();
                vec![0.0; if any && a < dims { cells } else { 0 }]
            }),
            cg: std::array::from_fn(|_| {
                let most = (0..dims).map(faces).max().unwrap_or(0);
                vec![0.0; if self.viscosity > 0.0 { most } else { 0 }]
            }),
        };
        Ok((fluid, state, work))
    }
}

/// Whether obstacle `o` may reach into the box `[lo, hi]` (a bounding test).
fn overlaps(o: &Obstacle, lo: [f64; 3], hi: [f64; 3]) -> bool {
    match o {
        Obstacle::Sphere { center, radius } => {
            (0..3).all(|a| center[a] + radius > lo[a] && center[a] - radius < hi[a])
        }
        Obstacle::Box { min, max } => (0..3).all(|a| max[a] > lo[a] && min[a] < hi[a]),
        Obstacle::Capsule { a, b, radius } => {
            (0..3).all(|k| a[k].max(b[k]) + radius > lo[k] && a[k].min(b[k]) - radius < hi[k])
        }
        Obstacle::Plane { .. }
        | Obstacle::Sdf(_)
        | Obstacle::Oriented { .. }
        | Obstacle::Hull { .. } => true,
    }
}

impl Fluid {
    /// The description it was built from.
    pub fn desc(&self) -> &FluidDesc {
        &self.desc
    }

    /// 2 or 3.
    pub fn dims(&self) -> usize {
        self.dims
    }

    /// Cells along each axis.
    pub fn cells(&self) -> [usize; 3] {
        self.desc.cells
    }

    /// Solid cells, when the scene has obstacles.
    pub fn solid(&self) -> Option<&[bool]> {
        self.solid.as_deref()
    }

    /// Whether smoke density is carried.
    pub fn has_density(&self) -> bool {
        self.has_density
    }

    /// Whether temperature is carried.
    pub fn has_temperature(&self) -> bool {
        self.has_temperature
    }

    /// Whether a viscosity solve was built.
    pub fn has_viscosity(&self) -> bool {
        self.diffusion.is_some()
    }

    fn periodic(&self) -> [bool; 3] {
        self.desc.boundaries.map(|b| b[0] == Boundary::Periodic)
    }

    /// The face grid of component `a`.
    fn face_field(&self, a: usize) -> Field {
        let mut n = self.desc.cells;
        n[a] += 1;
        let mut offset = [0.5; 3];
        offset[a] = 0.0;
        Field {
            n,
            offset,
            periodic: self.periodic(),
        }
    }

    /// The cell grid.
    fn cell_field(&self) -> Field {
        Field {
            n: self.desc.cells,
            offset: [0.5; 3],
            periodic: self.periodic(),
        }
    }

    /// The position (m) of face `f` of component `a`.
    pub fn face_position(&self, a: usize, f: usize) -> [f64; 3] {
        let fld = self.face_field(a);
        let p = fld.position(coords(fld.n, f));
        std::array::from_fn(|b| self.desc.origin[b] + p[b] * self.desc.h)
    }

    /// The centre (m) of cell `c`.
    pub fn cell_center(&self, c: usize) -> [f64; 3] {
        let q = coords(self.desc.cells, c);
        std::array::from_fn(|b| self.desc.origin[b] + (q[b] as f64 + 0.5) * self.desc.h)
    }

    fn initial_velocity(&self, s: &mut FluidState) {
        let d = &self.desc;
        for a in 0..self.dims {
            for f in 0..s.u[a].len() {
                if self.fixed[a][f] {
                    continue;
                }
                let p = self.face_position(a, f);
                s.u[a][f] = match d.initial {
                    Initial::Rest => 0.0,
                    Initial::Uniform(v) => v[a],
                    Initial::TaylorGreen { speed } => {
                        let k = 2.0 * std::f64::consts::PI / (d.cells[0] as f64 * d.h);
                        let (x, y) = (p[0] - d.origin[0], p[1] - d.origin[1]);
                        match a {
                            0 => speed * (k * x).sin() * (k * y).cos(),
                            1 => -speed * (k * x).cos() * (k * y).sin(),
                            _ => 0.0,
                        }
                    }
                };
            }
        }
        self.sync_faces(&mut s.u);
    }

    /// Zeroes the fixed faces and copies face 0 onto the last face of periodic axes.
    fn sync_faces(&self, u: &mut [Vec<f64>; 3]) {
        for (ua, (zero, mirror)) in u
            .iter_mut()
            .zip(self.zero_faces.iter().zip(&self.mirror_faces))
        {
            for &f in zero {
                ua[f as usize] = 0.0;
            }
            for &(last, first) in mirror {
                ua[last as usize] = ua[first as usize];
            }
        }
    }

    fn apply_sources(&self, s: &mut FluidState, initial: bool) {
        let n = self.desc.cells;
        for (src, cells) in self.desc.sources.iter().zip(&self.source_cells) {
            if !initial && s.time >= src.until {
                continue;
            }
            for &c in cells {
                let c = c as usize;
                if let Some(d) = src.density {
                    s.density[c] = s.density[c].max(d);
                }
                if let Some(t) = src.temperature {
                    s.temperature[c] = s.temperature[c].max(t);
                }
                if let Some(v) = src.velocity {
                    let q = coords(n, c);
                    for a in 0..self.dims {
                        let mut fnn = n;
                        fnn[a] += 1;
                        for off in 0..2 {
                            let mut fc = q;
                            fc[a] += off;
                            let f = idx(fnn, fc);
                            if !self.fixed[a][f] {
                                s.u[a][f] = v[a];
                            }
                        }
                    }
                }
            }
        }
        self.sync_faces(&mut s.u);
    }

    /// The viscosity operator of component `a` (module docs, step 4).
    fn diffusion_of(&self, a: usize) -> Diffusion {
        if a >= self.dims {
            return Diffusion {
                nbr: Vec::new(),
                degree: Vec::new(),
                lid: Vec::new(),
                lid_faces: Vec::new(),
            };
        }
        let n = self.desc.cells;
        let mut fnn = n;
        fnn[a] += 1;
        let faces: usize = fnn.iter().product();
        let mut nbr = vec![[u32::MAX; 6]; faces];
        let mut degree = vec![0.0; faces];
        let mut lid = vec![0.0; faces];
        let per = self.periodic();
        // The face index of periodic face `c` (the last face is face 0).
        let canon = |mut c: [usize; 3]| {
            if per[a] && c[a] == n[a] {
                c[a] = 0;
            }
            idx(fnn, c)
        };
        for f in 0..faces {
            if self.fixed[a][f] {
                continue;
            }
            let c = coords(fnn, f);
            let mut slot = 0;
            for b in 0..self.dims {
                for dir in [-1isize, 1] {
                    let q = c[b] as isize + dir;
                    let count = if b == a { n[a] + 1 } else { n[b] };
                    let mut qc = c;
                    if q >= 0 && (q as usize) < count {
                        qc[b] = q as usize;
                    } else if per[b] {
                        let period = n[b] as isize;
                        qc[b] = q.rem_euclid(period) as usize;
                    } else {
                        // Beyond the domain: only tangential components and the open
                        // sides' normal faces get here.
                        let side = self.desc.boundaries[b][usize::from(dir > 0)];
                        match side {
                            Boundary::Wall => degree[f] += 2.0,
                            Boundary::Lid(v) if b != a => {
                                degree[f] += 2.0;
                                lid[f] += 2.0 * v[a];
                            }
                            Boundary::Lid(_) => degree[f] += 2.0,
                            _ => {} // slip, open: zero gradient
                        }
                        continue;
                    }
                    let g = canon(qc);
                    degree[f] += 1.0;
                    if !self.fixed[a][g] || (per[a] && qc[a] == n[a]) {
                        nbr[f][slot] = g as u32;
                        slot += 1;
                    }
                }
            }
        }
        let lid_faces = (0..faces as u32)
            .filter(|&f| lid[f as usize] != 0.0)
            .collect();
        Diffusion {
            nbr,
            degree,
            lid,
            lid_faces,
        }
    }

    /// The largest speed on any face (m/s).
    pub fn max_speed(&self, s: &FluidState) -> f64 {
        let mut m = 0.0f64;
        for a in 0..self.dims {
            for &v in &s.u[a] {
                m = m.max(v.abs());
            }
        }
        m
    }

    /// One step of `dt` (module docs), sub-stepped by the CFL condition. Runs on a
    /// thread of rayon's pool ([`largestep_kernels::par::on_pool`]).
    pub fn step(
        &self,
        s: &mut FluidState,
        w: &mut FluidWork,
        dt: f64,
    ) -> Result<FluidStepInfo, FluidError> {
        largestep_kernels::par::on_pool(|| self.step_here(s, w, dt))
    }

    /// [`Fluid::step`] on the calling thread.
    fn step_here(
        &self,
        s: &mut FluidState,
        w: &mut FluidWork,
        dt: f64,
    ) -> Result<FluidStepInfo, FluidError> {
        let step = s.steps + 1;
        let d = &self.desc;
        // A state handed in with a NaN is named before it spreads.
        self.check_finite(s, step)?;
        let speed = self.max_speed(s);
        let moved = dt * speed / d.h;
        let needed = (moved / d.cfl).ceil().max(1.0);
        if !needed.is_finite() || needed > d.max_substeps as f64 {
            return Err(FluidError::Cfl {
                step,
                dt,
                speed,
                cells: moved,
                cfl: d.cfl,
                needed,
                max: d.max_substeps,
                limit: d.max_substeps as f64 * d.cfl * d.h / speed,
            });
        }
        let sub = needed as usize;
        let h = dt / sub as f64;
        let mut info = FluidStepInfo {
            substeps: sub,
            ..FluidStepInfo::default()
        };
        let driven = d.force != [0.0; 3]
            || d.buoyancy.is_some()
            || d.vorticity > 0.0
            || !d.sources.is_empty();
        for _ in 0..sub {
            self.advect(s, w, h);
            let before = if driven { self.kinetic_energy(s) } else { 0.0 };
            self.add_forces(s, w, h);
            self.apply_sources(s, false);
            if driven {
                s.external_work += self.kinetic_energy(s) - before;
            }
            if let Some(diff) = &self.diffusion {
                let t = Instant::now();
                for (a, df) in diff.iter().enumerate().take(self.dims) {
                    let it = self
                        .diffuse(a, df, s, w, h)
                        .map_err(|e| FluidError::Solve {
                            step,
                            what: "viscosity",
                            source: e,
                        })?;
                    info.viscosity_iterations += it;
                }
                self.sync_faces(&mut s.u);
                s.external_work += h * self.lid_power(s);
                info.solve_seconds += t.elapsed().as_secs_f64();
            }
            let p = self.project(s, w, h).map_err(|e| FluidError::Solve {
                step,
                what: "pressure",
                source: e,
            })?;
            info.pressure_iterations += p.iterations;
            info.residual = p.residual;
            info.solve_seconds += p.seconds;
            s.time += h;
            s.substeps += 1;
        }
        s.steps = step;
        self.check_finite(s, step)?;
        Ok(info)
    }

    fn velocity<'a>(&self, u: &'a [Vec<f64>; 3]) -> Velocity<'a> {
        Velocity {
            cells: self.desc.cells,
            periodic: self.periodic(),
            comp: [&u[0], &u[1], &u[2]],
            dims: self.dims,
        }
    }

    /// Step 1: advection of velocity and scalars by the velocity at the start.
    fn advect(&self, s: &mut FluidState, w: &mut FluidWork, dt: f64) {
        let d = &self.desc;
        let adv = d.advection;
        let vel = self.velocity(&s.u);
        let corrected = adv.correction != Correction::None;
        // The feet of one layout at a time, forwards and (corrected schemes) backwards.
        let feet = |layout: &Field, feet: &mut [Vec<f32>; 2]| {
            let len = 3 * layout.len();
            kf::trace_feet(&mut feet[0][..len], layout, &vel, dt / d.h, adv.trace);
            if corrected {
                kf::trace_feet(&mut feet[1][..len], layout, &vel, -dt / d.h, adv.trace);
            }
            (len, if corrected { len } else { 0 })
        };
        for a in 0..self.dims {
            let layout = self.face_field(a);
            let (lf, lb) = feet(&layout, &mut w.feet);
            let [f0, f1] = &w.feet;
            let [s0, s1] = &mut w.tmp[a];
            advect_one(
                &mut w.next[a],
                &s.u[a],
                [s0, s1],
                &layout,
                [&f0[..lf], &f1[..lb]],
                adv.interp,
                adv.correction,
            );
        }
        if !s.density.is_empty() || !s.temperature.is_empty() {
            let cell = self.cell_field();
            let (lf, lb) = feet(&cell, &mut w.feet);
            let [f0, f1] = &w.feet;
            let [t0, t1, t2] = &mut w.scalar_tmp;
            for field in [&mut s.density, &mut s.temperature] {
                if field.is_empty() {
                    continue;
                }
                advect_one(
                    t0,
                    field,
                    [t1, t2],
                    &cell,
                    [&f0[..lf], &f1[..lb]],
                    adv.interp,
                    adv.correction,
                );
                field.copy_from_slice(t0);
            }
        }
        for a in 0..self.dims {
            std::mem::swap(&mut s.u[a], &mut w.next[a]);
        }
        self.sync_faces(&mut s.u);
    }

    /// The cell-centred velocity at cell `q` (the average of its two faces per axis).
    fn center_velocity(&self, u: &[Vec<f64>; 3], q: [usize; 3]) -> [f64; 3] {
        let n = self.desc.cells;
        let mut v = [0.0; 3];
        for (a, va) in v.iter_mut().enumerate().take(self.dims) {
            let mut fnn = n;
            fnn[a] += 1;
            let mut hi = q;
            hi[a] += 1;
            *va = 0.5 * (u[a][idx(fnn, q)] + u[a][idx(fnn, hi)]);
        }
        v
    }

    /// Step 2: body force, buoyancy and vorticity confinement.
    fn add_forces(&self, s: &mut FluidState, w: &mut FluidWork, dt: f64) {
        let d = &self.desc;
        let n = d.cells;
        let cells = self.desc.cell_count();
        for a in 0..self.dims {
            if d.force[a] != 0.0 {
                for (v, &fixed) in s.u[a].iter_mut().zip(&self.fixed[a]) {
                    if !fixed {
                        *v += dt * d.force[a];
                    }
                }
            }
        }
        if d.buoyancy.is_none() && d.vorticity == 0.0 {
            self.sync_faces(&mut s.u);
            return;
        }
        for f in w.force.iter_mut().take(self.dims) {
            f.fill(0.0);
        }
        if let Some(b) = d.buoyancy {
            let len = b.up.iter().map(|x| x * x).sum::<f64>().sqrt();
            let up = b.up.map(|x| x / len);
            for c in 0..cells {
                let smoke = if s.density.is_empty() {
                    0.0
                } else {
                    s.density[c]
                };
                let heat = if s.temperature.is_empty() {
                    0.0
                } else {
                    s.temperature[c] - b.ambient
                };
                let mag = -b.smoke * smoke + b.heat * heat;
                for (fa, ua) in w.force.iter_mut().zip(up).take(self.dims) {
                    fa[c] += mag * ua;
                }
            }
        }
        if d.vorticity > 0.0 {
            // The centred velocity, once, into `next` (free after advection; as long as
            // the cells or longer), then w = curl u per cell in scalar_tmp.
            let [n0, n1, n2] = &mut w.next;
            let cv2 = &mut n2[..cv2_len(self.dims, cells)];
            self.center_velocities(&s.u, [&mut n0[..cells], &mut n1[..cells], cv2]);
            let [wx, wy, wz] = &mut w.scalar_tmp;
            self.curl(
                [&n0[..cells], &n1[..cells], &n2[..cv2_len(self.dims, cells)]],
                [wx, wy, wz],
            );
            let mag = |q: [usize; 3]| {
                let c = idx(n, q);
                (wx[c] * wx[c] + wy[c] * wy[c] + wz[c] * wz[c]).sqrt()
            };
            for c in 0..cells {
                let q = coords(n, c);
                let g: [f64; 3] = std::array::from_fn(|a| self.diff(q, a, &mag));
                let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
                if len < 1e-12 {
                    continue;
                }
                let nn = g.map(|x| x / len);
                let om = [wx[c], wy[c], wz[c]];
                let f = [
                    nn[1] * om[2] - nn[2] * om[1],
                    nn[2] * om[0] - nn[0] * om[2],
                    nn[0] * om[1] - nn[1] * om[0],
                ];
                for (fa, ff) in w.force.iter_mut().zip(f).take(self.dims) {
                    fa[c] += d.vorticity * d.h * ff;
                }
            }
        }
        // Cell forces to faces: the average of the two cells beside each face (the one
        // cell at the domain's edge).
        let per = self.periodic();
        for a in 0..self.dims {
            let mut fnn = n;
            fnn[a] += 1;
            for (f, v) in s.u[a].iter_mut().enumerate() {
                if self.fixed[a][f] {
                    continue;
                }
                let c = coords(fnn, f);
                let mut lo = c;
                let lo_ok = if c[a] > 0 {
                    lo[a] -= 1;
                    true
                } else if per[a] {
                    lo[a] = n[a] - 1;
                    true
                } else {
                    false
                };
                let hi_ok = c[a] < n[a];
                let fl = if lo_ok {
                    Some(w.force[a][idx(n, lo)])
                } else {
                    None
                };
                let fh = if hi_ok {
                    Some(w.force[a][idx(n, c)])
                } else {
                    None
                };
                let force = match (fl, fh) {
                    (Some(x), Some(y)) => 0.5 * (x + y),
                    (Some(x), None) | (None, Some(x)) => x,
                    (None, None) => 0.0,
                };
                *v += dt * force;
            }
        }
        self.sync_faces(&mut s.u);
    }

    /// Step 4 for component `a`: `(I - nu dt lap) u = u*` by Jacobi-preconditioned CG
    /// from `u*`; returns the iterations.
    fn diffuse(
        &self,
        a: usize,
        df: &Diffusion,
        s: &mut FluidState,
        w: &mut FluidWork,
        dt: f64,
    ) -> Result<usize, SolveError> {
        let d = &self.desc;
        let c = d.viscosity * dt / (d.h * d.h);
        let len = s.u[a].len();
        let fixed = &self.fixed[a];
        let apply = |y: &mut [f64], x: &[f64]| {
            for f in 0..len {
                if fixed[f] {
                    y[f] = 0.0;
                    continue;
                }
                let mut off = 0.0;
                for &j in &df.nbr[f] {
                    if j != u32::MAX {
                        off += x[j as usize];
                    }
                }
                y[f] = x[f] + c * (df.degree[f] * x[f] - off);
            }
        };
        let [b, r, z, p, q] = &mut w.cg;
        let (b, r, z, p, q) = (
            &mut b[..len],
            &mut r[..len],
            &mut z[..len],
            &mut p[..len],
            &mut q[..len],
        );
        let x = &mut s.u[a];
        for f in 0..len {
            b[f] = if fixed[f] { 0.0 } else { x[f] + c * df.lid[f] };
            if fixed[f] {
                x[f] = 0.0;
            }
        }
        let inv = |f: usize| {
            if fixed[f] {
                0.0
            } else {
                1.0 / (1.0 + c * df.degree[f])
            }
        };
        crate::solve::krylov::cg(
            &apply,
            &|z: &mut [f64], r: &[f64]| {
                for (f, (zf, rf)) in z.iter_mut().zip(r).enumerate() {
                    *zf = inv(f) * rf;
                }
            },
            x,
            b,
            [r, z, p, q],
            d.poisson.tolerance,
            d.poisson.max_iterations,
        )
        .map(|i| i.iterations)
    }

    /// Step 5: the pressure projection.
    fn project(
        &self,
        s: &mut FluidState,
        w: &mut FluidWork,
        dt: f64,
    ) -> Result<SolveInfo, SolveError> {
        self.divergence(&s.u, &mut w.div);
        for (r, dv) in w.rhs.iter_mut().zip(&w.div) {
            *r = -dv / dt;
        }
        let info = w
            .poisson
            .solve(&mut s.pressure, &w.rhs, &self.desc.poisson)?;
        self.subtract_gradient(&mut s.u, &s.pressure, dt);
        Ok(info)
    }

    /// `div u` per cell (1/s; zero on solid cells).
    pub fn divergence(&self, u: &[Vec<f64>; 3], div: &mut [f64]) {
        let n = self.desc.cells;
        let inv_h = 1.0 / self.desc.h;
        for (c, dv) in div.iter_mut().enumerate() {
            if self.solid.as_ref().is_some_and(|s| s[c]) {
                *dv = 0.0;
                continue;
            }
            let q = coords(n, c);
            let mut sum = 0.0;
            for (a, ua) in u.iter().enumerate().take(self.dims) {
                let mut fnn = n;
                fnn[a] += 1;
                let mut hi = q;
                hi[a] += 1;
                sum += ua[idx(fnn, hi)] - ua[idx(fnn, q)];
            }
            *dv = sum * inv_h;
        }
    }

    /// `u -= dt grad p` on the free faces (p = 0 beyond open sides).
    fn subtract_gradient(&self, u: &mut [Vec<f64>; 3], p: &[f64], dt: f64) {
        let n = self.desc.cells;
        let per = self.periodic();
        let scale = dt / self.desc.h;
        for a in 0..self.dims {
            let mut fnn = n;
            fnn[a] += 1;
            for (f, v) in u[a].iter_mut().enumerate() {
                if self.fixed[a][f] {
                    continue;
                }
                let c = coords(fnn, f);
                let hi = if c[a] < n[a] { p[idx(n, c)] } else { 0.0 };
                let lo = if c[a] > 0 {
                    let mut l = c;
                    l[a] -= 1;
                    p[idx(n, l)]
                } else if per[a] {
                    let mut l = c;
                    l[a] = n[a] - 1;
                    p[idx(n, l)]
                } else {
                    0.0
                };
                *v -= scale * (hi - lo);
            }
        }
        self.sync_faces(u);
    }

    fn check_finite(&self, s: &FluidState, step: u64) -> Result<(), FluidError> {
        for a in 0..self.dims {
            if let Some(f) = s.u[a].iter().position(|v| !v.is_finite()) {
                let fld = self.face_field(a);
                return Err(FluidError::NonFinite {
                    step,
                    field: "velocity",
                    at: format!("{} face {:?}", ["x", "y", "z"][a], coords(fld.n, f)),
                });
            }
        }
        for (name, v) in [("density", &s.density), ("temperature", &s.temperature)] {
            if let Some(c) = v.iter().position(|v| !v.is_finite()) {
                return Err(FluidError::NonFinite {
                    step,
                    field: name,
                    at: format!("cell {:?}", coords(self.desc.cells, c)),
                });
            }
        }
        Ok(())
    }

    /// Kinetic energy (J): `rho / 2 sum u^2 h^3` over the faces (a 2-D fluid is one cell,
    /// h, deep).
    pub fn kinetic_energy(&self, s: &FluidState) -> f64 {
        let d = &self.desc;
        let vol = d.h.powi(3);
        let n = d.cells;
        let per = self.periodic();
        let mut e = 0.0;
        for a in 0..self.dims {
            let mut fnn = n;
            fnn[a] += 1;
            for (f, v) in s.u[a].iter().enumerate() {
                let c = coords(fnn, f);
                if per[a] && c[a] == n[a] {
                    continue;
                }
                // Faces on the domain's edge hold half a cell.
                let w = if !per[a] && (c[a] == 0 || c[a] == n[a]) {
                    0.5
                } else {
                    1.0
                };
                e += w * v * v;
            }
        }
        0.5 * d.density * vol * e
    }

    /// The power the moving lids put in (W): on each face beside a lid, the shear force
    /// `rho nu (U - u) 2 / h` times the face's area `h^2` (a 2-D fluid is one cell deep)
    /// times the lid's speed U: the discrete form of the ghost coupling of the viscosity
    /// solve.
    fn lid_power(&self, s: &FluidState) -> f64 {
        let d = &self.desc;
        let Some(diff) = &self.diffusion else {
            return 0.0;
        };
        let mut p = 0.0;
        for (df, u) in diff.iter().zip(&s.u).take(self.dims) {
            // `lid[f]` is 2 U summed over the face's lid ghosts: the shear force of one
            // lid is rho nu (2 U - 2 u) / h on the face's area h^2, its power that times U.
            for &f in &df.lid_faces {
                let (two_u, uf) = (df.lid[f as usize], u[f as usize]);
                p += d.density * d.viscosity * (two_u - 2.0 * uf) * d.h * 0.5 * two_u;
            }
        }
        p
    }

    /// The velocity at cell centres, component-major (3 x cells).
    pub fn cell_velocity(&self, s: &FluidState) -> Vec<f64> {
        let cells = self.desc.cell_count();
        let mut out = vec![0.0; 3 * cells];
        let (x, rest) = out.split_at_mut(cells);
        let (y, z) = rest.split_at_mut(cells);
        self.center_velocities(&s.u, [x, y, z]);
        out
    }

    /// The velocity at every cell centre into `out` (one slice per component; the z one
    /// may be empty in 2-D).
    fn center_velocities(&self, u: &[Vec<f64>; 3], out: [&mut [f64]; 3]) {
        let n = self.desc.cells;
        let [x, y, z] = out;
        for c in 0..x.len() {
            let v = self.center_velocity(u, coords(n, c));
            x[c] = v[0];
            y[c] = v[1];
            if let Some(zc) = z.get_mut(c) {
                *zc = v[2];
            }
        }
    }

    /// The derivative along axis `a` at cell `q` of the cell field `get` (1/m times its
    /// unit): central differences, one-sided at the domain's edge, wrapped along periodic
    /// axes; zero along an axis of one cell.
    fn diff(&self, q: [usize; 3], a: usize, get: &dyn Fn([usize; 3]) -> f64) -> f64 {
        let n = self.desc.cells;
        if n[a] < 2 {
            return 0.0;
        }
        let per = self.periodic()[a];
        let (mut lo, mut hi) = (q, q);
        let mut span = 0.0;
        if q[a] > 0 {
            lo[a] -= 1;
            span += 1.0;
        } else if per {
            lo[a] = n[a] - 1;
            span += 1.0;
        }
        if q[a] + 1 < n[a] {
            hi[a] += 1;
            span += 1.0;
        } else if per {
            hi[a] = 0;
            span += 1.0;
        }
        (get(hi) - get(lo)) / (span * self.desc.h)
    }

    /// `w = curl u` at cell centres (1/s), from [`Fluid::diff`] of the centred velocity
    /// `cv` (the z component unread in 2-D, where only w's z component is non-zero).
    fn curl(&self, cv: [&[f64]; 3], w: [&mut [f64]; 3]) {
        let n = self.desc.cells;
        let [wx, wy, wz] = w;
        let comp = |k: usize| move |q: [usize; 3]| cv[k][idx(n, q)];
        let d = |q: [usize; 3], k: usize, a: usize| self.diff(q, a, &comp(k));
        for c in 0..wx.len() {
            let q = coords(n, c);
            wz[c] = d(q, 1, 0) - d(q, 0, 1);
            if self.dims == 3 {
                wx[c] = d(q, 2, 1) - d(q, 1, 2);
                wy[c] = d(q, 0, 2) - d(q, 2, 0);
            } else {
                wx[c] = 0.0;
                wy[c] = 0.0;
            }
        }
    }

    /// The vorticity at cell centres (1/s): the z component in 2-D, the magnitude in
    /// 3-D.
    pub fn vorticity(&self, s: &FluidState) -> Vec<f64> {
        let cells = self.desc.cell_count();
        let cv = self.cell_velocity(s);
        let mut w: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; cells]);
        let [wx, wy, wz] = &mut w;
        let (x, rest) = cv.split_at(cells);
        let (y, z) = rest.split_at(cells);
        self.curl([x, y, z], [wx, wy, wz]);
        if self.dims == 2 {
            return std::mem::take(wz);
        }
        (0..cells)
            .map(|c| (wx[c] * wx[c] + wy[c] * wy[c] + wz[c] * wz[c]).sqrt())
            .collect()
    }
}

/// Cells of the centred velocity's z component: none in 2-D.
fn cv2_len(dims: usize, cells: usize) -> usize {
    if dims == 3 {
        cells
    } else {
        0
    }
}

/// `out` = `values` advected along the feet `fwd` (and, for the corrected schemes, back
/// along `back`, the forward traces), with two scratch buffers.
fn advect_one(
    out: &mut [f64],
    values: &[f64],
    scratch: [&mut [f64]; 2],
    layout: &Field,
    feet: [&[f32]; 2],
    interp: Interp,
    correction: Correction,
) {
    let [s0, s1] = scratch;
    let [fwd, back] = feet;
    match correction {
        Correction::None => kf::advect(out, values, layout, fwd, interp),
        Correction::MacCormack => {
            kf::advect(s0, values, layout, fwd, interp);
            kf::advect(s1, s0, layout, back, interp);
            kf::advect_limited(out, values, s0, Some(s1), layout, fwd);
        }
        Correction::Bfecc => {
            kf::advect(s0, values, layout, fwd, interp);
            kf::advect(s1, s0, layout, back, interp);
            // s1 = values + (values - back) / 2, carried forth and limited.
            for (t, v) in s1.iter_mut().zip(values) {
                *t = v + 0.5 * (v - *t);
            }
            kf::advect(s0, s1, layout, fwd, interp);
            kf::advect_limited(out, values, s0, None, layout, fwd);
        }
    }
}
