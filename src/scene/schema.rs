//! The scene-wide TOML tables (serde), exactly as users write them: `[scene]`, `[solver]`
//! and `[output]`. Unknown fields are errors. Each system's table belongs to its domain
//! (the `scene.rs` of the domain's folder), with the shared obstacle, load and step
//! control tables of [`super::shared`] inside it.
//!
//! ```toml
//! [scene]
//! name = "hanging-chain"      # default: the file name; names the output folder
//! dt = 0.0005                 # s, > 0
//! duration = 3.0              # s, > 0
//! integrator = "rk4"          # see `largestep::integrate::Method` (default backward-euler)
//! gravity = [0.0, -9.81, 0.0] # m/s^2, for every system
//!
//! [solver]                    # implicit integrators only (all optional)
//! linear = "auto"             # auto (Cholesky up to 30,000 unknowns, PCG above) | pcg | cholesky
//! tolerance = 1e-8            # PCG relative residual
//! max_iterations = 1000       # PCG
//! preconditioner = "block-jacobi"  # none | jacobi | block-jacobi | multigrid | smoothed-aggregation
//! newton_tolerance = 1e-9
//! newton_max_iterations = 50
//! reuse_jacobian = 0          # steps one factored Jacobian may serve (0: full Newton)
//! forcing = 0.5               # inexact Newton: PCG tolerance up to this (Eisenstat-Walker)
//! reuse_preconditioner = 0    # steps one PCG multigrid hierarchy may serve (0: new each time)
//! predictor = true            # Newton starts from the last step's velocity change carried on
//! second_order_predictor = false  # ... from the last two changes extrapolated linearly
//! newton_rate_test = false    # Newton stops on the error left, from its contraction rate
//! newton_skip_last_residual = false  # ... and takes the step it accepts unevaluated
//! rounded_products = false    # PCG's products with the multigrid's f32 copy (Newton steps)
//!
//! [mass_spring.chain]         # one table per system: [mass_spring], [cloth], ...
//! count = 20
//! ...
//!
//! [output]
//! frames = "obj"              # obj | ply | none
//! every = 33                  # steps per frame (default: about 30 frames per second)
//! width = 1280                # preview images (`largestep run --preview`, `largestep render`)
//! height = 720
//! supersample = 2             # 1..=4 samples per pixel each way
//! wireframe = false
//! ground = true
//! [output.camera]             # default: auto-framed from azimuth and elevation
//! azimuth = 35.0              # degrees about the up axis, 0 looks from +z
//! elevation = 22.0            # degrees above the ground
//! fov = 40.0                  # vertical field of view, degrees
//! up = [0.0, 1.0, 0.0]        # default: against gravity, else +y
//! # eye = [3.0, 2.0, 3.0]     # a fixed camera instead (then target is required)
//! # target = [0.0, 0.0, 0.0]
//! ```

use serde::Deserialize;

/// `[scene]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneTable {
    /// Name used in reports.
    #[serde(default)]
    pub name: Option<String>,
    /// Time step (s).
    pub dt: f64,
    /// Simulated time (s).
    pub duration: f64,
    /// Integrator name (default `backward-euler`; systems that integrate nothing, such as
    /// modal sound, need none).
    #[serde(default)]
    pub integrator: Option<String>,
    /// Gravity (m/s^2).
    #[serde(default)]
    pub gravity: Option<[f64; 3]>,
}

/// `[solver]`
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverTable {
    /// `auto`, `pcg` or `cholesky`.
    pub linear: Option<String>,
    /// PCG tolerance.
    pub tolerance: Option<f64>,
    /// PCG iteration limit.
    pub max_iterations: Option<i64>,
    /// `none`, `jacobi`, `block-jacobi`.
    pub preconditioner: Option<String>,
    /// Newton relative tolerance.
    pub newton_tolerance: Option<f64>,
    /// Newton iteration limit.
    pub newton_max_iterations: Option<i64>,
    /// Steps one factored Jacobian may serve (the chord method; 0: full Newton).
    pub reuse_jacobian: Option<i64>,
    /// Inexact Newton: the largest PCG tolerance the forcing terms may choose.
    pub forcing: Option<f64>,
    /// Steps one PCG multigrid hierarchy may serve (0: a new one for each Jacobian).
    pub reuse_preconditioner: Option<i64>,
    /// Newton's first guess from the last step's velocity change (default true).
    pub predictor: Option<bool>,
    /// The predictor extrapolates the last two velocity changes (default false).
    pub second_order_predictor: Option<bool>,
    /// Newton's step test on the error estimated from the contraction rate (default
    /// false).
    pub newton_rate_test: Option<bool>,
    /// With the rate test, the step it accepts is taken without evaluating the residual
    /// at its end (default false).
    pub newton_skip_last_residual: Option<bool>,
    /// PCG's products through the multigrid's `f32` copy in Newton steps (default false).
    pub rounded_products: Option<bool>,
}

/// `[output]`
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputTable {
    /// `obj`, `ply` or `none`.
    pub frames: Option<String>,
    /// Steps per frame.
    pub every: Option<i64>,
    /// Preview width (pixels).
    pub width: Option<i64>,
    /// Preview height (pixels).
    pub height: Option<i64>,
    /// Samples per pixel along each axis.
    pub supersample: Option<i64>,
    /// Triangle edges over the shading.
    pub wireframe: Option<bool>,
    /// Ground plane with grid and shadows.
    pub ground: Option<bool>,
    /// `[output.camera]`
    pub camera: Option<CameraTable>,
}

/// `[output.camera]`
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraTable {
    /// Eye position (m): a fixed camera.
    pub eye: Option<[f64; 3]>,
    /// Point looked at (m), with `eye`.
    pub target: Option<[f64; 3]>,
    /// World up.
    pub up: Option<[f64; 3]>,
    /// Vertical field of view (degrees).
    pub fov: Option<f64>,
    /// Auto-framing azimuth (degrees).
    pub azimuth: Option<f64>,
    /// Auto-framing elevation (degrees).
    pub elevation: Option<f64>,
}
