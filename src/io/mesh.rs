//! OBJ and PLY (ASCII) writers for frames: vertices, and triangles or line segments.

use std::io::Write;

/// A mesh to write: component-major positions (3n values), triangles and segments
/// (0-based vertex indices; either may be empty).
#[derive(Clone, Copy, Debug)]
pub struct MeshRef<'a> {
    /// Positions, component-major Vec3s data.
    pub positions: &'a [f64],
    /// Triangles.
    pub triangles: &'a [[u32; 3]],
    /// Line segments (springs, chains).
    pub segments: &'a [[u32; 2]],
}

impl MeshRef<'_> {
    fn n(&self) -> usize {
        self.positions.len() / 3
    }
    fn vertex(&self, i: usize) -> [f64; 3] {
        let n = self.n();
        [
            self.positions[i],
            self.positions[n + i],
            self.positions[2 * n + i],
        ]
    }
}

/// Writes a Wavefront OBJ: `v` lines, then `f` (1-based) for triangles and `l` for segments.
pub fn write_obj(w: &mut dyn Write, mesh: MeshRef<'_>, comment: &str) -> std::io::Result<()> {
    writeln!(w, "# {comment}")?;
    for i in 0..mesh.n() {
        let [x, y, z] = mesh.vertex(i);
        writeln!(w, "v {x} {y} {z}")?;
    }
    for t in mesh.triangles {
        writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    for s in mesh.segments {
        writeln!(w, "l {} {}", s[0] + 1, s[1] + 1)?;
    }
    Ok(())
}

/// Writes an ASCII PLY with vertices, faces and edges.
pub fn write_ply(w: &mut dyn Write, mesh: MeshRef<'_>, comment: &str) -> std::io::Result<()> {
    writeln!(w, "ply\nformat ascii 1.0\ncomment {comment}")?;
    writeln!(
        w,
        "element vertex {}\nproperty double x\nproperty double y\nproperty double z",
        mesh.n()
    )?;
    writeln!(
        w,
        "element face {}\nproperty list uchar int vertex_indices",
        mesh.triangles.len()
    )?;
    writeln!(
        w,
        "element edge {}\nproperty int vertex1\nproperty int vertex2",
        mesh.segments.len()
    )?;
    writeln!(w, "end_header")?;
    for i in 0..mesh.n() {
        let [x, y, z] = mesh.vertex(i);
        writeln!(w, "{x} {y} {z}")?;
    }
    for t in mesh.triangles {
        writeln!(w, "3 {} {} {}", t[0], t[1], t[2])?;
    }
    for s in mesh.segments {
        writeln!(w, "{} {}", s[0], s[1])?;
    }
    Ok(())
}

/// An owned mesh (what [`read_obj`] returns and frame sequences hold): component-major
/// positions and shared topology, so that frames of one animation share their
/// triangles and segments.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Positions, component-major Vec3s data (3n values).
    pub positions: Vec<f64>,
    /// Triangles (0-based).
    pub triangles: std::sync::Arc<[[u32; 3]]>,
    /// Line segments (0-based).
    pub segments: std::sync::Arc<[[u32; 2]]>,
}

impl Mesh {
    /// A copy of `m`.
    pub fn from_ref(m: MeshRef<'_>) -> Mesh {
        Mesh {
            positions: m.positions.to_vec(),
            triangles: m.triangles.into(),
            segments: m.segments.into(),
        }
    }

    /// The borrowed view.
    pub fn as_ref(&self) -> MeshRef<'_> {
        MeshRef {
            positions: &self.positions,
            triangles: &self.triangles,
            segments: &self.segments,
        }
    }

    /// Makes this mesh share `other`'s topology when it is the same.
    pub fn share_topology(&mut self, other: &Mesh) {
        if self.triangles == other.triangles {
            self.triangles = other.triangles.clone();
        }
        if self.segments == other.segments {
            self.segments = other.segments.clone();
        }
    }
}

