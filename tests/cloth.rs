//! Baraff-Witkin cloth elements (stretch, shear): forces are minus the energy gradient,
//! Jacobians are the derivatives of the forces and symmetric, rest and rigid motions give
//! no force, internal forces have no net force or torque.

use largestep::kernels::cloth::{shear_element, stretch_element, ElementOut, TriangleRest};
use proptest::prelude::*;

type Element = fn(&TriangleRest, &[[f64; 3]; 3], &[[f64; 3]; 3], f64, f64) -> ElementOut<3>;

fn stretch(
    r: &TriangleRest,
    x: &[[f64; 3]; 3],
    v: &[[f64; 3]; 3],
    k: f64,
    kd: f64,
) -> ElementOut<3> {
    stretch_element(r, x, v, k, kd, [1.0, 1.0])
}

const ELEMENTS: [(&str, Element); 2] = [("stretch", stretch), ("shear", shear_element)];

/// Three vertices' positions or velocities.
type Tri3 = [[f64; 3]; 3];

fn triangle(vals: &[f64]) -> Option<(TriangleRest, Tri3, Tri3)> {
    let uv = [[vals[0], vals[1]], [vals[2], vals[3]], [vals[4], vals[5]]];
    let area = 0.5
        * ((uv[1][0] - uv[0][0]) * (uv[2][1] - uv[0][1])
            - (uv[2][0] - uv[0][0]) * (uv[1][1] - uv[0][1]));
    if area.abs() < 0.02 {
        return None;
    }
    let r = TriangleRest::new(uv)?;
    let x = std::array::from_fn(|i| std::array::from_fn(|c| vals[6 + 3 * i + c]));
    let v = std::array::from_fn(|i| std::array::from_fn(|c| vals[15 + 3 * i + c]));
    Some((r, x, v))
}

fn rotation(a: f64, b: f64) -> [[f64; 3]; 3] {
    let (ca, sa, cb, sb) = (a.cos(), a.sin(), b.cos(), b.sin());
    // Rz(a) * Rx(b)
    [
        [ca, -sa * cb, sa * sb],
        [sa, ca * cb, -ca * sb],
        [0.0, sb, cb],
    ]
}

