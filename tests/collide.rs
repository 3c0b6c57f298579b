//! Collision detection against brute force: every broad-phase structure returns exactly
//! the pair set of testing every pair (touching, zero-size and duplicate boxes included),
//! queries return what a linear scan returns, bounding volumes hold their points.

use largestep::kernels::collide::bv::{Aabb, Obb, Sphere};
use largestep::kernels::collide::bvh::{Bvh, PairWork, Updated};
use largestep::kernels::collide::grid::{CellGrid, Cells, SweepAndPrune};
use proptest::prelude::*;

/// Boxes on a coarse integer lattice (scaled), so touching faces, zero-size boxes and
/// exact duplicates are common.
fn lattice_boxes(max: usize) -> impl Strategy<Value = Vec<Aabb>> {
    prop::collection::vec(
        (
            0i32..12,
            0i32..12,
            0i32..12,
            0i32..4,
            0i32..4,
            0i32..4,
            any::<bool>(),
        ),
        0..max,
    )
    .prop_flat_map(|v| {
        let boxes: Vec<Aabb> = v
            .into_iter()
            .map(|(x, y, z, a, b, c, dup)| {
                let min = [x as f64 * 0.25, y as f64 * 0.25, z as f64 * 0.25];
                let size = if dup {
                    [0.0, 0.0, 0.0]
                } else {
                    [a as f64 * 0.25, b as f64 * 0.25, c as f64 * 0.25]
                };
                Aabb {
                    min,
                    max: [min[0] + size[0], min[1] + size[1], min[2] + size[2]],
                }
            })
            .collect();
        // Append duplicates of a prefix.
        let k = boxes.len() / 4;
        Just(
            boxes
                .iter()
                .copied()
                .chain(boxes[..k].iter().copied())
                .collect::<Vec<_>>(),
        )
    })
}

/// Boxes with random real coordinates of random size.
fn random_boxes(max: usize) -> impl Strategy<Value = Vec<Aabb>> {
    prop::collection::vec(
        (
            0f64..1.0,
            0f64..1.0,
            0f64..1.0,
            0f64..0.2,
            0f64..0.2,
            0f64..0.2,
        ),
        0..max,
    )
    .prop_map(|v| {
        v.into_iter()
            .map(|(x, y, z, a, b, c)| Aabb {
                min: [x, y, z],
                max: [x + a, y + b, z + c],
            })
            .collect()
    })
}

fn brute_self(b: &[Aabb]) -> Vec<[u32; 2]> {
    let mut out = Vec::new();
    for i in 0..b.len() {
        for j in i + 1..b.len() {
            if b[i].overlaps(&b[j]) {
                out.push([i as u32, j as u32]);
            }
        }
    }
    out
}

fn sorted(mut v: Vec<[u32; 2]>) -> Vec<[u32; 2]> {
    v.sort_unstable();
    v
}

