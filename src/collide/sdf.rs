//! Signed-distance grids: distances sampled at the nodes of a regular grid and read with
//! trilinear interpolation (`kernels::interp::sample3_grad`, whose gradient is the
//! interpolant's exact one), from Batty's SDFGen text files or by sampling a function.

use largestep_kernels::interp::Grid3;

/// A signed-distance grid: distances (m, negative inside) at the nodes of a regular grid,
/// x fastest (`i + n_x (j + n_y k)`).
#[derive(Clone, Debug, PartialEq)]
pub struct SdfGrid {
    /// The grid.
    pub grid: Grid3,
    /// Signed distance at each node (m).
    pub phi: Vec<f64>,
}

impl SdfGrid {
    /// Samples `f` (a signed distance, m) at the nodes of `grid`.
    pub fn sample(grid: Grid3, f: impl Fn([f64; 3]) -> f64) -> SdfGrid {
        let mut phi = Vec::with_capacity(grid.len());
        for k in 0..grid.n[2] {
            for j in 0..grid.n[1] {
                for i in 0..grid.n[0] {
                    let p = [
                        grid.origin[0] + i as f64 * grid.spacing[0],
                        grid.origin[1] + j as f64 * grid.spacing[1],
                        grid.origin[2] + k as f64 * grid.spacing[2],
                    ];
                    phi.push(f(p));
                }
            }
        }
        SdfGrid { grid, phi }
    }

    /// Parses the text format of Batty's SDFGen: `ni nj nk`, then the origin `x y z`, then
    /// the spacing `dx`, then `ni nj nk` distances with i fastest, whitespace-separated.
    /// Errors name the file and line.
    pub fn parse(text: &str, path: &str) -> Result<SdfGrid, crate::io::ReadError> {
        let err = |line: usize, message: String| crate::io::ReadError {
            path: path.to_string(),
            line,
            message,
        };
        let mut tokens = text
            .lines()
            .enumerate()
            .flat_map(|(l, s)| s.split_whitespace().map(move |t| (l + 1, t)));
        let mut last_line = 1;
        let mut next = |what: &str| -> Result<(usize, f64), crate::io::ReadError> {
            match tokens.next() {
                Some((l, t)) => {
                    last_line = l;
                    t.parse::<f64>()
                        .map(|v| (l, v))
                        .map_err(|_| err(l, format!("{what}: expected a number, found `{t}`")))
                }
                None => Err(err(last_line, format!("{what}: the file ends early"))),
            }
        };
        let mut n = [0usize; 3];
        let mut header_line = 1;
        for (a, na) in n.iter_mut().enumerate() {
            let (l, v) = next("grid size")?;
            header_line = l;
            if !(v >= 2.0 && v.fract() == 0.0 && v <= 4096.0) {
                return Err(err(
                    l,
                    format!(
                        "grid size {} = {v}: expected an integer in 2..=4096",
                        ["ni", "nj", "nk"][a]
                    ),
                ));
            }
            *na = v as usize;
        }
        let mut origin = [0.0; 3];
        for o in origin.iter_mut() {
            let (l, v) = next("origin")?;
            if !v.is_finite() {
                return Err(err(l, format!("origin = {v}: must be finite")));
            }
            *o = v;
        }
        let (l, dx) = next("spacing")?;
        if !(dx.is_finite() && dx > 0.0) {
            return Err(err(l, format!("spacing = {dx}: must be finite and > 0")));
        }
        let grid = Grid3 {
            n,
            origin,
            spacing: [dx; 3],
        };
        // What the file can hold before anything is allocated: every distance takes at
        // least a digit and a separator.
        let room = text.len().div_ceil(2);
        if grid.len() > room {
            return Err(err(
                header_line,
                format!(
                    "the header asks for {} x {} x {} = {} distances, but the file's {} bytes hold at most {room}",
                    n[0],
                    n[1],
                    n[2],
                    grid.len(),
                    text.len()
                ),
            ));
        }
        let mut phi = Vec::with_capacity(grid.len());
        for k in 0..grid.len() {
            let (l, v) = next("distance")?;
            if !v.is_finite() {
                return Err(err(l, format!("distance {k} = {v}: must be finite")));
            }
            phi.push(v);
        }
        if let Some((l, t)) = tokens.next() {
            return Err(err(
                l,
                format!("unexpected `{t}` after the {} distances", grid.len()),
            ));
        }
        Ok(SdfGrid { grid, phi })
    }

    /// Reads an SDFGen file (see [`SdfGrid::parse`]) of at most `max_bytes` bytes through
    /// [`crate::io::read_text`].
    pub fn read(path: &std::path::Path, max_bytes: u64) -> Result<SdfGrid, crate::io::ReadError> {
        let text = crate::io::read_text(path, max_bytes)?;
        Self::parse(&text, &path.display().to_string())
    }
}