fn apply(r: &[[f64; 3]; 3], p: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2])
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn forces_are_minus_the_energy_gradient_and_jacobians_match_finite_differences(
        vals in prop::collection::vec(-1f64..1.0, 24..25),
    ) {
        let Some((r, x, v)) = triangle(&vals) else { return Ok(()) };
        for (name, el) in ELEMENTS {
            let out = el(&r, &x, &v, 3.0, 0.0);
            let h = 1e-6;
            for i in 0..3 {
                for a in 0..3 {
                    let (mut xp, mut xm) = (x, x);
                    xp[i][a] += h;
                    xm[i][a] -= h;
                    let (op, om) = (el(&r, &xp, &v, 3.0, 0.0), el(&r, &xm, &v, 3.0, 0.0));
                    let grad = (op.energy - om.energy) / (2.0 * h);
                    prop_assert!((out.f[i][a] + grad).abs() < 1e-6 * (1.0 + grad.abs()), "{name}: f[{i}][{a}] = {} vs -dE = {}", out.f[i][a], -grad);
                    for j in 0..3 {
                        for b in 0..3 {
                            let fd = (op.f[j][b] - om.f[j][b]) / (2.0 * h);
                            let an = out.kx[j][i][3 * b + a];
                            prop_assert!((fd - an).abs() < 1e-5 * (1.0 + an.abs()), "{name}: df[{j}][{b}]/dx[{i}][{a}] fd {fd} vs {an}");
                        }
                    }
                }
            }
            // Symmetric: df_i/dx_j = (df_j/dx_i)^T.
            for i in 0..3 {
                for j in 0..3 {
                    for a in 0..3 {
                        for b in 0..3 {
                            prop_assert!((out.kx[i][j][3 * a + b] - out.kx[j][i][3 * b + a]).abs() < 1e-12 * (1.0 + out.kx[i][j][3 * a + b].abs()));
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn damping_jacobian_matches_finite_differences_in_velocity(
        vals in prop::collection::vec(-1f64..1.0, 24..25),
    ) {
        let Some((r, x, v)) = triangle(&vals) else { return Ok(()) };
        for (name, el) in ELEMENTS {
            let out = el(&r, &x, &v, 3.0, 0.7);
            let h = 1e-6;
            for i in 0..3 {
                for a in 0..3 {
                    let (mut vp, mut vm) = (v, v);
                    vp[i][a] += h;
                    vm[i][a] -= h;
                    let (op, om) = (el(&r, &x, &vp, 3.0, 0.7), el(&r, &x, &vm, 3.0, 0.7));
                    for j in 0..3 {
                        for b in 0..3 {
                            let fd = (op.f[j][b] - om.f[j][b]) / (2.0 * h);
                            let an = out.kv[j][i][3 * b + a];
                            prop_assert!((fd - an).abs() < 1e-6 * (1.0 + an.abs()), "{name}: df/dv fd {fd} vs {an}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn internal_forces_have_no_net_force_or_torque_and_rigid_motions_change_nothing(
        vals in prop::collection::vec(-1f64..1.0, 24..25),
        angles in (-3.0f64..3.0, -3.0f64..3.0),
        shift in prop::array::uniform3(-5f64..5.0),
    ) {
        let Some((r, x, _)) = triangle(&vals) else { return Ok(()) };
        let rot = rotation(angles.0, angles.1);
        let moved: [[f64; 3]; 3] = std::array::from_fn(|i| {
            let p = apply(&rot, x[i]);
            [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]
        });
        for (name, el) in ELEMENTS {
            let out = el(&r, &x, &[[0.0; 3]; 3], 2.0, 0.0);
            let total: [f64; 3] = std::array::from_fn(|c| out.f.iter().map(|f| f[c]).sum());
            let torque: [f64; 3] = std::array::from_fn(|c| {
                (0..3).map(|i| {
                    let (p, f) = (x[i], out.f[i]);
                    [p[1] * f[2] - p[2] * f[1], p[2] * f[0] - p[0] * f[2], p[0] * f[1] - p[1] * f[0]][c]
                }).sum()
            });
            let scale = 1.0 + out.f.iter().flatten().map(|c| c.abs()).sum::<f64>();
            prop_assert!(total.iter().all(|c| c.abs() < 1e-12 * scale), "{name}: net force {total:?}");
            prop_assert!(torque.iter().all(|c| c.abs() < 1e-11 * scale), "{name}: net torque {torque:?}");
            let e2 = el(&r, &moved, &[[0.0; 3]; 3], 2.0, 0.0).energy;
            prop_assert!((e2 - out.energy).abs() < 1e-10 * (1.0 + out.energy), "{name}: energy {} after a rigid motion, {} before", e2, out.energy);
            // A rigid velocity field (rotation about an axis plus a translation) does not
            // stretch or shear: no damping force.
            let omega = [0.3, -1.1, 0.7];
            let rigid: [[f64; 3]; 3] = std::array::from_fn(|i| {
                let p = x[i];
                [omega[1] * p[2] - omega[2] * p[1] + 0.5, omega[2] * p[0] - omega[0] * p[2], omega[0] * p[1] - omega[1] * p[0] - 2.0]
            });
            let damped = el(&r, &x, &rigid, 0.0, 1.0);
            prop_assert!(damped.f.iter().flatten().all(|c| c.abs() < 1e-11), "{name}: damping under rigid motion {:?}", damped.f);
        }
    }

    #[test]
    fn the_rest_shape_and_its_rigid_motions_give_zero_condition_and_force(
        uv in prop::collection::vec(-1f64..1.0, 6..7),
        angles in (-3.0f64..3.0, -3.0f64..3.0),
        shift in prop::array::uniform3(-5f64..5.0),
    ) {
        let uvt = [[uv[0], uv[1]], [uv[2], uv[3]], [uv[4], uv[5]]];
        let Some(r) = TriangleRest::new(uvt) else { return Ok(()) };
        if r.area < 0.01 { return Ok(()) }
        let rot = rotation(angles.0, angles.1);
        let x: [[f64; 3]; 3] = std::array::from_fn(|i| {
            let p = apply(&rot, [uvt[i][0], uvt[i][1], 0.0]);
            [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]
        });
        for (name, el) in ELEMENTS {
            let out = el(&r, &x, &[[0.0; 3]; 3], 5.0, 0.0);
            prop_assert!(out.energy < 1e-24, "{name}: energy at rest {}", out.energy);
            prop_assert!(out.f.iter().flatten().all(|c| c.abs() < 1e-11), "{name}: force at rest {:?}", out.f);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn closed_form_triangle_jacobians_equal_the_condition_by_condition_ones(
        vals in prop::collection::vec(-1f64..1.0, 24..25),
        project in any::<bool>(),
    ) {
        use largestep::kernels::cloth::{add_shear, add_stretch, triangle_jacobians, TriangleParams};
        let Some((r, x, v)) = triangle(&vals) else { return Ok(()) };
        let p = TriangleParams {
            stretch: 3.0,
            stretch_damping: 0.4,
            shear: 1.5,
            shear_damping: 0.2,
            rest_stretch: [1.0, 0.9],
            project,
        };
        let mut e = ElementOut::new(project);
        add_stretch(&mut e, &r, &x, &v, p.stretch, p.stretch_damping, p.rest_stretch);
        add_shear(&mut e, &r, &x, &v, p.shear, p.shear_damping);
        let (mut f, mut kx, mut kv) = ([0.0; 9], [0.0; 54], [0.0; 54]);
        let energy = triangle_jacobians(&r, &x, &v, &p, &mut f, &mut kx, Some(&mut kv));
        let scale = e.kx.iter().flatten().flatten().chain(e.kv.iter().flatten().flatten())
            .fold(1e-300f64, |m, v| m.max(v.abs()));
        let tol = 1e-12 * scale;
        prop_assert!((energy - e.energy).abs() <= 1e-12 * e.energy.abs().max(1e-300));
        let fscale = e.f.iter().flatten().fold(1e-300f64, |m, v| m.max(v.abs()));
        for i in 0..3 {
            for c in 0..3 {
                prop_assert!((f[3 * i + c] - e.f[i][c]).abs() <= 1e-12 * fscale);
            }
        }
        let mut slot = 0;
        for i in 0..3 {
            for j in i..3 {
                for k in 0..9 {
                    prop_assert!((kx[9 * slot + k] - e.kx[i][j][k]).abs() <= tol, "kx {i} {j}");
                    prop_assert!((kv[9 * slot + k] - e.kv[i][j][k]).abs() <= tol, "kv {i} {j}");
                }
                slot += 1;
            }
        }
    }
}

/// Four triangles' energies, forces, `kx` and `kv`.
type Outs = ([f64; 4], Vec<f64>, Vec<f64>, Vec<f64>);

/// Four triangles through [`triangle_jacobians_x4`] and one by one through
/// [`triangle_jacobians`], outputs pre-filled with NaN so that a value left unwritten
/// shows.
fn x4_and_scalar(
    r: &[TriangleRest; 4],
    x: &[Tri3; 4],
    v: &[Tri3; 4],
    p: &[largestep::kernels::cloth::TriangleParams; 4],
    with_kv: bool,
) -> [Outs; 2] {
    use largestep::kernels::cloth::{triangle_jacobians, triangle_jacobians_x4};
    let nan = |len| vec![f64::NAN; len];
    let (mut f4, mut kx4, mut kv4) = (nan(36), nan(216), nan(216));
    let e4 = triangle_jacobians_x4(
        r,
        x,
        v,
        p,
        &mut f4,
        &mut kx4,
        with_kv.then_some(&mut kv4[..]),
    );
    let (mut f1, mut kx1, mut kv1) = (nan(36), nan(216), nan(216));
    let e1 = std::array::from_fn(|l| {
        triangle_jacobians(
            &r[l],
            &x[l],
            &v[l],
            &p[l],
            &mut f1[9 * l..9 * l + 9],
            &mut kx1[54 * l..54 * l + 54],
            with_kv.then_some(&mut kv1[54 * l..54 * l + 54]),
        )
    });
    [(e4, f4, kx4, kv4), (e1, f1, kx1, kv1)]
}

/// Lane `l` of the SIMD outputs `a` equals that of the scalar ones `b` within `rel` of the
/// largest magnitude in the lane's share of each output (and NaN exactly where `b` is).
fn lane_close(a: &Outs, b: &Outs, l: usize, rel: f64) -> Result<(), String> {
    let same = |what: &str, x: &[f64], y: &[f64]| -> Result<(), String> {
        let scale = y
            .iter()
            .filter(|v| !v.is_nan())
            .fold(1e-300f64, |m, v| m.max(v.abs()));
        for (i, (p, q)) in x.iter().zip(y).enumerate() {
            let ok = if q.is_nan() {
                p.is_nan()
            } else {
                (p - q).abs() <= rel * scale
            };
            if !ok {
                return Err(format!("lane {l}: {what}[{i}] {p} (x4) vs {q} (scalar)"));
            }
        }
        Ok(())
    };
    same("energy", &a.0[l..l + 1], &b.0[l..l + 1])?;
    same("f", &a.1[9 * l..9 * l + 9], &b.1[9 * l..9 * l + 9])?;
    same("kx", &a.2[54 * l..54 * l + 54], &b.2[54 * l..54 * l + 54])?;
    same("kv", &a.3[54 * l..54 * l + 54], &b.3[54 * l..54 * l + 54])
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Four random triangles, stretched or compressed (rest stretch up to 2.5 against
    /// deformations of order 1, so the lanes' `project` branches differ), with their own
    /// parameters and `project` flags, with and without `kv`.
    #[test]
    fn simd_triangle_jacobians_equal_the_scalar_kernel(
        vals in prop::collection::vec(-1f64..1.0, 96..97),
        consts in prop::collection::vec(0.1f64..10.0, 24..25),
        project in any::<[bool; 4]>(),
        with_kv in any::<bool>(),
    ) {
        let mut tris = vec![];
        for l in 0..4 {
            let Some(t) = triangle(&vals[24 * l..24 * l + 24]) else { return Ok(()) };
            tris.push(t);
        }
        let r = std::array::from_fn(|l| tris[l].0);
        let x = std::array::from_fn(|l| tris[l].1);
        let v = std::array::from_fn(|l| tris[l].2);
        let p = std::array::from_fn(|l| {
            let c = &consts[6 * l..6 * l + 6];
            largestep::kernels::cloth::TriangleParams {
                stretch: c[0],
                stretch_damping: c[1],
                shear: c[2],
                shear_damping: c[3],
                rest_stretch: [0.25 * c[4], 0.25 * c[5]],
                project: project[l],
            }
        });
        let [simd, scalar] = x4_and_scalar(&r, &x, &v, &p, with_kv);
        for l in 0..4 {
            prop_assert!(scalar.1[9 * l..9 * l + 9].iter().all(|v| v.is_finite()));
            lane_close(&simd, &scalar, l, 1e-12).map_err(TestCaseError::fail)?;
        }
        if !with_kv {
            prop_assert!(simd.3.iter().all(|v| v.is_nan()), "kv written without kv");
        }
    }
}

/// A lane whose `w_u` has zero length (no stretch-u direction), a collapsed lane (no
/// direction at all) and a NaN lane give exactly what the scalar kernel gives for them,
/// and the other lanes give the same whatever sits beside them.
#[test]
fn simd_triangle_jacobians_keep_degenerate_and_nan_lanes_to_themselves() {
    use largestep::kernels::cloth::TriangleParams;
    let r = TriangleRest::new([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]).unwrap();
    let rs = [r; 4];
    let healthy: Tri3 = [[0.1, 0.0, 0.2], [1.3, 0.1, 0.0], [0.0, 0.7, 0.1]];
    // w_u = x1 - x0 = 0, w_v = x2 - x0 compressed to 0.6.
    let zero_wu: Tri3 = [[0.2, 0.3, 0.0], [0.2, 0.3, 0.0], [0.2, 0.9, 0.0]];
    let collapsed: Tri3 = [[0.5; 3]; 3];
    let nan: Tri3 = [[f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let compressed: Tri3 = [[0.0; 3], [0.8, 0.1, 0.0], [0.05, 0.7, 0.2]];
    let vel: Tri3 = [[0.3, -0.2, 0.1], [0.0, 0.4, -0.3], [-0.1, 0.2, 0.5]];
    let p = |project| TriangleParams {
        stretch: 4.0,
        stretch_damping: 0.3,
        shear: 2.0,
        shear_damping: 0.1,
        rest_stretch: [1.0, 1.0],
        project,
    };
    for project in [false, true] {
        let ps = [p(project), p(!project), p(project), p(true)];
        let run = |x: [Tri3; 4]| x4_and_scalar(&rs, &x, &[vel; 4], &ps, true);
        let [simd, scalar] = run([healthy, zero_wu, nan, compressed]);
        for l in 0..4 {
            lane_close(&simd, &scalar, l, 1e-12).unwrap();
        }
        // The zero-length stretch gives nothing: its lane's energy is the v stretch's and
        // the shear's only, finite; the NaN lane is NaN; the others are finite.
        assert!(scalar.1[..18]
            .iter()
            .chain(&scalar.1[27..])
            .all(|v| v.is_finite()));
        assert!(simd.0[2].is_nan() && simd.1[18..27].iter().all(|v| v.is_nan()));
        // Neighbours do not matter: the healthy and compressed lanes give the same bits
        // beside a collapsed lane and beside the degenerate ones.
        let [other, _] = run([healthy, collapsed, collapsed, compressed]);
        for l in [0, 3] {
            let bits = |o: &Outs| {
                let (f, k) = (9 * l..9 * l + 9, 54 * l..54 * l + 54);
                let vals = [&o.0[l..l + 1], &o.1[f], &o.2[k.clone()], &o.3[k]].concat();
                vals.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            };
            assert_eq!(bits(&simd), bits(&other), "lane {l}");
        }
        let [simd, scalar] = run([collapsed, healthy, collapsed, zero_wu]);
        for l in 0..4 {
            lane_close(&simd, &scalar, l, 1e-12).unwrap();
        }
        assert!(simd.1[..9].iter().all(|v| v.is_finite()), "collapsed lane");
    }
}

#[test]
fn degenerate_rest_triangles_are_rejected() {
    assert!(TriangleRest::new([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]).is_none());
    assert!(TriangleRest::new([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]]).is_none());
    assert!(TriangleRest::new([[0.0, f64::NAN], [1.0, 0.0], [0.0, 1.0]]).is_none());
    let r = TriangleRest::new([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]]).unwrap();
    assert_eq!(r.area, 1.0);
    // A collapsed triangle (all vertices at one point) has no stretch direction: zero
    // stretch force rather than NaN.
    let out = stretch_element(&r, &[[1.0; 3]; 3], &[[0.0; 3]; 3], 1.0, 1.0, [1.0, 1.0]);
    assert!(out.f.iter().flatten().all(|c| *c == 0.0));
    assert!(out.energy.is_finite());
}

mod bend {
    use super::{apply, rotation};
    use largestep::kernels::cloth::{
        add_bend, bend_element, bend_gradient, bend_gradient_ad, dihedral_angle, ElementOut,
    };
    use proptest::prelude::*;

    fn hinge(vals: &[f64]) -> [[f64; 3]; 4] {
        // A well-shaped hinge near the flat one, then bent and moved by `vals`.
        let base = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.4, 0.9, 0.0],
            [0.6, -0.8, 0.0],
        ];
        std::array::from_fn(|i| std::array::from_fn(|c| base[i][c] + 0.3 * vals[3 * i + c]))
    }

    #[test]
    fn the_angle_is_the_fold_angle() {
        for phi in [0.0f64, 0.3, 1.0, 2.0, 3.0] {
            let x = [
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.5, 1.0, 0.0],
                [0.5, -phi.cos(), phi.sin()],
            ];
            let theta = dihedral_angle(&x);
            assert!(
                (theta.abs() - phi).abs() < 1e-12,
                "fold {phi}: theta {theta}"
            );
        }
        // Degenerate: a zero-area triangle has no normal.
        let x = [[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.5, -1.0, 0.0]];
        assert!(bend_element(&x, &[[0.0; 3]; 4], 1.0, 0.0, 0.0).is_none());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn closed_form_angle_gradient_equals_automatic_differentiation(
            vals in prop::collection::vec(-1f64..1.0, 12..13),
        ) {
            let x = hinge(&vals);
            let (t, g) = bend_gradient(&x).unwrap();
            let (ta, ga) = bend_gradient_ad(&x).unwrap();
            prop_assert_eq!(t, ta);
            let scale = ga.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, b) in g.iter().flatten().zip(ga.iter().flatten()) {
                prop_assert!((a - b).abs() <= 1e-12 * scale, "{:?} vs {:?}", g, ga);
            }
        }

        #[test]
        fn written_projected_bend_jacobians_equal_the_element_ones(
            vals in prop::collection::vec(-1f64..1.0, 24..25),
        ) {
            use largestep::kernels::cloth::bend_jacobians_projected;
            let x = hinge(&vals);
            let v: [[f64; 3]; 4] = std::array::from_fn(|i| std::array::from_fn(|c| vals[12 + 3 * i + c]));
            let mut e = ElementOut::new(true);
            prop_assert!(add_bend(&mut e, &x, &v, 2.0, 0.3, 0.2));
            let (mut f, mut kx, mut kv) = ([0.0; 12], [0.0; 90], [0.0; 90]);
            let energy = bend_jacobians_projected(&x, &v, 2.0, 0.3, 0.2, false, &mut f, &mut kx, Some(&mut kv));
            prop_assert!((energy - e.energy).abs() <= 1e-14 * e.energy.max(1.0));
            for i in 0..4 {
                for c in 0..3 {
                    prop_assert!((f[3 * i + c] - e.f[i][c]).abs() <= 1e-12 * (1.0 + e.f[i][c].abs()));
                }
            }
            let mut slot = 0;
            for i in 0..4 {
                for j in i..4 {
                    for k in 0..9 {
                        prop_assert!((kx[9 * slot + k] - e.kx[i][j][k]).abs() <= 1e-12 * (1.0 + e.kx[i][j][k].abs()));
                        prop_assert!((kv[9 * slot + k] - e.kv[i][j][k]).abs() <= 1e-12 * (1.0 + e.kv[i][j][k].abs()));
                    }
                    slot += 1;
                }
            }
        }

        #[test]
        fn projected_bend_stiffness_is_the_negative_gauss_newton_matrix(
            vals in prop::collection::vec(-1f64..1.0, 12..13),
        ) {
            // With projection the curvature term is dropped: df/dx = -k g g^T exactly,
            // whatever the angle, so it is negative semi-definite.
            let x = hinge(&vals);
            let (_, g) = bend_gradient(&x).unwrap();
            let mut out = ElementOut::new(true);
            prop_assert!(add_bend(&mut out, &x, &[[0.0; 3]; 4], 2.0, 0.0, 0.3));
            for i in 0..4 {
                for j in 0..4 {
                    for e in 0..9 {
                        let want = -2.0 * g[i][e / 3] * g[j][e % 3];
                        prop_assert!((out.kx[i][j][e] - want).abs() < 1e-12 * want.abs().max(1.0));
                    }
                }
            }
        }

        #[test]
        fn bend_forces_and_jacobians_are_exact(
            vals in prop::collection::vec(-1f64..1.0, 24..25),
            theta0 in -0.5f64..0.5,
        ) {
            let x = hinge(&vals);
            let v: [[f64; 3]; 4] = std::array::from_fn(|i| std::array::from_fn(|c| vals[12 + 3 * i + c]));
            let out = bend_element(&x, &v, 2.0, 0.0, theta0).unwrap();
            let h = 1e-6;
            for i in 0..4 {
                for a in 0..3 {
                    let (mut xp, mut xm) = (x, x);
                    xp[i][a] += h;
                    xm[i][a] -= h;
                    let op = bend_element(&xp, &v, 2.0, 0.0, theta0).unwrap();
                    let om = bend_element(&xm, &v, 2.0, 0.0, theta0).unwrap();
                    let grad = (op.energy - om.energy) / (2.0 * h);
                    prop_assert!((out.f[i][a] + grad).abs() < 1e-6 * (1.0 + grad.abs()), "f vs -dE: {} {}", out.f[i][a], -grad);
                    for j in 0..4 {
                        for b in 0..3 {
                            let fd = (op.f[j][b] - om.f[j][b]) / (2.0 * h);
                            let an = out.kx[j][i][3 * b + a];
                            prop_assert!((fd - an).abs() < 1e-5 * (1.0 + an.abs()), "df[{j}][{b}]/dx[{i}][{a}]: fd {fd} vs {an}");
                            prop_assert!((out.kx[i][j][3 * a + b] - out.kx[j][i][3 * b + a]).abs() < 1e-10 * (1.0 + an.abs()));
                        }
                    }
                }
            }
            // Damping Jacobian against finite differences in velocity.
            let damped = bend_element(&x, &v, 0.0, 0.4, theta0).unwrap();
            for i in 0..4 {
                for a in 0..3 {
                    let (mut vp, mut vm) = (v, v);
                    vp[i][a] += h;
                    vm[i][a] -= h;
                    let op = bend_element(&x, &vp, 0.0, 0.4, theta0).unwrap();
                    let om = bend_element(&x, &vm, 0.0, 0.4, theta0).unwrap();
                    for j in 0..4 {
                        for b in 0..3 {
                            let fd = (op.f[j][b] - om.f[j][b]) / (2.0 * h);
                            prop_assert!((fd - damped.kv[j][i][3 * b + a]).abs() < 1e-6 * (1.0 + fd.abs()));
                        }
                    }
                }
            }
        }

        #[test]
        fn bending_has_no_net_force_or_torque_and_ignores_rigid_motions(
            vals in prop::collection::vec(-1f64..1.0, 12..13),
            angles in (-3.0f64..3.0, -3.0f64..3.0),
            shift in prop::array::uniform3(-5f64..5.0),
        ) {
            let x = hinge(&vals);
            let out = bend_element(&x, &[[0.0; 3]; 4], 3.0, 0.0, 0.1).unwrap();
            let total: [f64; 3] = std::array::from_fn(|c| out.f.iter().map(|f| f[c]).sum());
            let torque: [f64; 3] = std::array::from_fn(|c| {
                (0..4).map(|i| {
                    let (p, f) = (x[i], out.f[i]);
                    [p[1] * f[2] - p[2] * f[1], p[2] * f[0] - p[0] * f[2], p[0] * f[1] - p[1] * f[0]][c]
                }).sum()
            });
            let scale = 1.0 + out.f.iter().flatten().map(|c| c.abs()).sum::<f64>();
            prop_assert!(total.iter().all(|c| c.abs() < 1e-12 * scale), "net force {total:?}");
            prop_assert!(torque.iter().all(|c| c.abs() < 1e-11 * scale), "net torque {torque:?}");
            let rot = rotation(angles.0, angles.1);
            let moved: [[f64; 3]; 4] = std::array::from_fn(|i| {
                let p = apply(&rot, x[i]);
                [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]
            });
            prop_assert!((dihedral_angle(&moved) - dihedral_angle(&x)).abs() < 1e-11);
            // Flat and at rest angle 0: no force.
            let flat = hinge(&[0.0; 12]);
            let rest = bend_element(&flat, &[[0.0; 3]; 4], 3.0, 0.0, 0.0).unwrap();
            prop_assert!(rest.f.iter().flatten().all(|c| c.abs() < 1e-14));
        }
    }

    /// The shared `atan2` of the hinge kernels stays within 2 ulp (and 1e-15 rad) of the
    /// C library's, over all four quadrants and tiny sines, and is exact on the axes.
    #[test]
    fn the_kernels_atan2_is_the_c_librarys_to_two_ulp() {
        use largestep::kernels::cloth::atan2_x4;
        use wide::f64x4;
        let at = |y: f64, x: f64| atan2_x4(f64x4::splat(y), f64x4::splat(x)).to_array()[0];
        let mut state = 0x2545f4914f6cdd1du64;
        let mut rand = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for i in 0..200_000 {
            let scale = [1.0, 1e-3, 1e-9][i % 3];
            let (y, x) = (scale * rand(), rand());
            let (ours, libm) = (at(y, x), y.atan2(x));
            let ulp = f64::EPSILON * libm.abs();
            assert!(
                (ours - libm).abs() <= (2.0 * ulp).max(1e-300) && (ours - libm).abs() < 1e-15,
                "atan2({y}, {x}): {ours} vs {libm}"
            );
        }
        let pi = std::f64::consts::PI;
        for (y, x, want) in [
            (0.0, 1.0, 0.0),
            (1.0, 0.0, 0.5 * pi),
            (0.0, -1.0, pi),
            (-0.0, -1.0, -pi),
            (-1.0, 0.0, -0.5 * pi),
        ] {
            assert_eq!(at(y, x), want, "atan2({y}, {x})");
        }
    }

    type Hinge = [[f64; 3]; 4];

    /// Four hinges through `bend_force_gradient_x4` and one by one through
    /// `bend_force_gradient`: energies, then forces and gradients (4 x 12 each), outputs
    /// pre-filled with NaN so that a value left unwritten shows.
    fn hinges_x4_and_scalar(
        x: &[Hinge; 4],
        v: &[Hinge; 4],
        theta0: [f64; 4],
    ) -> [([f64; 4], Vec<f64>, Vec<f64>); 2] {
        use largestep::kernels::cloth::{bend_force_gradient, bend_force_gradient_x4};
        let (k, kd) = (2.5, 0.3);
        let (mut f4, mut g4) = (vec![f64::NAN; 48], vec![f64::NAN; 48]);
        let e4 = bend_force_gradient_x4(x, v, k, kd, theta0, &mut f4, &mut g4);
        let (mut f1, mut g1) = (vec![f64::NAN; 48], vec![f64::NAN; 48]);
        let e1 = std::array::from_fn(|l| {
            let r = 12 * l..12 * l + 12;
            bend_force_gradient(
                &x[l],
                &v[l],
                k,
                kd,
                theta0[l],
                &mut f1[r.clone()],
                &mut g1[r],
            )
        });
        [(e4, f4, g4), (e1, f1, g1)]
    }

    /// The bits of every value.
    fn bits(o: &([f64; 4], Vec<f64>, Vec<f64>)) -> Vec<u64> {
        o.0.iter()
            .chain(&o.1)
            .chain(&o.2)
            .map(|v| v.to_bits())
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        /// Near-flat hinges (`hinge`) and hinges of four arbitrary points (any fold, up to
        /// nearly closed), with their own rest angles: the SIMD lanes give the scalar
        /// kernel's values to the bit.
        #[test]
        fn simd_bend_forces_and_gradients_equal_the_scalar_kernel(
            vals in prop::collection::vec(-1f64..1.0, 96..97),
            theta0 in prop::array::uniform4(-3.0f64..3.0),
            arbitrary in any::<[bool; 4]>(),
        ) {
            let x: [Hinge; 4] = std::array::from_fn(|l| {
                let s = &vals[24 * l..24 * l + 12];
                if arbitrary[l] {
                    std::array::from_fn(|i| std::array::from_fn(|c| s[3 * i + c]))
                } else {
                    hinge(s)
                }
            });
            let v: [Hinge; 4] = std::array::from_fn(|l| {
                let s = &vals[24 * l + 12..24 * l + 24];
                std::array::from_fn(|i| std::array::from_fn(|c| s[3 * i + c]))
            });
            let [simd, scalar] = hinges_x4_and_scalar(&x, &v, theta0);
            prop_assert!(scalar.1.iter().chain(&scalar.2).all(|v| v.is_finite()));
            prop_assert_eq!(bits(&simd), bits(&scalar));
        }
    }

    /// A hinge with a zero-area triangle, one with a zero-length edge and a NaN one write
    /// zeros and zero energy, as the scalar kernel does, and the healthy lane beside them
    /// gives the same bits as beside healthy neighbours.
    #[test]
    fn simd_bend_kernel_keeps_degenerate_and_nan_lanes_to_themselves() {
        let healthy = hinge(&[
            0.1, -0.2, 0.3, 0.0, 0.1, -0.1, 0.2, 0.0, 0.4, -0.3, 0.1, 0.2,
        ]);
        let flat_triangle = [[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.5, -1.0, 0.0]];
        let no_edge = [[0.3; 3], [0.3; 3], [0.4, 0.9, 0.0], [0.6, -0.8, 0.0]];
        let mut nan = healthy;
        nan[3][1] = f64::NAN;
        let vel = [
            [0.3, -0.2, 0.1],
            [0.0, 0.4, -0.3],
            [-0.1, 0.2, 0.5],
            [0.2, 0.1, -0.4],
        ];
        let theta0 = [0.2, -0.1, 0.0, 0.3];
        let [simd, scalar] =
            hinges_x4_and_scalar(&[healthy, flat_triangle, no_edge, nan], &[vel; 4], theta0);
        assert_eq!(bits(&simd), bits(&scalar));
        assert_eq!(simd.0[1..], [0.0; 3]);
        assert!(simd.1[12..].iter().chain(&simd.2[12..]).all(|v| *v == 0.0));
        let [beside_healthy, _] = hinges_x4_and_scalar(&[healthy; 4], &[vel; 4], [theta0[0]; 4]);
        assert_eq!(bits(&simd)[..1], bits(&beside_healthy)[..1]);
        assert_eq!(simd.1[..12], beside_healthy.1[..12]);
        assert_eq!(simd.2[..12], beside_healthy.2[..12]);
        assert!(simd.0[0] > 0.0);
    }
}

mod model {
    use largestep::cloth::*;
    use largestep::integrate::*;
    use largestep::simulation::{MechModel, MechSimulation};
    use largestep::sparse::Bsr3;

    fn material() -> ClothMaterial {
        ClothMaterial {
            density: 0.2,
            stretch: 500.0,
            shear: 50.0,
            bend: 0.05,
            stretch_damping: 0.5,
            shear_damping: 0.1,
            bend_damping: 0.001,
            rest_stretch: [1.0, 1.0],
        }
    }

    fn sheet(nu: usize, nv: usize) -> ClothDesc {
        cloth_grid(&ClothGridOptions {
            nu,
            nv,
            size: [1.0, 0.8],
            origin: [0.0, 1.0, 0.0],
            u_axis: [1.0, 0.0, 0.0],
            v_axis: [0.0, 0.0, 1.0],
            material: material(),
        })
    }

    fn deformed(nu: usize, nv: usize) -> ClothDesc {
        let mut d = sheet(nu, nv);
        // Exact Jacobians are checked without the definiteness projection.
        d.definiteness_fix = false;
        for (i, p) in d.positions.iter_mut().enumerate() {
            let s = (i * 7919 % 97) as f64 / 97.0 - 0.5;
            p[0] += 0.05 * s;
            p[1] += 0.1 * (3.0 * p[0]).sin() + 0.03 * s;
            p[2] -= 0.04 * s * s;
        }
        d.velocities = d
            .positions
            .iter()
            .map(|p| [p[2], -0.3 * p[0], 0.2])
            .collect();
        d
    }

    #[test]
    fn bend_damping_alone_gives_a_velocity_jacobian_proportional_to_the_stiffness() {
        // Projected hinges only (no stretch or shear, so the triangles write no df/dv):
        // df/dx = -k sum w g g^T and df/dv = -k_d sum w g g^T, so df/dv = (k_d / k) df/dx,
        // whatever the matrix held before.
        let mut d = deformed(4, 3);
        d.definiteness_fix = true;
        d.material.stretch = 0.0;
        d.material.shear = 0.0;
        d.material.stretch_damping = 0.0;
        d.material.shear_damping = 0.0;
        let (k, kd) = (d.material.bend, d.material.bend_damping);
        let (c, st) = d.build().unwrap();
        let n = c.vertex_count();
        let mut w = c.work();
        let pattern = c.prepare_jacobians(&mut w).unwrap().unwrap();
        let (mut kx, mut kv) = (Bsr3::zeros(pattern.clone()), Bsr3::zeros(pattern));
        kv.values_mut().fill(f64::NAN);
        let mut f = vec![0.0; 3 * n];
        let (x, v) = (st.x.as_slice(), st.v.as_slice());
        c.force_jacobians(&mut w, 0.0, x, v, &mut f, &mut kx, Some(&mut kv))
            .unwrap();
        let scale = kx.values().iter().fold(0.0f64, |m, a| m.max(a.abs()));
        assert!(scale > 0.0);
        for (a, b) in kx.values().iter().zip(kv.values()) {
            assert!(
                (a * kd / k - b).abs() <= 1e-12 * scale,
                "{b} against {}",
                a * kd / k
            );
        }
    }

    #[test]
    fn assembled_jacobians_match_finite_differences_and_are_symmetric() {
        let (c, st) = deformed(4, 3).build().unwrap();
        let n = c.vertex_count();
        assert!(!c.hinges().is_empty());
        let mut w = c.work();
        let pattern = c.prepare_jacobians(&mut w).unwrap().unwrap();
        let (mut kx, mut kv) = (Bsr3::zeros(pattern.clone()), Bsr3::zeros(pattern));
        let (x, v) = (st.x.as_slice().to_vec(), st.v.as_slice().to_vec());
        let mut f = vec![0.0; 3 * n];
        c.force_jacobians(&mut w, 0.0, &x, &v, &mut f, &mut kx, Some(&mut kv))
            .unwrap();
        let mut f2 = vec![0.0; 3 * n];
        c.force(&mut w, 0.0, &x, &v, &mut f2);
        for (a, b) in f.iter().zip(&f2) {
            assert!((a - b).abs() < 1e-12 * (1.0 + a.abs()), "force paths agree");
        }
        assert!(kx.max_asymmetry() < 1e-9, "{}", kx.max_asymmetry());
        let (dx, dv) = (kx.to_dense(), kv.to_dense());
        let h = 1e-7;
        for col in 0..3 * n {
            for (which, dense) in [(0, &dx), (1, &dv)] {
                let (mut xp, mut xm, mut vp, mut vm) = (x.clone(), x.clone(), v.clone(), v.clone());
                if which == 0 {
                    xp[col] += h;
                    xm[col] -= h;
                } else {
                    vp[col] += h;
                    vm[col] -= h;
                }
                let (mut fp, mut fm) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
                c.force(&mut w, 0.0, &xp, &vp, &mut fp);
                c.force(&mut w, 0.0, &xm, &vm, &mut fm);
                for row in 0..3 * n {
                    let fd = (fp[row] - fm[row]) / (2.0 * h);
                    let an = dense[row * 3 * n + col];
                    // Damping forces depend on positions too; that derivative is left out
                    // (BW98 5.2), so df/dx is checked with the velocities' share removed
                    // below instead.
                    if which == 1 {
                        assert!(
                            (fd - an).abs() < 1e-5 * (1.0 + an.abs()),
                            "df/dv [{row},{col}] fd {fd} vs {an}"
                        );
                    }
                }
            }
        }
        // df/dx on the undamped cloth, exact.
        let mut und = deformed(4, 3);
        und.material.stretch_damping = 0.0;
        und.material.shear_damping = 0.0;
        und.material.bend_damping = 0.0;
        let (c, _) = und.build().unwrap();
        let mut w = c.work();
        let pattern = c.prepare_jacobians(&mut w).unwrap().unwrap();
        let mut kx = Bsr3::zeros(pattern);
        c.force_jacobians(&mut w, 0.0, &x, &v, &mut f, &mut kx, None)
            .unwrap();
        let dx = kx.to_dense();
        for col in 0..3 * n {
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[col] += h;
            xm[col] -= h;
            let (mut fp, mut fm) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            c.force(&mut w, 0.0, &xp, &v, &mut fp);
            c.force(&mut w, 0.0, &xm, &v, &mut fm);
            for row in 0..3 * n {
                let fd = (fp[row] - fm[row]) / (2.0 * h);
                let an = dx[row * 3 * n + col];
                assert!(
                    (fd - an).abs() < 1e-4 * (1.0 + an.abs()),
                    "df/dx [{row},{col}] fd {fd} vs {an}"
                );
            }
        }
    }

    #[test]
    fn internal_forces_sum_to_zero_and_threads_do_not_matter() {
        let (c, st) = deformed(6, 5).build().unwrap();
        let n = c.vertex_count();
        let mut f = vec![0.0; 3 * n];
        let mut w = c.work();
        c.force(&mut w, 0.0, st.x.as_slice(), st.v.as_slice(), &mut f);
        let scale: f64 = f.iter().map(|x| x.abs()).sum();
        for comp in 0..3 {
            let s: f64 = f[comp * n..(comp + 1) * n].iter().sum();
            assert!(s.abs() < 1e-12 * scale, "net force {s}");
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let mut f3 = vec![0.0; 3 * n];
        pool.install(|| c.force(&mut w, 0.0, st.x.as_slice(), st.v.as_slice(), &mut f3));
        assert_eq!(f, f3);
    }

    #[test]
    fn hanging_sheet_keeps_pins_and_does_not_gain_energy_with_implicit_steps() {
        let mut d = sheet(10, 10);
        d.material.stretch_damping = 0.0;
        d.material.shear_damping = 0.0;
        d.material.bend_damping = 0.0;
        // Hung in the x-y plane from its two top corners (vertices 0 and 9, at y = 1).
        d = ClothDesc {
            positions: d
                .positions
                .iter()
                .map(|p| [p[0], 1.0 - p[2], 0.0])
                .collect(),
            ..d
        };
        d.gravity = [0.0, -9.81, 0.0];
        d.pinned = vec![0, 9];
        let pinned: Vec<[f64; 3]> = d.pinned.iter().map(|&p| d.positions[p]).collect();
        let (c, st) = d.build().unwrap();
        let settings = MechSettings::new(Method::LinearizedBackwardEuler);
        let mut sim = MechSimulation::new(c, st, settings).unwrap();
        sim.set_step_control(None); // every step at dt
        let energy = |c: &Cloth, st: &ClothState| {
            kinetic_energy(c.mass(), st.v.as_slice())
                + c.potential_energy(0.0, st.x.as_slice()).unwrap()
        };
        let mut e_prev = energy(sim.model(), sim.state());
        let dt = 1.0 / 60.0;
        for k in 0..60 {
            sim.step(dt).unwrap();
            let (c, st) = (sim.model(), sim.state());
            let e = energy(c, st);
            assert!(
                e <= e_prev + 1e-9 * e_prev.abs().max(1.0),
                "step {k}: energy {e} > {e_prev}"
            );
            e_prev = e;
            for (i, &p) in [0usize, 9].iter().enumerate() {
                assert_eq!(st.x.get(p), pinned[i], "pinned vertex {p} moved");
            }
        }
        // It hangs: the free top edge between the pins sags, and so does the bottom edge.
        let st = sim.state();
        assert!(st.x.get(5)[1] < 1.0 - 0.01, "{:?}", st.x.get(5));
        assert!(st.x.get(95)[1] < 0.2 - 0.005, "{:?}", st.x.get(95));
    }

    #[test]
    fn bad_cloth_input_names_the_element() {
        let mut d = sheet(3, 3);
        d.uv[4] = d.uv[0];
        let e = d.build().unwrap_err().to_string();
        assert!(
            e.starts_with("triangle ") && e.contains("zero rest (u, v) area"),
            "{e}"
        );
        let mut d = sheet(3, 3);
        d.triangles.push([0, 1, 4]);
        d.triangles.push([0, 1, 5]);
        let e = d.build().unwrap_err().to_string();
        assert!(
            e.contains("edge (0, 1)") && e.contains("at most two"),
            "{e}"
        );
        let mut d = sheet(3, 3);
        d.material.stretch = f64::NAN;
        assert!(d.build().unwrap_err().to_string().contains("stretch = NaN"));
        let mut d = sheet(3, 3);
        d.triangles[2] = [0, 1, 42];
        assert!(d
            .build()
            .unwrap_err()
            .to_string()
            .contains("triangle 2 names vertex 42"));
        let mut d = sheet(3, 3);
        d.positions[3][1] = f64::INFINITY;
        assert!(d
            .build()
            .unwrap_err()
            .to_string()
            .contains("vertex 3: y = inf"));
    }
}

mod scene {
    use largestep::scene::Scene;

    const SHEET: &str = r#"
[scene]
dt = 0.016
duration = 0.1
integrator = "linearized-backward-euler"
gravity = [0.0, -9.81, 0.0]

[cloth]
pinned = [0, 3]

[cloth.grid]
nu = 4
nv = 4
size = [1.0, 1.0]

[cloth.material]
density = 0.2
stretch = 1000.0
shear = 100.0
bend = 0.01
"#;

    #[test]
    fn cloth_tables_are_validated_with_lines() {
        assert!(Scene::parse(SHEET, "ok.toml").is_ok());
        let cases = [
            (SHEET.replace("nu = 4", "nu = 1"), "nu = 1", "cloth.grid.nu"),
            (SHEET.replace("pinned = [0, 3]", "pinned = [0, 16]"), "pinned =", "vertex 16 does not exist"),
            (SHEET.replace("density = 0.2", "density = 0.0"), "density = 0.0", "cloth.material.density"),
            (SHEET.replace("stretch = 1000.0", "stretch = nan"), "stretch = nan", "cloth.material.stretch"),
            (SHEET.replace("bend = 0.01", "bend = 0.01\nwrinkle = 1.0"), "wrinkle", "unknown field `wrinkle`"),
            (
                SHEET.replace("[cloth.grid]", "[[cloth.capsule]]\na = [0.0, 0.0, 0.0]\nb = [1.0, 0.0, 0.0]\nradius = -0.1\n[cloth.grid]"),
                "radius = -0.1",
                "radius = -0.1 is invalid",
            ),
            (
                SHEET.replace("[cloth.grid]", "[[cloth.box]]\nmin = [0.0, 0.0, 0.0]\nmax = [1.0, 0.0, 1.0]\n[cloth.grid]"),
                "max = [1.0, 0.0, 1.0]",
                "must be above min",
            ),
            (
                SHEET.replace("[cloth.grid]", "[[cloth.plane]]\npoint = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 0.0]\n[cloth.grid]"),
                "normal = [0.0, 0.0, 0.0]",
                "must not be zero",
            ),
            (
                SHEET.replace("[cloth.grid]", "[[cloth.sdf]]\nfile = \"no-such.sdf\"\n[cloth.grid]"),
                "no-such.sdf",
                "no-such.sdf",
            ),
            (
                SHEET.replace("[cloth.grid]", "[cloth.wind]\nvelocity = [1.0, 0.0, 0.0]\ndrag = -1.0\n[cloth.grid]"),
                "drag = -1.0",
                "cloth.wind.drag",
            ),
            (
                SHEET.replace("[cloth.grid]", "[[cloth.path]]\nvertices = [1]\ntimes = [0.0, 0.0]\noffsets = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\n[cloth.grid]"),
                "times = [0.0, 0.0]",
                "increasing",
            ),
            (
                SHEET.replace("[cloth.grid]", "[[cloth.path]]\nvertices = [99]\ntimes = [0.0]\noffsets = [[0.0, 0.0, 0.0]]\n[cloth.grid]"),
                "vertices = [99]",
                "vertex 99 does not exist",
            ),
            (
                SHEET.replace("[cloth.grid]", "[cloth.step_control]\nmax_strain_change = 0.0\n[cloth.grid]"),
                "max_strain_change = 0.0",
                "max_strain_change must be",
            ),
            // A cloth and a mass-spring system may share a scene (tests/scene.rs); a table
            // no domain owns is an error at its line.
            (
                format!("{SHEET}\n[jello]\nn = 8\n"),
                "[jello]",
                "unknown table `jello`",
            ),
        ];
        for (text, needle, words) in cases {
            let e = Scene::parse(&text, "bad.toml").unwrap_err().to_string();
            let line = text.lines().position(|l| l.contains(needle)).unwrap() + 1;
            assert!(
                e.starts_with(&format!("bad.toml:{line}:")) && e.contains(words),
                "{e}"
            );
        }
    }
}

#[test]
fn definiteness_fix_makes_the_assembled_stiffness_negative_semidefinite() {
    use largestep::cloth::*;
    use largestep::simulation::MechModel;
    use largestep::sparse::Bsr3;
    let mut d = cloth_grid(&ClothGridOptions {
        nu: 4,
        nv: 4,
        size: [1.0, 1.0],
        origin: [0.0; 3],
        u_axis: [1.0, 0.0, 0.0],
        v_axis: [0.0, 0.0, 1.0],
        material: ClothMaterial {
            density: 0.2,
            stretch: 500.0,
            shear: 50.0,
            bend: 0.05,
            stretch_damping: 0.0,
            shear_damping: 0.0,
            bend_damping: 0.0,
            rest_stretch: [1.0, 1.0],
        },
    });
    // Compress and crumple it: without the fix the stiffness has positive eigenvalues.
    for (i, p) in d.positions.iter_mut().enumerate() {
        p[0] *= 0.7;
        p[1] += 0.15 * ((i * 37 % 11) as f64 / 11.0 - 0.5);
    }
    let eig_max = |fix: bool| {
        let mut d = d.clone();
        d.definiteness_fix = fix;
        let (c, st) = d.build().unwrap();
        let n = c.vertex_count();
        let mut w = c.work();
        let mut kx = Bsr3::zeros(c.prepare_jacobians(&mut w).unwrap().unwrap());
        let mut f = vec![0.0; 3 * n];
        let (x, v) = (st.x.as_slice().to_vec(), st.v.as_slice().to_vec());
        c.force_jacobians(&mut w, 0.0, &x, &v, &mut f, &mut kx, None)
            .unwrap();
        let dense = nalgebra::DMatrix::from_row_slice(3 * n, 3 * n, &kx.to_dense());
        dense.symmetric_eigen().eigenvalues.max()
    };
    assert!(
        eig_max(false) > 1e-3,
        "the crumpled sheet should be indefinite without the fix"
    );
    assert!(
        eig_max(true) < 1e-9,
        "largest eigenvalue with the fix: {}",
        eig_max(true)
    );
}

#[test]
fn draped_sheet_stays_outside_the_sphere() {
    use largestep::scene::{Runner, Scene};
    use largestep::simulation::MechSimulation;
    let text = r#"
[scene]
dt = 0.016666666666666666
duration = 1.5
integrator = "linearized-backward-euler"
gravity = [0.0, -9.81, 0.0]

[cloth]
friction = 0.4

[[cloth.sphere]]
center = [0.0, 0.0, 0.0]
radius = 0.5

[cloth.grid]
nu = 14
nv = 14
size = [1.6, 1.6]
origin = [-0.8, 0.6, -0.8]

[cloth.material]
density = 0.2
stretch = 2000.0
shear = 200.0
bend = 0.0002
stretch_damping = 0.2
shear_damping = 0.02
"#;
    let scene = Scene::parse(text, "drape.toml").unwrap();
    let out = std::env::temp_dir().join(format!("largestep-drape-{}", std::process::id()));
    let mut runner = Runner::new(scene, &out);
    runner.run(None, &mut |_| {}).unwrap();
    // Every frame's deepest penetration into the sphere (the CSV's penetration column):
    // contacts are corrected after each step, so vertices sit on the surface plus the
    // contact thickness; the bound is a rounding allowance.
    let worst = runner
        .records()
        .iter()
        .map(|r| r.penetration)
        .fold(0.0f64, f64::max);
    assert!(worst < 1e-9, "deepest penetration {worst} m");
    // It drapes: the sheet's corners fell below the sphere's centre.
    let sim = runner.simulation();
    let sim = sim
        .downcast_ref::<MechSimulation<largestep::cloth::Cloth>>()
        .unwrap();
    let y = sim.state().x.y();
    assert!(
        y[0] < 0.0 && y[13] < 0.0,
        "corners at {} and {}",
        y[0],
        y[13]
    );
    // And rests on top: the middle vertex is on the sphere's surface.
    let mid = sim.state().x.get(7 * 14 + 7);
    let r = (mid[0] * mid[0] + mid[1] * mid[1] + mid[2] * mid[2]).sqrt();
    assert!((r - 0.5).abs() < 0.02, "middle vertex at distance {r}");
}

mod obstacles {
    use largestep::collide::{Obstacle, SdfGrid};
    use largestep::kernels::interp::Grid3;
    use std::sync::Arc;

    fn shapes() -> Vec<Obstacle> {
        vec![
            Obstacle::plane_through([0.0, 0.1, 0.0], [0.0, 2.0, 0.0]).unwrap(),
            Obstacle::Sphere {
                center: [0.1, 0.0, -0.1],
                radius: 0.4,
            },
            Obstacle::Box {
                min: [-0.3, -0.2, -0.4],
                max: [0.3, 0.25, 0.2],
            },
            Obstacle::Capsule {
                a: [-0.3, 0.0, 0.0],
                b: [0.3, 0.1, 0.0],
                radius: 0.2,
            },
        ]
    }

    fn points() -> Vec<[f64; 3]> {
        (0..200)
            .map(|i| {
                let f = |k: usize| ((i * k) % 97) as f64 / 97.0 - 0.5;
                [1.4 * f(13), 1.4 * f(31), 1.4 * f(57)]
            })
            .collect()
    }

    #[test]
    fn analytic_distances_have_unit_gradients_equal_to_their_normals() {
        for o in shapes() {
            for p in points() {
                let Some((d, n)) = o.distance(p) else {
                    continue;
                };
                // The normal is the distance's gradient (central differences), away from
                // the box's medial planes where it jumps.
                let h = 1e-6;
                let g: [f64; 3] = std::array::from_fn(|c| {
                    let (mut a, mut b) = (p, p);
                    a[c] += h;
                    b[c] -= h;
                    (o.distance(a).unwrap().0 - o.distance(b).unwrap().0) / (2.0 * h)
                });
                let err = (0..3).map(|c| (g[c] - n[c]).abs()).fold(0.0, f64::max);
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                assert!(
                    (len - 1.0).abs() < 1e-12,
                    "{} normal length {len}",
                    o.kind()
                );
                let medial = matches!(o, Obstacle::Box { .. }) && d < 0.0;
                assert!(
                    medial || err < 1e-6,
                    "{} at {p:?}: gradient {g:?} normal {n:?}",
                    o.kind()
                );
            }
        }
    }

    #[test]
    fn a_sampled_sphere_grid_approximates_the_sphere() {
        let sphere = Obstacle::Sphere {
            center: [0.0; 3],
            radius: 0.5,
        };
        let grid = Grid3::spanning([41; 3], [-1.0; 3], [1.0; 3]); // h = 0.05
        let sdf = Obstacle::Sdf(Arc::new(SdfGrid::sample(grid, |p| {
            (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.5
        })));
        let mut worst_d = 0.0f64;
        let mut worst_n = 0.0f64;
        for p in points() {
            let (Some((d0, n0)), Some((d1, n1))) = (sphere.distance(p), sdf.distance(p)) else {
                continue;
            };
            if d0.abs() > 0.3 {
                continue; // near the surface is what contacts use
            }
            worst_d = worst_d.max((d0 - d1).abs());
            worst_n = worst_n.max((0..3).map(|c| (n0[c] - n1[c]).abs()).fold(0.0, f64::max));
        }
        // Trilinear interpolation of a smooth distance: error O(h^2 / r) = 5e-3 m; the
        // gradient is first order in h.
        assert!(worst_d < 5e-3, "distance error {worst_d}");
        assert!(worst_n < 0.1, "normal error {worst_n}");
        // Outside the grid: no contact.
        assert!(sdf.distance([2.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn sdfgen_files_are_read_and_errors_name_the_line() {
        let text = "2 2 2\n0 0 0\n0.5\n-1 -1 -1 -1\n1 1 1 1\n";
        let s = SdfGrid::parse(text, "t.sdf").unwrap();
        assert_eq!(s.grid.n, [2, 2, 2]);
        assert_eq!(s.phi[4], 1.0);
        let (d, n) = Obstacle::Sdf(Arc::new(s))
            .distance([0.25, 0.25, 0.25])
            .unwrap();
        assert!(d.abs() < 1e-12 && (n[2] - 1.0).abs() < 1e-12, "{d} {n:?}");
        for (bad, line, what) in [
            ("2 2 x\n0 0 0\n0.5\n", 1, "expected a number"),
            ("2 2 2\n0 0 0\n-0.5\n", 3, "spacing"),
            ("2 2 2\n0 0 0\n0.5\n1 1 1\n1 1\n", 5, "ends early"),
            (
                "2 2 2\n0 0 0\n0.5\n1 1 1 1\n1 1 1 nan\n",
                5,
                "must be finite",
            ),
            ("2 2 2\n0 0 0\n0.5\n1 1 1 1\n1 1 1 1\n7\n", 6, "unexpected"),
            ("1 2 2\n0 0 0\n0.5\n", 1, "grid size"),
        ] {
            let e = SdfGrid::parse(bad, "t.sdf").unwrap_err();
            assert_eq!(e.line, line, "{bad:?}: {e}");
            assert!(e.to_string().contains(what), "{bad:?}: {e}");
        }
    }
}

mod scenes {
    use largestep::cloth::Cloth;
    use largestep::integrate::MechState;
    use largestep::scene::{Runner, Scene};
    use largestep::simulation::{MechSimulation, Simulation};

    type ClothSim = MechSimulation<Cloth>;

    /// The cloth simulation of a run's scene.
    fn cloth_sim(r: &Runner) -> &ClothSim {
        r.simulation().downcast_ref().expect("a cloth scene")
    }

    /// The state of a run's cloth.
    fn state(r: &Runner) -> &MechState {
        cloth_sim(r).state()
    }

    /// The scene's one simulation and its dt.
    fn simulation(scene: Scene) -> (Box<dyn Simulation>, f64) {
        let dt = scene.dt;
        (scene.into_simulation().expect("one system"), dt)
    }

    fn as_cloth(sim: &dyn Simulation) -> &ClothSim {
        sim.downcast_ref().expect("a cloth scene")
    }

    const MATERIAL: &str = r#"
[cloth.material]
density = 0.2
stretch = 2000.0
shear = 200.0
bend = 0.0002
stretch_damping = 0.2
shear_damping = 0.02
"#;

    fn run(text: &str, name: &str) -> Runner {
        let scene = Scene::parse(text, name).unwrap();
        let out = std::env::temp_dir().join(format!(
            "largestep-cloth-{}-{}",
            name.replace('.', "-"),
            std::process::id()
        ));
        let mut runner = Runner::new(scene, &out);
        runner.run(None, &mut |_| {}).unwrap();
        runner
    }

    fn sheet(extra: &str, duration: f64) -> String {
        format!(
            r#"
[scene]
dt = 0.016666666666666666
duration = {duration}
integrator = "linearized-backward-euler"
gravity = [0.0, -9.81, 0.0]
[output]
frames = "none"
every = 1
[cloth]
friction = 0.3
{extra}
[cloth.grid]
nu = 12
nv = 12
size = [1.0, 1.0]
origin = [-0.5, 0.5, -0.5]
{MATERIAL}"#
        )
    }

    #[test]
    fn the_tablecloth_keeps_its_energy_and_the_table_edges_under_it() {
        // The shipped scene through the moment the cloth meets the table (t = 0.2 s) and
        // its settling. Energy: gravity's potential plus the cloth's elastic and kinetic
        // energy may only fall (damping, friction, inelastic contact); before speculative
        // contacts and edge contacts it went from 7.55 J to 18.7 J at the impact.
        use largestep::collide::{edge_through_triangle, Obstacle, CONTACT_THICKNESS};
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/tablecloth.toml");
        let (mut sim, dt) = simulation(Scene::load(&path).unwrap());
        let e0 = as_cloth(&*sim).energy();
        let (start, mut highest) = (e0.kinetic + e0.potential, f64::NEG_INFINITY);
        for _ in 0..(0.8 / dt).round() as usize {
            sim.step(dt).unwrap();
            let e = as_cloth(&*sim).energy();
            highest = highest.max(e.kinetic + e.potential);
        }
        assert!(
            highest <= start * (1.0 + 1e-6),
            "energy rose from {start} J to {highest} J"
        );
        // No table edge comes through a triangle: every edge point over a triangle lies
        // under it (away from the outside, where the box's normals at the triangle's
        // vertices point), at least half the contact thickness down.
        let cloth = as_cloth(&*sim);
        let model = cloth.model();
        let table = model
            .obstacles()
            .iter()
            .find(|o| matches!(o, Obstacle::Box { .. }))
            .expect("the table");
        let x = &cloth.state().x;
        let mut worst = f64::NEG_INFINITY;
        let mut checked = 0;
        for tri in model.triangles() {
            let t = tri.map(|i| x.get(i as usize));
            let e1: [f64; 3] = std::array::from_fn(|k| t[1][k] - t[0][k]);
            let e2: [f64; 3] = std::array::from_fn(|k| t[2][k] - t[0][k]);
            let c = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            let len = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
            let mut n = c.map(|v| v / len);
            // Outside is where the box's normals at the vertices point.
            let out: f64 = t
                .iter()
                .filter_map(|&p| table.distance(p))
                .map(|(_, m)| (0..3).map(|k| m[k] * n[k]).sum::<f64>())
                .sum();
            if out < 0.0 {
                n = n.map(|v| -v);
            }
            for (a, b) in table.sharp_edges() {
                let e: [f64; 3] = std::array::from_fn(|k| b[k] - a[k]);
                let el = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
                let along = ((0..3).map(|k| e[k] * n[k]).sum::<f64>() / el).abs();
                if along > 0.5 {
                    continue; // an edge standing across the triangle, not under it
                }
                if let Some((height, _)) = edge_through_triangle(t, n, a, b) {
                    if height > -0.2 {
                        worst = worst.max(height);
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 50, "{checked} triangles over the table's edges");
        assert!(
            worst <= -0.5 * CONTACT_THICKNESS,
            "a table edge is {worst} m through the cloth"
        );
    }

    #[test]
    fn no_vertex_ends_inside_any_obstacle() {
        // Every obstacle kind under a falling sheet. Analytic shapes: contacts put
        // vertices on the surface plus the contact thickness, so the bound is rounding.
        // The distance grid (h = 0.05 m) is held to its interpolation error instead.
        let sdf_file =
            std::env::temp_dir().join(format!("largestep-ball-{}.sdf", std::process::id()));
        let mut text = String::from("41 41 41\n-1 -1 -1\n0.05\n");
        for k in 0..41 {
            for j in 0..41 {
                for i in 0..41 {
                    let p = [i, j, k].map(|a| -1.0 + 0.05 * a as f64);
                    let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.3;
                    text.push_str(&format!("{d} "));
                }
            }
            text.push('\n');
        }
        std::fs::write(&sdf_file, text).unwrap();
        let cases = [
            (
                "plane",
                "[[cloth.plane]]\npoint = [0.0, 0.2, 0.0]\nnormal = [0.0, 1.0, 0.1]",
                1e-9,
            ),
            (
                "sphere",
                "[[cloth.sphere]]\ncenter = [0.0, 0.0, 0.0]\nradius = 0.3",
                1e-9,
            ),
            (
                "box",
                "[[cloth.box]]\nmin = [-0.25, -1.0, -0.25]\nmax = [0.25, 0.2, 0.25]",
                1e-9,
            ),
            (
                "capsule",
                "[[cloth.capsule]]\na = [-0.3, 0.1, 0.0]\nb = [0.3, 0.1, 0.0]\nradius = 0.15",
                1e-9,
            ),
            (
                "sdf",
                &format!("[[cloth.sdf]]\nfile = {:?}", sdf_file.display().to_string()),
                // Contacts push to the interpolated surface: the true ball may be off by
                // the interpolation error, O(h^2 / r) ~ 4e-3 m.
                5e-3,
            ),
        ];
        for (name, table, bound) in cases {
            let r = run(&sheet(table, 1.0), &format!("{name}.toml"));
            let worst = r
                .records()
                .iter()
                .map(|r| r.penetration)
                .fold(0.0f64, f64::max);
            let true_worst = if name == "sdf" {
                let x = &state(&r).x;
                (0..x.len())
                    .map(|i| {
                        let p = x.get(i);
                        0.3 - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
                    })
                    .fold(0.0f64, f64::max)
            } else {
                worst
            };
            assert!(
                worst <= bound && true_worst <= bound,
                "{name}: penetration {worst} (true {true_worst})"
            );
            // And the sheet did touch it: something rests on the obstacle.
            let y_mid = state(&r).x.get(6 * 12 + 6)[1];
            assert!(
                y_mid < 0.5 - 0.05,
                "{name}: the sheet did not fall ({y_mid})"
            );
        }
        let _ = std::fs::remove_file(sdf_file);
    }

    #[test]
    fn path_vertices_follow_their_path_exactly() {
        let path = "[[cloth.path]]\nvertices = [0, 11]\ntimes = [0.0, 0.5]\noffsets = [[0.0, 0.0, 0.0], [0.0, 0.3, 0.2]]";
        let scene = Scene::parse(&sheet(path, 0.7), "path.toml").unwrap();
        let out = std::env::temp_dir().join(format!("largestep-path-{}", std::process::id()));
        let mut r = Runner::new(scene, &out);
        let p0 = [state(&r).x.get(0), state(&r).x.get(11)];
        let mut checked = 0;
        r.run(None, &mut |_| {}).unwrap();
        // At the end (t = 0.7 > 0.5) they hold the last offset.
        for (k, &i) in [0usize, 11].iter().enumerate() {
            let p = state(&r).x.get(i);
            let want = [p0[k][0], p0[k][1] + 0.3, p0[k][2] + 0.2];
            for c in 0..3 {
                assert!(
                    (p[c] - want[c]).abs() < 1e-12,
                    "vertex {i}: {p:?} vs {want:?}"
                );
            }
            checked += 1;
        }
        assert_eq!(checked, 2);
        // Mid-path, step by step.
        let scene = Scene::parse(&sheet(path, 0.7), "path.toml").unwrap();
        let (mut sim, dt) = simulation(scene);
        for _ in 0..15 {
            sim.step(dt).unwrap();
            let s = (sim.time() / 0.5).min(1.0);
            let p = as_cloth(&*sim).state().x.get(11);
            assert!(
                (p[1] - (p0[1][1] + 0.3 * s)).abs() < 1e-12,
                "t = {}: {p:?}",
                sim.time()
            );
        }
    }

    #[test]
    fn wind_blows_the_sheet_downwind() {
        let hang = "pinned = [132, 143]";
        let base = sheet(hang, 1.0).replace("friction = 0.3\n", "");
        let windy = base.replace(
            "pinned = [132, 143]",
            "pinned = [132, 143]\n[cloth.wind]\nvelocity = [0.0, 0.0, 4.0]\ndrag = 1.0",
        );
        let still = run(&base, "still.toml");
        let blown = run(&windy, "windy.toml");
        let mean_z = |r: &Runner| {
            let x = &state(r).x;
            x.z().iter().sum::<f64>() / x.len() as f64
        };
        assert!(
            mean_z(&blown) > mean_z(&still) + 0.05,
            "wind {} vs still {}",
            mean_z(&blown),
            mean_z(&still)
        );
    }

    #[test]
    fn scenes_choose_the_multigrid_preconditioner() {
        // The same sheet with PCG and multigrid, and with Cholesky: the same motion.
        let solver =
            "[solver]\nlinear = \"pcg\"\ntolerance = 1e-9\npreconditioner = \"multigrid\"\n";
        let base = sheet("pinned = [132, 143]", 0.3);
        let mg = run(
            &base.replace("[output]", &format!("{solver}[output]")),
            "mg.toml",
        );
        let chol = run(
            &base.replace("[output]", "[solver]\nlinear = \"cholesky\"\n[output]"),
            "chol.toml",
        );
        let (a, b) = (state(&mg).x.y(), state(&chol).x.y());
        let diff = a
            .iter()
            .zip(b)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        assert!(diff < 1e-6, "multigrid and Cholesky differ by {diff} m");
        // An unknown name lists the choices, at its key.
        let bad = base.replace(
            "[output]",
            "[solver]\nlinear = \"pcg\"\npreconditioner = \"amg\"\n[output]",
        );
        let e = Scene::parse(&bad, "bad.toml").unwrap_err().to_string();
        assert!(
            e.contains("preconditioner") && e.contains("multigrid"),
            "{e}"
        );
    }

    #[test]
    fn step_control_halves_failing_steps_and_reports_when_it_gives_up() {
        // A stiff sheet at a huge step with a PCG cap too small to converge: every try
        // fails until the step is small enough for warm-started PCG to converge.
        let solver = "[solver]\nlinear = \"pcg\"\ntolerance = 1e-3\nmax_iterations = 60\n";
        let text = sheet("pinned = [132, 143]", 0.5)
            .replace("dt = 0.016666666666666666", "dt = 0.25")
            .replace("[output]", &format!("{solver}[output]"));
        let scene = Scene::parse(&text, "halve.toml").unwrap();
        let (mut sim, dt) = simulation(scene);
        sim.step(dt).unwrap();
        assert!(as_cloth(&*sim).sub_step() < 0.25, "no halving happened");
        assert!(sim.steps() > 1, "{} sub-steps", sim.steps());
        assert!((sim.time() - 0.25).abs() < 1e-12);
        // That step was retried for its strain change (from 0 to 3.1 at dt = 0.25). With no halving
        // allowed and a solver that cannot converge, the step fails, naming the step,
        // the iterations and the residual.
        let text = text
            .replace("max_iterations = 60", "max_iterations = 5")
            .replace(
                "[cloth.grid]",
                "[cloth.step_control]\nmax_halvings = 0\nmax_strain_change = 1e9\n[cloth.grid]",
            );
        let scene = Scene::parse(&text, "halve.toml").unwrap();
        let (mut sim, dt) = simulation(scene);
        let e = sim.step(dt).unwrap_err().to_string();
        assert!(
            e.contains("step 1") && e.contains("5 iterations") && e.contains("residual"),
            "{e}"
        );
    }

    #[test]
    fn obj_meshes_with_texture_coordinates_are_cloth() {
        let dir = std::env::temp_dir().join(format!("largestep-obj-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // A 3 x 3 vertex square, two triangles per cell, texture coordinates in [0, 1].
        let mut obj = String::new();
        for j in 0..3 {
            for i in 0..3 {
                obj.push_str(&format!(
                    "v {} 0.5 {}\nvt {} {}\n",
                    i as f64 * 0.4,
                    j as f64 * 0.4,
                    i as f64 * 0.5,
                    j as f64 * 0.5
                ));
            }
        }
        for j in 0..2 {
            for i in 0..2 {
                let a = 1 + i + 3 * j;
                let (b, c, d) = (a + 1, a + 3, a + 4);
                obj.push_str(&format!(
                    "f {a}/{a} {b}/{b} {d}/{d}\nf {a}/{a} {d}/{d} {c}/{c}\n"
                ));
            }
        }
        std::fs::write(dir.join("sheet.obj"), &obj).unwrap();
        let text = format!(
            "[scene]\ndt = 0.01\nduration = 0.1\nintegrator = \"linearized-backward-euler\"\ngravity = [0.0, -9.81, 0.0]\n[cloth]\npinned = [0]\n[cloth.mesh]\nfile = \"sheet.obj\"\nuv_scale = 0.8\n{MATERIAL}"
        );
        let scene_path = dir.join("mesh.toml");
        std::fs::write(&scene_path, &text).unwrap();
        let scene = Scene::load(&scene_path).unwrap();
        let (mut sim, dt) = simulation(scene);
        // Rest (u, v) = 0.8 * vt equals the positions' spacing: the sheet starts at rest.
        let c = as_cloth(&*sim);
        assert!(c.model().max_strain(c.state().x.as_slice()) < 1e-12);
        sim.step(dt).unwrap();
        // A seam and a missing texture coordinate are errors naming the line.
        let seam = obj.replace("f 1/1 2/2 5/5", "f 1/3 2/2 5/5");
        std::fs::write(dir.join("sheet.obj"), seam).unwrap();
        let e = Scene::load(&scene_path).unwrap_err().to_string();
        assert!(
            e.contains("sheet.obj:") && e.contains("texture seam"),
            "{e}"
        );
        let plain = obj.replace("f 1/1 2/2 5/5", "f 1 2 5");
        std::fs::write(dir.join("sheet.obj"), plain).unwrap();
        let e = Scene::load(&scene_path).unwrap_err().to_string();
        assert!(e.contains("no texture coordinate"), "{e}");
        let _ = std::fs::remove_dir_all(dir);
    }
}

#[test]
fn a_hanging_strip_stretches_by_the_analytic_amount() {
    // A strip of width W and length L hung by its top edge stretches under its own weight
    // by rho g L^2 / (2 k) (k the stretch stiffness per unit area: the stress at height y
    // carries the weight below it, strain rho g (L - y) / k). With linear triangles and
    // lumped masses each row carries the weight below it, and the discrete elongation is
    // the midpoint rule of that linear strain, exact. What remains is the triangulation:
    // its diagonals give the two columns unequal lumped masses, so the strip shears
    // sideways by 8e-5 m and the elongation differs from the analytic one by 4e-4
    // (measured); the bound is 1e-3.
    use largestep::cloth::*;
    use largestep::integrate::*;
    use largestep::simulation::MechSimulation;
    let (w, l, rho, k) = (0.1, 1.0, 0.2, 10.0);
    let nv = 21;
    let mut d = cloth_grid(&ClothGridOptions {
        nu: 2,
        nv,
        size: [w, l],
        origin: [0.0; 3],
        u_axis: [1.0, 0.0, 0.0],
        v_axis: [0.0, -1.0, 0.0], // hangs down from y = 0
        material: ClothMaterial {
            density: rho,
            stretch: k,
            shear: 1.0,
            bend: 0.0,
            stretch_damping: 0.5,
            shear_damping: 0.05,
            bend_damping: 0.0,
            rest_stretch: [1.0, 1.0],
        },
    });
    d.gravity = [0.0, -9.81, 0.0];
    d.pinned = vec![0, 1];
    let (c, st) = d.build().unwrap();
    let mut settings = MechSettings::new(Method::LinearizedBackwardEuler);
    settings.linear = LinearSolverKind::Cholesky;
    let mut sim = MechSimulation::new(c, st, settings).unwrap();
    sim.set_step_control(None);
    let dt = 1.0 / 60.0;
    for _ in 0..600 {
        sim.step(dt).unwrap();
    }
    let st = sim.state();
    let expected = rho * 9.81 * l * l / (2.0 * k); // 0.0981 m
    for col in 0..2 {
        let bottom = st.x.get(2 * (nv - 1) + col);
        let elongation = -bottom[1] - l;
        assert!(
            (elongation - expected).abs() < 1e-3 * expected,
            "column {col}: elongation {elongation} m, analytic {expected} m"
        );
        assert!((bottom[0] - col as f64 * w).abs() < 1e-3 * w, "{bottom:?}");
    }
}

/// Aggregation multigrid (`Preconditioner::Multigrid`) on a draped sheet: the same step
/// as block Jacobi to the solve's tolerance, in a fraction of the iterations (the
/// sheet's stretch stiffness makes block Jacobi slow on the smooth error modes).
#[test]
fn multigrid_gives_the_same_step_as_block_jacobi_in_far_fewer_iterations() {
    use largestep::cloth::{cloth_grid, ClothGridOptions, ClothMaterial};
    use largestep::collide::Obstacle;
    use largestep::integrate::{LinearSolverKind, MechSettings, Method};
    use largestep::simulation::MechSimulation;
    use largestep::solve::{PcgParams, Preconditioner};
    let n = 40;
    let mut d = cloth_grid(&ClothGridOptions {
        nu: n,
        nv: n,
        size: [1.0, 1.0],
        origin: [-0.5, 0.3, -0.5],
        u_axis: [1.0, 0.0, 0.0],
        v_axis: [0.0, 0.0, 1.0],
        material: ClothMaterial {
            density: 0.2,
            stretch: 1000.0,
            shear: 100.0,
            bend: 1e-4,
            stretch_damping: 0.1,
            shear_damping: 0.01,
            bend_damping: 0.0,
            rest_stretch: [1.0, 1.0],
        },
    });
    d.gravity = [0.0, -9.81, 0.0];
    d.pinned = vec![0, n * n - 1];
    d.obstacles = vec![Obstacle::Sphere {
        center: [0.0; 3],
        radius: 0.25,
    }];
    d.friction = 0.3;
    let (cloth, st) = d.build().unwrap();
    let settings = |preconditioner| {
        let mut s = MechSettings::new(Method::LinearizedBackwardEuler);
        s.linear = LinearSolverKind::Pcg(PcgParams {
            tolerance: 1e-8,
            max_iterations: 5000,
            preconditioner,
        });
        s
    };
    let h = 1.0 / 60.0;
    let mut sim = MechSimulation::new(cloth, st, settings(Preconditioner::Multigrid)).unwrap();
    sim.set_step_control(None);
    while sim.time() < 0.4 {
        sim.step(h).unwrap();
    }
    assert!(sim.contact_count() > 10, "draped: {}", sim.contact_count());
    // One step from this state (its contacts too) with each preconditioner, both from a
    // zero guess.
    let mut results = Vec::new();
    for pre in [Preconditioner::BlockJacobi, Preconditioner::Multigrid] {
        let mut s = sim.fork(settings(pre)).unwrap();
        let info = s.step(h).unwrap();
        results.push((info.linear_iterations, s.state().v.as_slice().to_vec()));
    }
    let (bj, mg) = (&results[0], &results[1]);
    assert!(
        3 * mg.0 <= bj.0,
        "multigrid {} iterations against block Jacobi {}",
        mg.0,
        bj.0
    );
    let scale = bj.1.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let diff =
        bj.1.iter()
            .zip(&mg.1)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(
        diff < 1e-5 * scale,
        "velocities differ by {diff} (scale {scale})"
    );
    // The pinned corners stay fixed under both.
    for v in [&bj.1, &mg.1] {
        for &i in &[0, n * n - 1] {
            let nn = n * n;
            assert_eq!([v[i], v[nn + i], v[2 * nn + i]], [0.0; 3]);
        }
    }
}

/// Multigrid on a stiff, light sheet at a large step (stretch 1e5 N/m per unit area, 10
/// g/m^2, dt = 1/30 s: the stiffness-to-mass ratio is 5000 times the draped scenes'):
/// the steps agree with the Cholesky path's.
#[test]
fn multigrid_matches_cholesky_on_a_stiff_light_sheet_at_large_steps() {
    use largestep::cloth::{cloth_grid, ClothGridOptions, ClothMaterial};
    use largestep::integrate::{LinearSolverKind, MechSettings, Method};
    use largestep::simulation::MechSimulation;
    use largestep::solve::{PcgParams, Preconditioner};
    let n = 24;
    let mut d = cloth_grid(&ClothGridOptions {
        nu: n,
        nv: n,
        size: [1.0, 1.0],
        origin: [0.0; 3],
        u_axis: [1.0, 0.0, 0.0],
        v_axis: [0.0, 0.0, 1.0],
        material: ClothMaterial {
            density: 0.01,
            stretch: 1e5,
            shear: 1e4,
            bend: 1e-3,
            stretch_damping: 1.0,
            shear_damping: 0.1,
            bend_damping: 0.0,
            rest_stretch: [1.0, 1.0],
        },
    });
    d.gravity = [0.0, -9.81, 0.0];
    d.pinned = vec![0, n - 1];
    let mut finals = Vec::new();
    for linear in [
        LinearSolverKind::Cholesky,
        LinearSolverKind::Pcg(PcgParams {
            tolerance: 1e-9,
            max_iterations: 5000,
            preconditioner: Preconditioner::Multigrid,
        }),
    ] {
        let (cloth, st) = d.build().unwrap();
        let mut s = MechSettings::new(Method::LinearizedBackwardEuler);
        s.linear = linear;
        let mut sim = MechSimulation::new(cloth, st, s).unwrap();
        sim.set_step_control(None);
        let h = 1.0 / 30.0;
        for _ in 0..15 {
            sim.step(h).unwrap();
        }
        finals.push(sim.state().x.as_slice().to_vec());
    }
    let diff = finals[0]
        .iter()
        .zip(&finals[1])
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    // The sheet swings by about a metre; 1e-6 m is the solve tolerance's reach.
    assert!(diff < 1e-6, "positions differ by {diff} m");
}

/// The model is immutable data: one `Arc<Cloth>` serves two simulations stepped at the
/// same time on two threads, and each moves bitwise as a simulation of its own copy.
#[test]
fn one_shared_model_serves_simultaneous_simulations() {
    use largestep::cloth::{cloth_grid, Cloth, ClothGridOptions, ClothMaterial};
    use largestep::collide::Obstacle;
    use largestep::integrate::{MechSettings, Method};
    use largestep::simulation::MechSimulation;
    use std::sync::Arc;
    fn shareable<T: Send + Sync>() {}
    shareable::<Cloth>();
    let mut d = cloth_grid(&ClothGridOptions {
        nu: 12,
        nv: 12,
        size: [1.0, 1.0],
        origin: [-0.5, 0.3, -0.5],
        u_axis: [1.0, 0.0, 0.0],
        v_axis: [0.0, 0.0, 1.0],
        material: ClothMaterial {
            density: 0.2,
            stretch: 1000.0,
            shear: 100.0,
            bend: 1e-3,
            stretch_damping: 0.1,
            shear_damping: 0.01,
            bend_damping: 0.0,
            rest_stretch: [1.0, 1.0],
        },
    });
    d.gravity = [0.0, -9.81, 0.0];
    d.obstacles = vec![Obstacle::Sphere {
        center: [0.0; 3],
        radius: 0.25,
    }];
    d.friction = 0.3;
    let (cloth, st) = d.build().unwrap();
    let settings = MechSettings::new(Method::LinearizedBackwardEuler);
    let run = |mut sim: MechSimulation<Cloth>, dt: f64| {
        for _ in 0..30 {
            sim.step(dt).unwrap();
        }
        (sim.state().x.as_slice().to_vec(), sim.contact_count())
    };
    let shared = Arc::new(cloth.clone());
    let (a, b) = std::thread::scope(|s| {
        let a = MechSimulation::new(shared.clone(), st.clone(), settings).unwrap();
        let b = MechSimulation::new(shared.clone(), st.clone(), settings).unwrap();
        let ha = s.spawn(move || run(a, 1.0 / 60.0));
        let hb = s.spawn(move || run(b, 1.0 / 120.0));
        (ha.join().unwrap(), hb.join().unwrap())
    });
    let own_a = run(
        MechSimulation::new(cloth.clone(), st.clone(), settings).unwrap(),
        1.0 / 60.0,
    );
    let own_b = run(
        MechSimulation::new(cloth, st, settings).unwrap(),
        1.0 / 120.0,
    );
    assert!(a.1 > 0, "the sheet reached the sphere");
    assert_eq!(a, own_a, "dt = 1/60 from the shared model");
    assert_eq!(b, own_b, "dt = 1/120 from the shared model");
    assert_eq!(Arc::strong_count(&shared), 1);
}

/// The study's report, plot and numbers say what it ran (issue 14: the plot's title said
/// T = 1 s of a 0.2 s study, and `--quick` kept the full sweep's dt range in the legend).
#[cfg(feature = "cli")]
#[test]
fn the_quick_accuracy_study_labels_what_it_ran() {
    let out = std::env::temp_dir().join(format!("largestep-study-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    largestep::study::run(
        "cloth-accuracy",
        &out,
        true,
        &largestep::study::Progress::silent(),
    )
    .unwrap();
    let md = std::fs::read_to_string(out.join("cloth-accuracy.md")).unwrap();
    let json = std::fs::read_to_string(out.join("cloth-accuracy.json")).unwrap();
    let svg = std::fs::read_to_string(out.join("cloth-accuracy.svg")).unwrap();
    for text in [&md, &json, &svg] {
        assert!(
            text.contains("dt from 1/30 to 1/120 s"),
            "the quick sweep's range"
        );
        assert!(
            !text.contains("to 1/480"),
            "no step the quick sweep did not take"
        );
        assert!(text.contains("1e-1 to 1e-3"), "the quick tolerance range");
    }
    assert!(svg.contains("T = 0.2 s") && !svg.contains("T = 1 s"));
}

/// Self contacts enter the implicit solve's filter: a vertex falling onto a still
/// triangle of its own surface is held at the triangle's normal speed; a vertex at rest
/// under a falling triangle is not pushed (its share comes from the impulses after).
#[test]
fn self_contacts_stop_a_vertex_closing_on_its_own_sheet_in_the_filter() {
    use largestep::collide::SelfCollision;
    use largestep::solve::Filter;
    // Two triangles 2 mm apart (thickness 4 mm): the lower one still, the upper falling
    // at 1 m/s. Component-major positions and velocities of 6 vertices.
    let tris: std::sync::Arc<[[u32; 3]]> = vec![[0, 1, 2], [3, 4, 5]].into();
    let corners = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
    let n = 6;
    let mut x = vec![0.0; 3 * n];
    let mut v = vec![0.0; 3 * n];
    for (i, c) in corners
        .iter()
        .chain(&[[0.2, 0.2], [0.5, 0.2], [0.2, 0.5]])
        .enumerate()
    {
        x[i] = c[0];
        x[2 * n + i] = c[1];
        if i >= 3 {
            x[n + i] = 0.002;
            v[n + i] = -1.0;
        }
    }
    let mut sc = SelfCollision::new(tris, 0.004);
    sc.begin(&x, &v, &[1.0; 6], 1.0 / 60.0);
    // The upper triangle's vertices close on the lower triangle (normal up); the lower
    // triangle's vertices lie beyond the upper one's edges.
    let mut held: Vec<u32> = sc.approaches().iter().map(|a| a.vertex).collect();
    held.sort();
    assert_eq!(held, [3, 4, 5]);
    assert!(sc.approaches().iter().all(|a| a.normal[1] > 0.999));
    let mut filter = Filter::new(n);
    sc.constraints(&mut filter);
    for i in 3..6 {
        // Stopped along the normal: the still triangle's speed, 0.
        let got = filter.imposed(i, [0.0, -1.0, 0.0]);
        assert!(got.iter().all(|c| c.abs() < 1e-12), "vertex {i}: {got:?}");
        assert_eq!(
            filter
                .unilateral()
                .iter()
                .filter(|a| a.vertex == i as u32)
                .count(),
            1
        );
    }
    // A vertex already held (a pin, an obstacle contact) keeps its own constraint.
    let mut filter = Filter::new(n);
    filter.fix(4);
    sc.constraints(&mut filter);
    assert_eq!(filter.imposed(4, [0.3, -1.0, 0.2]), [0.0; 3]);
    // The upper vertices at rest, the lower triangle rising onto them: they close, but
    // the solve does not push them (the impulses after the step do).
    for i in 0..3 {
        v[n + i] = 1.0;
        v[n + i + 3] = 0.0;
    }
    sc.begin(&x, &v, &[1.0; 6], 1.0 / 60.0);
    assert_eq!(sc.approaches().len(), 3);
    let mut filter = Filter::new(n);
    sc.constraints(&mut filter);
    assert!(filter.is_empty(), "vertices at rest are not pushed");
    // Both falling, the upper faster: the upper vertices fall with the lower triangle.
    for i in 3..6 {
        v[n + i] = -1.0;
    }
    for i in 0..3 {
        v[n + i] = -0.5;
    }
    sc.begin(&x, &v, &[1.0; 6], 1.0 / 60.0);
    let mut filter = Filter::new(n);
    sc.constraints(&mut filter);
    let got = filter.imposed(3, [0.0, -1.0, 0.0]);
    assert!((got[1] + 0.5).abs() < 1e-12, "{got:?}");
}

/// The two self-collision scenes, smaller: no pair of triangles sharing no vertex crosses
/// after any step; without `[cloth.self_collision]` the same runs end up crossed (the
/// check can fail).
#[test]
fn folding_sheets_never_cross_themselves() {
    use largestep::collide::crossed_triangle_pairs;
    use largestep::scene::Scene;
    use largestep::simulation::FrameData;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    for (file, steps) in [("cloth-fold.toml", 110), ("cloth-pinned-bottom.toml", 130)] {
        let text = std::fs::read_to_string(dir.join(file)).unwrap();
        let small = text
            .replace("nu = 30", "nu = 16")
            .replace("nv = 30", "nv = 16")
            .replace("[870, 899]", "[240, 255]");
        for with in [true, false] {
            let text = if with {
                small.clone()
            } else {
                small.replace("[cloth.self_collision]\nthickness = 0.004\n", "")
            };
            let mut scene = Scene::parse(&text, file).unwrap();
            let dt = scene.dt;
            let sim = &mut scene.systems[0].sim;
            let mut first_crossing = None;
            for step in 0..steps {
                sim.step(dt).unwrap();
                let FrameData::Mesh(m) = sim.frame() else {
                    panic!("a cloth frame is a mesh")
                };
                let crossed = crossed_triangle_pairs(m.triangles, m.positions);
                if !crossed.is_empty() {
                    first_crossing = Some((step, crossed.len()));
                    break;
                }
            }
            if with {
                assert_eq!(first_crossing, None, "{file}: crossed with self-collision");
            } else {
                assert!(
                    first_crossing.is_some(),
                    "{file}: without self-collision the sheet should pass through itself"
                );
                eprintln!("{file} without self-collision: first crossing {first_crossing:?}");
            }
        }
    }
}
