//! Legacy VTK unstructured grids (the "VTK file formats" document, Kitware): read
//! tetrahedra and hexahedra, write tetrahedra with displacement, velocity and von Mises
//! stress for ParaView.
//!
//! Reading takes `POINTS`, `CELLS` and `CELL_TYPES` (ASCII, any whitespace layout) and
//! skips the rest (`CELL_DATA`, `POINT_DATA`, fields). Tetrahedra (type 10) are kept;
//! hexahedra (type 12, VTK's vertex order: 0-3 one face, 4-7 the opposite one) are split
//! into 24 tetrahedra around the cell's centre and the centres of its six faces. A face
//! centre is one new vertex shared by the two cells on the face, so the split is
//! conforming whatever the diagonals of neighbouring cells would have been (a split into
//! 5 or 6 tetrahedra must pick face diagonals that agree across cells, which not every
//! hexahedral mesh allows without extra vertices; Dompierre et al. 1999). Other cell types
//! are errors naming the line. Counts are checked against the tokens the file holds
//! before anything is allocated.

use super::mesh::TetMesh;
use super::Fem;
use crate::io::ReadError;
use largestep_kernels::fem::{det, mul, signed_volume, transpose};
use std::collections::HashMap;
use std::io::Write;

/// A cell as read: its line and its points.
type Cell = (usize, Vec<u32>);

/// Whitespace-separated tokens with their 1-based line numbers.
struct Tokens<'a> {
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
    current: std::str::SplitWhitespace<'a>,
    line: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str) -> Self {
        Self {
            lines: text.lines().enumerate(),
            current: "".split_whitespace(),
            line: 0,
        }
    }

    fn next(&mut self) -> Option<(usize, &'a str)> {
        loop {
            if let Some(t) = self.current.next() {
                return Some((self.line, t));
            }
            let (k, l) = self.lines.next()?;
            self.line = k + 1;
            self.current = l.split_whitespace();
        }
    }
}