fn check_tree(boxes: &[Aabb], max_leaf: usize) -> Result<(), TestCaseError> {
    let mut bvh = Bvh::new();
    bvh.max_leaf = max_leaf;
    bvh.build(boxes);
    let mut work = PairWork::default();
    let mut pairs = Vec::new();
    bvh.self_pairs(&mut work, &mut pairs);
    let n = pairs.len();
    let pairs = sorted(pairs);
    prop_assert_eq!(&pairs, &brute_self(boxes));
    // Each pair once.
    let mut dedup = pairs.clone();
    dedup.dedup();
    prop_assert_eq!(dedup.len(), n);
    // Every node's bounds hold its subtree's boxes; every primitive is in one leaf.
    let nodes = bvh.nodes();
    let mut seen = vec![0u32; boxes.len()];
    for node in nodes {
        if node.is_leaf() {
            for s in node.first..node.first + node.count {
                let id = bvh.leaf_ids()[s as usize] as usize;
                seen[id] += 1;
                let b = boxes[id];
                let nb = node.aabb();
                prop_assert!((0..3).all(|a| nb.min[a] <= b.min[a] && b.max[a] <= nb.max[a]));
            }
        } else {
            let nb = node.aabb();
            for c in [node.first, node.first + 1] {
                let cb = nodes[c as usize].aabb();
                prop_assert!((0..3).all(|a| nb.min[a] <= cb.min[a] && cb.max[a] <= nb.max[a]));
            }
        }
    }
    prop_assert!(seen.iter().all(|&s| s == 1));
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    #[test]
    fn bvh_self_pairs_equal_brute_force(boxes in lattice_boxes(300), leaf in 1usize..9) {
        check_tree(&boxes, leaf)?;
    }

    #[test]
    fn bvh_self_pairs_equal_brute_force_real(boxes in random_boxes(400)) {
        check_tree(&boxes, 4)?;
    }

    #[test]
    fn bvh_queries_equal_linear_scans(
        boxes in random_boxes(300),
        others in lattice_boxes(100),
        q in (0f64..1.0, 0f64..1.0, 0f64..1.0, 0f64..0.5),
        ray in (-1f64..2.0, -1f64..2.0, -1f64..2.0, -1f64..1.0, -1f64..1.0, -1f64..1.0),
    ) {
        let bvh = Bvh::from_boxes(&boxes);
        // Box overlap.
        let qb = Aabb { min: [q.0, q.1, q.2], max: [q.0 + q.3, q.1 + q.3, q.2 + q.3] };
        let (mut stack, mut got) = (Vec::new(), Vec::new());
        bvh.overlapping(&qb, &mut stack, &mut got);
        got.sort_unstable();
        let want: Vec<u32> = (0..boxes.len() as u32).filter(|&i| boxes[i as usize].overlaps(&qb)).collect();
        prop_assert_eq!(got, want);
        // Tree against tree.
        let other = Bvh::from_boxes(&others);
        let mut work = PairWork::default();
        let mut pairs = Vec::new();
        bvh.pairs_with(&other, &mut work, &mut pairs);
        let mut want = Vec::new();
        for (i, a) in boxes.iter().enumerate() {
            for (j, b) in others.iter().enumerate() {
                if a.overlaps(b) {
                    want.push([i as u32, j as u32]);
                }
            }
        }
        prop_assert_eq!(sorted(pairs), want);
        // Closest box (squared distance to the box itself).
        let p = [q.0, q.1 + 0.3, q.2 - 0.2];
        let mut st = Vec::new();
        let got = bvh.closest(p, f64::INFINITY, &mut st, |id, _| boxes[id as usize].distance_squared(p));
        let want = boxes.iter().map(|b| b.distance_squared(p)).fold(f64::INFINITY, f64::min);
        match got {
            None => prop_assert!(boxes.is_empty()),
            Some((id, d2)) => {
                prop_assert_eq!(d2, want);
                prop_assert_eq!(boxes[id as usize].distance_squared(p), want);
            }
        }
        // Ray against the boxes themselves: the nearest entry parameter.
        let (o, d) = ([ray.0, ray.1, ray.2], [ray.3, ray.4, ray.5]);
        let inv = d.map(|c| 1.0 / c);
        let got = bvh.ray(o, d, 10.0, &mut st, |id, tb| boxes[id as usize].ray(o, inv, tb).map(|t| t.0));
        let want = boxes.iter().filter_map(|b| b.ray(o, inv, 10.0)).map(|t| t.0).fold(f64::INFINITY, f64::min);
        match got {
            None => prop_assert!(want.is_infinite()),
            Some((id, t)) => {
                prop_assert_eq!(t, want);
                prop_assert_eq!(boxes[id as usize].ray(o, inv, 10.0).map(|t| t.0), Some(want));
            }
        }
    }

    #[test]
    fn bvh_refit_follows_motion(boxes in random_boxes(300), shift in prop::collection::vec(-0.3f64..0.3, 3)) {
        let mut bvh = Bvh::from_boxes(&boxes);
        // Move every other box; the refit tree must still give the exact pair set.
        let moved: Vec<Aabb> = boxes
            .iter()
            .enumerate()
            .map(|(i, b)| if i % 2 == 0 { *b } else {
                Aabb { min: [0, 1, 2].map(|a| b.min[a] + shift[a]), max: [0, 1, 2].map(|a| b.max[a] + shift[a]) }
            })
            .collect();
        bvh.refit(&moved);
        let mut work = PairWork::default();
        let mut pairs = Vec::new();
        bvh.self_pairs(&mut work, &mut pairs);
        prop_assert_eq!(sorted(pairs), brute_self(&moved));
    }

    #[test]
    fn bounding_volumes_hold_their_points(
        pts in prop::collection::vec((-5f64..5.0, -5f64..5.0, -5f64..5.0), 1..40),
        flat in any::<bool>(),
    ) {
        let pts: Vec<[f64; 3]> = pts.into_iter().map(|(x, y, z)| [x, y, if flat { 0.5 * x - y } else { z }]).collect();
        let s = Sphere::of_points(&pts).unwrap();
        let o = Obb::of_points(&pts).unwrap();
        let b = Aabb::of_points(pts.iter().copied());
        for p in &pts {
            let d = [p[0] - s.center[0], p[1] - s.center[1], p[2] - s.center[2]];
            prop_assert!((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() <= s.radius * (1.0 + 1e-12) + 1e-12);
            prop_assert!(o.contains(*p, 1e-9));
            prop_assert!(b.contains(*p));
        }
        // The OBB's axes are orthonormal and right-handed.
        let a = o.axes;
        let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        for i in 0..3 {
            for j in 0..3 {
                let want = if i == j { 1.0 } else { 0.0 };
                prop_assert!((dot(a[i], a[j]) - want).abs() < 1e-9);
            }
        }
        let c = [a[0][1] * a[1][2] - a[0][2] * a[1][1], a[0][2] * a[1][0] - a[0][0] * a[1][2], a[0][0] * a[1][1] - a[0][1] * a[1][0]];
        prop_assert!(dot(c, a[2]) > 0.999);
        // A covariance box is no larger than the axis box on flat sets.
        if flat {
            prop_assert!(o.half.iter().product::<f64>() <= 1e-6 + (0..3).map(|k| 0.5 * (b.max[k] - b.min[k])).product::<f64>());
        }
    }

    #[test]
    fn obb_overlap_equals_sampled_separation(
        c in (-2f64..2.0, -2f64..2.0, -2f64..2.0),
        ang in (0f64..6.3, 0f64..6.3),
        h in (0.1f64..1.0, 0.1f64..1.0, 0.1f64..1.0),
    ) {
        // Against the axis box [-1, 1]^3: an OBB overlaps it exactly when one of its
        // points is inside; sample the OBB's corners, edges and faces densely for the
        // "yes" direction, and check the SAT's "no" by the distance of its corners.
        let (s1, c1, s2, c2) = (ang.0.sin(), ang.0.cos(), ang.1.sin(), ang.1.cos());
        let axes = [[c1, s1, 0.0], [-s1 * c2, c1 * c2, s2], [s1 * s2, -c1 * s2, c2]];
        let o = Obb { center: [c.0, c.1, c.2], axes, half: [h.0, h.1, h.2] };
        let unit = Aabb { min: [-1.0; 3], max: [1.0; 3] };
        let sat = o.overlaps(&Obb::of_aabb(&unit));
        let k = 12;
        let mut inside = false;
        for i in 0..=k {
            for j in 0..=k {
                for l in 0..=k {
                    let s = [i, j, l].map(|t| 2.0 * t as f64 / k as f64 - 1.0);
                    let p: [f64; 3] = std::array::from_fn(|m| o.center[m] + (0..3).map(|a| s[a] * o.half[a] * o.axes[a][m]).sum::<f64>());
                    inside |= unit.contains(p);
                }
            }
        }
        // A sampled point inside means overlap; the SAT may also find overlaps the
        // samples miss (a corner of the unit box poking into the OBB's interior).
        if inside {
            prop_assert!(sat);
        }
        if sat && !inside {
            // Then some corner of the unit box must be inside the OBB, or the two touch
            // within the sample spacing.
            let corner_in = (0..8).any(|m| o.contains([0, 1, 2].map(|a| if m >> a & 1 == 1 { 1.0 } else { -1.0 }), 0.0));
            let near = unit.distance_squared(o.center).sqrt() <= o.half.iter().map(|h| h * h).sum::<f64>().sqrt() + 1e-9;
            prop_assert!(corner_in || near);
        }
    }
}

/// The cell maps under test: a dense grid over the unit box (points outside clamp to
/// its border cells), a hash table large enough, and one so small that most cells collide.
fn maps() -> [Cells; 3] {
    [
        Cells::Dense {
            origin: [0.0; 3],
            dims: [5, 4, 6],
        },
        Cells::Hashed { buckets: 1009 },
        Cells::Hashed { buckets: 3 },
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn grids_find_exactly_the_close_points(
        pts in prop::collection::vec((-0.3f64..1.3, -0.3f64..1.3, -0.3f64..1.3), 0..200),
        r in 0f64..0.3,
        q in (-0.5f64..1.5, -0.5f64..1.5, -0.5f64..1.5, 0f64..2.0),
    ) {
        let n = pts.len();
        let mut x = vec![0.0; 3 * n];
        for (i, p) in pts.iter().enumerate() {
            x[i] = p.0;
            x[n + i] = p.1;
            x[2 * n + i] = p.2;
        }
        let d2 = |i: usize, j: usize| {
            let d = [pts[i].0 - pts[j].0, pts[i].1 - pts[j].1, pts[i].2 - pts[j].2];
            d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        };
        let mut want = Vec::new();
        for i in 0..n {
            for j in i + 1..n {
                if d2(i, j) <= r * r {
                    want.push([i as u32, j as u32]);
                }
            }
        }
        for cells in maps() {
            let mut g = CellGrid::new(0.3, cells);
            g.build_points(&x);
            let mut got = Vec::new();
            g.point_pairs(r, &mut Vec::new(), &mut Vec::new(), &mut got);
            prop_assert_eq!(sorted(got), want.clone(), "{:?}", cells);
            // A ball query of any radius (larger than a cell included).
            let p = [q.0, q.1, q.2];
            let (mut scratch, mut got) = (Vec::new(), Vec::new());
            g.points_within(p, q.3, &mut scratch, &mut got);
            got.sort_unstable();
            let wantq: Vec<u32> = (0..n as u32)
                .filter(|&i| {
                    let d = [pts[i as usize].0 - p[0], pts[i as usize].1 - p[1], pts[i as usize].2 - p[2]];
                    d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= q.3 * q.3
                })
                .collect();
            prop_assert_eq!(got, wantq, "{:?}", cells);
        }
    }

    #[test]
    fn grids_and_sweep_find_exactly_the_overlapping_boxes(
        boxes in lattice_boxes(150),
        big in prop::collection::vec((0f64..3.0, 0f64..3.0, 0f64..3.0, 0f64..60.0), 0..3),
        moves in prop::collection::vec(-0.5f64..0.5, 3),
    ) {
        // Lattice boxes (touching, zero-size, duplicates) plus a few huge ones that cover
        // more cells than the small tables have buckets.
        let mut boxes = boxes;
        for b in big {
            boxes.push(Aabb { min: [b.0, b.1, b.2], max: [b.0 + b.3, b.1 + 0.5 * b.3, b.2 + 0.25 * b.3] });
        }
        // One empty box: overlaps nothing.
        boxes.push(Aabb::EMPTY);
        let want = brute_self(&boxes);
        for cells in maps() {
            let mut g = CellGrid::new(0.5, cells);
            g.build_boxes(&boxes);
            let mut got = Vec::new();
            g.box_pairs(&mut got);
            let n = got.len();
            let got = sorted(got);
            prop_assert_eq!(&got, &want, "{:?}", cells);
            prop_assert_eq!(n, want.len(), "each pair once");
        }
        let mut sap = SweepAndPrune::new();
        let mut got = Vec::new();
        sap.pairs(&boxes, &mut got);
        prop_assert_eq!(sorted(got), want.clone());
        // With a limit: all of them when they fit, else max + 1 of them and `false`.
        let mut got = Vec::new();
        prop_assert!(sap.pairs_at_most(&boxes, want.len(), &mut got));
        prop_assert_eq!(sorted(got), want.clone());
        if !want.is_empty() {
            let max = want.len() / 2;
            let mut got = Vec::new();
            prop_assert!(!sap.pairs_at_most(&boxes, max, &mut got));
            prop_assert_eq!(got.len(), max + 1);
            prop_assert!(got.iter().all(|p| want.binary_search(p).is_ok()));
        }
        // Move every third box and sweep again from the kept order.
        let moved: Vec<Aabb> = boxes
            .iter()
            .enumerate()
            .map(|(i, b)| if i % 3 != 0 || b.is_empty() { *b } else {
                Aabb { min: [0, 1, 2].map(|a| b.min[a] + moves[a]), max: [0, 1, 2].map(|a| b.max[a] + moves[a]) }
            })
            .collect();
        let mut got = Vec::new();
        sap.pairs(&moved, &mut got);
        prop_assert_eq!(sorted(got), brute_self(&moved));
    }
}

#[test]
fn bvh_results_do_not_depend_on_thread_count() {
    // 20,000 boxes build in parallel above PAR_BUILD; the pair list must be identical.
    let mut s = 12345u64;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let boxes: Vec<Aabb> = (0..20_000)
        .map(|_| {
            let p = [rnd(), rnd(), rnd()];
            Aabb {
                min: p,
                max: p.map(|c| c + 0.02),
            }
        })
        .collect();
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let bvh = Bvh::from_boxes(&boxes);
                let mut pairs = Vec::new();
                bvh.self_pairs(&mut PairWork::default(), &mut pairs);
                (bvh.nodes().to_vec(), pairs)
            })
    };
    let (n1, p1) = run(1);
    let (n3, p3) = run(3);
    assert_eq!(n1, n3);
    assert_eq!(p1, p3);
    assert_eq!(sorted(p1).len(), brute_self(&boxes).len());
}

#[test]
fn bvh_rebuilds_when_refitting_degrades_it() {
    let boxes: Vec<Aabb> = (0..2000)
        .map(|i| {
            let p = [(i % 20) as f64, ((i / 20) % 10) as f64, (i / 200) as f64];
            Aabb {
                min: p,
                max: p.map(|c| c + 0.5),
            }
        })
        .collect();
    let mut bvh = Bvh::from_boxes(&boxes);
    // Small motion: refit.
    let nudged: Vec<Aabb> = boxes
        .iter()
        .map(|b| Aabb {
            min: b.min.map(|c| c + 0.01),
            max: b.max.map(|c| c + 0.01),
        })
        .collect();
    assert_eq!(bvh.update(&nudged), Updated::Refit);
    // A shuffle (each box sent to another's place) ruins the topology: rebuild.
    let shuffled: Vec<Aabb> = (0..2000).map(|i| nudged[(i * 7919) % 2000]).collect();
    let cost_refit = {
        let mut t = bvh.clone();
        t.refit(&shuffled);
        t.sah_cost()
    };
    assert_eq!(bvh.update(&shuffled), Updated::Rebuilt);
    assert!(
        bvh.sah_cost() < cost_refit / 3.0,
        "{} vs {}",
        bvh.sah_cost(),
        cost_refit
    );
    // A different count rebuilds.
    assert_eq!(bvh.update(&shuffled[..1000]), Updated::Rebuilt);
    assert_eq!(bvh.len(), 1000);
}

