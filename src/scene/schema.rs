//! The TOML scene schema (serde), exactly as users write it. Unknown fields are errors.
//!
//! ```toml
//! [scene]
//! name = "hanging-chain"
//! dt = 0.0005                 # s, > 0
//! duration = 3.0              # s, > 0
//! integrator = "rk4"          # see `largestep::integrate::Method`
//! gravity = [0.0, -9.81, 0.0] # m/s^2
//!
//! [solver]                    # implicit integrators only (all optional)
//! linear = "auto"             # auto (Cholesky up to 30,000 unknowns, PCG above) | pcg | cholesky
//! tolerance = 1e-8            # PCG relative residual
//! max_iterations = 1000       # PCG
//! preconditioner = "block-jacobi"  # none | jacobi | block-jacobi | multigrid
//! newton_tolerance = 1e-9
//! newton_max_iterations = 50
//!
//! [mass_spring]               # one of: chain, grid, lattice, or particle + spring lists
//! pinned = [0]
//! definiteness_fix = true
//! [mass_spring.chain]
//! count = 20
//! ...
//!
//! [mass_spring.lattice]       # the jello cube: structural, shear and bend springs
//! n = [8, 8, 8]
//! size = [1.0, 1.0, 1.0]      # rest extent (m); origin = [x, y, z] optional
//! mass = 0.001953             # per particle (kg)
//! structural = 200.0          # shear, bend, damping, velocity optional
//! [mass_spring.collisions]    # penalty springs (rest length 0) while a point penetrates
//! box_min = [-2.0, -2.0, -2.0]
//! box_max = [2.0, 2.0, 2.0]
//! planes = [[-1.0, 1.0, 1.0, 2.0]]   # a x + b y + c z + d = 0; points stay where they start
//! stiffness = 400.0
//! damping = 0.25
//! [mass_spring.force_field]   # forces (N) on an r^3 grid over [min, max], trilinear
//! min = [-2.0, -2.0, -2.0]
//! max = [2.0, 2.0, 2.0]
//! resolution = 2
//! forces = [[0.0, -0.02, 0.0], ...]  # r^3 entries, x outermost, z innermost
//!
//! [cloth]                     # instead of [mass_spring]: a Baraff-Witkin sheet
//! pinned = [0, 9]             # grid vertex (i, j) is i + nu j
//! friction = 0.3             # of contacts
//! [[cloth.sphere]]            # obstacles (any number of each)
//! center = [0.0, 0.0, 0.0]
//! radius = 0.5
//! # [[cloth.plane]] point, normal; [[cloth.box]] min, max; [[cloth.capsule]] a, b, radius
//! # [[cloth.sdf]] file = "shape.sdf"   (SDFGen text: ni nj nk / origin / dx / values)
//! # [cloth.wind] velocity = [3.0, 0.0, 0.0], drag = 0.5, gust = 0.5, frequency = 1.5
//! # [[cloth.path]] vertices = [0], times = [0.0, 1.0], offsets = [[0,0,0], [0.3,0,0]]
//! # [cloth.step_control] max_strain_change = 0.25, max_halvings = 6   (these are the defaults)
//! [cloth.grid]                # or [cloth.mesh] file = "sheet.obj" (with vt), uv_scale
//! nu = 10
//! nv = 10
//! size = [1.0, 1.0]           # rest (u, v) extent (m); origin, u_axis, v_axis optional
//! [cloth.material]
//! density = 0.2               # kg/m^2
//! stretch = 500.0             # shear, bend, *_damping optional
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

/// The whole file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct File {
    /// `[scene]`
    pub scene: SceneTable,
    /// `[solver]`
    #[serde(default)]
    pub solver: Option<SolverTable>,
    /// `[mass_spring]`
    #[serde(default)]
    pub mass_spring: Option<MassSpringTable>,
    /// `[cloth]`
    #[serde(default)]
    pub cloth: Option<ClothTable>,
    /// `[output]`
    #[serde(default)]
    pub output: Option<OutputTable>,
}

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
    /// Integrator name.
    pub integrator: String,
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
}

/// `[mass_spring]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MassSpringTable {
    /// Pinned particle indices.
    #[serde(default)]
    pub pinned: Vec<i64>,
    /// Clamp the compression term of spring Jacobians (default true).
    #[serde(default)]
    pub definiteness_fix: Option<bool>,
    /// A chain generator.
    #[serde(default)]
    pub chain: Option<ChainTable>,
    /// A grid generator.
    #[serde(default)]
    pub grid: Option<GridTable>,
    /// A 3-D lattice generator (the jello cube).
    #[serde(default)]
    pub lattice: Option<LatticeTable>,
    /// Penalty collisions.
    #[serde(default)]
    pub collisions: Option<CollisionsTable>,
    /// An external force field.
    #[serde(default)]
    pub force_field: Option<ForceFieldTable>,
    /// Explicit particles.
    #[serde(default)]
    pub particle: Vec<ParticleTable>,
    /// Explicit springs.
    #[serde(default)]
    pub spring: Vec<SpringTable>,
}

