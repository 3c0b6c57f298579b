//! Tetrahedral meshes in: TetGen's `.node` / `.ele` files, and a box of hexahedra split
//! into tetrahedra at any resolution.
//!
//! TetGen's formats (TetGen 1.5 manual, section 5.2): `.node` has the header
//! `<points> <dimension = 3> <attributes> <boundary marker 0|1>` and then one line per
//! point, `<index> <x> <y> <z> [attributes] [marker]`; `.ele` has `<tetrahedra> <nodes per
//! tetrahedron = 4> <region attribute 0|1>` and then `<index> <n1> <n2> <n3> <n4>
//! [attribute]`. `#` starts a comment. Indices start at 0 or 1, as the first point's
//! index says; the elements use the same base. Every count is checked against the lines
//! the file holds before anything is allocated, and every error names the file and line.

use crate::io::ReadError;
use largestep_kernels::fem::signed_volume;
use std::path::Path;

/// Vertices and tetrahedra.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TetMesh {
    /// Positions (m, or the file's units).
    pub positions: Vec<[f64; 3]>,
    /// Tetrahedra (0-based vertex indices).
    pub tets: Vec<[u32; 4]>,
}

/// The data lines of a TetGen file: `(1-based line, fields)`, comments and blank lines
/// left out.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(k, l)| {
        let l = l.split('#').next().unwrap_or("");
        let fields: Vec<&str> = l.split_whitespace().collect();
        (!fields.is_empty()).then_some((k + 1, fields))
    })
}

fn field<T: std::str::FromStr>(
    name: &str,
    line: usize,
    fields: &[&str],
    k: usize,
    what: &str,
) -> Result<T, ReadError> {
    let err = |message: String| ReadError {
        path: name.to_string(),
        line,
        message,
    };
    let s = fields.get(k).ok_or_else(|| {
        err(format!(
            "expected {what} in field {}, found only {} fields",
            k + 1,
            fields.len()
        ))
    })?;
    s.parse()
        .map_err(|_| err(format!("field {} (`{s}`) is not {what}", k + 1)))
}

/// `Ok` when a header's count `n` (at line `hl`) fits the lines the file has: what is
/// allocated is sized by what the file can hold, not by what its header claims.
fn claim_fits(text: &str, name: &str, hl: usize, n: usize, what: &str) -> Result<(), ReadError> {
    let lines = text.lines().count();
    if n > lines {
        return Err(ReadError {
            path: name.to_string(),
            line: hl,
            message: format!("the header claims {n} {what}, but the file has only {lines} lines"),
        });
    }
    Ok(())
}

/// `Ok` when the file held the `n` items its header claimed (`got` read) and nothing
/// after them (`after`: the next data line, if any).
fn held_as_claimed(
    name: &str,
    n: usize,
    got: usize,
    after: Option<(usize, Vec<&str>)>,
    what: &str,
) -> Result<(), ReadError> {
    let (line, message) = if got < n {
        (
            0,
            format!("the header claims {n} {what}, the file holds {got}"),
        )
    } else if let Some((line, _)) = after {
        (line, format!("data after the {n} {what} the header claims"))
    } else {
        return Ok(());
    };
    Err(ReadError {
        path: name.to_string(),
        line,
        message,
    })
}