#[test]
fn element_and_particle_boxes_hold_their_elements() {
    use largestep::kernels::collide::bv::{element_boxes, particle_boxes};
    // Component-major: x of 4 points, then y, then z.
    let x = [0.0, 1.0, 0.0, 0.2, 0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 1.0];
    let mut boxes = Vec::new();
    element_boxes(&mut boxes, &x, &[[0u32, 1, 2, 3]], 0.1);
    assert_eq!(
        boxes,
        vec![Aabb {
            min: [-0.1; 3],
            max: [1.1; 3]
        }]
    );
    element_boxes(&mut boxes, &x, &[[0u32, 1, 2], [1, 2, 3]], 0.0);
    assert_eq!(
        boxes[1],
        Aabb {
            min: [0.0, 0.0, 0.0],
            max: [1.0, 1.0, 1.0]
        }
    );
    particle_boxes(&mut boxes, &x, &[0.5]);
    assert_eq!(
        boxes[3],
        Aabb {
            min: [-0.3, -0.2, 0.5],
            max: [0.7, 0.8, 1.5]
        }
    );
    // A BVH over tetrahedra answers point queries through their boxes.
    element_boxes(&mut boxes, &x, &[[0u32, 1, 2, 3]], 0.0);
    let bvh = Bvh::from_boxes(&boxes);
    let (mut stack, mut out) = (Vec::new(), Vec::new());
    bvh.overlapping(&Aabb::point([0.5, 0.5, 0.5]), &mut stack, &mut out);
    assert_eq!(out, vec![0]);
}

#[test]
fn empty_and_single_trees() {
    let mut work = PairWork::default();
    let mut pairs = vec![[9, 9]];
    let empty = Bvh::from_boxes(&[]);
    empty.self_pairs(&mut work, &mut pairs);
    assert!(pairs.is_empty());
    assert_eq!(
        empty.ray(
            [0.0; 3],
            [1.0, 0.0, 0.0],
            1.0,
            &mut Vec::new(),
            |_, _| Some(0.0)
        ),
        None
    );
    let one = Bvh::from_boxes(&[Aabb::point([0.5; 3])]);
    one.self_pairs(&mut work, &mut pairs);
    assert!(pairs.is_empty());
    one.pairs_with(&one, &mut work, &mut pairs);
    assert_eq!(pairs, vec![[0, 0]]);
    empty.pairs_with(&one, &mut work, &mut pairs);
    assert!(pairs.is_empty());
}

mod distance_fields {
    use super::*;
    use largestep::collide::{check_closed, winding_numbers, SdfGrid, EXACT_BAND};
    use largestep::io::Mesh;
    use largestep::kernels::collide::prox::{closest_on_triangle, norm2};
    use largestep::kernels::collide::sdf::{union_distance_grad, Shape};
    use largestep::kernels::interp::sample3_grad;

    fn shapes() -> Vec<Shape> {
        let n = {
            let v = [0.3f64, -0.5, 0.8];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|c| c / l)
        };
        vec![
            Shape::Plane {
                normal: n,
                offset: 0.2,
            },
            Shape::Sphere {
                center: [0.1, 0.2, -0.3],
                radius: 0.7,
            },
            Shape::Box {
                center: [0.2, -0.1, 0.0],
                half: [0.5, 0.3, 0.8],
            },
            Shape::Capsule {
                a: [-0.5, 0.0, 0.1],
                b: [0.4, 0.3, -0.2],
                radius: 0.25,
            },
            Shape::Torus {
                center: [0.0, 0.1, 0.0],
                axis: n,
                major: 0.6,
                minor: 0.2,
            },
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// Exact distance functions: unit gradient off the medial axis (by central
        /// differences), and the foot `p - phi grad` lies on the surface (phi = 0 there)
        /// at distance |phi|: together with 1-Lipschitz, phi is the distance.
        #[test]
        fn analytic_distances_are_exact(p in (-1.5f64..1.5, -1.5f64..1.5, -1.5f64..1.5), q in (-1.5f64..1.5, -1.5f64..1.5, -1.5f64..1.5)) {
            let (p, q) = ([p.0, p.1, p.2], [q.0, q.1, q.2]);
            for s in shapes() {
                let (d, g) = s.distance_grad(p);
                let e = 1e-6;
                let fd: [f64; 3] = std::array::from_fn(|a| {
                    let (mut hi, mut lo) = (p, p);
                    hi[a] += e;
                    lo[a] -= e;
                    (s.distance(hi) - s.distance(lo)) / (2.0 * e)
                });
                let gn = norm2(g).sqrt();
                let fdn = norm2(fd).sqrt();
                // Off the medial axis the difference quotient is the gradient, a unit
                // vector; on it (a kink) the quotient's length drops below 1.
                if (fdn - 1.0).abs() < 1e-4 {
                    prop_assert!((gn - 1.0).abs() < 1e-9, "{:?}: |grad| = {}", s, gn);
                    prop_assert!(norm2([g[0] - fd[0], g[1] - fd[1], g[2] - fd[2]]).sqrt() < 1e-4, "{:?}", s);
                }
                if gn > 0.5 {
                    let foot = [p[0] - d * g[0], p[1] - d * g[1], p[2] - d * g[2]];
                    prop_assert!(s.distance(foot).abs() < 1e-9, "{:?}: phi(foot) = {}", s, s.distance(foot));
                }
                // 1-Lipschitz.
                let pq = norm2([p[0] - q[0], p[1] - q[1], p[2] - q[2]]).sqrt();
                prop_assert!((s.distance(p) - s.distance(q)).abs() <= pq * (1.0 + 1e-12) + 1e-12, "{:?}", s);
            }
            // A union is exact outside all parts: the least distance.
            let all = shapes();
            let (du, _) = union_distance_grad(&all[1..], p);
            let least = all[1..].iter().map(|s| s.distance(p)).fold(f64::INFINITY, f64::min);
            prop_assert_eq!(du, least);
        }
    }

    #[test]
    fn analytic_values_at_known_points() {
        let b = Shape::Box {
            center: [0.0; 3],
            half: [1.0, 2.0, 3.0],
        };
        assert_eq!(b.distance([2.0, 0.0, 0.0]), 1.0);
        assert_eq!(b.distance([2.0, 3.0, 0.0]), 2f64.sqrt());
        assert_eq!(b.distance([0.0, 0.0, 0.0]), -1.0);
        assert_eq!(b.distance([0.5, 1.9, 0.0]), 1.9 - 2.0);
        let t = Shape::Torus {
            center: [0.0; 3],
            axis: [0.0, 0.0, 1.0],
            major: 2.0,
            minor: 0.5,
        };
        assert_eq!(t.distance([2.0, 0.0, 0.0]), -0.5);
        assert_eq!(t.distance([0.0, 0.0, 0.0]), 1.5);
        assert_eq!(t.distance([0.0, 3.0, 0.0]), 0.5);
        // On the axis every point of the core circle is nearest.
        assert_eq!(t.distance([0.0, 0.0, 1.5]), (4.0f64 + 2.25).sqrt() - 0.5);
        let c = Shape::Capsule {
            a: [0.0; 3],
            b: [0.0, 0.0, 2.0],
            radius: 1.0,
        };
        assert_eq!(c.distance([0.0, 3.0, 1.0]), 2.0);
        assert_eq!(c.distance([0.0, 0.0, -2.0]), 1.0);
    }

    /// Exact distance from `p` to the surface, by brute force.
    fn brute_distance(m: &Mesh, p: [f64; 3]) -> f64 {
        let r = m.as_ref();
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| r.vertex(v as usize));
                let (q, _) = closest_on_triangle(p, a, b, c);
                norm2([p[0] - q[0], p[1] - q[1], p[2] - q[2]]).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Checks a sampled field against brute force: band nodes exact, others within
    /// `far_tol` h above the true distance (never below), signs from `inside`.
    fn check_field(
        m: &Mesh,
        h: f64,
        far_tol: f64,
        inside: impl Fn([f64; 3]) -> Option<bool>,
    ) -> (f64, f64) {
        let sdf = SdfGrid::from_mesh(m, h, 3, 1 << 22).unwrap();
        let g = sdf.grid;
        let (mut worst_band, mut worst_far) = (0.0f64, 0.0f64);
        for k in 0..g.n[2] {
            for j in 0..g.n[1] {
                for i in 0..g.n[0] {
                    let p = [
                        g.origin[0] + i as f64 * h,
                        g.origin[1] + j as f64 * h,
                        g.origin[2] + k as f64 * h,
                    ];
                    let phi = sdf.phi[i + g.n[0] * (j + g.n[1] * k)];
                    let d = brute_distance(m, p);
                    let err = phi.abs() - d;
                    assert!(
                        err >= -1e-12,
                        "below the true distance at {p:?}: {phi} vs {d}"
                    );
                    if d <= EXACT_BAND as f64 * h * 0.999 {
                        worst_band = worst_band.max(err.abs());
                    } else {
                        worst_far = worst_far.max(err);
                    }
                    if d > 1e-9 {
                        if let Some(want) = inside(p) {
                            assert_eq!(phi < 0.0, want, "sign at {p:?}: phi {phi}");
                        }
                    }
                }
            }
        }
        assert!(worst_band < 1e-12, "band error {worst_band}");
        assert!(worst_far <= far_tol * h, "far error {worst_far} (h = {h})");
        (worst_band, worst_far / h)
    }