/// `[mass_spring.chain]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChainTable {
    /// Particles (>= 2).
    pub count: i64,
    /// First particle (m).
    #[serde(default)]
    pub anchor: Option<[f64; 3]>,
    /// Direction of the chain.
    #[serde(default)]
    pub direction: Option<[f64; 3]>,
    /// Distance between particles (m).
    pub spacing: f64,
    /// Mass of each particle (kg).
    pub mass: f64,
    /// Spring stiffness (N/m).
    pub stiffness: f64,
    /// Spring damping (N s/m).
    #[serde(default)]
    pub damping: f64,
}

/// `[mass_spring.grid]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridTable {
    /// Particles along the first axis (>= 2).
    pub nu: i64,
    /// Particles along the second axis (>= 2).
    pub nv: i64,
    /// Extent (m).
    pub size: [f64; 2],
    /// Corner particle position (m).
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    /// First axis direction.
    #[serde(default)]
    pub u_axis: Option<[f64; 3]>,
    /// Second axis direction.
    #[serde(default)]
    pub v_axis: Option<[f64; 3]>,
    /// Total mass (kg).
    pub mass: f64,
    /// Structural stiffness (N/m).
    pub structural: f64,
    /// Shear stiffness (N/m).
    #[serde(default)]
    pub shear: f64,
    /// Bend stiffness (N/m).
    #[serde(default)]
    pub bend: f64,
    /// Damping of every spring (N s/m).
    #[serde(default)]
    pub damping: f64,
}

/// `[cloth]`: a Baraff-Witkin sheet.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothTable {
    /// Pinned vertices (index `i + nu j` of grid vertex (i, j)).
    #[serde(default)]
    pub pinned: Vec<i64>,
    /// Project element stiffness matrices to keep implicit systems definite (default true).
    #[serde(default)]
    pub definiteness_fix: Option<bool>,
    /// Friction of contacts (default 0).
    #[serde(default)]
    pub friction: f64,
    /// `[[cloth.sphere]]` obstacles.
    #[serde(default)]
    pub sphere: Vec<SphereTable>,
    /// `[[cloth.plane]]` obstacles.
    #[serde(default)]
    pub plane: Vec<PlaneTable>,
    /// `[[cloth.box]]` obstacles.
    #[serde(default, rename = "box")]
    pub boxes: Vec<BoxTable>,
    /// `[[cloth.capsule]]` obstacles.
    #[serde(default)]
    pub capsule: Vec<CapsuleTable>,
    /// `[[cloth.sdf]]` obstacles (signed-distance grid files).
    #[serde(default)]
    pub sdf: Vec<SdfTable>,
    /// `[cloth.wind]`
    #[serde(default)]
    pub wind: Option<WindTable>,
    /// `[[cloth.path]]` vertices moved along prescribed paths.
    #[serde(default)]
    pub path: Vec<PathTable>,
    /// `[cloth.step_control]` (defaults apply when absent).
    #[serde(default)]
    pub step_control: Option<StepControlTable>,
    /// `[cloth.grid]` (or `[cloth.mesh]`).
    #[serde(default)]
    pub grid: Option<ClothGridTable>,
    /// `[cloth.mesh]`: an OBJ triangle mesh with texture coordinates.
    #[serde(default)]
    pub mesh: Option<ClothMeshTable>,
    /// `[cloth.material]`
    pub material: ClothMaterialTable,
}

/// `[[cloth.sphere]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereTable {
    /// Centre (m).
    pub center: [f64; 3],
    /// Radius (m).
    pub radius: f64,
}

/// `[[cloth.plane]]`: the half-space behind a plane.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneTable {
    /// A point on the plane (m).
    pub point: [f64; 3],
    /// Outward normal.
    pub normal: [f64; 3],
}

/// `[[cloth.box]]`: a solid axis-aligned box.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxTable {
    /// Lower corner (m).
    pub min: [f64; 3],
    /// Upper corner (m).
    pub max: [f64; 3],
}

/// `[[cloth.capsule]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapsuleTable {
    /// Segment start (m).
    pub a: [f64; 3],
    /// Segment end (m).
    pub b: [f64; 3],
    /// Radius (m).
    pub radius: f64,
}

/// `[[cloth.sdf]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SdfTable {
    /// An SDFGen text file (relative to the scene file).
    pub file: String,
}

/// `[cloth.wind]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindTable {
    /// Air velocity (m/s).
    pub velocity: [f64; 3],
    /// Drag coefficient (N s/m^3).
    pub drag: f64,
    /// Relative gust amplitude (default 0).
    #[serde(default)]
    pub gust: f64,
    /// Gust frequency (Hz, default 0).
    #[serde(default)]
    pub frequency: f64,
}