/// Parses a `.node` file: the positions and the index base (0 or 1).
pub fn parse_node(text: &str, name: &str) -> Result<(Vec<[f64; 3]>, u32), ReadError> {
    let mut lines = data_lines(text);
    let err = |line: usize, message: String| ReadError {
        path: name.to_string(),
        line,
        message,
    };
    let (hl, header) = lines
        .next()
        .ok_or_else(|| err(0, "no header line".into()))?;
    let n: usize = field(name, hl, &header, 0, "a point count")?;
    let dim: usize = field(name, hl, &header, 1, "a dimension")?;
    if dim != 3 {
        return Err(err(
            hl,
            format!("dimension {dim}: only 3-D points are read"),
        ));
    }
    let attrs: usize = field(name, hl, &header, 2, "an attribute count")?;
    let markers: usize = field(name, hl, &header, 3, "a boundary marker flag (0 or 1)")?;
    claim_fits(text, name, hl, n, "points")?;
    let mut positions = Vec::with_capacity(n);
    let mut base = 0u32;
    for (k, (line, fields)) in lines.by_ref().take(n).enumerate() {
        let index: u64 = field(name, line, &fields, 0, "a point index")?;
        if k == 0 {
            if index > 1 {
                return Err(err(
                    line,
                    format!("the first point's index is {index}: expected 0 or 1"),
                ));
            }
            base = index as u32;
        }
        if index != k as u64 + base as u64 {
            return Err(err(
                line,
                format!(
                    "point index {index}, expected {} (points must be numbered in order)",
                    k as u64 + base as u64
                ),
            ));
        }
        let mut p = [0.0f64; 3];
        for (c, pc) in p.iter_mut().enumerate() {
            *pc = field(name, line, &fields, 1 + c, "a number")?;
            if !pc.is_finite() {
                return Err(err(line, format!("coordinate {} is not finite", c + 1)));
            }
        }
        let expected = 4 + attrs + markers.min(1);
        if fields.len() != expected {
            return Err(err(
                line,
                format!(
                    "{} fields, expected {expected} (index, x, y, z, {attrs} attributes{})",
                    fields.len(),
                    if markers > 0 { ", marker" } else { "" }
                ),
            ));
        }
        positions.push(p);
    }
    held_as_claimed(name, n, positions.len(), lines.next(), "points")?;
    Ok((positions, base))
}

/// Parses an `.ele` file of linear tetrahedra over `points` points numbered from `base`.
pub fn parse_ele(
    text: &str,
    name: &str,
    points: usize,
    base: u32,
) -> Result<Vec<[u32; 4]>, ReadError> {
    let mut lines = data_lines(text);
    let err = |line: usize, message: String| ReadError {
        path: name.to_string(),
        line,
        message,
    };
    let (hl, header) = lines
        .next()
        .ok_or_else(|| err(0, "no header line".into()))?;
    let n: usize = field(name, hl, &header, 0, "a tetrahedron count")?;
    let per: usize = field(name, hl, &header, 1, "nodes per tetrahedron")?;
    if per != 4 {
        return Err(err(
            hl,
            format!("{per} nodes per tetrahedron: only linear tetrahedra (4) are read"),
        ));
    }
    let attrs: usize = field(name, hl, &header, 2, "a region attribute flag")?;
    claim_fits(text, name, hl, n, "tetrahedra")?;
    let mut tets = Vec::with_capacity(n);
    for (k, (line, fields)) in lines.by_ref().take(n).enumerate() {
        let index: u64 = field(name, line, &fields, 0, "a tetrahedron index")?;
        if index != k as u64 + base as u64 {
            return Err(err(
                line,
                format!(
                    "tetrahedron index {index}, expected {}",
                    k as u64 + base as u64
                ),
            ));
        }
        if fields.len() != 5 + attrs.min(1) {
            return Err(err(
                line,
                format!("{} fields, expected {}", fields.len(), 5 + attrs.min(1)),
            ));
        }
        let mut t = [0u32; 4];
        for (c, tc) in t.iter_mut().enumerate() {
            let i: u64 = field(name, line, &fields, 1 + c, "a point index")?;
            if i < base as u64 || i - base as u64 >= points as u64 {
                return Err(err(
                    line,
                    format!(
                        "point {i} is out of range: the points are numbered {base} to {}",
                        points as u64 + base as u64 - 1
                    ),
                ));
            }
            *tc = (i - base as u64) as u32;
        }
        tets.push(t);
    }
    held_as_claimed(name, n, tets.len(), lines.next(), "tetrahedra")?;
    Ok(tets)
}

