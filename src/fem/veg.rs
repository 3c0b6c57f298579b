//! Vega FEM's `.veg` volumetric meshes (Barbič et al., Vega FEM 2.0, `volumetricMesh`
//! library): vertices, tetrahedra (or cubes, split as a hexahedral VTK cell is), materials
//! and the regions that give each element its material.
//!
//! The file is a list of sections, `#` starting a comment:
//!
//! ```text
//! *VERTICES
//! <count> 3 0 0
//! <index> <x> <y> <z>            (indices from 1, or from 0 as the first says)
//! *ELEMENTS
//! TET                            (or CUBIC: eight vertices, Vega's corner order)
//! <count> 4 0
//! <index> <v1> <v2> <v3> <v4>
//! *MATERIAL <name>
//! ENU, <density>, <E>, <nu>
//! *SET <name>
//! <element>, <element>, ...      (1-based, over one or more lines)
//! *REGION
//! <set name>, <material name>
//! ```
//!
//! The set `allElements` holds every element. Elements no region names take the first
//! material, as in Vega. Other material kinds (orthotropic, Mooney-Rivlin) and `*INCLUDE`
//! are errors naming the line. Counts are checked against the file's lines before
//! allocating; every error names the file and line.

use super::mesh::TetMesh;
use crate::io::ReadError;

/// A `.veg` file's content.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VegMesh {
    /// Vertices and tetrahedra (cubes split into tetrahedra).
    pub mesh: TetMesh,
    /// Materials in file order: name, density (kg/m^3), Young's modulus (Pa), Poisson's
    /// ratio.
    pub materials: Vec<VegMaterial>,
    /// Each tetrahedron's material (index into `materials`).
    pub element_material: Vec<u32>,
}

/// An `ENU` material of a `.veg` file.
#[derive(Clone, Debug, PartialEq)]
pub struct VegMaterial {
    /// Its name.
    pub name: String,
    /// Density (kg/m^3).
    pub density: f64,
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
}

/// Reads a `.veg` file of at most `max_bytes`.
pub fn read_veg(path: &std::path::Path, max_bytes: u64) -> Result<VegMesh, ReadError> {
    parse_veg(
        &crate::io::read_text(path, max_bytes)?,
        &path.display().to_string(),
    )
}