    #[test]
    fn mesh_fields_match_brute_force() {
        // A box whose faces, edges and corners lie on grid nodes and rows: the winding
        // rule's ties.
        let cube = largestep::shapes::cuboid([0.0; 3], [0.5, 0.25, 0.75]);
        let (b1, f1) = check_field(&cube, 0.05, 0.1, |p| {
            Some(
                p.iter()
                    .zip([0.5, 0.25, 0.75])
                    .all(|(&c, hi)| c > 0.0 && c < hi),
            )
        });
        // A UV sphere, off the grid.
        let sphere = largestep::shapes::uv_sphere([0.013, -0.021, 0.007], 0.4, 12, 16);
        let (b2, f2) = check_field(&sphere, 0.06, 0.1, |p| {
            let r = norm2([p[0] - 0.013, p[1] + 0.021, p[2] - 0.007]).sqrt();
            // Between the polygon and the sphere the answer is the polygon's: skip.
            (!(0.35..=0.41).contains(&r)).then_some(r < 0.35)
        });
        eprintln!("band errors {b1:.1e} {b2:.1e}; far errors {f1:.3} h, {f2:.3} h");
    }

    #[test]
    fn real_mesh_field_signs_and_trilinear_error() {
        // The nut surface from the shared data (TetGen example, 1046 triangles).
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/tetmesh/nut-surface.off");
        let m = largestep::io::read_surface(&path, 1 << 24).unwrap();
        check_closed(&m).unwrap();
        let bounds = Aabb::of_points((0..m.positions.len() / 3).map(|i| m.as_ref().vertex(i)));
        let size = (0..3)
            .map(|a| bounds.max[a] - bounds.min[a])
            .fold(0.0, f64::max);
        let h = size / 24.0;
        let sdf = SdfGrid::from_mesh(&m, h, 2, 1 << 22).unwrap();
        // Node signs against the winding number at the nodes themselves, and the
        // trilinear interpolant's error at random points against brute force: within
        // the grid's stated error, h (trilinear reproduces planes; near edges and
        // corners the distance has kinks of size up to h / 2 per cell).
        let w = winding_numbers(&m, sdf.grid.origin, h, sdf.grid.n);
        assert!(
            w.iter().all(|&w| w == 0 || w == 1),
            "a closed outward surface winds 0 or 1"
        );
        assert!(w.contains(&1));
        let mut s = 7u64;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut worst = 0.0f64;
        for _ in 0..300 {
            let p: [f64; 3] =
                std::array::from_fn(|a| bounds.min[a] + rnd() * (bounds.max[a] - bounds.min[a]));
            let (phi, grad) = sample3_grad(&sdf.phi, sdf.grid, p);
            let d = brute_distance(&m, p);
            worst = worst.max((phi.abs() - d).abs());
            assert!(grad.iter().all(|c| c.is_finite()));
        }
        eprintln!(
            "nut: {} nodes, worst trilinear error {:.3} h",
            sdf.phi.len(),
            worst / h
        );
        assert!(worst < h, "trilinear error {worst} vs h {h}");
    }

    #[test]
    fn bad_surfaces_are_named() {
        let cube = largestep::shapes::cuboid([0.0; 3], [1.0; 3]);
        let msg = |m: &Mesh| {
            SdfGrid::from_mesh(m, 0.1, 1, 1 << 20)
                .unwrap_err()
                .to_string()
        };
        // Open: one triangle removed.
        let mut open = cube.clone();
        open.triangles = cube.triangles[1..].to_vec().into();
        let e = msg(&open);
        assert!(e.contains("open") && e.contains("edge"), "{e}");
        // A flipped triangle.
        let mut flipped = cube.clone();
        let mut t = cube.triangles.to_vec();
        t[3] = [t[3][0], t[3][2], t[3][1]];
        flipped.triangles = t.into();
        let e = msg(&flipped);
        assert!(e.contains("not consistently oriented"), "{e}");
        // NaN coordinates.
        let mut nan = cube.clone();
        nan.positions[5] = f64::NAN;
        let e = msg(&nan);
        assert!(e.contains("vertex 5") && e.contains("finite"), "{e}");
        // A degenerate triangle.
        let degenerate = largestep::shapes::from_triangles(
            &[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
            &[[0, 1, 2]],
        );
        let e = msg(&degenerate);
        assert!(e.contains("triangle 0") && e.contains("degenerate"), "{e}");
        // Empty, a bad index, a bad spacing, too many nodes.
        let empty = largestep::shapes::from_triangles(&[], &[]);
        assert!(msg(&empty).contains("no triangles"));
        let bad = largestep::shapes::from_triangles(&[[0.0; 3]], &[[0, 0, 3]]);
        assert!(msg(&bad).contains("names vertex 3"), "{}", msg(&bad));
        assert!(SdfGrid::from_mesh(&cube, 0.0, 1, 1 << 20)
            .unwrap_err()
            .to_string()
            .contains("spacing"));
        let e = SdfGrid::from_mesh(&cube, 1e-4, 1, 1 << 20)
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than the limit"), "{e}");
    }
}

mod narrow_phase {
    use super::*;
    use largestep::kernels::collide::narrow::{
        box_box, capsule_capsule, gjk_epa, sphere_sphere, Convex,
    };
    use largestep::kernels::collide::prox::{closest_on_triangle, closest_segments, norm2};

    fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    }

    fn tri_strategy() -> impl Strategy<Value = [[f64; 3]; 3]> {
        prop::array::uniform3(prop::array::uniform3(-1f64..1.0))
    }