/// A malformed input file: the file, the 1-based line (0 when the file as a whole is
/// wrong) and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}{}: {message}", if *line > 0 { format!(":{line}") } else { String::new() })]
pub struct ReadError {
    /// The file.
    pub path: String,
    /// 1-based line, 0 if none.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// Reads a Wavefront OBJ file: `v` (3 coordinates; a 4th is ignored), `f` (3 or more
/// vertices, `i`, `i/t`, `i//n` or `i/t/n`, 1-based or negative relative indices; polygons
/// become fans) and `l` (polylines become segments). `vt`, `vn`, `vp`, `o`, `g`, `s`,
/// `usemtl`, `mtllib` and comments are ignored; any other statement is an error.
/// Non-finite coordinates are kept (a renderer skips what uses them).
pub fn read_obj(path: &std::path::Path) -> Result<Mesh, ReadError> {
    let text = std::fs::read_to_string(path).map_err(|e| ReadError {
        path: path.display().to_string(),
        line: 0,
        message: e.to_string(),
    })?;
    parse_obj(&text, &path.display().to_string())
}

/// [`read_obj`] on text; `name` is used in errors.
pub fn parse_obj(text: &str, name: &str) -> Result<Mesh, ReadError> {
    let mut xyz: Vec<[f64; 3]> = Vec::new();
    let mut triangles = Vec::new();
    let mut segments = Vec::new();
    // Faces may name vertices defined later, so indices are checked at the end against
    // the largest one used (and the line using it).
    let mut largest: Option<(usize, usize)> = None;
    for (ln, raw) in text.lines().enumerate() {
        let line = ln + 1;
        let err = |message: String| ReadError {
            path: name.to_string(),
            line,
            message,
        };
        let content = raw.split('#').next().unwrap_or("");
        let mut it = content.split_whitespace();
        let Some(key) = it.next() else { continue };
        match key {
            "v" => {
                let vals: Vec<&str> = it.collect();
                if !(3..=4).contains(&vals.len()) {
                    return Err(err(format!(
                        "`v` needs 3 coordinates, found {}",
                        vals.len()
                    )));
                }
                let mut p = [0.0; 3];
                for (k, s) in vals[..3].iter().enumerate() {
                    p[k] = s
                        .parse()
                        .map_err(|_| err(format!("`{s}` is not a number (vertex coordinate)")))?;
                }
                xyz.push(p);
            }
            "f" | "l" => {
                let mut idx = Vec::new();
                for tok in it {
                    let first = tok.split('/').next().unwrap_or("");
                    let i: i64 = first.parse().map_err(|_| {
                        err(format!(
                            "`{tok}` is not a vertex index (expected i, i/t, i//n or i/t/n)"
                        ))
                    })?;
                    let abs = if i > 0 {
                        i - 1
                    } else if i < 0 {
                        xyz.len() as i64 + i
                    } else {
                        return Err(err("vertex index 0: OBJ indices start at 1".into()));
                    };
                    if abs < 0 {
                        return Err(err(format!(
                            "relative index {i} reaches before the first vertex ({} defined so far)",
                            xyz.len()
                        )));
                    }
                    if abs > u32::MAX as i64 {
                        return Err(err(format!("vertex index {i} is too large")));
                    }
                    idx.push(abs as u32);
                    if largest.is_none_or(|(k, _)| abs as usize > k) {
                        largest = Some((abs as usize, line));
                    }
                }
                if key == "f" {
                    if idx.len() < 3 {
                        return Err(err(format!(
                            "`f` needs at least 3 vertices, found {}",
                            idx.len()
                        )));
                    }
                    for k in 1..idx.len() - 1 {
                        triangles.push([idx[0], idx[k], idx[k + 1]]);
                    }
                } else {
                    if idx.len() < 2 {
                        return Err(err(format!(
                            "`l` needs at least 2 vertices, found {}",
                            idx.len()
                        )));
                    }
                    segments.extend(idx.windows(2).map(|w| [w[0], w[1]]));
                }
            }
            "vt" | "vn" | "vp" | "o" | "g" | "s" | "usemtl" | "mtllib" => {}
            other => {
                return Err(err(format!(
                "unknown statement `{other}` (expected v, f, l, vt, vn, o, g, s, usemtl or mtllib)"
            )))
            }
        }
    }
    let n = xyz.len();
    if let Some((k, line)) = largest.filter(|&(k, _)| k >= n) {
        return Err(ReadError {
            path: name.to_string(),
            line,
            message: format!(
                "vertex {} does not exist: the file defines {n} vertices",
                k + 1
            ),
        });
    }
    Ok(Mesh {
        positions: crate::soa::Vec3s::from_aos(&xyz).into_vec(),
        triangles: triangles.into(),
        segments: segments.into(),
    })
}
