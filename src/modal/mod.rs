//! Modal analysis (issue 16; course notes section 17; O'Brien, Shen and Gatchalian 2002):
//! the lowest vibration modes of a tetrahedral mesh, `K x = lambda M x` with the FEM's
//! stiffness at rest (linear elasticity: every material's tangent at `F = I`) and its
//! lumped or consistent mass, through [`crate::solve::lowest_modes`]. Frequencies are
//! `f = sqrt(lambda) / 2 pi`; the rigid modes of an unconstrained body are counted and
//! kept apart.
//!
//! This is what `largestep modes MESH ...` runs; the library entry is [`analyse`]. The
//! modes' sound when struck: [`sound`].

pub mod beam;
pub mod scene;
pub mod sound;

use crate::fem::mesh::{read_volume_mesh, TetMesh};
use crate::fem::voxel;
use crate::fem::{Fem, FemDesc, FemMass, FemMaterial, Material};
use crate::io::ReadError;
use crate::simulation::MechModel;
use crate::solve::{lowest_modes, EigenParams, Mass, Modes, SolveError};
use crate::sparse::Bsr3;
use std::path::Path;

/// Non-rigid modes reported unless asked otherwise.
pub const DEFAULT_COUNT: usize = 20;

/// What [`analyse`] computes.
#[derive(Clone, Debug, PartialEq)]
pub struct ModesOptions {
    /// Young's modulus (Pa), Poisson's ratio and density (kg/m^3); `None`: the `.veg`
    /// file's materials, or steel (200 GPa, 0.30, 7850 kg/m^3).
    pub young: Option<f64>,
    pub poisson: Option<f64>,
    pub density: Option<f64>,
    /// Non-rigid modes wanted.
    pub count: usize,
    /// Lumped or consistent mass.
    pub mass: FemMass,
    /// Vertices held fixed.
    pub fixed: Option<Selector>,
    /// For a closed surface (`.obj`, `.off`): the voxel mesher's cube size (the file's
    /// units); `None`: the longest side of its bounding box over [`VOXELS_ACROSS`].
    pub voxel: Option<f64>,
}

/// Voxels along the longest side of a surface's bounding box unless told otherwise.
pub const VOXELS_ACROSS: f64 = 40.0;

/// Most grid cubes the voxel mesher may use for `largestep modes` (about 150 bytes each
/// while meshing).
pub const MAX_VOXELS: usize = 20_000_000;

impl Default for ModesOptions {
    fn default() -> Self {
        Self {
            young: None,
            poisson: None,
            density: None,
            count: DEFAULT_COUNT,
            mass: FemMass::Consistent,
            fixed: None,
            voxel: None,
        }
    }
}

/// A selection of vertices.
#[derive(Clone, Debug, PartialEq)]
pub enum Selector {
    /// `x<=V`, `y>=V`, ...: the vertices on that side of a plane normal to an axis (within
    /// 1e-9 of the mesh's size).
    Side {
        axis: usize,
        below: bool,
        value: f64,
    },
    /// `box:X0,Y0,Z0,X1,Y1,Z1`: the vertices inside the box (ends included).
    Box { min: [f64; 3], max: [f64; 3] },
    /// `vertices:I,J,...`: by index (from 0).
    Vertices(Vec<usize>),
}

