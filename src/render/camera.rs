//! Cameras: look-at with a vertical field of view, and auto-framing of scene bounds.

use super::RenderError;

/// An axis-aligned box (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Smallest corner.
    pub min: [f64; 3],
    /// Largest corner.
    pub max: [f64; 3],
}

impl Bounds {
    /// The empty box (grows from nothing).
    pub const EMPTY: Bounds = Bounds {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };

    /// Grows the box to hold `p`; non-finite points are ignored.
    pub fn add(&mut self, p: [f64; 3]) {
        if p.iter().all(|c| c.is_finite()) {
            self.min = std::array::from_fn(|k| self.min[k].min(p[k]));
            self.max = std::array::from_fn(|k| self.max[k].max(p[k]));
        }
    }

    /// Grows the box to hold every point of component-major positions (3n values).
    pub fn add_positions(&mut self, positions: &[f64]) {
        let n = positions.len() / 3;
        for i in 0..n {
            self.add(largestep_kernels::get3(positions, n, i));
        }
    }

    /// Grows the box to hold `other`.
    pub fn union(&mut self, other: &Bounds) {
        if !other.is_empty() {
            self.add(other.min);
            self.add(other.max);
        }
    }

    /// True when no point was added.
    pub fn is_empty(&self) -> bool {
        self.min[0] > self.max[0]
    }

    /// The box, or the unit cube round the origin when empty (so an empty scene still has
    /// a camera and a ground).
    pub fn or_unit(&self) -> Bounds {
        if self.is_empty() {
            Bounds {
                min: [-0.5; 3],
                max: [0.5; 3],
            }
        } else {
            *self
        }
    }

    /// The height of the lowest corner along the unit vector `up` (m).
    pub fn lowest_along(&self, up: [f64; 3]) -> f64 {
        (0..8)
            .map(|c| {
                (0..3)
                    .map(|k| {
                        up[k]
                            * if c >> k & 1 == 1 {
                                self.max[k]
                            } else {
                                self.min[k]
                            }
                    })
                    .sum::<f64>()
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Centre.
    pub fn center(&self) -> [f64; 3] {
        std::array::from_fn(|k| 0.5 * (self.min[k] + self.max[k]))
    }

    /// Half the diagonal, at least 1e-3 m (a single point still gets a view).
    pub fn radius(&self) -> f64 {
        let d: f64 = (0..3).map(|k| (self.max[k] - self.min[k]).powi(2)).sum();
        (0.5 * d.sqrt()).max(1e-3)
    }
}

/// A perspective camera looking from `eye` at `target`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Position (m).
    pub eye: [f64; 3],
    /// Point looked at (m).
    pub target: [f64; 3],
    /// World up direction (any length > 0).
    pub up: [f64; 3],
    /// Vertical field of view (degrees), in (0, 180).
    pub fov_y_deg: f64,
}

/// How to place the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CameraSpec {
    /// Frame the scene's bounds from this direction: azimuth about the up axis from the
    /// +z side towards +x, and elevation above the ground (degrees).
    Auto {
        /// Degrees.
        azimuth_deg: f64,
        /// Degrees, in (-90, 90).
        elevation_deg: f64,
        /// Vertical field of view (degrees).
        fov_y_deg: f64,
        /// World up.
        up: [f64; 3],
    },
    /// A given camera.
    Fixed(Camera),
}

/// Default auto-framing azimuth (degrees): a three-quarter view.
pub const DEFAULT_AZIMUTH_DEG: f64 = 35.0;
/// Default auto-framing elevation (degrees).
pub const DEFAULT_ELEVATION_DEG: f64 = 22.0;
/// Default vertical field of view (degrees).
pub const DEFAULT_FOV_DEG: f64 = 40.0;

impl Default for CameraSpec {
    /// Three-quarter view from slightly above, y up.
    fn default() -> Self {
        CameraSpec::Auto {
            azimuth_deg: DEFAULT_AZIMUTH_DEG,
            elevation_deg: DEFAULT_ELEVATION_DEG,
            fov_y_deg: DEFAULT_FOV_DEG,
            up: [0.0, 1.0, 0.0],
        }
    }
}

pub(crate) use largestep_kernels::v3::{cross, dot, sub};
pub(crate) fn normalize(a: [f64; 3]) -> Option<[f64; 3]> {
    largestep_kernels::v3::length_and_unit(a).map(|(_, u)| u)
}

/// An orthonormal camera frame: right, up and forward (into the scene).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Basis {
    /// Camera position (m).
    pub eye: [f64; 3],
    /// Right.
    pub right: [f64; 3],
    /// Up on screen.
    pub up: [f64; 3],
    /// Forward.
    pub forward: [f64; 3],
    /// The world up direction used (unit).
    pub world_up: [f64; 3],
    /// `tan(fov_y / 2)`.
    pub tan_half_fov: f64,
}