    /// Brute-force distance between two triangles that do not cross: the least of the
    /// six vertex-triangle and nine edge-edge distances.
    fn brute_triangles(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> f64 {
        let mut d = f64::INFINITY;
        for (p, t) in a.iter().map(|p| (p, b)).chain(b.iter().map(|p| (p, a))) {
            let (q, _) = closest_on_triangle(*p, t[0], t[1], t[2]);
            d = d.min(norm2(sub(*p, q)).sqrt());
        }
        for i in 0..3 {
            for j in 0..3 {
                let (_, _, p, q) = closest_segments(a[i], a[(i + 1) % 3], b[j], b[(j + 1) % 3]);
                d = d.min(norm2(sub(p, q)).sqrt());
            }
        }
        d
    }

    /// The faces of the convex hull of a few points, by brute force (every triple with
    /// all points on one side).
    fn hull_faces(p: &[[f64; 3]]) -> Vec<[usize; 3]> {
        let mut f = Vec::new();
        for i in 0..p.len() {
            for j in i + 1..p.len() {
                for k in j + 1..p.len() {
                    let n = {
                        let (u, v) = (sub(p[j], p[i]), sub(p[k], p[i]));
                        [
                            u[1] * v[2] - u[2] * v[1],
                            u[2] * v[0] - u[0] * v[2],
                            u[0] * v[1] - u[1] * v[0],
                        ]
                    };
                    if norm2(n) < 1e-12 {
                        continue;
                    }
                    let side = |q: [f64; 3]| {
                        let d = sub(q, p[i]);
                        n[0] * d[0] + n[1] * d[1] + n[2] * d[2]
                    };
                    let (mut pos, mut neg) = (false, false);
                    for q in p {
                        let s = side(*q);
                        pos |= s > 1e-12;
                        neg |= s < -1e-12;
                    }
                    if !(pos && neg) {
                        f.push([i, j, k]);
                    }
                }
            }
        }
        f
    }

    fn brute_hulls(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
        let (fa, fb) = (hull_faces(a), hull_faces(b));
        let mut d = f64::INFINITY;
        for f in &fa {
            for g in &fb {
                d = d.min(brute_triangles(
                    [a[f[0]], a[f[1]], a[f[2]]],
                    [b[g[0]], b[g[1]], b[g[2]]],
                ));
            }
        }
        d
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        #[test]
        fn gjk_distance_of_triangles_equals_brute_force(a in tri_strategy(), b in tri_strategy(), gap in 0.05f64..2.0) {
            // Shift b along x beyond a so they cannot cross.
            let shift = a.iter().map(|p| p[0]).fold(f64::MIN, f64::max) - b.iter().map(|p| p[0]).fold(f64::MAX, f64::min) + gap;
            let b = b.map(|p| [p[0] + shift, p[1], p[2]]);
            let c = gjk_epa(&Convex::Triangle(a), &Convex::Triangle(b)).unwrap();
            let want = brute_triangles(a, b);
            prop_assert!((-c.depth - want).abs() < 1e-9 * (1.0 + want), "gjk {} brute {}", -c.depth, want);
            // The witnesses realise the distance.
            prop_assert!((norm2(sub(c.point_a, c.point_b)).sqrt() - want).abs() < 1e-9);
        }

        #[test]
        fn gjk_distance_of_hulls_equals_brute_force(
            a in prop::collection::vec(prop::array::uniform3(-1f64..1.0), 4..9),
            b in prop::collection::vec(prop::array::uniform3(-1f64..1.0), 4..9),
            dir in prop::array::uniform3(-1f64..1.0),
            gap in 0.0f64..1.5,
        ) {
            let Some(l) = Some(norm2(dir).sqrt()).filter(|l| *l > 0.1) else { return Ok(()) };
            let u = dir.map(|c| c / l);
            // Separate b from a along u by the projections' gap.
            let reach_a = a.iter().map(|p| p[0] * u[0] + p[1] * u[1] + p[2] * u[2]).fold(f64::MIN, f64::max);
            let low_b = b.iter().map(|p| p[0] * u[0] + p[1] * u[1] + p[2] * u[2]).fold(f64::MAX, f64::min);
            let s = reach_a - low_b + gap + 1e-3;
            let b: Vec<[f64; 3]> = b.iter().map(|p| [p[0] + s * u[0], p[1] + s * u[1], p[2] + s * u[2]]).collect();
            let c = gjk_epa(&Convex::Hull(&a), &Convex::Hull(&b)).unwrap();
            let want = brute_hulls(&a, &b);
            prop_assert!((-c.depth - want).abs() < 1e-8 * (1.0 + want), "gjk {} brute {}", -c.depth, want);
        }

        #[test]
        fn epa_depth_of_boxes_equals_sat(
            ha in prop::array::uniform3(0.1f64..1.0),
            hb in prop::array::uniform3(0.1f64..1.0),
            ang in prop::array::uniform3(0f64..6.3),
            off in prop::array::uniform3(-0.8f64..0.8),
        ) {
            let rot = |a: [f64; 3]| {
                let (s1, c1, s2, c2, s3, c3) = (a[0].sin(), a[0].cos(), a[1].sin(), a[1].cos(), a[2].sin(), a[2].cos());
                // Z-Y-X Euler rotation; its columns are the axes.
                let m = [
                    [c1 * c2, c1 * s2 * s3 - s1 * c3, c1 * s2 * c3 + s1 * s3],
                    [s1 * c2, s1 * s2 * s3 + c1 * c3, s1 * s2 * c3 - c1 * s3],
                    [-s2, c2 * s3, c2 * c3],
                ];
                [[m[0][0], m[1][0], m[2][0]], [m[0][1], m[1][1], m[2][1]], [m[0][2], m[1][2], m[2][2]]]
            };
            let ax = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
            let bx = rot(ang);
            let sat = box_box([0.0; 3], ax, ha, off, bx, hb);
            let a = Convex::Box { center: [0.0; 3], axes: ax, half: ha };
            let b = Convex::Box { center: off, axes: bx, half: hb };
            let c = gjk_epa(&a, &b).unwrap();
            if sat.depth > 1e-6 {
                // Overlapping: the least translation is the same number.
                prop_assert!((c.depth - sat.depth).abs() < 1e-6 * (1.0 + sat.depth), "epa {} sat {}", c.depth, sat.depth);
                // Moving B by the normal times the depth (plus a little) leaves them at
                // most touching: the SAT depth along EPA's normal is then about zero.
                let s = c.depth * (1.0 + 1e-6) + 1e-9;
                let moved = [off[0] + c.normal[0] * s, off[1] + c.normal[1] * s, off[2] + c.normal[2] * s];
                let after = box_box([0.0; 3], ax, ha, moved, bx, hb);
                prop_assert!(after.depth < 1e-6 * (1.0 + c.depth), "still {} deep after the move", after.depth);
            } else if sat.depth < -1e-6 {
                // Apart: SAT's gap is a lower bound on GJK's distance.
                prop_assert!(c.depth < 0.0 && -c.depth >= -sat.depth - 1e-9);
            }
        }

        #[test]
        fn closed_forms_agree_with_gjk(
            c1 in prop::array::uniform3(-1f64..1.0), c2 in prop::array::uniform3(-1f64..1.0),
            e1 in prop::array::uniform3(-1f64..1.0), e2 in prop::array::uniform3(-1f64..1.0),
            r1 in 0.05f64..0.6, r2 in 0.05f64..0.6,
        ) {
            // GJK and EPA run on the cores (points, segments) with the radii as margins,
            // so spheres and capsules get the closed forms' depth, apart or overlapping.
            let s = sphere_sphere(c1, r1, c2, r2);
            let g = gjk_epa(&Convex::Sphere { center: c1, radius: r1 }, &Convex::Sphere { center: c2, radius: r2 }).unwrap();
            prop_assert!((s.depth - g.depth).abs() < 1e-9, "sphere {} gjk {}", s.depth, g.depth);
            let k = capsule_capsule(c1, e1, r1, c2, e2, r2);
            let g = gjk_epa(&Convex::Capsule { a: c1, b: e1, radius: r1 }, &Convex::Capsule { a: c2, b: e2, radius: r2 }).unwrap();
            prop_assert!((k.depth - g.depth).abs() < 1e-9, "capsule {} gjk {}", k.depth, g.depth);
            // The witnesses lie on the rounded surfaces, `depth` apart along the normal.
            let gap = sub(g.point_b, g.point_a);
            for (d, n) in gap.iter().zip(g.normal) {
                prop_assert!((d + n * g.depth).abs() < 1e-9);
            }
        }

        #[test]
        fn gjk_epa_of_a_sphere_and_a_box_equals_the_closed_form(
            c in prop::array::uniform3(-1.5f64..1.5),
            h in prop::array::uniform3(0.1f64..1.0),
            rot in prop::array::uniform3(-3.2f64..3.2),
            r in 0.01f64..0.8,
        ) {
            use largestep::kernels::collide::manifold::{sphere_box, BoxPose};
            let q = largestep::kernels::quat::exp(rot);
            let b = BoxPose {
                center: [0.1, -0.2, 0.3],
                axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|e| largestep::kernels::quat::rotate(q, e)),
                half: h,
            };
            let g = gjk_epa(&Convex::Sphere { center: c, radius: r }, &b.convex()).unwrap();
            let m = sphere_box(c, r, &b, f64::INFINITY).unwrap();
            prop_assert!((g.depth - m.points[0].depth).abs() < 1e-9 * (1.0 + r), "gjk {} closed {}", g.depth, m.points[0].depth);
        }

        #[test]
        fn polytope_manifolds_lie_within_both_shapes(
            a in prop::collection::vec(prop::array::uniform3(-1f64..1.0), 4..12),
            b in prop::collection::vec(prop::array::uniform3(-1f64..1.0), 4..12),
            shift in prop::array::uniform3(-1.5f64..1.5),
        ) {
            use largestep::kernels::collide::manifold::convex_convex;
            let b: Vec<[f64; 3]> = b.iter().map(|p| [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]).collect();
            let (ca, cb) = (Convex::Hull(&a), Convex::Hull(&b));
            let epa = gjk_epa(&ca, &cb).unwrap();
            let Some(m) = convex_convex(&ca, &cb, 0.0) else {
                prop_assert!(epa.depth < 1e-9);
                return Ok(());
            };
            prop_assert!(m.count >= 1 && m.normal == epa.normal);
            // EPA's witnesses are `depth` apart along the normal.
            let gap = [0, 1, 2].map(|k| epa.point_a[k] - epa.point_b[k] - epa.normal[k] * epa.depth);
            prop_assert!(norm2(gap).sqrt() < 1e-9, "witnesses off by {gap:?}");
            // A support feature takes the vertices within a fiftieth of the shape's
            // extent along the normal as flat: points may be that far off its surface.
            let extent = |h: &[[f64; 3]]| {
                let d = h.iter().map(|p| p[0] * m.normal[0] + p[1] * m.normal[1] + p[2] * m.normal[2]);
                d.clone().fold(f64::MIN, f64::max) - d.fold(f64::MAX, f64::min)
            };
            let flat = 0.02 * extent(&a).max(extent(&b));
            for p in m.points() {
                // No deeper than the penetration depth (the least over directions) beyond
                // that, and within depth (plus it) of both hulls: their distance, by GJK
                // to a point hull, at most how far the point is outside.
                prop_assert!(p.depth <= epa.depth + flat + 1e-9, "{} vs {}", p.depth, epa.depth);
                for hull in [&a, &b] {
                    let out = -gjk_epa(&Convex::Hull(std::slice::from_ref(&p.point)), &Convex::Hull(hull)).unwrap().depth;
                    prop_assert!(out <= 0.5 * p.depth.abs() + flat + 1e-9, "point {:?} {out} outside a hull, depth {}", p.point, p.depth);
                }
            }
        }

        #[test]
        fn gjk_distance_of_nearly_touching_boxes_equals_brute_force(
            ha in prop::array::uniform3(0.1f64..1.0),
            hb in prop::array::uniform3(0.1f64..1.0),
            ra in prop::array::uniform3(-3.2f64..3.2),
            spin in -3.2f64..3.2,
            face in 0usize..3,
            slide in prop::array::uniform2(-1f64..1.0),
            log_gap in -9f64..-3.0,
        ) {
            // B is A turned about one of A's face normals, beyond that face by `gap`: two
            // parallel faces, whose flat simplices once made GJK call such pairs touching
            // or report a distance far too large.
            use largestep::kernels::quat;
            let gap = 10f64.powf(log_gap);
            let qa = quat::exp(ra);
            let e = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
            let axa = e.map(|x| quat::rotate(qa, x));
            let mut turn = [0.0; 3];
            turn[face] = spin;
            let qb = quat::mul(qa, quat::exp(turn));
            let axb = e.map(|x| quat::rotate(qb, x));
            let n = axa[face];
            let (u, v) = (axa[(face + 1) % 3], axa[(face + 2) % 3]);
            let reach = ha[face] + (0..3).map(|k| hb[k] * (axb[k][0] * n[0] + axb[k][1] * n[1] + axb[k][2] * n[2]).abs()).sum::<f64>();
            let (su, sv) = (slide[0] * ha[(face + 1) % 3], slide[1] * ha[(face + 2) % 3]);
            let cb: [f64; 3] = std::array::from_fn(|i| n[i] * (reach + gap) + u[i] * su + v[i] * sv);
            let corners = |c: [f64; 3], ax: [[f64; 3]; 3], h: [f64; 3]| -> Vec<[f64; 3]> {
                (0..8).map(|m| std::array::from_fn(|i| {
                    c[i] + (0..3).map(|k| if m >> k & 1 == 1 { h[k] } else { -h[k] } * ax[k][i]).sum::<f64>()
                })).collect()
            };
            let want = brute_hulls(&corners([0.0; 3], axa, ha), &corners(cb, axb, hb));
            let c = gjk_epa(&Convex::Box { center: [0.0; 3], axes: axa, half: ha }, &Convex::Box { center: cb, axes: axb, half: hb }).unwrap();
            prop_assert!((-c.depth - want).abs() < 1e-9 * (1.0 + want), "gjk {} brute {}", -c.depth, want);
        }
    }
}

