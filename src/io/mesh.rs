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