impl Camera {
    /// Frames `bounds` from the direction of `spec` for an image of width/height `aspect`:
    /// every corner of the box is in view with 8% to spare, and the eye is outside the
    /// bounding sphere.
    pub fn auto(
        bounds: &Bounds,
        aspect: f64,
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_y_deg: f64,
        up: [f64; 3],
    ) -> Result<Camera, RenderError> {
        check_fov(fov_y_deg)?;
        if elevation_deg.is_nan() || elevation_deg.abs() >= 90.0 || !azimuth_deg.is_finite() {
            return Err(RenderError::Camera(format!(
                "elevation must lie in (-90, 90) degrees and azimuth be finite, got {elevation_deg} and {azimuth_deg}"
            )));
        }
        let b = bounds.or_unit();
        let world_up = normalize(up)
            .ok_or_else(|| RenderError::Camera("the up vector is zero or not finite".into()))?;
        // For y up: azimuth 0 looks from +z, 90 degrees from +x.
        let front = perpendicular(world_up);
        let side = cross(world_up, front);
        let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
        let dir: [f64; 3] = std::array::from_fn(|k| {
            el.cos() * (az.cos() * front[k] + az.sin() * side[k]) + el.sin() * world_up[k]
        });
        // Distance at which all eight corners of the box fit the view: a corner p
        // (relative to the centre) has depth D - p.dir and must satisfy
        // |p.right| <= depth tan(fov_x / 2) and |p.up| <= depth tan(fov_y / 2).
        let tan_y = (0.5 * fov_y_deg.to_radians()).tan();
        let tan_x = tan_y * aspect;
        let c = b.center();
        let right = normalize(cross(dir.map(|x| -x), world_up)).unwrap_or(side);
        let up_s = cross(right, dir.map(|x| -x));
        let r = b.radius();
        let mut dist: f64 = 0.0;
        for corner in 0..8 {
            let p: [f64; 3] = std::array::from_fn(|k| {
                if corner >> k & 1 == 1 {
                    b.max[k] - c[k]
                } else {
                    b.min[k] - c[k]
                }
            });
            let along = dot(p, dir);
            dist = dist
                .max(along + dot(p, right).abs() / tan_x)
                .max(along + dot(p, up_s).abs() / tan_y)
                .max(along + 0.05 * r);
        }
        // 8% margin; never inside the bounding sphere.
        let dist = (1.08 * dist).max(1.05 * r);
        Ok(Camera {
            eye: std::array::from_fn(|k| c[k] + dist * dir[k]),
            target: c,
            up: world_up,
            fov_y_deg,
        })
    }

    /// The camera frame. An `up` that is zero or parallel to the view direction falls back
    /// to the world axis most perpendicular to it, with a warning; a camera with
    /// `eye == target`, a non-finite coordinate or a field of view outside (0, 180) is an
    /// error.
    pub fn basis(&self, warnings: &mut Vec<String>) -> Result<Basis, RenderError> {
        check_fov(self.fov_y_deg)?;
        if !self
            .eye
            .iter()
            .chain(&self.target)
            .chain(&self.up)
            .all(|c| c.is_finite())
        {
            return Err(RenderError::Camera(format!(
                "camera coordinates must be finite: eye {:?}, target {:?}, up {:?}",
                self.eye, self.target, self.up
            )));
        }
        let forward = normalize(sub(self.target, self.eye)).ok_or_else(|| {
            RenderError::Camera(format!(
                "eye and target are the same point {:?}: no view direction",
                self.eye
            ))
        })?;
        let mut world_up = normalize(self.up);
        let right = world_up
            .and_then(|u| normalize(cross(forward, u)))
            .filter(|r| dot(*r, *r) > 0.5 && dot(world_up.unwrap(), forward).abs() < 0.9999);
        let right = match right {
            Some(r) => r,
            None => {
                let axis = perpendicular(forward);
                warnings.push(format!(
                    "camera up vector {:?} is zero or parallel to the view direction; using {:?}",
                    self.up, axis
                ));
                world_up = Some(axis);
                normalize(cross(forward, axis)).expect("axis is perpendicular to forward")
            }
        };
        let up = cross(right, forward);
        Ok(Basis {
            eye: self.eye,
            right,
            up,
            forward,
            world_up: world_up.expect("set above"),
            tan_half_fov: (0.5 * self.fov_y_deg.to_radians()).tan(),
        })
    }
}

fn check_fov(fov: f64) -> Result<(), RenderError> {
    if fov > 0.0 && fov < 180.0 {
        Ok(())
    } else {
        Err(RenderError::Camera(format!(
            "field of view must lie in (0, 180) degrees, got {fov}"
        )))
    }
}

/// The world axis least aligned with the unit vector `d`, made perpendicular to it.
fn perpendicular(d: [f64; 3]) -> [f64; 3] {
    // Prefer y, then z, then x: a y-up world keeps its up whenever it can.
    let axes = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]];
    let a = axes
        .into_iter()
        .min_by(|a, b| dot(*a, d).abs().total_cmp(&dot(*b, d).abs()))
        .expect("three axes");
    normalize(sub(a, d.map(|c| c * dot(a, d)))).expect("least aligned axis")
}