/// Polytopes resting on a face touch at the face's corners: a cube hull on a box gets
/// four points, on its edge two (issue 19: one point made hulls rock).
#[test]
fn a_hull_resting_on_a_face_gets_the_face_corners() {
    use largestep::kernels::collide::manifold::convex_convex;
    use largestep::kernels::collide::narrow::Convex;
    use largestep::kernels::quat;
    let ground = Convex::Box {
        center: [0.0, -1.0, 0.0],
        axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        half: [5.0, 1.0, 5.0],
    };
    for turn in [0.0, 0.3, 1.0] {
        // A unit cube turned about y, its bottom 1 mm into the ground.
        let q = quat::exp([0.0, turn, 0.0]);
        let cube: Vec<[f64; 3]> = (0..8)
            .map(|k| {
                let c = [0, 1, 2].map(|a| if k >> a & 1 == 1 { 0.5 } else { -0.5 });
                let r = quat::rotate(q, c);
                [r[0] + 0.2, r[1] + 0.499, r[2] - 0.1]
            })
            .collect();
        let m = convex_convex(&Convex::Hull(&cube), &ground, 0.01).unwrap();
        assert_eq!(m.count, 4, "turn {turn}: {m:?}");
        assert!((m.normal[1] + 1.0).abs() < 1e-9, "{:?}", m.normal);
        for p in m.points() {
            assert!((p.depth - 1e-3).abs() < 1e-9, "depth {}", p.depth);
            assert!((p.point[1] - (-0.0005)).abs() < 1e-9, "{:?}", p.point);
        }
        // Each of the cube's bottom corners is a point.
        for c in cube.iter().filter(|c| c[1] < 0.0) {
            assert!(m
                .points()
                .iter()
                .any(|p| (p.point[0] - c[0]).abs() < 1e-9 && (p.point[2] - c[2]).abs() < 1e-9));
        }
    }
    // On an edge (turned 45 degrees about z): the edge's two ends.
    let q = quat::exp([0.0, 0.0, std::f64::consts::FRAC_PI_4]);
    let h = 0.5 * std::f64::consts::SQRT_2;
    let cube: Vec<[f64; 3]> = (0..8)
        .map(|k| {
            let c = [0, 1, 2].map(|a| if k >> a & 1 == 1 { 0.5 } else { -0.5 });
            let r = quat::rotate(q, c);
            [r[0], r[1] + h - 0.002, r[2]]
        })
        .collect();
    let m = convex_convex(&Convex::Hull(&cube), &ground, 0.01).unwrap();
    assert_eq!(m.count, 2, "{m:?}");
    for p in m.points() {
        assert!(
            (p.depth - 0.002).abs() < 1e-9 && (p.point[2].abs() - 0.5).abs() < 1e-9,
            "{p:?}"
        );
    }
}

mod continuous {
    use super::*;
    use largestep::kernels::collide::ccd::{
        edge_edge, edge_edge_ccd, vertex_triangle, vertex_triangle_ccd,
    };

    const ETA: f64 = 1e-6;

    fn at(x: [[f64; 3]; 2], t: f64) -> [f64; 3] {
        std::array::from_fn(|k| x[0][k] + t * (x[1][k] - x[0][k]))
    }

    /// A trajectory through `x` at time `ts` with velocity `v`.
    fn through(x: [f64; 3], ts: f64, v: [f64; 3]) -> [[f64; 3]; 2] {
        let x0 = std::array::from_fn(|k| x[k] - ts * v[k]);
        [x0, std::array::from_fn(|k| x0[k] + v[k])]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// A vertex crossing a moving triangle's interior at `ts` is found at or before.
        #[test]
        fn vertex_crossings_are_never_missed(
            tri in prop::array::uniform3(prop::array::uniform3(-1f64..1.0)),
            w in (0.05f64..1.0, 0.05f64..1.0, 0.05f64..1.0),
            ts in 0f64..1.0,
            vel in prop::array::uniform4(prop::array::uniform3(-2f64..2.0)),
        ) {
            let s = w.0 + w.1 + w.2;
            let w = [w.0 / s, w.1 / s, w.2 / s];
            let n = {
                let (u, v) = ([tri[1][0] - tri[0][0], tri[1][1] - tri[0][1], tri[1][2] - tri[0][2]], [tri[2][0] - tri[0][0], tri[2][1] - tri[0][1], tri[2][2] - tri[0][2]]);
                [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
            };
            prop_assume!(n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 1e-4);
            let x: [f64; 3] = std::array::from_fn(|k| w[0] * tri[0][k] + w[1] * tri[1][k] + w[2] * tri[2][k]);
            let (a, b, c) = (through(tri[0], ts, vel[0]), through(tri[1], ts, vel[1]), through(tri[2], ts, vel[2]));
            let p = through(x, ts, vel[3]);
            let hit = vertex_triangle_ccd(p, a, b, c, ETA);
            prop_assert!(hit.is_some(), "missed a crossing at t = {ts}");
            let (t, pr) = hit.unwrap();
            prop_assert!(t <= ts + 1e-9, "found {t} after the crossing at {ts}");
            prop_assert!(pr.distance <= ETA);
        }

        /// Two edges crossing at interior points at `ts` are found at or before.
        #[test]
        fn edge_crossings_are_never_missed(
            x in prop::array::uniform3(-1f64..1.0),
            e in prop::array::uniform2(prop::array::uniform3(-1f64..1.0)),
            uv in (0.02f64..0.98, 0.02f64..0.98),
            ts in 0f64..1.0,
            vel in prop::array::uniform4(prop::array::uniform3(-2f64..2.0)),
        ) {
            let cr = [e[0][1] * e[1][2] - e[0][2] * e[1][1], e[0][2] * e[1][0] - e[0][0] * e[1][2], e[0][0] * e[1][1] - e[0][1] * e[1][0]];
            prop_assume!(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2] > 1e-4);
            let p = std::array::from_fn(|k| x[k] - uv.0 * e[0][k]);
            let q = std::array::from_fn(|k| x[k] + (1.0 - uv.0) * e[0][k]);
            let r = std::array::from_fn(|k| x[k] - uv.1 * e[1][k]);
            let s = std::array::from_fn(|k| x[k] + (1.0 - uv.1) * e[1][k]);
            let hit = edge_edge_ccd(through(p, ts, vel[0]), through(q, ts, vel[1]), through(r, ts, vel[2]), through(s, ts, vel[3]), ETA);
            prop_assert!(hit.is_some(), "missed an edge crossing at t = {ts}");
            let (t, pr) = hit.unwrap();
            prop_assert!(t <= ts + 1e-9, "found {t} after the crossing at {ts}");
            prop_assert!(pr.distance <= ETA);
        }

        /// Random motion: a reported hit is a real contact, and when none is reported no
        /// sampled time brings the features within eta.
        #[test]
        fn reported_contacts_are_real_and_none_means_none(
            pts in prop::array::uniform4(prop::array::uniform2(prop::array::uniform3(-1f64..1.0))),
        ) {
            let [p, a, b, c] = pts;
            match vertex_triangle_ccd(p, a, b, c, ETA) {
                Some((t, pr)) => {
                    let again = vertex_triangle(at(p, t), at(a, t), at(b, t), at(c, t));
                    prop_assert!(again.distance <= ETA && pr.distance <= ETA);
                }
                None => {
                    // No crossing between samples: where the vertex projects into the
                    // triangle at two consecutive samples, its side of the plane holds.
                    let side = |t: f64| {
                        let (pa, pb, pc, pp) = (at(a, t), at(b, t), at(c, t), at(p, t));
                        let u = [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]];
                        let v = [pc[0] - pa[0], pc[1] - pa[1], pc[2] - pa[2]];
                        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
                        let ln = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                        let sd = (n[0] * (pp[0] - pa[0]) + n[1] * (pp[1] - pa[1]) + n[2] * (pp[2] - pa[2])) / ln;
                        let d = vertex_triangle(pp, pa, pb, pc).distance;
                        // Projects inside when the nearest point is the plane's foot.
                        ((d - sd.abs()).abs() < 1e-9 * (1.0 + d), sd)
                    };
                    let mut prev = side(0.0);
                    for k in 1..=2000 {
                        let now = side(k as f64 / 2000.0);
                        if prev.0 && now.0 {
                            prop_assert!((prev.1 < 0.0) == (now.1 < 0.0) || prev.1 == 0.0 || now.1 == 0.0, "a crossing near t = {} was missed", k as f64 / 2000.0);
                        }
                        prev = now;
                    }
                }
            }
            let [p, q, r, s] = pts;
            if let Some((t, _)) = edge_edge_ccd(p, q, r, s, ETA) {
                prop_assert!(edge_edge(at(p, t), at(q, t), at(r, t), at(s, t)).distance <= ETA);
            }
        }
    }
}

mod haptics {
    use largestep::haptics::{latency, replay, DevicePath, GodObject};

    fn nut() -> largestep::io::Mesh {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/tetmesh/nut-surface.off");
        largestep::io::read_surface(&path, 1 << 24).unwrap()
    }