impl std::str::FromStr for Selector {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        let numbers = |list: &str| -> Result<Vec<f64>, String> {
            list.split(',')
                .map(|v| {
                    v.trim()
                        .parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .ok_or_else(|| format!("`{s}`: `{}` is not a finite number", v.trim()))
                })
                .collect()
        };
        if let Some(list) = t.strip_prefix("box:") {
            let v = numbers(list)?;
            if v.len() != 6 {
                return Err(format!("`{s}`: a box needs six numbers, X0,Y0,Z0,X1,Y1,Z1"));
            }
            let (min, max) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
            if (0..3).any(|c| min[c] > max[c]) {
                return Err(format!("`{s}`: the box's first corner must be its lowest"));
            }
            return Ok(Selector::Box { min, max });
        }
        if let Some(list) = t.strip_prefix("vertices:") {
            let v = list
                .split(',')
                .map(|v| v.trim().parse::<usize>())
                .collect::<Result<Vec<_>, _>>()
                .map_err(|_| format!("`{s}`: vertices are indices from 0, separated by commas"))?;
            return Ok(Selector::Vertices(v));
        }
        let axis = match t.chars().next() {
            Some('x' | 'X') => 0,
            Some('y' | 'Y') => 1,
            Some('z' | 'Z') => 2,
            _ => {
                return Err(format!(
                    "`{s}`: expected x<=V, y>=V, ..., box:X0,Y0,Z0,X1,Y1,Z1 or vertices:I,J,..."
                ))
            }
        };
        let rest = t[1..].trim_start();
        let (below, value) = if let Some(v) = rest.strip_prefix("<=").or(rest.strip_prefix('<')) {
            (true, v)
        } else if let Some(v) = rest.strip_prefix(">=").or(rest.strip_prefix('>')) {
            (false, v)
        } else {
            return Err(format!("`{s}`: expected <= or >= after the axis"));
        };
        let value = numbers(value)?;
        if value.len() != 1 {
            return Err(format!("`{s}`: one number after the comparison"));
        }
        Ok(Selector::Side {
            axis,
            below,
            value: value[0],
        })
    }
}

impl Selector {
    /// The selected vertices of `positions`, or an error naming what is wrong (an index out
    /// of range, nothing selected).
    pub fn select(&self, positions: &[[f64; 3]]) -> Result<Vec<usize>, String> {
        let n = positions.len();
        let size = (0..3)
            .map(|c| {
                let (lo, hi) = positions
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
                        (l.min(p[c]), h.max(p[c]))
                    });
                hi - lo
            })
            .fold(0.0f64, f64::max);
        let eps = 1e-9 * size.max(f64::MIN_POSITIVE);
        let chosen: Vec<usize> = match self {
            Selector::Side { axis, below, value } => (0..n)
                .filter(|&i| {
                    let x = positions[i][*axis];
                    if *below {
                        x <= value + eps
                    } else {
                        x >= value - eps
                    }
                })
                .collect(),
            Selector::Box { min, max } => (0..n)
                .filter(|&i| {
                    (0..3)
                        .all(|c| positions[i][c] >= min[c] - eps && positions[i][c] <= max[c] + eps)
                })
                .collect(),
            Selector::Vertices(v) => {
                if let Some(&bad) = v.iter().find(|&&i| i >= n) {
                    return Err(format!(
                        "fixed vertex {bad} out of range: the mesh has {n} vertices"
                    ));
                }
                let mut v = v.clone();
                v.sort_unstable();
                v.dedup();
                v
            }
        };
        if chosen.is_empty() {
            return Err("the fixed selection holds no vertex of the mesh".into());
        }
        Ok(chosen)
    }
}

