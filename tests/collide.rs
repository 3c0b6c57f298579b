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
        Cells::Dense { origin: [0.0; 3], dims: [5, 4, 6] },
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
            g.point_pairs(r, &mut got);
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
        prop_assert_eq!(sorted(got), want);
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
