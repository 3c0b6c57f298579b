//! External loads, shared by every domain: force terms a model adds to its own
//! (element) forces, each with its force and, where it has one, its energy.
//!
//! - [`Gravity`]: `f_i = m_i g`, potential `-sum m_i g . x_i`.
//! - [`Wind`]: linear drag of each surface triangle along its normal towards the air's
//!   (gusting) velocity; no potential.
//! - [`ForceField`]: forces sampled on a grid, trilinearly interpolated at each vertex
//!   (the jello assignment's field); no potential (a sampled field need not have one).
//!
//! Like Vega FEM's force models, every term speaks one interface ([`Load`]) and a model
//! composes the terms it was given ([`Loads`]: gravity, then wind, then the field, always
//! in that order, so results do not depend on how a scene lists them). Loads enter
//! implicit steps explicitly, as Baraff and Witkin treat external forces: none adds a
//! Jacobian (gravity's is zero; the wind's velocity derivative and the field's gradient
//! are left out), so no load ever changes a model's matrix pattern.

mod field;
mod wind;

pub use field::ForceField;
pub use wind::Wind;

use crate::simulation::Stage;
use crate::validate::{check, ModelError, Rule};

/// What a load acts on: the model's lumped masses (kg, one per vertex) and its surface
/// triangles (for loads on area, such as wind; may be empty).
#[derive(Clone, Copy, Debug)]
pub struct Body<'a> {
    /// Mass per vertex (kg).
    pub mass: &'a [f64],
    /// Surface triangles.
    pub triangles: &'a [[u32; 3]],
}

/// One external force term. Positions, velocities and forces are component-major Vec3s
/// data of the body's n vertices.
pub trait Load: std::fmt::Debug + Send + Sync {
    /// Adds the load's force (N) at time `t` (s) to `f`.
    fn add_forces(&self, t: f64, body: &Body<'_>, x: &[f64], v: &[f64], f: &mut [f64]);
    /// The load's potential energy (J) at `x` when it is conservative (`f = -dU/dx`),
    /// else `None`.
    fn potential(&self, body: &Body<'_>, x: &[f64]) -> Option<f64> {
        let _ = (body, x);
        None
    }
    /// The rate (W) at which a load without a potential does work on the body,
    /// `sum f_i . v_i`; `None` for a conservative load, whose work is its potential's
    /// change. Energy accounting integrates it, so that a run driven by wind or a force
    /// field is not taken for an unstable one.
    fn work_rate(&self, t: f64, body: &Body<'_>, x: &[f64], v: &[f64]) -> Option<f64> {
        let _ = (t, body, x, v);
        None
    }
    /// Checks the parameters (errors name the load as the item).
    fn validate(&self) -> Result<(), ModelError>;
    /// The `--explain` line of the load.
    fn stage(&self) -> Stage;
}

/// Uniform gravity: acceleration `g` (m/s^2).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Gravity(pub [f64; 3]);

impl Gravity {
    /// `f_i = m_i g` (N), overwriting `f`.
    pub fn write_forces(&self, body: &Body<'_>, f: &mut [f64]) {
        self.apply(body, f, false);
    }

    /// `f_i = m_i g`, written or added.
    fn apply(&self, body: &Body<'_>, f: &mut [f64], add: bool) {
        let n = body.mass.len();
        assert_eq!(f.len(), 3 * n);
        for (c, gc) in self.0.iter().enumerate() {
            let fc = f[c * n..(c + 1) * n].iter_mut().zip(body.mass);
            if add {
                fc.for_each(|(fi, m)| *fi += m * gc);
            } else {
                fc.for_each(|(fi, m)| *fi = m * gc);
            }
        }
    }
}

impl Load for Gravity {
    fn add_forces(&self, _t: f64, body: &Body<'_>, _x: &[f64], _v: &[f64], f: &mut [f64]) {
        self.apply(body, f, true);
    }

    fn potential(&self, body: &Body<'_>, x: &[f64]) -> Option<f64> {
        let (mass, g) = (body.mass, self.0);
        let n = mass.len();
        assert_eq!(x.len(), 3 * n);
        Some(
            (0..n)
                .map(|i| -mass[i] * (g[0] * x[i] + g[1] * x[n + i] + g[2] * x[2 * n + i]))
                .sum(),
        )
    }

    fn validate(&self) -> Result<(), ModelError> {
        for (c, &g) in self.0.iter().enumerate() {
            check("gravity", c, "component", g, Rule::Finite)?;
        }
        Ok(())
    }

    fn stage(&self) -> Stage {
        let g = self.0;
        if g == [0.0; 3] {
            Stage::left_out("gravity", "gravity is zero")
        } else {
            Stage::built("gravity", format!("{g:?} m/s^2"))
        }
    }
}

/// The external loads of a model, applied in a fixed order: gravity, wind, force field.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Loads {
    /// Gravity (zero: none).
    pub gravity: Gravity,
    /// Wind on the surface triangles, if any.
    pub wind: Option<Wind>,
    /// A force field, if any.
    pub field: Option<ForceField>,
}

impl Loads {
    /// The terms present, in application order.
    fn terms(&self) -> impl Iterator<Item = &dyn Load> {
        let wind = self.wind.as_ref().map(|w| w as &dyn Load);
        let field = self.field.as_ref().map(|f| f as &dyn Load);
        std::iter::once(&self.gravity as &dyn Load)
            .chain(wind)
            .chain(field)
    }

    /// `f` = the sum of the loads' forces (N) at time `t`, overwriting `f`: gravity
    /// writes it (one pass, not a zeroing and an addition), the others add to it.
    pub fn forces(&self, t: f64, body: &Body<'_>, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.gravity.write_forces(body, f);
        for load in self.terms().skip(1) {
            load.add_forces(t, body, x, v, f);
        }
    }

    /// The potential energy (J) of the conservative loads (gravity); wind and field have
    /// none and add nothing.
    pub fn potential(&self, body: &Body<'_>, x: &[f64]) -> f64 {
        self.terms()
            .filter_map(|l| l.potential(body, x))
            .fold(0.0, |a, b| a + b)
    }

    /// The rate (W) at which the loads without a potential (wind, field) do work.
    pub fn work_rate(&self, t: f64, body: &Body<'_>, x: &[f64], v: &[f64]) -> f64 {
        self.terms()
            .filter_map(|l| l.work_rate(t, body, x, v))
            .fold(0.0, |a, b| a + b)
    }

    /// Whether any load does work outside a potential.
    pub fn does_work(&self) -> bool {
        self.wind.is_some() || self.field.is_some()
    }

    /// Checks every load.
    pub fn validate(&self) -> Result<(), ModelError> {
        self.terms().try_for_each(|l| l.validate())
    }

    /// The `--explain` lines: gravity always, wind and field when present.
    pub fn stages(&self) -> Vec<Stage> {
        self.terms().map(|l| l.stage()).collect()
    }
}