/// Reads TetGen's `stem.node` and `stem.ele` (each at most `max_bytes`).
pub fn read_tetgen(stem: &Path, max_bytes: u64) -> Result<TetMesh, ReadError> {
    let node = stem.with_extension("node");
    let ele = stem.with_extension("ele");
    let (positions, base) = parse_node(
        &crate::io::read_text(&node, max_bytes)?,
        &node.display().to_string(),
    )?;
    let tets = parse_ele(
        &crate::io::read_text(&ele, max_bytes)?,
        &ele.display().to_string(),
        positions.len(),
        base,
    )?;
    Ok(TetMesh { positions, tets })
}

/// A `.veg` file's materials and each tetrahedron's material.
pub type VegParts = (Vec<super::veg::VegMaterial>, Vec<u32>);

/// A volume mesh read from `file` by its extension: legacy VTK (`.vtk`), Gmsh (`.msh`),
/// Vega (`.veg`, with its materials and their regions) or TetGen (`.node` with the
/// `.ele` beside it; any other name is taken as TetGen's stem). Each file at most
/// `max_bytes`.
pub fn read_volume_mesh(
    file: &Path,
    max_bytes: u64,
) -> Result<(TetMesh, Option<VegParts>), ReadError> {
    let is = |ext: &str| {
        file.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case(ext))
    };
    if is("vtk") {
        super::vtk::read_vtk(file, max_bytes).map(|m| (m, None))
    } else if is("msh") {
        super::gmsh::read_msh(file, max_bytes).map(|m| (m, None))
    } else if is("veg") {
        let v = super::veg::read_veg(file, max_bytes)?;
        Ok((v.mesh, Some((v.materials, v.element_material))))
    } else {
        read_tetgen(&file.with_extension(""), max_bytes).map(|m| (m, None))
    }
}

/// A box `origin + [0, size]` of `cells[0] x cells[1] x cells[2]` cubes, each split into
/// six tetrahedra around its diagonal from the low corner to the high one (the
/// Freudenthal-Kuhn split: one tetrahedron per order of the axes). Every cube is split
/// the same way, so faces shared by neighbouring cubes are split the same way from both
/// sides: the mesh is conforming. Vertices are numbered x fastest; all elements are
/// positively oriented.
pub fn box_mesh(cells: [usize; 3], size: [f64; 3], origin: [f64; 3]) -> TetMesh {
    let [nx, ny, nz] = cells;
    let idx = |i: usize, j: usize, k: usize| (i + (nx + 1) * (j + (ny + 1) * k)) as u32;
    let mut positions = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                positions.push([
                    origin[0] + size[0] * i as f64 / nx as f64,
                    origin[1] + size[1] * j as f64 / ny as f64,
                    origin[2] + size[2] * k as f64 / nz as f64,
                ]);
            }
        }
    }
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                tets.extend(cube_tets([i, j, k], |c| idx(c[0], c[1], c[2]), &positions));
            }
        }
    }
    TetMesh { positions, tets }
}

/// The six tetrahedra of the grid cube whose low corner is `ijk`, one per order of the
/// axes along the diagonal from that corner to the opposite one (Freudenthal-Kuhn),
/// positively oriented; `corner` numbers the grid's corners.
pub(super) fn cube_tets(
    ijk: [usize; 3],
    corner: impl Fn([usize; 3]) -> u32,
    positions: &[[f64; 3]],
) -> [[u32; 4]; 6] {
    const ORDERS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    ORDERS.map(|order| {
        let mut c = ijk;
        let mut t = [corner(c); 4];
        for (s, &axis) in order.iter().enumerate() {
            c[axis] += 1;
            t[s + 1] = corner(c);
        }
        if signed_volume(&t.map(|v| positions[v as usize])) < 0.0 {
            t.swap(2, 3);
        }
        t
    })
}
