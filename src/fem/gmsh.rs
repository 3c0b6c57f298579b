//! Gmsh's `.msh` files, ASCII versions 2.2 and 4.1 (Gmsh reference manual, section
//! "MSH file format"): the nodes and the 4-node tetrahedra (element type 4); other element
//! types (the boundary's triangles, lines, points) are skipped, quadratic tetrahedra
//! (type 11) are an error. Node tags may have gaps (4.1 numbers nodes per entity); they
//! are mapped to indices in the order the nodes come. Every count is checked against the
//! lines the file holds before anything is allocated; errors name the file and line.

use super::mesh::TetMesh;
use crate::io::ReadError;
use std::collections::HashMap;

/// Parses a `.msh` file (see the module docs); `name` is used in errors.
pub fn parse_msh(text: &str, name: &str) -> Result<TetMesh, ReadError> {
    let err = |line: usize, message: String| ReadError {
        path: name.to_string(),
        line,
        message,
    };
    let lines: Vec<&str> = text.lines().collect();
    let max = lines.len();
    let section = |tag: &str| lines.iter().position(|l| l.trim() == tag);
    let fmt = section("$MeshFormat")
        .ok_or_else(|| err(0, "no $MeshFormat section: not a Gmsh mesh".into()))?;
    let header: Vec<&str> = lines
        .get(fmt + 1)
        .map_or(vec![], |l| l.split_whitespace().collect());
    let version = header.first().copied().unwrap_or("");
    if header.get(1) != Some(&"0") {
        return Err(err(
            fmt + 2,
            "binary .msh files are not read; save as ASCII".into(),
        ));
    }
    let v4 = match version {
        "2.2" | "2.1" | "2" => false,
        "4.1" => true,
        _ => {
            return Err(err(
                fmt + 2,
                format!("version `{version}`: only 2.2 and 4.1 are read"),
            ))
        }
    };
    let nodes_at = section("$Nodes").ok_or_else(|| err(0, "no $Nodes section".into()))?;
    let elements_at = section("$Elements").ok_or_else(|| err(0, "no $Elements section".into()))?;
    let fields = |k: usize| -> Vec<&str> {
        lines
            .get(k)
            .map_or(vec![], |l| l.split_whitespace().collect())
    };
    let num = |k: usize, i: usize, what: &str| -> Result<u64, ReadError> {
        let f = fields(k);
        let s = f
            .get(i)
            .ok_or_else(|| err(k + 1, format!("expected {what}")))?;
        s.parse()
            .map_err(|_| err(k + 1, format!("`{s}` is not {what}")))
    };
    let coord = |k: usize, i: usize| -> Result<f64, ReadError> {
        let f = fields(k);
        let s = f
            .get(i)
            .ok_or_else(|| err(k + 1, "expected a coordinate".into()))?;
        let v: f64 = s
            .parse()
            .map_err(|_| err(k + 1, format!("`{s}` is not a number")))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(err(k + 1, format!("coordinate `{s}` is not finite")))
        }
    };
    let bounded = |v: u64, k: usize, what: &str| -> Result<usize, ReadError> {
        if v as usize > max {
            Err(err(
                k + 1,
                format!("{what} {v} is more than the file's {max} lines can hold"),
            ))
        } else {
            Ok(v as usize)
        }
    };
    let mut positions = Vec::new();
    let mut index: HashMap<u64, u32> = HashMap::new();
    let mut k = nodes_at + 1;
    if v4 {
        let blocks = bounded(num(k, 0, "a block count")?, k, "block count")?;
        let total = bounded(num(k, 1, "a node count")?, k, "node count")?;
        positions.reserve(total);
        k += 1;
        for _ in 0..blocks {
            let count = bounded(num(k, 3, "a node count")?, k, "node count")?;
            let tags_at = k + 1;
            let coords_at = tags_at + count;
            for j in 0..count {
                let tag = num(tags_at + j, 0, "a node tag")?;
                let p = [
                    coord(coords_at + j, 0)?,
                    coord(coords_at + j, 1)?,
                    coord(coords_at + j, 2)?,
                ];
                if index.insert(tag, positions.len() as u32).is_some() {
                    return Err(err(tags_at + j + 1, format!("node {tag} appears twice")));
                }
                positions.push(p);
            }
            k = coords_at + count;
        }
    } else {
        let total = bounded(num(k, 0, "a node count")?, k, "node count")?;
        positions.reserve(total);
        for j in 0..total {
            let l = k + 1 + j;
            let tag = num(l, 0, "a node tag")?;
            let p = [coord(l, 1)?, coord(l, 2)?, coord(l, 3)?];
            if index.insert(tag, positions.len() as u32).is_some() {
                return Err(err(l + 1, format!("node {tag} appears twice")));
            }
            positions.push(p);
        }
    }
    let node = |tag: u64, l: usize| -> Result<u32, ReadError> {
        index
            .get(&tag)
            .copied()
            .ok_or_else(|| err(l + 1, format!("node {tag} is not in $Nodes")))
    };
    let tet_of = |f: &[&str], from: usize, l: usize| -> Result<[u32; 4], ReadError> {
        let mut t = [0u32; 4];
        for (c, tc) in t.iter_mut().enumerate() {
            let s = f
                .get(from + c)
                .ok_or_else(|| err(l + 1, "a tetrahedron needs 4 nodes".into()))?;
            let tag: u64 = s
                .parse()
                .map_err(|_| err(l + 1, format!("`{s}` is not a node tag")))?;
            *tc = node(tag, l)?;
        }
        Ok(t)
    };
    let mut tets = Vec::new();
    let mut k = elements_at + 1;
    if v4 {
        let blocks = bounded(num(k, 0, "a block count")?, k, "block count")?;
        k += 1;
        for _ in 0..blocks {
            let ty = num(k, 2, "an element type")?;
            let count = bounded(num(k, 3, "an element count")?, k, "element count")?;
            if ty == 11 {
                return Err(err(
                    k + 1,
                    "quadratic tetrahedra (type 11) are not read: mesh with linear elements".into(),
                ));
            }
            for j in 0..count {
                let l = k + 1 + j;
                if ty == 4 {
                    tets.push(tet_of(&fields(l), 1, l)?);
                }
            }
            k += 1 + count;
        }
    } else {
        let total = bounded(num(k, 0, "an element count")?, k, "element count")?;
        for j in 0..total {
            let l = k + 1 + j;
            let ty = num(l, 1, "an element type")?;
            let tags = num(l, 2, "a tag count")? as usize;
            if ty == 11 {
                return Err(err(
                    l + 1,
                    "quadratic tetrahedra (type 11) are not read: mesh with linear elements".into(),
                ));
            }
            if ty == 4 {
                tets.push(tet_of(&fields(l), 3 + tags, l)?);
            }
        }
    }
    if tets.is_empty() {
        return Err(err(
            elements_at + 1,
            "no tetrahedra (element type 4)".into(),
        ));
    }
    // Gmsh orders a tetrahedron's nodes with a positive Jacobian; one that is not is left
    // as it is, for the model to report (or `FemDesc::reorient` to fix).
    Ok(TetMesh { positions, tets })
}

/// Reads a `.msh` file (at most `max_bytes`).
pub fn read_msh(path: &std::path::Path, max_bytes: u64) -> Result<TetMesh, ReadError> {
    parse_msh(
        &crate::io::read_text(path, max_bytes)?,
        &path.display().to_string(),
    )
}