/// Parses a legacy ASCII VTK unstructured grid of tetrahedra and hexahedra (see the
/// module docs); `name` is used in errors.
pub fn parse_vtk(text: &str, name: &str) -> Result<TetMesh, ReadError> {
    let err = |line: usize, message: String| ReadError {
        path: name.to_string(),
        line,
        message,
    };
    if !text.starts_with("# vtk DataFile") {
        return Err(err(
            1,
            "not a legacy VTK file (the first line must start with `# vtk DataFile`)".into(),
        ));
    }
    let body_start = text
        .match_indices('\n')
        .nth(1)
        .map_or(text.len(), |(i, _)| i + 1);
    // The title line may hold anything; tokens start on line 3.
    let mut tokens = Tokens::new(&text[body_start..]);
    let line_of = |l: usize| l + 2;
    let mut positions: Option<Vec<[f64; 3]>> = None;
    // The CELLS line, and each cell's line and points.
    let mut cells: Option<(usize, Vec<Cell>)> = None;
    let mut types: Option<Vec<(usize, u32)>> = None;
    let max_tokens = text.len() / 2 + 1;
    let count = |tok: Option<(usize, &str)>, what: &str, line: usize| -> Result<usize, ReadError> {
        let (l, t) = tok.ok_or_else(|| err(line_of(line), format!("expected {what}")))?;
        let v: usize = t
            .parse()
            .map_err(|_| err(line_of(l), format!("`{t}` is not {what}")))?;
        if v > max_tokens {
            return Err(err(
                line_of(l),
                format!("{what} {v} is more than the file can hold"),
            ));
        }
        Ok(v)
    };
    while let Some((line, t)) = tokens.next() {
        match t.to_ascii_uppercase().as_str() {
            "ASCII" => {}
            "BINARY" => {
                return Err(err(
                    line_of(line),
                    "binary VTK files are not read; write ASCII".into(),
                ))
            }
            "DATASET" => {
                let (l, kind) = tokens
                    .next()
                    .ok_or_else(|| err(line_of(line), "DATASET without a type".into()))?;
                if !kind.eq_ignore_ascii_case("UNSTRUCTURED_GRID") {
                    return Err(err(
                        line_of(l),
                        format!("dataset `{kind}`: only UNSTRUCTURED_GRID is read"),
                    ));
                }
            }
            "POINTS" => {
                let n = count(tokens.next(), "a point count", line)?;
                tokens.next(); // the value type (float, double)
                let mut p = Vec::with_capacity(n);
                for _ in 0..n {
                    let mut q = [0.0f64; 3];
                    for qc in &mut q {
                        let (l, s) = tokens.next().ok_or_else(|| {
                            err(
                                0,
                                format!("the file ends inside POINTS ({n} points claimed)"),
                            )
                        })?;
                        *qc = s
                            .parse()
                            .map_err(|_| err(line_of(l), format!("`{s}` is not a number")))?;
                        if !qc.is_finite() {
                            return Err(err(line_of(l), format!("coordinate `{s}` is not finite")));
                        }
                    }
                    p.push(q);
                }
                positions = Some(p);
            }
            "CELLS" => {
                let n = count(tokens.next(), "a cell count", line)?;
                let total = count(tokens.next(), "a list size", line)?;
                let mut list = Vec::with_capacity(n);
                let mut read = 0;
                for _ in 0..n {
                    let k = count(tokens.next(), "a cell's vertex count", line)?;
                    let cell_line = tokens.line;
                    let mut v = Vec::with_capacity(k.min(64));
                    for _ in 0..k {
                        let (l, s) = tokens
                            .next()
                            .ok_or_else(|| err(0, "the file ends inside CELLS".into()))?;
                        v.push(
                            s.parse().map_err(|_| {
                                err(line_of(l), format!("`{s}` is not a point index"))
                            })?,
                        );
                    }
                    read += k + 1;
                    list.push((line_of(cell_line), v));
                }
                if read != total {
                    return Err(err(
                        line_of(line),
                        format!("CELLS claims a list of {total} numbers, the cells hold {read}"),
                    ));
                }
                cells = Some((line_of(line), list));
            }
            "CELL_TYPES" => {
                let n = count(tokens.next(), "a cell count", line)?;
                let mut t = Vec::with_capacity(n);
                for _ in 0..n {
                    let (l, s) = tokens
                        .next()
                        .ok_or_else(|| err(0, "the file ends inside CELL_TYPES".into()))?;
                    t.push((
                        line_of(l),
                        s.parse()
                            .map_err(|_| err(line_of(l), format!("`{s}` is not a cell type")))?,
                    ));
                }
                types = Some(t);
            }
            "CELL_DATA" | "POINT_DATA" => break,
            _ => {}
        }
    }
    let positions = positions.ok_or_else(|| err(0, "no POINTS section".into()))?;
    let (cells_line, cells) = cells.ok_or_else(|| err(0, "no CELLS section".into()))?;
    let types = types.ok_or_else(|| err(0, "no CELL_TYPES section".into()))?;
    if types.len() != cells.len() {
        return Err(err(
            cells_line,
            format!("{} cells but {} cell types", cells.len(), types.len()),
        ));
    }
    let n = positions.len();
    let mut mesh = TetMesh {
        positions,
        tets: Vec::new(),
    };
    let mut face_centre: HashMap<[u32; 4], u32> = HashMap::new();
    for ((line, v), &(tline, ty)) in cells.iter().zip(&types) {
        if let Some(&bad) = v.iter().find(|&&i| i as usize >= n) {
            return Err(err(
                *line,
                format!("point {bad} is out of range: there are {n} points"),
            ));
        }
        match (ty, v.len()) {
            (10, 4) => mesh.tets.push([v[0], v[1], v[2], v[3]]),
            (12, 8) => split_hexahedron(&mut mesh, v, &mut face_centre),
            (10 | 12, k) => {
                return Err(err(
                    *line,
                    format!(
                        "a cell of type {ty} needs {} points, this one has {k}",
                        if ty == 10 { 4 } else { 8 }
                    ),
                ))
            }
            _ => {
                return Err(err(
                    tline,
                    format!(
                        "cell type {ty} is not read: only tetrahedra (10) and hexahedra (12) are"
                    ),
                ))
            }
        }
    }
    Ok(mesh)
}

