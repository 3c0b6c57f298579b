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
    /// Vertex i's position.
    pub fn vertex(&self, i: usize) -> [f64; 3] {
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

    /// One mesh of several: their vertices one after the other, and their elements with
    /// indices shifted to match.
    pub fn concat<'a>(meshes: impl IntoIterator<Item = MeshRef<'a>>) -> Mesh {
        let meshes: Vec<MeshRef<'a>> = meshes.into_iter().collect();
        let total: usize = meshes.iter().map(|m| m.n()).sum();
        let mut positions = vec![0.0; 3 * total];
        let (mut triangles, mut segments) = (Vec::new(), Vec::new());
        let mut first = 0;
        for m in &meshes {
            let n = m.n();
            for c in 0..3 {
                positions[c * total + first..c * total + first + n]
                    .copy_from_slice(&m.positions[c * n..(c + 1) * n]);
            }
            let o = first as u32;
            triangles.extend(m.triangles.iter().map(|t| t.map(|v| v + o)));
            segments.extend(m.segments.iter().map(|s| s.map(|v| v + o)));
            first += n;
        }
        Mesh {
            positions,
            triangles: triangles.into(),
            segments: segments.into(),
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

/// Every use of an edge by a triangle: `([a, b], triangle)` with `a < b`, sorted by edge
/// and then triangle, so that one edge's uses stand together (`chunk_by` on the edge):
/// two for an edge inside a closed or manifold surface, one on a border.
pub fn edge_uses(triangles: &[[u32; 3]]) -> Vec<([u32; 2], usize)> {
    let mut uses: Vec<([u32; 2], usize)> = Vec::with_capacity(3 * triangles.len());
    for (t, tri) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            uses.push(([a.min(b), a.max(b)], t));
        }
    }
    uses.sort_unstable();
    uses
}

/// The 1-based line of the `i`-th (0-based) `v` statement of OBJ text: where a vertex an
/// error names was defined.
pub fn obj_vertex_line(text: &str, i: usize) -> Option<usize> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.split_whitespace().next() == Some("v"))
        .nth(i)
        .map(|(ln, _)| ln + 1)
}

/// A malformed input file: the file, the 1-based line (0 when the file as a whole is
/// wrong) and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}{}: {}", if *line > 0 { format!(":{line}") } else { String::new() }, super::clip(message, super::MAX_MESSAGE))]
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
/// The file is read through [`super::read_text`], at most `max_bytes` bytes.
pub fn read_obj(path: &std::path::Path, max_bytes: u64) -> Result<Mesh, ReadError> {
    let text = super::read_text(path, max_bytes)?;
    parse_obj(&text, &path.display().to_string())
}

/// [`read_obj`] on text; `name` is used in errors.
pub fn parse_obj(text: &str, name: &str) -> Result<Mesh, ReadError> {
    parse_obj_impl(text, name, false).map(|(m, _)| m)
}

/// Reads an OBJ triangle mesh with texture coordinates, one `(u, v)` per vertex (what
/// cloth takes as rest coordinates): every face corner must name one (`i/t` or `i/t/n`),
/// and a vertex named with two different ones (a texture seam) is an error naming the
/// line; the mesh must be split at the seam. Otherwise as [`read_obj`].
pub fn read_obj_uv(
    path: &std::path::Path,
    max_bytes: u64,
) -> Result<(Mesh, Vec<[f64; 2]>), ReadError> {
    let text = super::read_text(path, max_bytes)?;
    parse_obj_uv(&text, &path.display().to_string())
}

/// [`read_obj_uv`] on text; `name` is used in errors.
pub fn parse_obj_uv(text: &str, name: &str) -> Result<(Mesh, Vec<[f64; 2]>), ReadError> {
    parse_obj_impl(text, name, true).map(|(m, uv)| (m, uv.unwrap_or_default()))
}

/// A mesh and, when asked for, one texture coordinate per vertex.
type MeshAndUv = (Mesh, Option<Vec<[f64; 2]>>);

