//! Structure-of-arrays buffers.
//!
//! [`Vec3s`] holds n 3-vectors in one `Vec<f64>` of length 3n, **component-major**:
//! `[x0..x(n-1), y0..y(n-1), z0..z(n-1)]`. The same buffer is the solvers' degree-of-freedom
//! vector, so models, integrators and linear algebra share it without conversion; block
//! (i, j) of a 3n x 3n operator touches rows {i, n+i, 2n+i} and columns {j, n+j, 2n+j}.
//! Array-of-structures (`[[f64; 3]]`) exists only at the edges, for I/O.

/// n 3-vectors, component-major (see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Vec3s {
    data: Vec<f64>,
}

impl Vec3s {
    /// n zero vectors.
    pub fn zeros(n: usize) -> Self {
        Self {
            data: vec![0.0; 3 * n],
        }
    }

    /// From array-of-structures form (I/O edge).
    pub fn from_aos(v: &[[f64; 3]]) -> Self {
        let n = v.len();
        let mut data = vec![0.0; 3 * n];
        for (i, p) in v.iter().enumerate() {
            data[i] = p[0];
            data[n + i] = p[1];
            data[2 * n + i] = p[2];
        }
        Self { data }
    }

    /// The component-major data, by value (for owned meshes and frames).
    pub fn into_vec(self) -> Vec<f64> {
        self.data
    }

    /// To array-of-structures form (I/O edge).
    pub fn to_aos(&self) -> Vec<[f64; 3]> {
        (0..self.len()).map(|i| self.get(i)).collect()
    }

    /// Number of vectors n.
    #[inline]
    pub fn len(&self) -> usize {
        self.data.len() / 3
    }

    /// Whether there are no vectors.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Vector i.
    #[inline]
    pub fn get(&self, i: usize) -> [f64; 3] {
        largestep_kernels::get3(&self.data, self.len(), i)
    }

    /// Sets vector i.
    #[inline]
    pub fn set(&mut self, i: usize, v: [f64; 3]) {
        let n = self.len();
        self.data[i] = v[0];
        self.data[n + i] = v[1];
        self.data[2 * n + i] = v[2];
    }

    /// All x components.
    pub fn x(&self) -> &[f64] {
        &self.data[..self.len()]
    }
    /// All y components.
    pub fn y(&self) -> &[f64] {
        let n = self.len();
        &self.data[n..2 * n]
    }
    /// All z components.
    pub fn z(&self) -> &[f64] {
        let n = self.len();
        &self.data[2 * n..]
    }

    /// The three component slices, mutable at once.
    pub fn xyz_mut(&mut self) -> [&mut [f64]; 3] {
        largestep_kernels::split3_mut(&mut self.data)
    }

    /// The flat component-major data (the solvers' view).
    #[inline]
    pub fn as_slice(&self) -> &[f64] {
        &self.data
    }

    /// The flat component-major data, mutable.
    #[inline]
    pub fn as_mut_slice(&mut self) -> &mut [f64] {
        &mut self.data
    }
}