    #[test]
    fn god_object_never_enters_the_surface_and_pushes_back() {
        let m = nut();
        let mut god = GodObject::new(&m, 500.0).unwrap();
        let b = god.bounds();
        let height = b.max[1] - b.min[1];
        let top = god.top();
        let path = DevicePath::stroke(&b, [top[0], top[2]], 0.1 * height);
        let ticks = replay(&mut god, &path).unwrap();
        assert_eq!(ticks.len(), 3001);
        let mut pressed = 0;
        for t in &ticks {
            // The proxy is never inside (every tick, by parity over all triangles).
            assert!(!god.inside(t.proxy), "proxy inside at t = {}", t.time);
            let depth = t
                .proxy
                .iter()
                .zip(&t.device)
                .map(|(p, d)| (p - d) * (p - d))
                .sum::<f64>()
                .sqrt();
            let f = t.force.iter().map(|c| c * c).sum::<f64>().sqrt();
            // The coupling spring: |F| = k |proxy - device|.
            assert!((f - 500.0 * depth).abs() <= 1e-9 * (1.0 + f));
            if god.inside(t.device) {
                pressed += 1;
                assert!(f > 0.0, "no force with the device inside at t = {}", t.time);
            } else {
                // Outside, the proxy reaches the device unless a face is in the way.
                assert!(depth < 0.2 * height);
            }
        }
        assert!(
            pressed > 300,
            "the stroke presses into the nut ({pressed} ticks)"
        );
        // Free space at the start: no force.
        assert_eq!(ticks[0].force, [0.0; 3]);
        // Deterministic replay.
        let again = replay(&mut god, &path).unwrap();
        assert!(ticks
            .iter()
            .zip(&again)
            .all(|(a, b)| a.force == b.force && a.proxy == b.proxy));
        let [p50, _, p99, _] = latency(&ticks);
        assert!(p50 <= p99);
    }

    /// On a convex body the god object rests at the surface point nearest the device (it
    /// minimises its distance to the device over the surface): on a fine sphere the force
    /// is k times the depth below the sphere, along the radius, also while sliding.
    #[test]
    fn god_object_on_a_sphere_is_the_nearest_surface_point() {
        let m = largestep::shapes::uv_sphere([0.0; 3], 1.0, 48, 96);
        let k = 500.0;
        let mut god = GodObject::new(&m, k).unwrap();
        let b = god.bounds();
        let top = god.top();
        let path = DevicePath::stroke(&b, [top[0] + 0.013, top[2] + 0.007], 0.2);
        let ticks = replay(&mut god, &path).unwrap();
        let mut checked = 0;
        for t in &ticks {
            let r = t.device.iter().map(|c| c * c).sum::<f64>().sqrt();
            if r > 0.97 || t.time < 0.2 {
                continue;
            }
            // The mesh lies within the sphere by at most its sagitta (1 - cos(pi / 48)).
            let sag = 1.0 - (std::f64::consts::PI / 48.0).cos();
            let f = t.force.iter().map(|c| c * c).sum::<f64>().sqrt();
            assert!(
                (f / k - (1.0 - r)).abs() <= sag + 1e-6,
                "t {}: |F|/k {} vs depth {}",
                t.time,
                f / k,
                1.0 - r
            );
            let along: f64 = (0..3).map(|a| t.force[a] * t.device[a]).sum::<f64>() / (f * r);
            assert!(along > 0.99, "t {}: force not radial ({along})", t.time);
            checked += 1;
        }
        assert!(checked > 1000, "{checked} ticks checked");
    }

    #[test]
    fn bad_paths_and_starts_are_named() {
        let e = DevicePath::parse("t,x,y,z\n0,0,0,0\n0.001,1,2\n", "p.csv")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("p.csv") && e.contains("3") && e.contains("4 fields"),
            "{e}"
        );
        let e = DevicePath::parse("0,0,0,0\n0,1,1,1\n", "p.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") || e.contains(":2"), "{e}");
        assert!(e.contains("increase"), "{e}");
        let e = DevicePath::parse("0,0,nan,0\n", "p.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("finite"), "{e}");
        let e = DevicePath::parse("# nothing\n", "p.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no positions"), "{e}");
        let e = DevicePath::parse("time,x,y,z\n", "p.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("header"), "{e}");
        let m = nut();
        let mut god = GodObject::new(&m, 500.0).unwrap();
        let c = god.bounds().center();
        // The nut's centre is its hole: find a point inside the solid by its vertices.
        let inside = (0..m.positions.len() / 3)
            .map(|i| {
                let v = m.as_ref().vertex(i);
                [
                    0.999 * v[0] + 0.001 * c[0],
                    0.999 * v[1] + 0.001 * c[1],
                    0.999 * v[2] + 0.001 * c[2],
                ]
            })
            .find(|p| god.inside(*p))
            .expect("a point just inside a vertex");
        let e = god.reset(inside).unwrap_err();
        assert!(e.contains("inside the surface"), "{e}");
        // A non-finite device position: no force, the proxy stays.
        god.reset([c[0], god.bounds().max[1] + 1.0, c[2]]).unwrap();
        let before = god.proxy();
        assert_eq!(god.tick([f64::NAN, 0.0, 0.0]), [0.0; 3]);
        assert_eq!(god.proxy(), before);
        // An open surface is refused.
        let mut open = m.clone();
        open.triangles = m.triangles[1..].to_vec().into();
        assert!(GodObject::new(&open, 500.0)
            .unwrap_err()
            .to_string()
            .contains("open"));
        assert!(GodObject::new(&m, -1.0)
            .unwrap_err()
            .to_string()
            .contains("stiffness"));
    }
}

mod six_dof {
    use largestep::collide::SdfGrid;
    use largestep::haptics::SixDof;
    use largestep::kernels::interp::Grid3;
    use largestep::kernels::quat::{exp as quat_exp, log as quat_log, IDENTITY};
    use std::sync::Arc;

    /// The floor `y <= 0` as a distance grid (trilinear reads of a linear field are
    /// exact).
    fn floor() -> Arc<SdfGrid> {
        let grid = Grid3::spanning([51, 31, 51], [-0.5, -0.3, -0.5], [0.5, 0.3, 0.5]);
        Arc::new(SdfGrid::sample(grid, |p| p[1]))
    }

