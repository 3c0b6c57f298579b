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

    /// Wraps component-major data; its length must be a multiple of 3.
    pub fn from_data(data: Vec<f64>) -> Self {
        assert!(data.len() % 3 == 0, "Vec3s data length must be 3n");
        Self { data }
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
        let n = self.len();
        [self.data[i], self.data[n + i], self.data[2 * n + i]]
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
        let n = self.len();
        let (x, rest) = self.data.split_at_mut(n);
        let (y, z) = rest.split_at_mut(n);
        [x, y, z]
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

    /// Consumes the buffer, returning its data.
    pub fn into_data(self) -> Vec<f64> {
        self.data
    }

    /// A read-only view.
    pub fn view(&self) -> Vec3sRef<'_> {
        Vec3sRef {
            data: &self.data,
            n: self.len(),
        }
    }
}

/// A borrowed component-major set of 3-vectors (for example one half of a state vector).
#[derive(Clone, Copy, Debug)]
pub struct Vec3sRef<'a> {
    data: &'a [f64],
    n: usize,
}

impl<'a> Vec3sRef<'a> {
    /// Views component-major data of length 3n.
    pub fn new(data: &'a [f64]) -> Self {
        assert!(data.len() % 3 == 0, "Vec3s data length must be 3n");
        Self {
            data,
            n: data.len() / 3,
        }
    }
    /// Number of vectors.
    pub fn len(&self) -> usize {
        self.n
    }
    /// Whether there are no vectors.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    /// Vector i.
    #[inline]
    pub fn get(&self, i: usize) -> [f64; 3] {
        [
            self.data[i],
            self.data[self.n + i],
            self.data[2 * self.n + i],
        ]
    }
    /// The flat data.
    pub fn as_slice(&self) -> &'a [f64] {
        self.data
    }
}

/// Vector i of component-major data `v` holding n vectors.
#[inline]
pub fn get3(v: &[f64], n: usize, i: usize) -> [f64; 3] {
    [v[i], v[n + i], v[2 * n + i]]
}

/// Sets vector i of component-major data `v` holding n vectors.
#[inline]
pub fn set3(v: &mut [f64], n: usize, i: usize, x: [f64; 3]) {
    v[i] = x[0];
    v[n + i] = x[1];
    v[2 * n + i] = x[2];
}