/// `[[cloth.path]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathTable {
    /// Vertices moved.
    pub vertices: Vec<i64>,
    /// Keyframe times (s).
    pub times: Vec<f64>,
    /// Offsets from the initial positions (m), one per time.
    pub offsets: Vec<[f64; 3]>,
}

/// `[cloth.step_control]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepControlTable {
    /// Largest change of any triangle's strain in one step before the step is retried
    /// at half the size.
    #[serde(default)]
    pub max_strain_change: Option<f64>,
    /// How many times a step may be halved before the run fails.
    #[serde(default)]
    pub max_halvings: Option<i64>,
}

/// `[cloth.mesh]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothMeshTable {
    /// OBJ file with texture coordinates (relative to the scene file).
    pub file: String,
    /// Metres per texture unit: rest (u, v) = scale * (vt) (default 1).
    #[serde(default)]
    pub uv_scale: Option<f64>,
    /// Multiplies the positions (default 1).
    #[serde(default)]
    pub scale: Option<f64>,
    /// Added to the positions after scaling (m, default 0).
    #[serde(default)]
    pub offset: Option<[f64; 3]>,
}

/// `[cloth.grid]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothGridTable {
    /// Vertices along u (>= 2).
    pub nu: i64,
    /// Vertices along v (>= 2).
    pub nv: i64,
    /// Extent along u and v (m); the rest (u, v).
    pub size: [f64; 2],
    /// Position of vertex (0, 0) (m).
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    /// Direction of u (default +x).
    #[serde(default)]
    pub u_axis: Option<[f64; 3]>,
    /// Direction of v (default +z).
    #[serde(default)]
    pub v_axis: Option<[f64; 3]>,
}

/// `[cloth.material]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothMaterialTable {
    /// Mass per unit area (kg/m^2).
    pub density: f64,
    /// Stretch stiffness (N/m).
    pub stretch: f64,
    /// Shear stiffness (N/m).
    #[serde(default)]
    pub shear: f64,
    /// Bend stiffness (N m); 0 leaves bending out.
    #[serde(default)]
    pub bend: f64,
    /// Stretch damping.
    #[serde(default)]
    pub stretch_damping: f64,
    /// Shear damping.
    #[serde(default)]
    pub shear_damping: f64,
    /// Bend damping.
    #[serde(default)]
    pub bend_damping: f64,
}

/// `[mass_spring.lattice]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LatticeTable {
    /// Particles along x, y, z (each >= 2).
    pub n: [i64; 3],
    /// Rest position of particle (0, 0, 0) (m).
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    /// Rest extent (m).
    pub size: [f64; 3],
    /// Mass of each particle (kg).
    pub mass: f64,
    /// Structural stiffness (N/m).
    pub structural: f64,
    /// Shear stiffness (N/m).
    #[serde(default)]
    pub shear: f64,
    /// Bend stiffness (N/m).
    #[serde(default)]
    pub bend: f64,
    /// Damping of every spring (N s/m).
    #[serde(default)]
    pub damping: f64,
    /// Initial velocity of every particle (m/s).
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
}

/// `[mass_spring.collisions]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollisionsTable {
    /// Bounding box corner (m), with `box_max`.
    #[serde(default)]
    pub box_min: Option<[f64; 3]>,
    /// Bounding box corner (m), with `box_min`.
    #[serde(default)]
    pub box_max: Option<[f64; 3]>,
    /// Planes `[a, b, c, d]` of `a x + b y + c z + d = 0`.
    #[serde(default)]
    pub planes: Vec<[f64; 4]>,
    /// Collision spring stiffness (N/m).
    pub stiffness: f64,
    /// Collision spring damping (N s/m).
    #[serde(default)]
    pub damping: f64,
}

/// `[mass_spring.force_field]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceFieldTable {
    /// Box corner the grid spans from (m).
    pub min: [f64; 3],
    /// Opposite corner (m).
    pub max: [f64; 3],
    /// Nodes per axis r (>= 2).
    pub resolution: i64,
    /// r^3 forces `[fx, fy, fz]` (N), node (i, j, k) at entry `i r^2 + j r + k` (the
    /// world files' order: x outermost).
    pub forces: Vec<[f64; 3]>,
}

/// `[[mass_spring.particle]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticleTable {
    /// Position (m).
    pub position: [f64; 3],
    /// Velocity (m/s).
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
    /// Mass (kg).
    pub mass: f64,
    /// Pinned.
    #[serde(default)]
    pub pinned: bool,
}

/// `[[mass_spring.spring]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpringTable {
    /// First particle.
    pub a: i64,
    /// Second particle.
    pub b: i64,
    /// Stiffness (N/m).
    pub stiffness: f64,
    /// Damping (N s/m).
    #[serde(default)]
    pub damping: f64,
    /// Rest length (m); default the initial distance.
    #[serde(default)]
    pub rest_length: Option<f64>,
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