fn parse_obj_impl(text: &str, name: &str, want_uv: bool) -> Result<MeshAndUv, ReadError> {
    let mut xyz: Vec<[f64; 3]> = Vec::new();
    // Texture coordinates as read, and for each vertex the one its faces name (with the
    // line that first named it).
    let mut vts: Vec<[f64; 2]> = Vec::new();
    let mut vt_of: Vec<(u32, usize)> = Vec::new();
    let mut vt_used: Option<(usize, usize)> = None;
    let mut triangles = Vec::new();
    let mut segments = Vec::new();
    // Faces may name vertices defined later: a first pass counts the vertices the file
    // defines, so an index is checked where it is used, against what the file holds,
    // before anything is sized by it.
    let defined = text
        .lines()
        .filter(|l| l.split_whitespace().next() == Some("v"))
        .count();
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
            "vt" if want_uv => {
                let vals: Vec<&str> = it.collect();
                if !(2..=3).contains(&vals.len()) {
                    return Err(err(format!(
                        "`vt` needs 2 coordinates, found {}",
                        vals.len()
                    )));
                }
                let mut t = [0.0; 2];
                for (k, s) in vals[..2].iter().enumerate() {
                    t[k] = s
                        .parse()
                        .map_err(|_| err(format!("`{s}` is not a number (texture coordinate)")))?;
                }
                vts.push(t);
            }
            "f" | "l" => {
                let mut idx = Vec::new();
                for tok in it {
                    let mut parts = tok.split('/');
                    let first = parts.next().unwrap_or("");
                    let tex = parts.next().unwrap_or("");
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
                    if abs >= defined as i64 {
                        return Err(err(format!(
                            "vertex {} does not exist: the file defines {defined} vertices",
                            abs + 1
                        )));
                    }
                    idx.push(abs as u32);
                    if want_uv && key == "f" {
                        let t: i64 = tex.parse().map_err(|_| {
                            err(format!(
                                "`{tok}` has no texture coordinate: cloth meshes need i/t or i/t/n on every face"
                            ))
                        })?;
                        let ta = if t > 0 { t - 1 } else { vts.len() as i64 + t };
                        if t == 0 || ta < 0 || ta > u32::MAX as i64 {
                            return Err(err(format!("texture index {t} is out of range")));
                        }
                        if vt_used.is_none_or(|(k, _)| ta as usize > k) {
                            vt_used = Some((ta as usize, line));
                        }
                        let a = abs as usize;
                        if vt_of.len() <= a {
                            vt_of.resize(a + 1, (u32::MAX, 0));
                        }
                        match vt_of[a] {
                            (u32::MAX, _) => vt_of[a] = (ta as u32, line),
                            (prev, _) if prev == ta as u32 => {}
                            (prev, first) => {
                                return Err(err(format!(
                                    "vertex {} has texture coordinate {} here but {} on line {first} (a texture seam): split the mesh at the seam",
                                    a + 1,
                                    ta + 1,
                                    prev + 1
                                )))
                            }
                        }
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
    let uv = if want_uv {
        if let Some((k, line)) = vt_used.filter(|&(k, _)| k >= vts.len()) {
            return Err(ReadError {
                path: name.to_string(),
                line,
                message: format!(
                    "texture coordinate {} does not exist: the file defines {}",
                    k + 1,
                    vts.len()
                ),
            });
        }
        let mut uv = Vec::with_capacity(n);
        for i in 0..n {
            match vt_of.get(i) {
                Some(&(t, _)) if t != u32::MAX => uv.push(vts[t as usize]),
                // A vertex in no face: no (u, v) needed; it gets no mass (the cloth pins it).
                _ => uv.push([0.0, 0.0]),
            }
        }
        Some(uv)
    } else {
        None
    };
    Ok((
        Mesh {
            positions: crate::soa::Vec3s::from_aos(&xyz).into_vec(),
            triangles: triangles.into(),
            segments: segments.into(),
        },
        uv,
    ))
}

/// Reads an OFF file (Object File Format, as Geomview and CGAL write it): `OFF`, then
/// `<vertices> <faces> <edges>`, the vertices (`x y z`) and the faces (`k i1 .. ik`,
/// 0-based; polygons become fans). `#` starts a comment. Counts are checked against the
/// lines the file has before allocating; errors name the file and line.
pub fn read_off(path: &std::path::Path, max_bytes: u64) -> Result<Mesh, ReadError> {
    let text = super::read_text(path, max_bytes)?;
    parse_off(&text, &path.display().to_string())
}

/// [`read_off`] on text; `name` is used in errors.
pub fn parse_off(text: &str, name: &str) -> Result<Mesh, ReadError> {
    let err = |line: usize, message: String| ReadError {
        path: name.to_string(),
        line,
        message,
    };
    let mut lines = text.lines().enumerate().filter_map(|(k, l)| {
        let l = l.split('#').next().unwrap_or("").trim();
        (!l.is_empty()).then_some((k + 1, l))
    });
    let (hl, head) = lines.next().ok_or_else(|| err(0, "empty file".into()))?;
    // The counts may follow `OFF` on the same line.
    let rest = head
        .strip_prefix("OFF")
        .ok_or_else(|| err(hl, format!("expected `OFF`, found `{head}`")))?
        .trim();
    let (cl, counts) = if rest.is_empty() {
        lines
            .next()
            .ok_or_else(|| err(hl, "no counts line".into()))?
    } else {
        (hl, rest)
    };
    let c: Vec<usize> = counts
        .split_whitespace()
        .map(|s| {
            s.parse()
                .map_err(|_| err(cl, format!("`{s}` is not a count")))
        })
        .collect::<Result<_, _>>()?;
    let (nv, nf) = match c[..] {
        [nv, nf, _] | [nv, nf] => (nv, nf),
        _ => return Err(err(cl, "expected `<vertices> <faces> <edges>`".into())),
    };
    let total = text.lines().count();
    if nv.saturating_add(nf) > total {
        return Err(err(
            cl,
            format!("the counts claim {nv} vertices and {nf} faces, but the file has only {total} lines"),
        ));
    }
    let mut xyz = Vec::with_capacity(nv);
    for j in 0..nv {
        let (l, v) = lines.next().ok_or_else(|| {
            err(
                0,
                format!("the counts claim {nv} vertices, the file holds {j}"),
            )
        })?;
        let f: Vec<f64> = v
            .split_whitespace()
            .take(3)
            .map(|s| {
                s.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| err(l, format!("`{s}` is not a finite coordinate")))
            })
            .collect::<Result<_, _>>()?;
        if f.len() != 3 {
            return Err(err(l, "a vertex needs x, y and z".into()));
        }
        xyz.push([f[0], f[1], f[2]]);
    }
    let mut triangles = Vec::with_capacity(nf);
    for j in 0..nf {
        let (l, face) = lines.next().ok_or_else(|| {
            err(
                0,
                format!("the counts claim {nf} faces, the file holds {j}"),
            )
        })?;
        let f: Vec<usize> = face
            .split_whitespace()
            .map(|s| {
                s.parse()
                    .map_err(|_| err(l, format!("`{s}` is not an index")))
            })
            .collect::<Result<_, _>>()?;
        let k = *f.first().ok_or_else(|| err(l, "empty face".into()))?;
        if k < 3 || f.len() - 1 < k {
            return Err(err(
                l,
                format!("a face of {k} vertices needs {k} indices after the count"),
            ));
        }
        let ids = &f[1..=k];
        if let Some(bad) = ids.iter().find(|&&i| i >= nv) {
            return Err(err(
                l,
                format!("vertex {bad} is out of range: there are {nv} vertices"),
            ));
        }
        for t in 1..k - 1 {
            triangles.push([ids[0] as u32, ids[t] as u32, ids[t + 1] as u32]);
        }
    }
    let mut positions = vec![0.0; 3 * nv];
    for (i, p) in xyz.iter().enumerate() {
        for c in 0..3 {
            positions[c * nv + i] = p[c];
        }
    }
    Ok(Mesh {
        positions,
        triangles: triangles.into(),
        segments: Vec::new().into(),
    })
}

/// Whether `file` names a closed triangle surface (`.obj`, `.off`): what the voxel mesher
/// and the fluid's mesh obstacles take.
pub fn is_surface_file(file: &std::path::Path) -> bool {
    file.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("obj") || e.eq_ignore_ascii_case("off"))
}

/// Reads the closed surface `file` (`.obj` or `.off`, at most `max_bytes`).
pub fn read_surface(file: &std::path::Path, max_bytes: u64) -> Result<Mesh, ReadError> {
    if file
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("off"))
    {
        read_off(file, max_bytes)
    } else {
        read_obj(file, max_bytes)
    }
}