/// Parses the text of a `.veg` file called `name` (for errors).
pub fn parse_veg(text: &str, name: &str) -> Result<VegMesh, ReadError> {
    let err = |line: usize, message: String| ReadError {
        path: name.to_string(),
        line,
        message,
    };
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.split('#').next().unwrap_or("").trim()))
        .filter(|(_, l)| !l.is_empty())
        .collect();
    let total = text.lines().count();
    let mut positions: Vec<[f64; 3]> = Vec::new();
    let mut base = 1u64;
    let mut elements: Vec<(usize, Vec<u32>)> = Vec::new();
    let mut per = 0usize;
    let mut materials: Vec<VegMaterial> = Vec::new();
    let mut sets: Vec<(String, Vec<usize>)> = Vec::new();
    let mut regions: Vec<(usize, String, String)> = Vec::new();
    let mut seen_vertices = false;
    let mut k = 0;
    let count = |line: usize, l: &str, what: &str| -> Result<(usize, usize), ReadError> {
        let f: Vec<&str> = l.split_whitespace().collect();
        let n: usize = f
            .first()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| err(line, format!("expected the {what} count, found `{l}`")))?;
        let per: usize = f.get(1).and_then(|s| s.parse().ok()).ok_or_else(|| {
            err(
                line,
                format!("expected the values per {what} after the count, found `{l}`"),
            )
        })?;
        if n > total {
            return Err(err(
                line,
                format!("the header claims {n} {what}s, but the file has only {total} lines"),
            ));
        }
        Ok((n, per))
    };
    while k < lines.len() {
        let (line, l) = lines[k];
        k += 1;
        let upper = l.to_ascii_uppercase();
        if upper == "*VERTICES" {
            let (hl, h) = *lines
                .get(k)
                .ok_or_else(|| err(line, "no vertex count".into()))?;
            k += 1;
            let (n, dim) = count(hl, h, "vertex")?;
            if dim != 3 {
                return Err(err(
                    hl,
                    format!("{dim} coordinates per vertex: only 3-D vertices are read"),
                ));
            }
            positions = Vec::with_capacity(n);
            for j in 0..n {
                let (vl, v) = *lines
                    .get(k)
                    .filter(|(_, v)| !v.starts_with('*'))
                    .ok_or_else(|| {
                        err(
                            hl,
                            format!("the header claims {n} vertices, the section holds {j}"),
                        )
                    })?;
                k += 1;
                let f: Vec<&str> = v
                    .split(|c: char| c.is_whitespace() || c == ',')
                    .filter(|s| !s.is_empty())
                    .collect();
                if f.len() != 4 {
                    return Err(err(
                        vl,
                        format!("{} fields, expected 4 (index, x, y, z)", f.len()),
                    ));
                }
                let index: u64 = f[0]
                    .parse()
                    .map_err(|_| err(vl, format!("`{}` is not a vertex index", f[0])))?;
                if j == 0 {
                    if index > 1 {
                        return Err(err(
                            vl,
                            format!("the first vertex's index is {index}: expected 0 or 1"),
                        ));
                    }
                    base = index;
                }
                if index != j as u64 + base {
                    return Err(err(vl, format!("vertex index {index}, expected {} (vertices must be numbered in order)", j as u64 + base)));
                }
                let mut p = [0.0; 3];
                for c in 0..3 {
                    p[c] = f[1 + c]
                        .parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| {
                            err(
                                vl,
                                format!("coordinate `{}` is not a finite number", f[1 + c]),
                            )
                        })?;
                }
                positions.push(p);
            }
            seen_vertices = true;
        } else if upper == "*ELEMENTS" {
            let (tl, kind) = *lines
                .get(k)
                .ok_or_else(|| err(line, "no element type".into()))?;
            k += 1;
            let want = match kind.to_ascii_uppercase().as_str() {
                "TET" => 4,
                "CUBIC" => 8,
                other => {
                    return Err(err(
                        tl,
                        format!("element type `{other}`: TET and CUBIC are read"),
                    ))
                }
            };
            let (hl, h) = *lines
                .get(k)
                .ok_or_else(|| err(tl, "no element count".into()))?;
            k += 1;
            let (n, p) = count(hl, h, "element")?;
            if p != want {
                return Err(err(
                    hl,
                    format!("{p} vertices per element, expected {want} for {kind}"),
                ));
            }
            per = want;
            elements = Vec::with_capacity(n);
            for j in 0..n {
                let (el, e) = *lines
                    .get(k)
                    .filter(|(_, e)| !e.starts_with('*'))
                    .ok_or_else(|| {
                        err(
                            hl,
                            format!("the header claims {n} elements, the section holds {j}"),
                        )
                    })?;
                k += 1;
                let f: Vec<&str> = e
                    .split(|c: char| c.is_whitespace() || c == ',')
                    .filter(|s| !s.is_empty())
                    .collect();
                if f.len() != 1 + want {
                    return Err(err(
                        el,
                        format!(
                            "{} fields, expected {} (index and {want} vertices)",
                            f.len(),
                            1 + want
                        ),
                    ));
                }
                let mut vs = Vec::with_capacity(want);
                for s in &f[1..] {
                    let i: u64 = s
                        .parse()
                        .map_err(|_| err(el, format!("`{s}` is not a vertex index")))?;
                    vs.push((el, i));
                }
                elements.push((
                    el,
                    vs.iter()
                        .map(|&(_, i)| i.min(u32::MAX as u64) as u32)
                        .collect(),
                ));
            }
        } else if let Some(rest) = upper.strip_prefix("*MATERIAL") {
            let name_m = l[l.len() - rest.len()..].trim().to_string();
            if name_m.is_empty() {
                return Err(err(line, "a material needs a name".into()));
            }
            let (ml, m) = *lines
                .get(k)
                .ok_or_else(|| err(line, "no material line".into()))?;
            k += 1;
            let f: Vec<&str> = m.split(',').map(str::trim).collect();
            if !f[0].eq_ignore_ascii_case("ENU") {
                return Err(err(
                    ml,
                    format!(
                        "material kind `{}`: only ENU (density, E, nu) is read",
                        f[0]
                    ),
                ));
            }
            if f.len() != 4 {
                return Err(err(
                    ml,
                    format!("ENU takes density, E and nu: {} values given", f.len() - 1),
                ));
            }
            let num = |s: &str, what: &str| -> Result<f64, ReadError> {
                s.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| err(ml, format!("{what} `{s}` is not a finite number")))
            };
            materials.push(VegMaterial {
                name: name_m,
                density: num(f[1], "density")?,
                young: num(f[2], "Young's modulus")?,
                poisson: num(f[3], "Poisson's ratio")?,
            });
        } else if let Some(rest) = upper.strip_prefix("*SET") {
            let set = l[l.len() - rest.len()..].trim().to_string();
            let mut members = Vec::new();
            while k < lines.len() && !lines[k].1.starts_with('*') {
                let (sl, s) = lines[k];
                k += 1;
                for e in s.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                    let i: usize = e
                        .parse()
                        .map_err(|_| err(sl, format!("`{e}` is not an element index")))?;
                    if i == 0 {
                        return Err(err(sl, "element indices in a set start at 1".into()));
                    }
                    members.push(i - 1);
                    if members.len() > total * 64 {
                        return Err(err(sl, "more set members than the file can hold".into()));
                    }
                }
            }
            sets.push((set, members));
        } else if upper == "*REGION" {
            while k < lines.len() && !lines[k].1.starts_with('*') {
                let (rl, r) = lines[k];
                k += 1;
                let f: Vec<&str> = r.split(',').map(str::trim).collect();
                if f.len() != 2 {
                    return Err(err(rl, format!("a region is `set, material`, found `{r}`")));
                }
                regions.push((rl, f[0].to_string(), f[1].to_string()));
            }
        } else if upper.starts_with("*INCLUDE") {
            return Err(err(line, "*INCLUDE is not supported: give one file".into()));
        } else {
            return Err(err(line, format!("unexpected `{l}`: expected a section (*VERTICES, *ELEMENTS, *MATERIAL, *SET, *REGION)")));
        }
    }
    if !seen_vertices {
        return Err(err(0, "no *VERTICES section".into()));
    }
    if elements.is_empty() {
        return Err(err(0, "no *ELEMENTS".into()));
    }
    // Vertex indices to 0-based, checked.
    let n = positions.len() as u64;
    let mut cells: Vec<Vec<u32>> = Vec::with_capacity(elements.len());
    for (el, vs) in &elements {
        let mut c = Vec::with_capacity(per);
        for &i in vs {
            let i = i as u64;
            if i < base || i - base >= n {
                return Err(err(
                    *el,
                    format!(
                        "vertex {i} is out of range: the vertices are numbered {base} to {}",
                        n + base - 1
                    ),
                ));
            }
            c.push((i - base) as u32);
        }
        cells.push(c);
    }
    // Each element's material: the first unless a region says otherwise.
    let mut material_of = vec![0u32; cells.len()];
    for (rl, set, mat) in &regions {
        let m = materials
            .iter()
            .position(|x| &x.name == mat)
            .ok_or_else(|| err(*rl, format!("no material `{mat}`")))?;
        let members: Vec<usize> = if set == "allElements" {
            (0..cells.len()).collect()
        } else {
            sets.iter()
                .find(|(s, _)| s == set)
                .map(|(_, m)| m.clone())
                .ok_or_else(|| err(*rl, format!("no set `{set}`")))?
        };
        for e in members {
            if e >= cells.len() {
                return Err(err(
                    *rl,
                    format!("set `{set}` names element {} of {}", e + 1, cells.len()),
                ));
            }
            material_of[e] = m as u32;
        }
    }
    if materials.is_empty() {
        return Err(err(0, "no *MATERIAL".into()));
    }
    let mut mesh = TetMesh {
        positions,
        tets: Vec::new(),
    };
    let mut element_material = Vec::new();
    if per == 4 {
        mesh.tets = cells.iter().map(|c| [c[0], c[1], c[2], c[3]]).collect();
        element_material = material_of;
    } else {
        // Vega's cube corners: 0-3 the bottom face counter-clockwise from above, 4-7 the
        // top face above them, VTK's hexahedron order, so the VTK reader's conforming
        // split applies.
        let mut face_centre = std::collections::HashMap::new();
        for (c, m) in cells.iter().zip(&material_of) {
            let before = mesh.tets.len();
            super::vtk::split_hexahedron(&mut mesh, c, &mut face_centre);
            element_material.extend(std::iter::repeat_n(*m, mesh.tets.len() - before));
        }
    }
    Ok(VegMesh {
        mesh,
        materials,
        element_material,
    })
}