/// Splits hexahedron `v` (VTK order) into 24 tetrahedra around its centre and its face
/// centres (shared through `face_centre`, keyed by the face's sorted vertices).
pub(super) fn split_hexahedron(
    mesh: &mut TetMesh,
    v: &[u32],
    face_centre: &mut HashMap<[u32; 4], u32>,
) {
    const FACES: [[usize; 4]; 6] = [
        [0, 1, 2, 3],
        [4, 5, 6, 7],
        [0, 1, 5, 4],
        [1, 2, 6, 5],
        [2, 3, 7, 6],
        [3, 0, 4, 7],
    ];
    let mean = |ids: &[u32], p: &[[f64; 3]]| -> [f64; 3] {
        std::array::from_fn(|c| {
            ids.iter().map(|&i| p[i as usize][c]).sum::<f64>() / ids.len() as f64
        })
    };
    let centre = mesh.positions.len() as u32;
    let c = mean(v, &mesh.positions);
    mesh.positions.push(c);
    for f in FACES {
        let ids = f.map(|k| v[k]);
        let mut key = ids;
        key.sort_unstable();
        let fc = *face_centre.entry(key).or_insert_with(|| {
            let p = mean(&ids, &mesh.positions);
            mesh.positions.push(p);
            (mesh.positions.len() - 1) as u32
        });
        for e in 0..4 {
            // Oriented here (the file's tetrahedra keep the file's orientation: VTK's is
            // positive, and an inverted one is the model's to report).
            let mut t = [ids[e], ids[(e + 1) % 4], fc, centre];
            if signed_volume(&t.map(|i| mesh.positions[i as usize])) < 0.0 {
                t.swap(2, 3);
            }
            mesh.tets.push(t);
        }
    }
}

/// Reads a legacy VTK file (at most `max_bytes`).
pub fn read_vtk(path: &std::path::Path, max_bytes: u64) -> Result<TetMesh, ReadError> {
    parse_vtk(
        &crate::io::read_text(path, max_bytes)?,
        &path.display().to_string(),
    )
}

impl Fem {
    /// The von Mises stress (Pa) of element e at positions x, from the Cauchy stress
    /// `sigma = P F^T / J`: `sqrt(((s11 - s22)^2 + (s22 - s33)^2 + (s33 - s11)^2) / 2 +
    /// 3 (s12^2 + s23^2 + s13^2))`.
    pub fn von_mises(&self, e: usize, x: &[f64]) -> f64 {
        let f = self.deformation_gradient(e, x);
        let p = self.stress_at(e, &f);
        let j = det(&f);
        let s = mul(&p, &transpose(&f)).map(|v| v / j);
        let d = (s[0] - s[4]).powi(2) + (s[4] - s[8]).powi(2) + (s[8] - s[0]).powi(2);
        let sh = s[1].powi(2) + s[5].powi(2) + s[2].powi(2);
        (0.5 * d + 3.0 * sh).sqrt()
    }

    /// Writes the model at positions x and velocities v (component-major) as a legacy
    /// ASCII VTK unstructured grid of tetrahedra: point vectors `displacement` (from the
    /// rest positions `rest`) and `velocity`, cell scalar `von_mises` (Pa). Full precision
    /// (Rust's shortest round-trip form).
    pub fn write_vtk(
        &self,
        w: &mut dyn Write,
        title: &str,
        rest: &[f64],
        x: &[f64],
        v: &[f64],
    ) -> std::io::Result<()> {
        let n = self.n;
        assert!(rest.len() == 3 * n && x.len() == 3 * n && v.len() == 3 * n);
        let m = self.tets.len();
        writeln!(w, "# vtk DataFile Version 3.0")?;
        // The title is one line of at most 256 characters.
        let title: String = title.replace(['\n', '\r'], " ").chars().take(255).collect();
        writeln!(w, "{title}")?;
        writeln!(w, "ASCII")?;
        writeln!(w, "DATASET UNSTRUCTURED_GRID")?;
        writeln!(w, "POINTS {n} double")?;
        for i in 0..n {
            writeln!(w, "{} {} {}", x[i], x[n + i], x[2 * n + i])?;
        }
        writeln!(w, "CELLS {m} {}", 5 * m)?;
        for t in &self.tets {
            writeln!(w, "4 {} {} {} {}", t[0], t[1], t[2], t[3])?;
        }
        writeln!(w, "CELL_TYPES {m}")?;
        for _ in 0..m {
            writeln!(w, "10")?;
        }
        writeln!(w, "POINT_DATA {n}")?;
        writeln!(w, "VECTORS displacement double")?;
        for i in 0..n {
            writeln!(
                w,
                "{} {} {}",
                x[i] - rest[i],
                x[n + i] - rest[n + i],
                x[2 * n + i] - rest[2 * n + i]
            )?;
        }
        writeln!(w, "VECTORS velocity double")?;
        for i in 0..n {
            writeln!(w, "{} {} {}", v[i], v[n + i], v[2 * n + i])?;
        }
        writeln!(w, "CELL_DATA {m}")?;
        writeln!(w, "SCALARS von_mises double 1")?;
        writeln!(w, "LOOKUP_TABLE default")?;
        for e in 0..m {
            writeln!(w, "{}", self.von_mises(e, x))?;
        }
        Ok(())
    }
}