/// What went wrong, with the file and line, the option, or the solver's numbers.
#[derive(Debug, thiserror::Error)]
pub enum ModalError {
    /// The mesh could not be read.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// An option is invalid.
    #[error("{0}")]
    Input(String),
    /// The model is invalid (an element, a material).
    #[error(transparent)]
    Model(crate::validate::ModelError),
    /// The eigensolver failed.
    #[error("eigensolver: {0}")]
    Solve(#[from] SolveError),
}

/// The result of [`analyse`]: the model, its modes and the vertices held.
#[derive(Debug)]
pub struct Analysis {
    /// The mesh's FEM model (its rest positions and elements, for output).
    pub fem: Fem,
    /// Rest positions, component-major.
    pub rest: Vec<f64>,
    /// The modes: the rigid ones first, then `count` non-rigid ones (fewer if the mesh has
    /// fewer free unknowns).
    pub modes: Modes,
    /// Fixed vertices.
    pub fixed: Vec<usize>,
    /// What making the mesh noticed (the voxel mesher's size and vertices it left off
    /// the surface).
    pub notes: Vec<String>,
}

/// The stiffness `K` (the negated force Jacobian) of `fem` at its rest positions `rest`
/// (component-major): linear elasticity's, whatever the material.
pub fn stiffness_at_rest(fem: &Fem, rest: &[f64]) -> Result<Bsr3, ModalError> {
    let n = fem.vertex_count();
    let mut work = fem.exact_work();
    let pattern = fem
        .prepare_jacobians(&mut work)
        .map_err(|e| ModalError::Input(e.to_string()))?
        .ok_or_else(|| ModalError::Input("the model has no stiffness".into()))?;
    let mut dfdx = Bsr3::zeros(pattern.clone());
    let mut f = vec![0.0; 3 * n];
    fem.force_jacobians(
        &mut work,
        0.0,
        rest,
        &vec![0.0; 3 * n],
        &mut f,
        &mut dfdx,
        None,
    )
    .map_err(|e| ModalError::Input(e.to_string()))?;
    let mut k = Bsr3::zeros(pattern);
    k.assign_lincomb(&[(-1.0, &dfdx)]);
    Ok(k)
}

/// The lowest modes of the mesh in `file` (any volume mesh the FEM reads; each file at
/// most `max_bytes`).
pub fn analyse(
    file: &Path,
    options: &ModesOptions,
    max_bytes: u64,
) -> Result<Analysis, ModalError> {
    let mut notes = Vec::new();
    let (mesh, veg) = if !voxel::is_surface_file(file) {
        read_volume_mesh(file, max_bytes)?
    } else {
        let s = voxel::read_surface(file, max_bytes)?;
        let h = match options.voxel {
            Some(h) => h,
            None => {
                // The longest side of the bounding box (positions component-major).
                let n = s.positions.len() / 3;
                let side = |c: usize| {
                    let p = &s.positions[c * n..(c + 1) * n];
                    let hi = p.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b));
                    let lo = p.iter().fold(f64::INFINITY, |a, &b| a.min(b));
                    hi - lo
                };
                (0..3).map(side).fold(0.0, f64::max) / VOXELS_ACROSS
            }
        };
        let v = voxel::voxel_mesh(&s, h, MAX_VOXELS)
            .map_err(|e| ModalError::Input(format!("{}: {e}", file.display())))?;
        notes.push(format!(
            "voxel-meshed with cubes of {h:.4e} ({} x {} x {} grid)",
            v.cells[0], v.cells[1], v.cells[2]
        ));
        notes.extend(v.note());
        (v.mesh, None)
    };
    let TetMesh { positions, tets } = mesh;
    if options.count == 0 {
        return Err(ModalError::Input("--count must be at least 1".into()));
    }
    let given = [options.young, options.poisson, options.density];
    let steel = FemMaterial::steel(Material::Linear);
    let material = FemMaterial {
        model: Material::Linear,
        young: options.young.unwrap_or(steel.young),
        poisson: options.poisson.unwrap_or(steel.poisson),
        density: options.density.unwrap_or(steel.density),
    };
    let fixed = match &options.fixed {
        Some(s) => s.select(&positions).map_err(ModalError::Input)?,
        None => Vec::new(),
    };
    let mut desc = FemDesc::new(positions, tets, material);
    if let Some(parts) = veg {
        if given.iter().all(Option::is_none) {
            desc.use_veg_materials(Material::Linear, parts);
        }
    }
    desc.mass = options.mass;
    let mut a = analyse_desc(desc, fixed, options.count).map_err(|e| match e {
        ModalError::Model(e) => ModalError::Input(format!("{}: {e}", file.display())),
        e => e,
    })?;
    a.notes = notes;
    Ok(a)
}

