//! 3-vector arithmetic on `[f64; 3]` (positions, normals, directions): the one copy the
//! element kernels, obstacles, contacts and the renderer's camera share.

/// `a + b`.
#[inline(always)]
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `s a`.
#[inline(always)]
pub fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a - b`.
#[inline(always)]
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a . b`.
#[inline(always)]
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a x b`.
#[inline(always)]
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `(|a|, a / |a|)`, `None` for a zero, infinite or NaN vector.
#[inline]
pub fn length_and_unit(a: [f64; 3]) -> Option<(f64, [f64; 3])> {
    let l = dot(a, a).sqrt();
    (l > 0.0 && l.is_finite()).then(|| (l, a.map(|c| c / l)))
}

/// Two unit vectors completing the unit `n` to a right-handed orthonormal frame
/// `(t1, t2, n)`: `t1` from the world axis least aligned with `n` (x unless `n` leans
/// toward it), `t2 = n x t1`. Deterministic in `n`, so frames built from the same normal
/// agree (contact friction directions, wire circles).
pub fn tangent_frame(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a = if n[0].abs() < 0.57 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let t1 = length_and_unit(cross(n, a)).map_or([0.0, 0.0, 1.0], |x| x.1);
    (t1, cross(n, t1))
}