    /// A cube of side 0.1 as a point shell: the surface points of a 5 x 5 x 5 lattice.
    fn cube() -> Vec<[f64; 3]> {
        let mut s = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                for k in 0..5 {
                    if [i, j, k].iter().any(|&c| c == 0 || c == 4) {
                        s.push([i, j, k].map(|c| -0.05 + 0.025 * c as f64));
                    }
                }
            }
        }
        s
    }

    #[test]
    fn pressed_flat_the_coupling_and_the_contacts_are_springs_in_series() {
        let (kt, kr, kc) = (1000.0, 10.0, 2e4);
        let mut tool = SixDof::new(cube(), floor(), kt, kr, kc).unwrap();
        tool.reset([0.0, 0.2, 0.0], IDENTITY);
        // Free: the tool follows the device exactly.
        let w = tool.tick([0.01, 0.15, -0.02], quat_exp([0.0, 0.0, 0.3]));
        assert!(
            w.force.iter().chain(&w.torque).all(|c| c.abs() < 1e-9),
            "{w:?}"
        );
        assert_eq!(w.contacts, 0);
        // The device 1 cm below resting contact (the cube's bottom at y = 0).
        let d = 0.01;
        tool.reset([0.0, 0.05, 0.0], IDENTITY);
        let w = tool.tick([0.0, 0.05 - d, 0.0], IDENTITY);
        let n = 25.0; // the bottom face's points
        let want = kt * kc * n * d / (kt + kc * n);
        assert!(
            (w.force[1] - want).abs() < 1e-9 * want,
            "F_y {} vs {want}",
            w.force[1]
        );
        assert!(w.force[0].abs() < 1e-9 && w.force[2].abs() < 1e-9);
        assert!(w.torque.iter().all(|c| c.abs() < 1e-9), "{:?}", w.torque);
        assert_eq!(w.contacts, 25);
        assert!((tool.penetration() - (d - want / kt)).abs() < 1e-9);
    }

    #[test]
    fn pressed_tilted_the_floor_flattens_the_tool() {
        let mut tool = SixDof::new(cube(), floor(), 1000.0, 10.0, 2e4).unwrap();
        tool.reset([0.0, 0.06, 0.0], IDENTITY);
        let tilt = quat_exp([0.0, 0.0, 10f64.to_radians()]);
        let mut w = tool.tick([0.0, 0.06, 0.0], tilt);
        for step in 0..50 {
            // Lower the device 0.4 mm a tick, 2 cm in all.
            w = tool.tick([0.0, 0.06 - 0.0004 * (step + 1) as f64, 0.0], tilt);
        }
        // The floor pushes straight up: no force along it.
        assert!(
            w.force[0].abs() < 1e-6 * w.force[1] && w.force[2].abs() < 1e-6 * w.force[1],
            "{w:?}"
        );
        assert!(w.force[1] > 0.0 && w.contacts > 0);
        // The tool is tilted less than the device: the contact torque opposes the
        // coupling's, about z only.
        let (_, q) = tool.pose();
        let tilt_tool = quat_log(q)[2];
        assert!(
            tilt_tool.abs() < 10f64.to_radians() && tilt_tool > 0.0,
            "tool tilt {tilt_tool}"
        );
        assert!(w.torque[0].abs() < 1e-9 && w.torque[1].abs() < 1e-9);
        assert!(
            w.torque[2] < 0.0,
            "the coupling turns the device back towards the tool"
        );
        // Bad input: named.
        assert!(SixDof::new(Vec::new(), floor(), 1.0, 1.0, 1.0)
            .unwrap_err()
            .contains("no points"));
        assert!(SixDof::new(cube(), floor(), 1.0, 0.0, 1.0)
            .unwrap_err()
            .contains("k_rotation"));
        assert!(SixDof::new(vec![[f64::NAN; 3]], floor(), 1.0, 1.0, 1.0)
            .unwrap_err()
            .contains("shell point 0"));
        let before = tool.pose();
        assert_eq!(tool.tick([f64::NAN; 3], IDENTITY).force, [0.0; 3]);
        assert_eq!(tool.pose(), before);
    }

    #[test]
    fn a_point_shell_covers_the_tool_surface_at_its_spacing() {
        use largestep::haptics::point_shell;
        let cube = largestep::shapes::cuboid([0.0; 3], [1.0; 3]);
        let shell = point_shell(&cube, 0.5, 1000).unwrap();
        // 8 corners; 12 cube edges of one interior point each and 6 face diagonals of
        // two; one point inside each of the 12 triangles (longest edge sqrt 2: 3 pieces).
        assert_eq!(shell.len(), 8 + 12 + 6 * 2 + 12);
        for (i, p) in shell.iter().enumerate() {
            // On the surface: some coordinate at 0 or 1, all within.
            assert!(p.iter().all(|c| (-1e-12..=1.0 + 1e-12).contains(c)));
            assert!(p.iter().any(|c| c.abs() < 1e-12 || (c - 1.0).abs() < 1e-12));
            // Each point once.
            for q in &shell[..i] {
                assert!(
                    p.iter().zip(q).any(|(a, b)| (a - b).abs() > 1e-9),
                    "{p:?} twice"
                );
            }
        }
        // Every point of the surface is within a spacing of some shell point.
        let fine = point_shell(&cube, 0.05, 100_000).unwrap();
        let far = fine
            .iter()
            .map(|p| {
                shell
                    .iter()
                    .map(|q| p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum::<f64>())
                    .fold(f64::INFINITY, f64::min)
                    .sqrt()
            })
            .fold(0.0, f64::max);
        assert!(far <= 0.5, "a surface point {far} from the shell");
        // Bad input: named, and the count checked before allocating.
        assert!(point_shell(&cube, 0.0, 10).unwrap_err().contains("spacing"));
        assert!(point_shell(&cube, 1e-4, 1000)
            .unwrap_err()
            .contains("limit of 1000"));
    }

    #[test]
    fn device_paths_carry_orientations_and_interpolate_them() {
        use largestep::haptics::DevicePath;
        let text = "t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,1,0,0,0,0,0,2\n";
        let p = DevicePath::parse(text, "pose.csv").unwrap();
        assert!(p.turns());
        // Normalised on reading; half way is half the turn (pi about z at t = 1).
        assert_eq!(p.orientations[1], [0.0, 0.0, 0.0, 1.0]);
        let half = quat_log(p.orientation_at(0.5));
        assert!(
            (half[2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12,
            "{half:?}"
        );
        assert!((p.at(0.5)[0] - 0.5).abs() < 1e-15);
        // Written and read back, the same path.
        assert_eq!(DevicePath::parse(&p.to_csv(), "again.csv").unwrap(), p);
        // Positions only: identity orientations, written as four columns.
        let q = DevicePath::parse("0,0,0,0\n1,0,1,0\n", "q.csv").unwrap();
        assert!(!q.turns() && q.to_csv().starts_with("t,x,y,z\n0,"));
        // Bad rows name the file and line.
        let e = DevicePath::parse("0,0,0,0,1,0,0,0\n1,0,0,0\n", "mixed.csv").unwrap_err();
        assert!(e.to_string().contains("mixed.csv") && e.line == 2, "{e}");
        let e =
            DevicePath::parse("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,0,0,0,0\n", "zero.csv").unwrap_err();
        assert!(e.line == 2 && e.to_string().contains("zero"), "{e}");
        let e = DevicePath::parse("0,0,0,0,1\n", "five.csv").unwrap_err();
        assert!(e.to_string().contains("found 5"), "{e}");
    }

    #[test]
    fn a_tool_replayed_along_a_stroke_stays_out_and_pushes_back() {
        use largestep::haptics::{point_shell, replay_tool, tool_trace_csv, DevicePath};
        // The shared nut's distance field; a 12 x 6 x 12 block tool pressed a tenth of
        // the nut's height into its top face, slid and tilted (the CLI's stroke).
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/tetmesh/nut-surface.off");
        let nut = largestep::io::read_surface(&path, 1 << 24).unwrap();
        let h = 1.0;
        let field = Arc::new(SdfGrid::from_mesh(&nut, h, 12, 1 << 24).unwrap());
        let block = largestep::shapes::cuboid([-6.0, -3.0, -6.0], [6.0, 3.0, 6.0]);
        let shell = point_shell(&block, h, 100_000).unwrap();
        let mut tool = SixDof::new(shell, field, 500.0, 500.0 * 72.0, 2000.0).unwrap();
        let bounds = largestep::kernels::collide::bv::Aabb::of_points(
            (0..nut.positions.len() / 3).map(|i| nut.as_ref().vertex(i)),
        );
        let depth = 0.1 * (bounds.max[1] - bounds.min[1]);
        let over = [
            0.75 * bounds.min[0] + 0.25 * bounds.max[0],
            0.5 * (bounds.min[2] + bounds.max[2]),
        ];
        let mut stroke = DevicePath::stroke(&bounds, over, depth);
        for p in &mut stroke.positions {
            p[1] += 3.0;
        }
        stroke.tilt([0.0, 0.0, 0.35], 1.0, 2.5);
        let ticks = replay_tool(&mut tool, &stroke);
        assert_eq!(ticks.len(), 3001);
        let pressed: Vec<_> = ticks.iter().filter(|t| t.wrench.contacts > 0).collect();
        assert!(pressed.len() > 300, "{} ticks in contact", pressed.len());
        for t in &ticks {
            // The contacts hold the tool well above the device: its deepest point at most
            // a tenth of the device's depth into the nut.
            assert!(
                t.penetration < 0.1 * depth,
                "{} deep at t = {}",
                t.penetration,
                t.time
            );
            // The surface pushes up while the tool presses on the top face (before it
            // reaches the hole).
            if t.time > 0.7 && t.time < 1.0 {
                assert!(t.wrench.force[1] > 0.0 && t.wrench.contacts > 0, "{t:?}");
            }
        }
        let csv = tool_trace_csv(&ticks);
        assert_eq!(csv.lines().count(), 3002);
        assert!(csv.lines().all(|l| l.split(',').count() == 24));
    }
}

/// A moving obstacle taken back in time (the pose a sub-step meets): a point of the body
/// keeps its distance to it when moved back with the rigid motion, two steps back are
/// one step of their sum back, and a point of the surface moves back at the velocity
/// the contacts use (`velocity_at`), to first order.
#[test]
fn moving_obstacles_go_back_along_their_motion() {
    use largestep::collide::{MovingObstacle, Obstacle};
    use largestep::kernels::rotation::exp_matrix;
    let center = [0.3, 1.1, -0.4];
    let axes = {
        let r = exp_matrix([0.3, -0.7, 0.2]);
        [0, 1, 2].map(|c| [r[0][c], r[1][c], r[2][c]])
    };
    let shapes = [
        Obstacle::Oriented {
            center,
            axes,
            half: [0.5, 0.2, 0.3],
        },
        Obstacle::Sphere {
            center,
            radius: 0.4,
        },
        Obstacle::Capsule {
            a: [0.1, 1.0, -0.4],
            b: [0.6, 1.3, -0.2],
            radius: 0.15,
        },
        Obstacle::Hull {
            points: std::sync::Arc::from(
                &[
                    [0.0, 0.0, 0.0],
                    [0.4, 0.0, 0.0],
                    [0.0, 0.5, 0.0],
                    [0.0, 0.0, 0.3],
                ][..],
            ),
            edges: std::sync::Arc::from(&[[[0.0, 0.0, 0.0], [0.4, 0.0, 0.0]]][..]),
            center,
            axes,
        },
        Obstacle::plane_through([0.2, 0.9, -0.3], [0.1, 1.0, 0.2]).unwrap(),
    ];
    let (v, w) = ([0.4, -1.2, 0.7], [2.0, -0.5, 1.5]);
    // The rigid motion back by s (rad/s and m/s constant), independently of `earlier`.
    let back = |p: [f64; 3], s: f64| -> [f64; 3] {
        let r = exp_matrix(w.map(|c| -s * c));
        let d: [f64; 3] = std::array::from_fn(|k| p[k] - center[k]);
        std::array::from_fn(|k| {
            center[k] - s * v[k] + r[k][0] * d[0] + r[k][1] * d[1] + r[k][2] * d[2]
        })
    };
    let probes: Vec<[f64; 3]> = (0..40)
        .map(|k| {
            let t = k as f64;
            [
                0.3 + 0.7 * (1.3 * t).sin(),
                1.1 + 0.6 * (0.7 * t).cos(),
                -0.4 + 0.5 * (2.1 * t).sin(),
            ]
        })
        .collect();
    for shape in shapes {
        let now = MovingObstacle {
            shape: shape.clone(),
            center,
            velocity: v,
            angular_velocity: w,
        };
        let same = now.earlier(0.0);
        let s = 0.013;
        let then = now.earlier(s);
        let twice = now.earlier(0.005).earlier(0.008);
        for &p in &probes {
            let (Some((d, _)), Some((z, _)), Some((e, _)), Some((f, _))) = (
                shape.distance(p),
                same.shape.distance(p),
                then.shape.distance(back(p, s)),
                twice.shape.distance(back(p, s)),
            ) else {
                continue;
            };
            assert!(
                (d - z).abs() < 1e-12,
                "{shape:?}: {d} against {z} not moved"
            );
            assert!((d - e).abs() < 1e-9, "{shape:?}: {d} against {e}");
            assert!(
                (d - f).abs() < 1e-9,
                "{shape:?}: {d} against {f} in two steps"
            );
            // First order: the point moved back by s times the surface's velocity.
            let u = now.velocity_at(p);
            let q: [f64; 3] = std::array::from_fn(|k| p[k] - s * u[k]);
            let g = then.shape.distance(q).unwrap().0;
            assert!(
                (d - g).abs() < 2.0 * s * s * 4.0,
                "{shape:?}: {d} against {g}"
            );
        }
    }
}