/// The lowest `count` non-rigid modes (and the rigid ones) of the model `desc` describes
/// (its material taken as linear), with the vertices `fixed` held.
pub fn analyse_desc(
    desc: FemDesc,
    fixed: Vec<usize>,
    count: usize,
) -> Result<Analysis, ModalError> {
    if count == 0 {
        return Err(ModalError::Input(
            "at least one mode must be asked for".into(),
        ));
    }
    let mut desc = desc;
    for m in &mut desc.materials {
        m.model = Material::Linear;
    }
    let (fem, state) = desc.build().map_err(ModalError::Model)?;
    let rest = state.x.as_slice().to_vec();
    let n = fem.vertex_count();
    let k = stiffness_at_rest(&fem, &rest)?;
    // Six more than asked, for the rigid modes of a free body.
    let free = 3 * (n - fixed.len());
    if count > free {
        return Err(ModalError::Input(format!(
            "{count} modes asked of a mesh with {free} free unknowns"
        )));
    }
    let params = EigenParams {
        count: (count + 6).min(free),
        ..EigenParams::default()
    };
    let mut modes = match fem.mass_matrix() {
        Some(m) => lowest_modes(&k, Mass::Consistent(m), &fixed, &params)?,
        None => lowest_modes(&k, Mass::Lumped(fem.mass()), &fixed, &params)?,
    };
    let keep = (modes.rigid + count).min(modes.eigenvalues.len());
    modes.eigenvalues.truncate(keep);
    modes.residuals.truncate(keep);
    modes.vectors.truncate(keep * 3 * n);
    Ok(Analysis {
        fem,
        rest,
        modes,
        fixed,
        notes: Vec::new(),
    })
}

/// Writes each non-rigid mode's shape as `dir/mode_NN.vtk` (legacy VTK, the FEM's
/// writer): positions displaced along the mode, scaled so the largest displacement is a
/// tenth of the mesh's size, with the displacement and the element stresses of that
/// shape. Returns the number of files.
pub fn write_shapes(a: &Analysis, dir: &Path) -> std::io::Result<usize> {
    std::fs::create_dir_all(dir)?;
    let zero = vec![0.0; a.rest.len()];
    let freqs = a.modes.frequencies_hz();
    for (j, f) in freqs.iter().enumerate() {
        let shape = scaled_shape(a, a.modes.rigid + j);
        let x: Vec<f64> = a.rest.iter().zip(&shape).map(|(r, d)| r + d).collect();
        let path = dir.join(format!("mode_{:02}.vtk", j + 1));
        crate::io::write_atomically(&path, |w| {
            a.fem.write_vtk(
                w,
                &format!("largestep mode {} at {f:.6} Hz", j + 1),
                &a.rest,
                &x,
                &zero,
            )
        })?;
    }
    Ok(freqs.len())
}

/// Mode j's boundary surface oscillating through one period in `frames` frames: the
/// rest positions plus `sin(2 pi k / frames)` times the shape scaled as in
/// [`write_shapes`] (for the preview renderer, which the CLI runs: physics draws nothing).
pub fn oscillation(a: &Analysis, j: usize, frames: usize) -> Vec<crate::io::Mesh> {
    let triangles: std::sync::Arc<[[u32; 3]]> = a.fem.triangles().into();
    let shape = scaled_shape(a, j);
    (0..frames)
        .map(|k| {
            let s = (2.0 * std::f64::consts::PI * k as f64 / frames as f64).sin();
            crate::io::Mesh {
                positions: a.rest.iter().zip(&shape).map(|(r, d)| r + s * d).collect(),
                triangles: triangles.clone(),
                segments: Vec::new().into(),
            }
        })
        .collect()
}

/// Mode j's shape scaled so that its largest displacement is a tenth of the mesh's size.
fn scaled_shape(a: &Analysis, j: usize) -> Vec<f64> {
    let n = a.rest.len() / 3;
    let size = (0..3)
        .map(|c| {
            let p = &a.rest[c * n..(c + 1) * n];
            p.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v))
                - p.iter().fold(f64::INFINITY, |m, &v| m.min(v))
        })
        .fold(0.0f64, f64::max);
    let shape = a.modes.mode(j);
    let largest = (0..n)
        .map(|i| (shape[i].powi(2) + shape[n + i].powi(2) + shape[2 * n + i].powi(2)).sqrt())
        .fold(0.0f64, f64::max);
    let s = if largest > 0.0 {
        0.1 * size / largest
    } else {
        0.0
    };
    shape.iter().map(|d| s * d).collect()
}
