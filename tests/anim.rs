//! Character animation: BVH motion capture read and written, skeletons, forward
//! kinematics against an independent implementation, pose blending, bad input.

use largestep::anim::bvh::Bvh;
use largestep::anim::skin::{SkinDesc, SkinMethod, SkinWork};
use largestep::anim::{add_layer, additive_delta, blend, JointDesc, Pose, SkeletonDesc};
use largestep::kernels::quat;
use std::path::PathBuf;

fn clip_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mocap/mixamo-freebvh.bvh")
}

fn clip() -> Bvh {
    Bvh::read(&clip_path(), 1 << 24).unwrap()
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("largestep-anim-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn reads_the_shared_clip() {
    let b = clip();
    // 55 joints with channels and 15 End Sites.
    assert_eq!(b.joints.len(), 70);
    assert_eq!(b.joints.iter().filter(|j| j.end_site).count(), 15);
    assert_eq!(b.channel_count(), 6 + 3 * 54);
    assert_eq!(b.frames(), 69);
    assert!((b.frame_time - 0.0333333).abs() < 1e-15);
    assert_eq!(b.joints[0].name, "mixamorig:Hips");
    assert!(b.joints[0].parent.is_none());
}

/// World positions against scipy's rotations (tests/reference/bvh_fk_scipy.py, an
/// independent reading of the same file: intrinsic rotations in channel order).
#[test]
fn forward_kinematics_matches_an_independent_implementation() {
    let b = clip();
    let cases: [(usize, &str, [f64; 3]); 6] = [
        (
            0,
            "mixamorig:LeftHand",
            [26.45787044716565, 88.6909066837909, -2.275492847821453],
        ),
        (
            0,
            "mixamorig:HeadTop_End_end",
            [-1.3799062804033086, 175.93996387291187, 11.977023581675946],
        ),
        (
            0,
            "mixamorig:RightToeBase_end",
            [-3.2874159673457135, 0.17552118150165957, 21.312808325636446],
        ),
        (
            40,
            "mixamorig:LeftHand",
            [-27.854970560223734, 88.07244092427965, 64.16718617472196],
        ),
        (
            40,
            "mixamorig:HeadTop_End_end",
            [14.836914661010136, 173.24134848452115, 68.5546006488859],
        ),
        (
            40,
            "mixamorig:RightToeBase",
            [11.221300846422677, 0.30265082937395427, 110.38602946489574],
        ),
    ];
    for (frame, name, want) in cases {
        let p = b.positions(frame).unwrap();
        let j = b.joints.iter().position(|j| j.name == name).unwrap();
        for c in 0..3 {
            assert!(
                (p[j][c] - want[c]).abs() < 1e-9,
                "{name} at frame {frame}: {:?} vs {want:?}",
                p[j]
            );
        }
    }
}

/// Read, write, read gives the identical clip; tabs or spaces and CRLF read the same.
#[test]
fn bvh_read_write_read_is_identical() {
    let a = clip();
    let mut text = Vec::new();
    a.write(&mut text).unwrap();
    let text = String::from_utf8(text).unwrap();
    let b = Bvh::parse(&text, "written.bvh").unwrap();
    assert_eq!(a, b);
    let spaced = text.replace('\t', "  ").replace('\n', "\r\n");
    assert_eq!(Bvh::parse(&spaced, "spaced.bvh").unwrap(), a);
}

/// Any channel order per joint; position channels on a non-root joint; braces on the
/// joint's line.
#[test]
fn channel_orders_and_layouts() {
    let text = "HIERARCHY\nROOT a {\n OFFSET 1 2 3\n CHANNELS 6 Xrotation Zposition Yrotation Xposition Zrotation Yposition\n JOINT b\n {\n  OFFSET 0 1 0\n  CHANNELS 4 Yrotation Xposition Xrotation Zrotation\n  End Site\n  {\n   OFFSET 0 2 0\n  }\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.5\n90 1 0 2 0 3 0 0.5 0 0\n";
    let b = Bvh::parse(text, "t.bvh").unwrap();
    assert_eq!(b.joints[2].name, "b_end");
    let p = b.positions(0).unwrap();
    // Root: translation (1+2, 2+3, 3+1), rotated 90 degrees about x.
    let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|c| (a[c] - b[c]).abs() < 1e-12);
    assert!(close(p[0], [3.0, 5.0, 4.0]), "{:?}", p[0]);
    // b: offset (0.5, 1, 0) in the root frame, turned by Rx(90): (0.5, 0, 1).
    assert!(close(p[1], [3.5, 5.0, 5.0]), "{:?}", p[1]);
    // b's end: (0, 2, 0) under Rx(90) -> (0, 0, 2).
    assert!(close(p[2], [3.5, 5.0, 7.0]), "{:?}", p[2]);
}

fn expect_error(text: &str, line: usize, words: &str) {
    match Bvh::parse(text, "bad.bvh") {
        Ok(_) => panic!("accepted: {text}"),
        Err(e) => {
            let s = e.to_string();
            assert_eq!(e.line, line, "{s}");
            assert!(s.starts_with("bad.bvh:"), "{s}");
            assert!(s.contains(words), "{s} lacks '{words}'");
        }
    }
}

const GOOD: &str = "HIERARCHY\nROOT r\n{\n\tOFFSET 0 0 0\n\tCHANNELS 3 Zrotation Yrotation Xrotation\n\tEnd Site\n\t{\n\t\tOFFSET 0 1 0\n\t}\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n1 2 3\n4 5 6\n";

#[test]
fn bad_files_are_named_by_line() {
    assert!(Bvh::parse(GOOD, "good.bvh").is_ok());
    expect_error(
        &GOOD.replace("4 5 6", "4 5"),
        15,
        "has 2 values; the hierarchy has 3 channels",
    );
    expect_error(&GOOD.replace("1 2 3", "1 2 3 7"), 14, "has 4 values");
    expect_error(
        &GOOD.replace("4 5 6\n", ""),
        14,
        "2 frames declared, 1 motion lines found",
    );
    expect_error(
        &format!("{GOOD}7 8 9\n"),
        16,
        "more motion lines than the 2 frames",
    );
    expect_error(
        &GOOD.replace("Zrotation Yrotation", "Wrotation Yrotation"),
        5,
        "unknown channel 'Wrotation'",
    );
    expect_error(
        &GOOD.replace("Zrotation Yrotation", "Yrotation Yrotation"),
        5,
        "appears twice",
    );
    expect_error(
        &GOOD.replace("CHANNELS 3", "CHANNELS 4"),
        5,
        "CHANNELS says 4 but names 3",
    );
    expect_error(
        &GOOD.replace("0.1", "0"),
        13,
        "not a positive number of seconds",
    );
    expect_error(&GOOD.replace("0.1", "nan"), 13, "not a positive number");
    expect_error(
        &GOOD.replace("4 5 6", "4 x 6"),
        15,
        "'x' is not a finite number",
    );
    expect_error(
        &GOOD.replace("Frames: 2", "Frames: 99999999999999"),
        12,
        "more values than the file can hold",
    );
    expect_error(&GOOD.replace("\tOFFSET 0 1 0\n", ""), 8, "has no OFFSET");
    expect_error(
        &GOOD.replace("OFFSET 0 1 0", "OFFSET 0 1"),
        8,
        "OFFSET needs three numbers",
    );
    expect_error(&GOOD.replace("}\nMOTION", "MOTION"), 10, "not closed");
    expect_error(&GOOD.replace("MOTION\n", ""), 11, "MOTION line missing");
}

/// Random edits of a valid file never panic: each gives a clip or a located error.
#[test]
fn mangled_files_never_panic() {
    use proptest::prelude::*;
    let base = GOOD.to_string();
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(512));
    runner
        .run(
            &(
                0usize..GOOD.len(),
                0usize..8,
                prop::sample::select(vec![
                    "",
                    "}",
                    "{",
                    "-",
                    "1e999",
                    "\n",
                    "End Site",
                    "JOINT j",
                    "CHANNELS 9",
                ]),
            ),
            |(at, cut, insert)| {
                let mut s = base.clone();
                let at = (0..=at).rev().find(|&i| s.is_char_boundary(i)).unwrap();
                let end = (at + cut).min(s.len());
                s.replace_range(at..end, insert);
                match Bvh::parse(&s, "m.bvh") {
                    Ok(b) => {
                        for k in 0..b.frames() {
                            let _ = b.positions(k);
                        }
                    }
                    Err(e) => prop_assert!(e.line > 0 || e.message.contains("ROOT"), "{e}"),
                }
                Ok(())
            },
        )
        .unwrap();
}

fn two_bone_skeleton() -> SkeletonDesc {
    SkeletonDesc {
        joints: vec![
            JointDesc::new("root", None, [0.0, 0.0, 0.0]),
            JointDesc::new("elbow", Some(0), [1.0, 0.0, 0.0]),
            JointDesc::new("hand", Some(1), [1.0, 0.0, 0.0]),
        ],
    }
}

#[test]
fn skeleton_build_names_the_bad_joint() {
    let mut d = two_bone_skeleton();
    d.joints[2].parent = Some(2);
    let e = d.build().unwrap_err();
    assert_eq!(e.index, 2);
    assert!(e.to_string().contains("joint 2 (hand)"), "{e}");
    let mut d = two_bone_skeleton();
    d.joints[1].name = "root".into();
    assert!(d
        .build()
        .unwrap_err()
        .to_string()
        .contains("same name as joint 0"));
    let mut d = two_bone_skeleton();
    d.joints[1].translation[0] = f64::NAN;
    assert!(d.build().is_err());
}

/// Blending two poses halfway turns the elbow by the mean angle; an additive layer of
/// the difference, at full weight, takes the first pose to the second.
#[test]
fn blending_and_additive_layers() {
    let s = two_bone_skeleton().build().unwrap();
    let mut a = s.rest().clone();
    let mut b = s.rest().clone();
    let z = |t: f64| quat::exp([0.0, 0.0, t]);
    a.set(1, [1.0, 0.0, 0.0], z(0.2), [1.0; 3]);
    // The same rotation in the other hemisphere: blending must not cancel it.
    let q = z(1.0).map(|c| -c);
    b.set(1, [1.0, 0.0, 0.0], q, [1.0; 3]);
    let mut out = Pose::identity(3);
    blend(&mut out, &[(&a, 1.0), (&b, 1.0)], s.rest());
    let angle = quat::log(out.rotation(1))[2];
    assert!((angle - 0.6).abs() < 1e-12, "{angle}");
    // Weights 3:1 give NLERP at t = 1/4 (between 0.2 and 1.0, not linear in angle).
    blend(&mut out, &[(&a, 3.0), (&b, 1.0)], s.rest());
    let angle = quat::log(out.rotation(1))[2];
    assert!(angle > 0.35 && angle < 0.45, "{angle}");
    // No weight: the rest pose.
    blend(&mut out, &[(&a, 0.0)], s.rest());
    assert_eq!(&out, s.rest());
    let d = additive_delta(&b, &a);
    let mut c = a.clone();
    add_layer(&mut c, &d, 1.0);
    let (qc, qb) = (c.rotation(1), b.rotation(1));
    let dot: f64 = (0..4).map(|k| qc[k] * qb[k]).sum();
    assert!(dot.abs() > 1.0 - 1e-14);
    // Model positions: the hand at the elbow plus one unit turned by 1 rad.
    let mut model = Vec::new();
    s.model(&c, &mut model);
    let hand = [model[2][3], model[2][7], model[2][11]];
    assert!((hand[0] - (1.0 + 1f64.cos())).abs() < 1e-12 && (hand[1] - 1f64.sin()).abs() < 1e-12);
}

/// `largestep anim fk FILE --frame K --json FILE`: the contract's JSON shape, in file
/// order with End Sites named `<parent>_end`; JSON on standard output without --json;
/// a frame out of range exits with 2 and says how many there are.
#[cfg(feature = "cli")]
#[test]
fn anim_fk_command_writes_the_contract() {
    let exe = env!("CARGO_BIN_EXE_largestep");
    let dir = temp_dir("fk");
    let json = dir.join("fk.json");
    let out = std::process::Command::new(exe)
        .args(["anim", "fk"])
        .arg(clip_path())
        .args(["--frame", "40", "--json"])
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let keys: Vec<_> = v.as_object().unwrap().keys().cloned().collect();
    assert_eq!(keys, ["frame", "joints"]);
    assert_eq!(v["frame"], 40);
    let joints = v["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 70);
    let b = clip();
    for (j, bj) in joints.iter().zip(&b.joints) {
        assert_eq!(j.as_object().unwrap().len(), 2);
        assert_eq!(j["name"], bj.name.as_str());
        assert_eq!(j["position"].as_array().unwrap().len(), 3);
    }
    assert_eq!(joints[7]["name"], "mixamorig:HeadTop_End_end");
    let hand = joints
        .iter()
        .find(|j| j["name"] == "mixamorig:LeftHand")
        .unwrap();
    assert!((hand["position"][0].as_f64().unwrap() + 27.854970560223734).abs() < 1e-9);

    let stdout = std::process::Command::new(exe)
        .args(["anim", "fk"])
        .arg(clip_path())
        .output()
        .unwrap();
    assert!(stdout.status.success());
    let v: serde_json::Value = serde_json::from_slice(&stdout.stdout).unwrap();
    assert_eq!(v["frame"], 0);

    let bad = std::process::Command::new(exe)
        .args(["anim", "fk"])
        .arg(clip_path())
        .args(["--frame", "69"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("the clip has 69 frames"));
}

/// A two-bone arm along x around a closed tube: joint 0 at the origin, joint 1 at
/// x = 1, the weight of joint 1 rising linearly from x = 0.5 to 1.5.
fn arm_skin(rings: usize) -> (largestep::anim::Skeleton, largestep::io::Mesh, SkinDesc) {
    let skeleton = SkeletonDesc {
        joints: vec![
            JointDesc::new("upper", None, [0.0; 3]),
            JointDesc::new("lower", Some(0), [1.0, 0.0, 0.0]),
        ],
    }
    .build()
    .unwrap();
    let mesh = largestep::shapes::tube(2.0, 0.2, rings, 24);
    let n = mesh.positions.len() / 3;
    let mut bind = Vec::new();
    skeleton.model(skeleton.rest(), &mut bind);
    let weights = (0..n)
        .map(|v| {
            let w = ((mesh.positions[v] - 0.5) / 1.0).clamp(0.0, 1.0);
            [1.0 - w, w, 0.0, 0.0]
        })
        .collect();
    let desc = SkinDesc {
        positions: mesh.positions.clone(),
        normals: Vec::new(),
        joints: vec![[0, 1, 0, 0]; n],
        weights,
        bind,
    };
    (skeleton, mesh, desc)
}

/// The bind pose skins to the rest mesh (to f32 rounding of the rest positions).
#[test]
fn bind_pose_skins_to_the_rest_mesh() {
    let (skeleton, mesh, desc) = arm_skin(41);
    let skin = desc.build().unwrap();
    let mut model = Vec::new();
    skeleton.model(skeleton.rest(), &mut model);
    let mut work = SkinWork::default();
    for method in [SkinMethod::Linear, SkinMethod::DualQuaternion] {
        skin.deform(method, &model, &mut work);
        for (a, b) in work.positions.iter().zip(&mesh.positions) {
            let exact = *b as f32;
            assert!(
                (a - exact).abs() <= f32::EPSILON * exact.abs().max(1.0),
                "{method:?}: {a} vs {b}"
            );
        }
    }
}

/// The candy wrapper: twisting the lower bone by 180 degrees collapses linear blend
/// skinning's tube at the joint (the blended matrix loses rank), while dual quaternions
/// keep the volume within a few percent.
#[test]
fn dual_quaternions_keep_the_volume_of_a_twisted_tube() {
    let (skeleton, mesh, desc) = arm_skin(81);
    let skin = desc.build().unwrap();
    let rest_volume = largestep::shapes::enclosed_volume(&mesh);
    // A 24-sided prism of circumradius 0.2 and length 2.
    let prism = 12.0 * 0.04 * (std::f64::consts::TAU / 24.0).sin() * 2.0;
    assert!(
        (rest_volume - prism).abs() < 1e-12 * prism,
        "{rest_volume} vs {prism}"
    );
    let mut pose = skeleton.rest().clone();
    pose.set(
        1,
        [1.0, 0.0, 0.0],
        quat::exp([std::f64::consts::PI * 0.999, 0.0, 0.0]),
        [1.0; 3],
    );
    let mut model = Vec::new();
    skeleton.model(&pose, &mut model);
    let mut work = SkinWork::default();
    let mut volume = |method| {
        skin.deform(method, &model, &mut work);
        let mut m = mesh.clone();
        m.positions = work.positions.iter().map(|&x| x as f64).collect();
        largestep::shapes::enclosed_volume(&m) / rest_volume
    };
    let lbs = volume(SkinMethod::Linear);
    let dqs = volume(SkinMethod::DualQuaternion);
    eprintln!("volume kept under a 180 degree twist: LBS {lbs:.4}, DQS {dqs:.4}");
    assert!(lbs < 0.75, "LBS keeps {lbs} of the volume");
    assert!((dqs - 1.0).abs() < 0.05, "DQS keeps {dqs} of the volume");
}

/// Bad skins are refused naming the vertex.
#[test]
fn bad_skins_name_the_vertex() {
    let (_, _, desc) = arm_skin(5);
    let mut d = desc.clone();
    // Vertex 80 lies on the ring at x = 1.5, all on joint 1; a zero-weight slot may
    // name any joint, a weighted one may not.
    d.joints[80] = [7, 5, 0, 0];
    let e = d.build().err().unwrap().to_string();
    assert!(e.starts_with("vertex 80: influence 1 names joint 5"), "{e}");
    let mut d = desc.clone();
    d.weights[3] = [0.0; 4];
    assert!(d.build().err().unwrap().to_string().contains("vertex 3"));
    let mut d = desc.clone();
    d.weights[2][0] = f64::NAN;
    assert!(d.build().err().unwrap().to_string().contains("vertex 2"));
    let mut d = desc;
    d.positions.pop();
    assert!(d.build().is_err());
}

/// A clip sampled at a frame's time gives that frame; between frames the hand moves
/// between its two positions; times out of range clamp, or wrap when looping.
#[test]
fn clip_sampling() {
    let b = clip();
    let c = largestep::anim::clip::Clip::from_bvh(&b);
    assert_eq!(c.frames(), 69);
    let s = b.skeleton().build().unwrap();
    let mut pose = Pose::identity(s.len());
    let mut model = Vec::new();
    let hand = s.find("mixamorig:LeftHand").unwrap();
    let at = |pose: &Pose, model: &mut Vec<_>| {
        s.model(pose, model);
        let m: &largestep::anim::Affine = &model[hand];
        [m[3], m[7], m[11]]
    };
    for k in [0, 17, 68] {
        c.sample(k as f64 * c.frame_time(), false, &mut pose);
        let p = at(&pose, &mut model);
        let want = b.positions(k).unwrap()[hand];
        assert!((0..3).all(|i| (p[i] - want[i]).abs() < 1e-9), "frame {k}");
    }
    c.sample(10.5 * c.frame_time(), false, &mut pose);
    let mid = at(&pose, &mut model);
    let (p10, p11) = (
        b.positions(10).unwrap()[hand],
        b.positions(11).unwrap()[hand],
    );
    let gap = (0..3)
        .map(|i| (p11[i] - p10[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    let off = (0..3)
        .map(|i| (mid[i] - 0.5 * (p10[i] + p11[i])).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(off < 0.05 * gap + 1e-9, "{off} vs gap {gap}");
    c.sample(1e9, false, &mut pose);
    let end = at(&pose, &mut model);
    let last = b.positions(68).unwrap()[hand];
    assert!((0..3).all(|i| (end[i] - last[i]).abs() < 1e-9));
    c.sample(c.duration() + 2.0 * c.frame_time(), true, &mut pose);
    let wrapped = at(&pose, &mut model);
    let second = b.positions(2).unwrap()[hand];
    assert!((0..3).all(|i| (wrapped[i] - second[i]).abs() < 1e-6));
    c.sample(f64::NAN, true, &mut pose);
}

mod ik {
    use super::*;
    use largestep::anim::ik::{Effector, Ik, IkJoint, IkMethod};

    /// Bones along x of the given lengths, each joint a child of the one before.
    fn arm(lengths: &[f64]) -> largestep::anim::Skeleton {
        let mut joints = vec![JointDesc::new("j0", None, [0.0; 3])];
        for (i, l) in lengths.iter().enumerate() {
            joints.push(JointDesc::new(
                &format!("j{}", i + 1),
                Some(i),
                [*l, 0.0, 0.0],
            ));
        }
        SkeletonDesc { joints }.build().unwrap()
    }

    fn hand(s: &largestep::anim::Skeleton, pose: &Pose, j: usize) -> [f64; 3] {
        let mut m = Vec::new();
        s.model(pose, &mut m);
        [m[j][3], m[j][7], m[j][11]]
    }

    /// A two-link planar arm (hinges about z, links 1 and 0.8) reaches a target with
    /// every method, at the closed-form angles of the elbow-up solution it starts near.
    #[test]
    fn two_link_arm_matches_the_closed_form() {
        let s = arm(&[1.0, 0.8]);
        let (l1, l2) = (1.0f64, 0.8f64);
        let target = [1.1, 0.9, 0.0];
        let (x, y) = (target[0], target[1]);
        let d = (x * x + y * y - l1 * l1 - l2 * l2) / (2.0 * l1 * l2);
        let t2 = d.acos();
        let t1 = y.atan2(x) - (l2 * t2.sin()).atan2(l1 + l2 * t2.cos());
        for method in IkMethod::all(0.05) {
            let mut ik = Ik::new(
                &s,
                vec![IkJoint::free(0, &[2]), IkJoint::free(1, &[2])],
                method,
            )
            .unwrap();
            ik.tolerance = 1e-9;
            ik.max_iterations = 2000;
            let mut pose = s.rest().clone();
            let mut angles = [0.2, 0.6];
            let r = ik
                .solve(&s, &mut pose, &mut angles, &[Effector { joint: 2, target }])
                .unwrap();
            assert!(r.reached[0], "{}: {r:?}", method.name());
            assert!(
                (angles[0] - t1).abs() < 1e-6 && (angles[1] - t2).abs() < 1e-6,
                "{}: {angles:?} vs {t1} {t2}",
                method.name()
            );
            let h = hand(&s, &pose, 2);
            assert!((0..3).all(|c| (h[c] - target[c]).abs() < 1e-8));
            eprintln!("{}: {} iterations", method.name(), r.iterations);
        }
    }

    /// Damped least squares on a target beyond reach settles at the closest pose (the
    /// arm straight toward it), reports it unreached, and stops instead of oscillating.
    #[test]
    fn damped_least_squares_settles_on_unreachable_targets() {
        let s = arm(&[1.0, 1.0, 1.0]);
        let joints = (0..3).map(|j| IkJoint::free(j, &[0, 1, 2])).collect();
        let mut ik = Ik::new(&s, joints, IkMethod::DampedLeastSquares { lambda: 0.1 }).unwrap();
        ik.max_iterations = 500;
        let target = [2.0, 3.0, 1.0];
        let mut pose = s.rest().clone();
        let mut angles = [0.1; 9];
        let r = ik
            .solve(&s, &mut pose, &mut angles, &[Effector { joint: 3, target }])
            .unwrap();
        let reach = (4.0f64 + 9.0 + 1.0).sqrt() - 3.0;
        assert!(!r.reached[0]);
        assert!((r.distances[0] - reach).abs() < 1e-4, "{r:?} vs {reach}");
        assert!(r.iterations < 500, "it stopped by itself: {r:?}");
        // One more solve from there moves nothing.
        let before = angles;
        let r2 = ik
            .solve(&s, &mut pose, &mut angles, &[Effector { joint: 3, target }])
            .unwrap();
        assert!((r2.distances[0] - r.distances[0]).abs() < 1e-6);
        assert!(before
            .iter()
            .zip(&angles)
            .all(|(a, b)| (a - b).abs() < 1e-2));
    }

    /// Limits hold: an elbow allowed 0 to 0.5 rad stops at 0.5 when the target asks
    /// for more; two effectors on a forked skeleton are reached together.
    #[test]
    fn limits_and_several_effectors() {
        let s = arm(&[1.0, 1.0]);
        let mut elbow = IkJoint::free(1, &[2]);
        elbow.limits = vec![(0.0, 0.5)];
        let ik = Ik::new(
            &s,
            vec![IkJoint::free(0, &[2]), elbow],
            IkMethod::DampedLeastSquares { lambda: 0.01 },
        )
        .unwrap();
        let mut pose = s.rest().clone();
        let mut angles = [0.0, 0.1];
        let r = ik
            .solve(
                &s,
                &mut pose,
                &mut angles,
                &[Effector {
                    joint: 2,
                    target: [0.3, 0.5, 0.0],
                }],
            )
            .unwrap();
        assert!(!r.reached[0]);
        assert!(angles[1] <= 0.5 && angles[1] >= 0.0);
        assert!((angles[1] - 0.5).abs() < 1e-9, "{angles:?}");

        let fork = SkeletonDesc {
            joints: vec![
                JointDesc::new("root", None, [0.0; 3]),
                JointDesc::new("a", Some(0), [1.0, 0.0, 0.0]),
                JointDesc::new("a_tip", Some(1), [1.0, 0.0, 0.0]),
                JointDesc::new("b", Some(0), [0.0, 1.0, 0.0]),
                JointDesc::new("b_tip", Some(3), [0.0, 1.0, 0.0]),
            ],
        }
        .build()
        .unwrap();
        // The root turns too, so the two effectors pull on one shared joint.
        let joints = [0, 1, 3]
            .into_iter()
            .map(|j| IkJoint::free(j, &[0, 1, 2]))
            .collect();
        let ik = Ik::new(&fork, joints, IkMethod::DampedLeastSquares { lambda: 0.01 }).unwrap();
        let mut pose = fork.rest().clone();
        let mut angles = [0.0; 9];
        let targets = [
            Effector {
                joint: 2,
                target: [0.9, 0.9, 0.7],
            },
            Effector {
                joint: 4,
                target: [-0.8, 1.1, 0.6],
            },
        ];
        let r = ik.solve(&fork, &mut pose, &mut angles, &targets).unwrap();
        assert!(r.reached.iter().all(|&x| x), "{r:?}");
    }

    /// Bad chains are refused naming the joint.
    #[test]
    fn bad_chains_name_the_joint() {
        let s = arm(&[1.0, 0.0, 1.0]);
        let e = Ik::new(
            &s,
            vec![IkJoint::free(0, &[2]), IkJoint::free(2, &[2])],
            IkMethod::Transpose,
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("joint 2 (j2): zero-length bone"),
            "{e}"
        );
        let e = Ik::new(&s, vec![IkJoint::free(0, &[2, 2])], IkMethod::Transpose).unwrap_err();
        assert!(e.to_string().contains("not distinct"), "{e}");
        let e = Ik::new(&s, vec![IkJoint::free(9, &[2])], IkMethod::Transpose).unwrap_err();
        assert!(e.to_string().contains("joint 9"), "{e}");
        let ik = Ik::new(&s, vec![IkJoint::free(1, &[2])], IkMethod::Ccd).unwrap();
        let mut pose = s.rest().clone();
        let e = ik
            .solve(
                &s,
                &mut pose,
                &mut [0.0],
                &[Effector {
                    joint: 0,
                    target: [1.0; 3],
                }],
            )
            .unwrap_err();
        assert!(e.to_string().contains("does not hang below"), "{e}");
        let e = ik
            .solve(
                &s,
                &mut pose,
                &mut [0.0],
                &[Effector {
                    joint: 3,
                    target: [f64::NAN; 3],
                }],
            )
            .unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
    }
}

/// The three animation scenes build and run: the clip's frames are its skeleton (70
/// points, 69 bones), the twist's two skinned tubes, the reach's five arms with their
/// targets; damped least squares and FABRIK keep within the 0.1 m the circle leaves
/// out of reach.
#[test]
fn animation_scenes_run() {
    use largestep::scene::Scene;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for (name, points, segments) in [
        ("anim-clip", 70, 69),
        ("anim-twist", 2 * (81 * 32 + 2), 0),
        ("anim-reach", 25, 15),
        ("anim-walk", 70, 69),
    ] {
        let scene = Scene::load(&root.join(format!("scenes/{name}.toml"))).unwrap();
        let mut sim = scene.into_simulation().unwrap();
        for _ in 0..10 {
            sim.step(0.05).unwrap();
        }
        let m = sim.frame().mesh();
        assert_eq!(m.positions.len(), 3 * points, "{name}");
        assert_eq!(m.segments.len(), segments, "{name}");
        assert!(m.positions.iter().all(|v| v.is_finite()), "{name}");
        if name == "anim-reach" {
            for _ in 0..70 {
                sim.step(0.05).unwrap();
            }
            let w = sim.warnings();
            for method in ["dls", "fabrik"] {
                let line = w
                    .iter()
                    .find(|l| l.contains(&format!("{method}:")))
                    .unwrap();
                let d: f64 = line.rsplit(' ').nth(1).unwrap().parse().unwrap();
                assert!(d < 0.105, "{line}");
            }
        }
    }
}

mod keyframes {
    use largestep::anim::keyframe::*;
    use largestep::kernels::quat;

    fn track(kind: Interpolation, times: &[f64], values: &[f64]) -> ScalarTrack {
        ScalarTrack::new(
            times
                .iter()
                .zip(values)
                .map(|(&t, &v)| Key::new(t, [v], kind))
                .collect(),
        )
        .unwrap()
    }

    fn at(tr: &ScalarTrack, t: f64) -> f64 {
        tr.sample(t, &mut Cursor::default())[0]
    }

    /// Slope by central differences.
    fn slope(tr: &ScalarTrack, t: f64) -> f64 {
        let h = 1e-6;
        (at(tr, t + h) - at(tr, t - h)) / (2.0 * h)
    }

    #[test]
    fn every_kind_passes_through_its_keys() {
        let (times, values) = ([0.0, 0.7, 1.5, 3.0], [1.0, -2.0, 0.5, 4.0]);
        for kind in [
            Interpolation::Step,
            Interpolation::Linear,
            Interpolation::Hermite,
            Interpolation::CatmullRom,
            Interpolation::Bezier,
            Interpolation::Tcb,
        ] {
            let tr = track(kind, &times, &values);
            for (t, v) in times.iter().zip(&values) {
                assert!((at(&tr, *t) - v).abs() < 1e-12, "{kind:?} at {t}");
            }
            // Held outside the keys.
            assert_eq!(at(&tr, -5.0), 1.0);
            assert_eq!(at(&tr, 50.0), 4.0);
        }
        let step = track(Interpolation::Step, &times, &values);
        assert_eq!(at(&step, 0.69), 1.0);
        let lin = track(Interpolation::Linear, &times, &values);
        assert!((at(&lin, 0.35) + 0.5).abs() < 1e-12);
    }

    /// Catmull-Rom is C1 across keys with the non-uniform slope; flat Hermite tangents
    /// give zero slope at the keys; user tangents are met.
    #[test]
    fn hermite_tangents() {
        let (times, values) = ([0.0, 0.7, 1.5, 3.0], [1.0, -2.0, 0.5, 4.0]);
        let cr = track(Interpolation::CatmullRom, &times, &values);
        for i in 1..3 {
            let (l, r) = (slope(&cr, times[i] - 1e-4), slope(&cr, times[i] + 1e-4));
            let want = (values[i + 1] - values[i - 1]) / (times[i + 1] - times[i - 1]);
            assert!(
                (l - want).abs() < 1e-2 && (r - want).abs() < 1e-2,
                "key {i}: {l} {r} {want}"
            );
        }
        let mut keys: Vec<_> = times
            .iter()
            .zip(&values)
            .map(|(&t, &v)| Key::new(t, [v], Interpolation::Hermite))
            .collect();
        for k in keys.iter_mut() {
            k.tangent = Tangent::Flat;
        }
        keys[1].tangent = Tangent::User([3.0], [-1.0]);
        let h = ScalarTrack::new(keys).unwrap();
        assert!(slope(&h, 1.5 - 1e-5).abs() < 1e-3 && slope(&h, 1.5 + 1e-5).abs() < 1e-3);
        assert!((slope(&h, 0.7 - 1e-5) - 3.0).abs() < 1e-3);
        assert!((slope(&h, 0.7 + 1e-5) + 1.0).abs() < 1e-3);
    }

    /// TCB with zero tension, continuity and bias is Catmull-Rom (uneven spacing
    /// included); tension 1 gives zero tangents, the flat Hermite curve.
    #[test]
    fn tcb_limits() {
        let (times, values) = ([0.0, 0.7, 1.5, 3.0], [1.0, -2.0, 0.5, 4.0]);
        let cr = track(Interpolation::CatmullRom, &times, &values);
        let tcb = track(Interpolation::Tcb, &times, &values);
        let mut keys: Vec<_> = times
            .iter()
            .zip(&values)
            .map(|(&t, &v)| Key::new(t, [v], Interpolation::Tcb))
            .collect();
        for k in keys.iter_mut() {
            k.tcb = [1.0, 0.0, 0.0];
        }
        let tense = ScalarTrack::new(keys).unwrap();
        let mut flat: Vec<_> = times
            .iter()
            .zip(&values)
            .map(|(&t, &v)| Key::new(t, [v], Interpolation::Hermite))
            .collect();
        for k in flat.iter_mut() {
            k.tangent = Tangent::Flat;
        }
        let flat = ScalarTrack::new(flat).unwrap();
        for k in 0..=300 {
            let t = 3.0 * k as f64 / 300.0;
            assert!((at(&cr, t) - at(&tcb, t)).abs() < 1e-12, "{t}");
            assert!((at(&tense, t) - at(&flat, t)).abs() < 1e-12, "{t}");
        }
        // Bias 1 overshoots before a key and continuity -1 makes a corner: the
        // left and right slopes at key 1 differ.
        let mut keys: Vec<_> = times
            .iter()
            .zip(&values)
            .map(|(&t, &v)| Key::new(t, [v], Interpolation::Tcb))
            .collect();
        keys[1].tcb = [0.0, -1.0, 0.0];
        let corner = ScalarTrack::new(keys).unwrap();
        assert!((slope(&corner, 0.7 - 1e-4) - slope(&corner, 0.7 + 1e-4)).abs() > 1.0);
    }

    /// Bezier with handles a third of the way along the Hermite tangents is the Hermite
    /// curve; the time inversion holds for uneven handles.
    #[test]
    fn bezier_matches_hermite_with_third_handles() {
        let (times, values) = ([0.0, 1.0, 2.5], [0.0, 2.0, -1.0]);
        let slopes = [1.5, -0.5, 2.0];
        let mut b = Vec::new();
        let mut h = Vec::new();
        for i in 0..3 {
            let d_in = if i > 0 { times[i] - times[i - 1] } else { 1.0 };
            let d_out = if i < 2 { times[i + 1] - times[i] } else { 1.0 };
            let mut k = Key::new(times[i], [values[i]], Interpolation::Bezier);
            k.handles = (
                (-d_in / 3.0, [-slopes[i] * d_in / 3.0]),
                (d_out / 3.0, [slopes[i] * d_out / 3.0]),
            );
            b.push(k);
            let mut k = Key::new(times[i], [values[i]], Interpolation::Hermite);
            k.tangent = Tangent::User([slopes[i]], [slopes[i]]);
            h.push(k);
        }
        let (b, h) = (ScalarTrack::new(b).unwrap(), ScalarTrack::new(h).unwrap());
        for k in 0..=250 {
            let t = 2.5 * k as f64 / 250.0;
            assert!(
                (at(&b, t) - at(&h, t)).abs() < 1e-9,
                "{t}: {} {}",
                at(&b, t),
                at(&h, t)
            );
        }
    }

    /// Ease: 0 and 1 kept, starting and ending at rest with full ease, and the eased
    /// linear track reaches the midpoint value at the middle time.
    #[test]
    fn ease_in_and_out() {
        assert_eq!(ease(0.0, 0.3, 0.3), 0.0);
        assert!((ease(1.0, 0.3, 0.3) - 1.0).abs() < 1e-15);
        assert!((ease(0.5, 0.5, 0.5) - 0.5).abs() < 1e-15);
        let d0 = (ease(1e-6, 0.5, 0.5) - ease(0.0, 0.5, 0.5)) / 1e-6;
        assert!(d0 < 1e-5);
        // Monotone, and the identity without ease.
        let mut last = 0.0;
        for k in 0..=100 {
            let u = k as f64 / 100.0;
            let e = ease(u, 0.7, 0.6);
            assert!(e >= last - 1e-15);
            last = e;
            assert_eq!(ease(u, 0.0, 0.0), u);
        }
    }

    /// The cursor gives the same samples as a fresh search, forward, backward and by
    /// jumps; baking gives the key values at the key times.
    #[test]
    fn cursor_and_bake() {
        let times: Vec<f64> = (0..50)
            .map(|k| k as f64 * 0.1 + (k % 3) as f64 * 0.01)
            .collect();
        let values: Vec<f64> = (0..50).map(|k| (k as f64 * 0.7).sin()).collect();
        let tr = track(Interpolation::CatmullRom, &times, &values);
        let mut c = Cursor::default();
        let mut ts: Vec<f64> = (0..500).map(|k| k as f64 * 0.01).collect();
        ts.extend((0..500).rev().map(|k| k as f64 * 0.0099));
        ts.extend([4.7, 0.05, 2.2, 4.9, 0.0]);
        for t in ts {
            assert_eq!(
                tr.sample(t, &mut c),
                tr.sample(t, &mut Cursor::default()),
                "{t}"
            );
        }
        let lin = track(Interpolation::Linear, &[0.0, 1.0, 2.0], &[0.0, 10.0, 0.0]);
        let mut baked = Vec::new();
        lin.bake(4.0, &mut baked);
        assert_eq!(baked.len(), 9);
        assert_eq!(baked[4], [10.0]);
        assert_eq!(baked[2], [5.0]);
    }

    /// Arc length: a path along a line with varying speed, sampled by length, moves in
    /// equal steps.
    #[test]
    fn arc_length_reparameterisation() {
        let keys = vec![
            // Uneven speed, but never backward (each segment's tangents within
            // Fritsch and Carlson's monotone region).
            Key::new(0.0, [0.0, 0.0, 0.0], Interpolation::CatmullRom),
            Key::new(0.5, [1.0, 0.0, 0.0], Interpolation::CatmullRom),
            Key::new(2.0, [2.0, 0.0, 0.0], Interpolation::CatmullRom),
            Key::new(3.0, [3.0, 0.0, 0.0], Interpolation::CatmullRom),
        ];
        let tr = VectorTrack::new(keys).unwrap();
        let arc = ArcLength::new(&tr, 16);
        assert!((arc.length() - 3.0).abs() < 1e-6, "{}", arc.length());
        let mut c = Cursor::default();
        for k in 0..=30 {
            let s = 0.1 * k as f64;
            let p = tr.sample(arc.time_at(s), &mut c);
            assert!((p[0] - s).abs() < 2e-3, "{s}: {p:?}");
        }
    }

    /// Rotation tracks: SLERP halfway between two keys, the double cover taken the
    /// short way, SQUAD through the keys; bad keys named.
    #[test]
    fn rotation_tracks() {
        let z = |a: f64| quat::exp([0.0, 0.0, a]);
        let q1 = z(1.0).map(|c| -c);
        let tr =
            RotationTrack::new(&[(0.0, z(0.0)), (1.0, q1)], RotationInterpolation::Slerp).unwrap();
        let h = tr.sample(0.5, &mut Cursor::default());
        assert!((quat::log(h)[2] - 0.5).abs() < 1e-12);
        let keys = [(0.0, z(0.0)), (1.0, z(0.8)), (2.0, z(1.0)), (3.0, z(2.5))];
        let sq = RotationTrack::new(&keys, RotationInterpolation::Squad).unwrap();
        for (t, q) in keys {
            let s = sq.sample(t, &mut Cursor::default());
            assert!((0..4).map(|k| s[k] * q[k]).sum::<f64>().abs() > 1.0 - 1e-12);
        }
        let e = RotationTrack::new(
            &[(0.0, z(0.0)), (0.0, z(1.0))],
            RotationInterpolation::Slerp,
        )
        .unwrap_err();
        assert_eq!(e.index, 1);
        let e = RotationTrack::new(&[(0.0, [0.0; 4])], RotationInterpolation::Slerp).unwrap_err();
        assert!(e.to_string().starts_with("key 0: rotation is zero"));
        let e = ScalarTrack::new(vec![
            Key::new(1.0, [0.0], Interpolation::Linear),
            Key::new(0.5, [0.0], Interpolation::Linear),
        ])
        .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("key 1: time 0.5 does not come after"),
            "{e}"
        );
        let mut k = Key::new(0.0, [0.0], Interpolation::Tcb);
        k.tcb = [2.0, 0.0, 0.0];
        assert!(ScalarTrack::new(vec![k]).is_err());
    }
}

mod blendshapes {
    use largestep::anim::blendshape::*;

    /// A rig of `n` vertices with `k` random base shapes (and optionally a corrective of
    /// the first two).
    fn rig(n: usize, k: usize, corrective: bool) -> BlendshapeDesc {
        let mut s = 12345u64;
        let mut rnd = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let neutral: Vec<f64> = (0..3 * n).map(|_| rnd()).collect();
        let mut shapes: Vec<ShapeDesc> = (0..k)
            .map(|i| ShapeDesc {
                name: format!("s{i}"),
                positions: neutral.iter().map(|b| b + 0.1 * rnd()).collect(),
                combines: Vec::new(),
            })
            .collect();
        if corrective {
            shapes.push(ShapeDesc {
                name: "s0+s1".into(),
                positions: (0..3 * n).map(|_| 0.05 * rnd()).collect(),
                combines: vec![0, 1],
            });
        }
        BlendshapeDesc { neutral, shapes }
    }

    /// Weights that made a face are found again by the bounded solve; a combination
    /// shape adds its delta at the product of its bases' weights.
    #[test]
    fn solve_recovers_weights_and_combinations_multiply() {
        let r = rig(200, 8, false).build().unwrap();
        let want = [0.3, 0.0, 1.0, 0.55, 0.9, 0.1, 0.0, 0.75];
        let mut face = vec![0.0; 600];
        r.evaluate(&want, &mut face);
        let (w, sweeps) = r.solve_weights(&face, &[], 0.0).unwrap();
        for k in 0..8 {
            assert!(
                (w[k] - want[k]).abs() < 1e-8,
                "{k}: {} vs {} after {sweeps} sweeps",
                w[k],
                want[k]
            );
        }
        // From twelve markers only (36 equations for 8 unknowns).
        let markers: Vec<usize> = (0..12).map(|i| 13 * i).collect();
        let (w, _) = r.solve_weights(&face, &markers, 0.0).unwrap();
        assert!(
            w.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-6),
            "{w:?}"
        );

        let d = rig(50, 3, true);
        let r = d.build().unwrap();
        let (mut a, mut b) = (vec![0.0; 150], vec![0.0; 150]);
        r.evaluate(&[0.5, 0.4, 0.0, 9.0], &mut a);
        r.evaluate(&[0.5, 0.4, 0.0, 0.0], &mut b);
        // The corrective's own entry is ignored; its delta comes in at 0.5 x 0.4.
        assert_eq!(a, b);
        let mut c = vec![0.0; 150];
        r.evaluate(&[0.5, 0.0, 0.0, 0.0], &mut c);
        let base_only: Vec<f64> = (0..150)
            .map(|i| d.neutral[i] + 0.5 * (d.shapes[0].positions[i] - d.neutral[i]))
            .collect();
        assert!(c.iter().zip(&base_only).all(|(x, y)| (x - y).abs() < 1e-15));
        let i = 7;
        let expect = d.neutral[i]
            + 0.5 * (d.shapes[0].positions[i] - d.neutral[i])
            + 0.4 * (d.shapes[1].positions[i] - d.neutral[i])
            + 0.2 * d.shapes[3].positions[i];
        assert!((a[i] - expect).abs() < 1e-15);
    }

    /// A face beyond the rig's range gets clamped weights; action units drive shapes.
    #[test]
    fn bounds_and_action_units() {
        let r = rig(100, 4, false).build().unwrap();
        let mut face = vec![0.0; 300];
        r.evaluate(&[1.6, 0.2, -0.5, 0.4], &mut face);
        let (w, _) = r.solve_weights(&face, &[], 0.0).unwrap();
        assert!(w.iter().all(|&x| (0.0..=1.0).contains(&x)), "{w:?}");
        assert_eq!(w[0], 1.0);
        assert_eq!(w[2], 0.0);
        let au = ActionUnits {
            units: vec![
                ("AU12".into(), vec![(0, 1.0), (1, 0.5)]),
                ("AU26".into(), vec![(1, 1.0), (3, 0.8)]),
            ],
        };
        let mut weights = vec![0.0; 4];
        au.weights(&[0.6, 0.7], &r, &mut weights).unwrap();
        assert!(
            (weights[0] - 0.6).abs() < 1e-15
                && (weights[1] - 1.0).abs() < 1e-15
                && (weights[3] - 0.56).abs() < 1e-15
        );
        let bad = ActionUnits {
            units: vec![("AU1".into(), vec![(9, 1.0)])],
        };
        assert!(bad
            .weights(&[1.0], &r, &mut weights)
            .unwrap_err()
            .contains("AU1"));
    }

    #[test]
    fn bad_rigs_name_the_shape() {
        let mut d = rig(10, 3, true);
        d.shapes[1].positions.pop();
        assert!(d
            .build()
            .unwrap_err()
            .to_string()
            .starts_with("shape 1 (s1): 29 coordinates"));
        let mut d = rig(10, 3, true);
        d.shapes[3].combines = vec![0, 0];
        assert!(d
            .build()
            .unwrap_err()
            .to_string()
            .contains("shape 3 (s0+s1)"));
        let mut d = rig(10, 3, true);
        d.shapes[3].combines = vec![0, 5];
        assert!(d.build().is_err());
        let mut d = rig(10, 3, false);
        d.shapes[2].name = "s0".into();
        assert!(d.build().unwrap_err().to_string().contains("name is used"));
        let r = rig(10, 3, false).build().unwrap();
        assert!(r
            .solve_weights(&[0.0; 30], &[10], 0.0)
            .unwrap_err()
            .contains("marker vertex 10"));
        assert!(r.solve_weights(&[0.0; 29], &[], 0.0).is_err());
    }
}

mod motion_graphs {
    use super::{clip, Pose};
    use largestep::anim::clip::Clip;
    use largestep::anim::motion_graph::{MotionGraph, MotionGraphDesc};

    fn graph() -> (largestep::anim::Skeleton, Clip, MotionGraph) {
        let b = clip();
        let s = b.skeleton().build().unwrap();
        let c = Clip::from_bvh(&b);
        let g = MotionGraph::build(
            &s,
            &c,
            &MotionGraphDesc {
                window: 6,
                threshold: 12.0,
                weights: Vec::new(),
            },
        )
        .unwrap();
        (s, c, g)
    }

    fn root(p: &Pose) -> [f64; 3] {
        p.translation(0)
    }

    /// The shared clip (a walk out, a turn, a walk back) has transitions from the walk
    /// back into the walk out (the same steps facing the other way, which the floor
    /// alignment removes); every transition is a local minimum below the threshold; the
    /// kept frames are strongly connected.
    #[test]
    fn transitions_and_the_kept_component() {
        let (_, _, g) = graph();
        let (d, side) = g.distances();
        for i in 0..side {
            assert!(d[i * side + i] < 1e-9, "a window's distance to itself");
            for j in 0..side {
                assert!((d[i * side + j] - d[j * side + i]).abs() < 1e-6 * (1.0 + d[i * side + j]));
            }
        }
        assert!(!g.transitions().is_empty());
        for t in g.transitions() {
            assert!(t.distance <= 12.0 && t.from.abs_diff(t.to) >= 6);
        }
        eprintln!(
            "{} transitions, {} of 69 frames kept",
            g.transitions().len(),
            g.kept_count()
        );
        assert!(g.kept_count() >= 20, "{}", g.kept_count());
        // Strong connection: from every kept frame, every other is reached.
        let n = 69;
        let succ = |f: usize| {
            let mut s: Vec<usize> = g
                .leaving(f)
                .iter()
                .map(|&t| g.transitions()[t].to + g.window())
                .collect();
            if f + 1 < n && g.kept(f + 1) {
                s.push(f + 1);
            }
            s
        };
        let kept: Vec<usize> = (0..n).filter(|&f| g.kept(f)).collect();
        for &start in &kept {
            let mut seen = vec![false; n];
            let mut stack = vec![start];
            while let Some(f) = stack.pop() {
                if std::mem::replace(&mut seen[f], true) {
                    continue;
                }
                stack.extend(succ(f));
            }
            assert!(kept.iter().all(|&f| seen[f]), "from {start}");
        }
    }

    /// A random walk runs as long as asked without a dead end, the root never jumps
    /// (at most twice the clip's largest step between frames), and the same seed gives
    /// the same walk.
    #[test]
    fn random_walks_are_continuous_and_repeatable() {
        let (s, c, g) = graph();
        let mut pose = s.rest().clone();
        let mut step: f64 = 0.0;
        let mut last = None;
        for f in 0..c.frames() {
            c.sample(f as f64 * c.frame_time(), false, &mut pose);
            let r = root(&pose);
            if let Some(l) = last {
                let l: [f64; 3] = l;
                step = step.max(((r[0] - l[0]).powi(2) + (r[2] - l[2]).powi(2)).sqrt());
            }
            last = Some(r);
        }
        let (mut a, mut b) = (Vec::new(), Vec::new());
        g.random_walk(&s, &c, 600, 7, &mut a);
        g.random_walk(&s, &c, 600, 7, &mut b);
        assert_eq!(a.len(), 600);
        assert_eq!(a, b);
        for w in a.windows(2) {
            let (p, q) = (root(&w[0]), root(&w[1]));
            let d = ((p[0] - q[0]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
            assert!(d <= 2.0 * step + 1e-9, "{d} against the clip's {step}");
            assert!(w[1].rotations.iter().all(|v| v.is_finite()));
        }
    }

    /// Following a straight path along +z keeps the root near it, farther than the clip
    /// alone goes (it turns back at about 93 cm).
    #[test]
    fn path_following_keeps_near_the_path() {
        let (s, c, g) = graph();
        let path = [[0.0, 0.0], [0.0, 2000.0]];
        let mut walk = Vec::new();
        g.follow_path(&s, &c, &path, 300, 90, &mut walk);
        assert_eq!(walk.len(), 300);
        let end = root(&walk[299]);
        let off: f64 = walk.iter().map(|p| root(p)[0].abs()).fold(0.0, f64::max);
        let mean = walk.iter().map(|p| root(p)[0].abs()).sum::<f64>() / walk.len() as f64;
        eprintln!(
            "path: root ends at z = {:.1}, {:.1} off the line on average, at most {:.1}",
            end[2], mean, off
        );
        // One 2.3 s clip gives five transitions: the walk goes on along the line
        // (the clip alone turns back at 93 cm), swinging off it where only the clip's
        // turn leads on. A horizon of 90 frames (3 s) sees past the turn; the greedy
        // one-choice look-ahead this replaced reached 252 cm, 51 cm off on average.
        assert!(end[2] > 200.0, "{end:?}");
        assert!(mean < 60.0, "{mean}");
    }

    #[test]
    fn bad_graphs_are_refused() {
        let b = clip();
        let s = b.skeleton().build().unwrap();
        let c = Clip::from_bvh(&b);
        for (window, threshold) in [(1, 5.0), (100, 5.0), (5, 0.0), (5, f64::NAN)] {
            let d = MotionGraphDesc {
                window,
                threshold,
                weights: Vec::new(),
            };
            assert!(MotionGraph::build(&s, &c, &d).is_err());
        }
        let d = MotionGraphDesc {
            window: 5,
            threshold: 5.0,
            weights: vec![1.0; 3],
        };
        assert!(MotionGraph::build(&s, &c, &d)
            .unwrap_err()
            .contains("3 weights for 70 joints"));
    }
}

/// Retargeting the clip onto a skeleton twice its size, its joints named without the
/// `mixamorig:` prefix, gives every joint at twice the source position; a target whose
/// rest pose lifts an arm still reaches the same arm directions; names that are not
/// there are errors.
#[test]
fn retargeting_by_joint_names() {
    use largestep::anim::retarget::Retarget;
    let b = clip();
    let source = b.skeleton().build().unwrap();
    let mut desc = b.skeleton();
    for j in desc.joints.iter_mut() {
        j.name = j.name.trim_start_matches("mixamorig:").to_string();
        j.translation = j.translation.map(|v| 2.0 * v);
    }
    let target = desc.build().unwrap();
    let r = Retarget::new(&source, &target, &[]).unwrap();
    assert_eq!(r.paired(), 70);
    assert!((r.scale() - 2.0).abs() < 1e-12);
    let mut pose = source.rest().clone();
    let mut out = target.rest().clone();
    let (mut ms, mut mt) = (Vec::new(), Vec::new());
    for k in [0, 40, 68] {
        b.pose(k, &mut pose);
        r.apply(&source, &pose, &target, &mut out);
        source.model(&pose, &mut ms);
        target.model(&out, &mut mt);
        for j in 0..70 {
            for c in [3, 7, 11] {
                assert!(
                    (mt[j][c] - 2.0 * ms[j][c]).abs() < 1e-9,
                    "frame {k} joint {j}"
                );
            }
        }
    }
    // A target whose left arm rests turned 40 degrees down: its bones still point
    // where the source's do.
    let mut desc = b.skeleton();
    let arm = desc
        .joints
        .iter()
        .position(|j| j.name == "mixamorig:LeftArm")
        .unwrap();
    let fore = desc
        .joints
        .iter()
        .position(|j| j.name == "mixamorig:LeftForeArm")
        .unwrap();
    desc.joints[arm].rotation = quat::exp([0.0, 0.0, -0.7]);
    let turned = desc.build().unwrap();
    let r = Retarget::new(&source, &turned, &[]).unwrap();
    b.pose(40, &mut pose);
    r.apply(&source, &pose, &turned, &mut out);
    source.model(&pose, &mut ms);
    turned.model(&out, &mut mt);
    let dir = |m: &Vec<largestep::anim::Affine>| {
        let d = [0, 1, 2].map(|c| m[fore][4 * c + 3] - m[arm][4 * c + 3]);
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|v| v / l)
    };
    let (a, c) = (dir(&ms), dir(&mt));
    // Carried in world space, the same world turn acts on both rest directions: the
    // angle between the bones is the angle between their rest directions.
    let angle = |u: [f64; 3], v: [f64; 3]| {
        (u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
            .clamp(-1.0, 1.0)
            .acos()
    };
    source.model(source.rest(), &mut ms);
    turned.model(turned.rest(), &mut mt);
    let rest_angle = angle(dir(&ms), dir(&mt));
    assert!(rest_angle > 0.5, "{rest_angle}");
    assert!(
        (angle(a, c) - rest_angle).abs() < 1e-9,
        "{} vs {rest_angle}",
        angle(a, c)
    );
    let e = Retarget::new(&source, &target, &[("mixamorig:Hips", "Pelvis")]).unwrap_err();
    assert!(e.to_string().contains("Pelvis"), "{e}");
}

mod acclaim {
    use largestep::anim::asf::{Amc, Asf};
    use largestep::anim::Pose;
    use largestep::kernels::quat;
    use largestep::kernels::rotation::axis_quat;

    const ASF: &str = "# a three-bone arm
:version 1.10
:name test
:units
  mass 1.0
  length 1.0
  angle deg
:documentation
  made by hand
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name upper
     direction 1 0 0
     length 2.0
     axis 0 0 30 XYZ
     dof rx ry rz
     limits (-180.0 180.0)
            (-180.0 180.0)
            (-180.0 180.0)
  end
  begin
     id 2
     name lower
     direction 0.6 0.8 0
     length 1.5
     axis 10 -20 5 XYZ
     dof rx rz
     limits (-180.0 180.0)
            (-180.0 180.0)
  end
  begin
     id 3
     name other
     direction 0 0 1
     length 1.0
     axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root upper other
    upper lower
  end
";

    const AMC: &str = ":FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 10 20 30
upper 15 -25 40
lower 35 -50
2
root 0 0 0 0 0 0
upper 0 0 0
lower 0 0
";

    /// Rotations about fixed axes, first applied first (the Acclaim reading), in degrees.
    fn fixed(axes: &[usize], deg: &[f64]) -> quat::Quat {
        let mut q = quat::IDENTITY;
        for (&a, &d) in axes.iter().zip(deg) {
            q = quat::mul(axis_quat(a, d.to_radians()), q);
        }
        q
    }

    /// The skeleton puts every bone's end where the Acclaim formula does
    /// (W = W_parent C M C^-1, end = start + length W direction), worked out here
    /// directly from the file's numbers.
    #[test]
    fn acclaim_skeleton_matches_the_formula() {
        let asf = Asf::parse(ASF, "t.asf").unwrap();
        let amc = Amc::parse(AMC, &asf, "t.amc").unwrap();
        assert_eq!(amc.frames.len(), 2);
        let skel = asf.skeleton().build().unwrap();
        // root, upper, lower, other, and the ends of lower and other.
        assert_eq!(skel.len(), 6);
        let mut pose = Pose::identity(skel.len());
        amc.pose(&asf, 0, &mut pose);
        let mut model = Vec::new();
        skel.model(&pose, &mut model);
        let at = |name: &str| {
            let j = skel.find(name).unwrap();
            [model[j][3], model[j][7], model[j][11]]
        };
        let conj = |c: quat::Quat, m: quat::Quat| quat::mul(quat::mul(c, m), quat::conj(c));
        let w_root = conj(quat::IDENTITY, fixed(&[0, 1, 2], &[10.0, 20.0, 30.0]));
        let root = [1.0, 2.0, 3.0];
        let c_up = fixed(&[0, 1, 2], &[0.0, 0.0, 30.0]);
        let w_up = quat::mul(w_root, conj(c_up, fixed(&[0, 1, 2], &[15.0, -25.0, 40.0])));
        let up_end: [f64; 3] =
            std::array::from_fn(|c| root[c] + 2.0 * quat::rotate(w_up, [1.0, 0.0, 0.0])[c]);
        let c_lo = fixed(&[0, 1, 2], &[10.0, -20.0, 5.0]);
        let w_lo = quat::mul(w_up, conj(c_lo, fixed(&[0, 2], &[35.0, -50.0])));
        let lo_end: [f64; 3] =
            std::array::from_fn(|c| up_end[c] + 1.5 * quat::rotate(w_lo, [0.6, 0.8, 0.0])[c]);
        let other_end: [f64; 3] =
            std::array::from_fn(|c| root[c] + quat::rotate(w_root, [0.0, 0.0, 1.0])[c]);
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|c| (a[c] - b[c]).abs() < 1e-12);
        assert!(close(at("root"), root));
        assert!(
            close(at("upper"), root),
            "bones start at their parent's end"
        );
        assert!(close(at("lower"), up_end), "{:?} {:?}", at("lower"), up_end);
        assert!(
            close(at("lower_end"), lo_end),
            "{:?} {:?}",
            at("lower_end"),
            lo_end
        );
        assert!(close(at("other_end"), other_end));
        // The zero frame is the rest: the bones along their directions.
        amc.pose(&asf, 1, &mut pose);
        skel.model(&pose, &mut model);
        let j = skel.find("lower_end").unwrap();
        assert!(close(
            [model[j][3], model[j][7], model[j][11]],
            [2.9, 1.2, 0.0]
        ));
        let clip = amc.clip(&asf, 1.0 / 120.0);
        assert_eq!(clip.frames(), 2);
    }

    #[test]
    fn bad_acclaim_files_are_named_by_line() {
        let e = Asf::parse(&ASF.replace("length 1.5", "length -1.5"), "t.asf").unwrap_err();
        assert_eq!(e.line, 31, "{e}");
        let e = Asf::parse(&ASF.replace("dof rx rz", "dof rx rw"), "t.asf").unwrap_err();
        assert!(e.to_string().contains("'rw' is not a dof"), "{e}");
        let e = Asf::parse(&ASF.replace("upper lower", "upper elbow"), "t.asf").unwrap_err();
        assert!(e.to_string().contains("'elbow' is not a bone"), "{e}");
        let e = Asf::parse(&ASF.replace("angle deg", "angle grad"), "t.asf").unwrap_err();
        assert_eq!(e.line, 7);
        let asf = Asf::parse(ASF, "t.asf").unwrap();
        let e = Amc::parse(&AMC.replace("lower 35 -50", "lower 35"), &asf, "t.amc").unwrap_err();
        assert_eq!(e.line, 6);
        assert!(
            e.to_string().contains("lower has 1 values; its dofs are 2"),
            "{e}"
        );
        let e = Amc::parse(&AMC.replace("\n2\n", "\n3\n"), &asf, "t.amc").unwrap_err();
        assert!(e.to_string().contains("frame 3 follows frame 1"), "{e}");
        let e = Amc::parse(&AMC.replace("upper 15", "wrist 15"), &asf, "t.amc").unwrap_err();
        assert!(e.to_string().contains("'wrist' is not a bone"), "{e}");
    }
}

mod gltf_assets {
    use super::{temp_dir, Pose};
    use largestep::anim::asset::{write_glb, Asset, AssetMesh};
    use largestep::anim::blendshape::{BlendshapeDesc, ShapeDesc};
    use largestep::anim::clip::Clip;
    use largestep::anim::skin::SkinDesc;
    use largestep::anim::{JointDesc, SkeletonDesc};
    use largestep::kernels::quat;

    /// A two-bone arm around a tube, skinned, with two morph targets and a three-frame
    /// clip.
    fn arm() -> (
        largestep::anim::Skeleton,
        AssetMesh,
        SkinDesc,
        BlendshapeDesc,
        Clip,
    ) {
        let s = SkeletonDesc {
            joints: vec![
                JointDesc::new("upper", None, [0.0, 1.0, 0.0]),
                JointDesc::new("lower", Some(0), [1.0, 0.0, 0.0]),
            ],
        }
        .build()
        .unwrap();
        let tube = largestep::shapes::tube(2.0, 0.2, 9, 8);
        let n = tube.positions.len() / 3;
        let mut bind = Vec::new();
        s.model(s.rest(), &mut bind);
        let skin = SkinDesc {
            positions: tube.positions.clone(),
            normals: Vec::new(),
            joints: vec![[0, 1, 0, 0]; n],
            weights: (0..n)
                .map(|v| {
                    let w = (tube.positions[v] - 0.5).clamp(0.0, 1.0);
                    [1.0 - w, w, 0.0, 0.0]
                })
                .collect(),
            bind,
        };
        let morphs = BlendshapeDesc {
            neutral: tube.positions.clone(),
            shapes: (0..2)
                .map(|k| ShapeDesc {
                    name: format!("target{k}"),
                    positions: tube
                        .positions
                        .iter()
                        .enumerate()
                        .map(|(i, p)| p + 0.01 * ((i * (k + 3)) % 7) as f64)
                        .collect(),
                    combines: Vec::new(),
                })
                .collect(),
        };
        let poses: Vec<Pose> = (0..3)
            .map(|f| {
                let mut p = s.rest().clone();
                p.set(
                    1,
                    [1.0, 0.1 * f as f64, 0.0],
                    quat::exp([0.5 * f as f64, 0.0, 0.2]),
                    [1.0; 3],
                );
                p
            })
            .collect();
        let clip = Clip::from_poses(0.5, &poses);
        let mesh = AssetMesh {
            positions: tube.positions.clone(),
            normals: Vec::new(),
            triangles: tube.triangles.to_vec(),
        };
        (s, mesh, skin, morphs, clip)
    }

    /// Written as .glb and read back: the same skeleton, mesh, influences, bind
    /// transforms, morph targets and clip, to f32 rounding.
    #[test]
    fn glb_round_trip() {
        let (s, mesh, skin, morphs, clip) = arm();
        let dir = temp_dir("gltf");
        let path = dir.join("arm.glb");
        let mut f = std::fs::File::create(&path).unwrap();
        write_glb(
            &mut f,
            &s,
            Some(&mesh),
            Some(&skin),
            Some(&morphs),
            Some(("wave", &clip)),
        )
        .unwrap();
        drop(f);
        let a = Asset::read(&path, 1 << 24, 2.0).unwrap();
        assert_eq!(a.skeleton.joints.len(), 2);
        assert_eq!(a.skeleton.joints[1].name, "lower");
        assert_eq!(a.skeleton.joints[1].parent, Some(0));
        assert!((a.skeleton.joints[0].translation[1] - 1.0).abs() < 1e-7);
        let m = a.mesh.as_ref().unwrap();
        assert_eq!(m.triangles, mesh.triangles);
        assert!(m
            .positions
            .iter()
            .zip(&mesh.positions)
            .all(|(x, y)| (x - y).abs() < 1e-6));
        let sk = a.skin.as_ref().unwrap();
        assert_eq!(sk.joints, skin.joints);
        assert!(sk
            .weights
            .iter()
            .flatten()
            .zip(skin.weights.iter().flatten())
            .all(|(x, y)| (x - y).abs() < 1e-7));
        for (b0, b1) in sk.bind.iter().zip(&skin.bind) {
            assert!(
                b0.iter().zip(b1).all(|(x, y)| (x - y).abs() < 1e-6),
                "{b0:?} {b1:?}"
            );
        }
        let mo = a.morphs.as_ref().unwrap();
        assert_eq!(mo.shapes.len(), 2);
        for (x, y) in mo.shapes[1]
            .positions
            .iter()
            .zip(&morphs.shapes[1].positions)
        {
            assert!((x - y).abs() < 1e-6);
        }
        assert_eq!(a.clips.len(), 1);
        assert_eq!(a.clips[0].0, "wave");
        let c = &a.clips[0].1;
        assert_eq!(c.frames(), 3);
        let (mut p, mut q) = (Pose::identity(2), Pose::identity(2));
        for f in 0..3 {
            c.sample(f as f64 * 0.5, false, &mut p);
            clip.sample(f as f64 * 0.5, false, &mut q);
            assert!(
                p.translations
                    .iter()
                    .zip(&q.translations)
                    .all(|(x, y)| (x - y).abs() < 1e-6),
                "frame {f}"
            );
            let dot: f64 = (0..4).map(|k| p.rotation(1)[k] * q.rotation(1)[k]).sum();
            assert!(dot.abs() > 1.0 - 1e-10, "frame {f}");
        }
    }

    /// Bad assets are errors naming what is wrong: not glTF, a missing buffer file, a
    /// data URI too short for its buffer, an accessor past its buffer, an index past the
    /// vertices; and a data URI that holds its buffer is read.
    #[test]
    fn bad_assets_are_refused() {
        let dir = temp_dir("gltf-bad");
        let write = |name: &str, text: &str| {
            let p = dir.join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        let e = Asset::read(&write("junk.gltf", "{ not json"), 1 << 20, 30.0).unwrap_err();
        assert!(e.to_string().contains("not a valid glTF"), "{e}");
        let head = r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"BUF","byteLength":36}],"bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":VIEW}],"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},{"bufferView":0,"byteOffset":12,"componentType":5125,"count":3,"type":"SCALAR"}],"meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}]}"#;
        let e = Asset::read(
            &write(
                "missing.gltf",
                &head.replace("BUF", "nowhere.bin").replace("VIEW", "36"),
            ),
            1 << 20,
            30.0,
        )
        .unwrap_err();
        assert!(e.to_string().contains("buffer 0 (nowhere.bin)"), "{e}");
        let e = Asset::read(
            &write(
                "data.gltf",
                &head
                    .replace("BUF", "data:application/octet-stream;base64,AAAA")
                    .replace("VIEW", "36"),
            ),
            1 << 20,
            30.0,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .contains("buffer 0 holds 3 bytes, the file says 36"),
            "{e}"
        );
        // A data URI that holds the triangle (positions, then indices 0, 1, 2).
        let tri = "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAEAAAACAAAA";
        let ok = head
            .replace("BUF", tri)
            .replace("\"byteLength\":36}]", "\"byteLength\":48}]")
            .replace("VIEW", "48")
            .replace("\"byteOffset\":12,", "\"byteOffset\":36,");
        let a = Asset::read(&write("embedded.gltf", &ok), 1 << 20, 30.0).unwrap();
        let m = a.mesh.unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        assert_eq!(
            m.positions,
            vec![0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
        );
        let bin: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        std::fs::write(dir.join("tri.bin"), &bin).unwrap();
        let e = Asset::read(
            &write(
                "short.gltf",
                &head.replace("BUF", "tri.bin").replace("VIEW", "24"),
            ),
            1 << 20,
            30.0,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .contains("accessor 0 runs past the end of buffer view 0"),
            "{e}"
        );
        // Indices read from the positions' bytes from the second point: 1.0 as a u32 is
        // 1065353216.
        let e = Asset::read(
            &write(
                "index.gltf",
                &head.replace("BUF", "tri.bin").replace("VIEW", "36"),
            ),
            1 << 20,
            30.0,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .contains("index 1065353216 past the mesh's 3 vertices"),
            "{e}"
        );
    }
}

/// Mangled .glb files (bytes of the JSON changed at random) give an asset or an
/// error, never a panic.
#[test]
fn mangled_glb_files_never_panic() {
    use largestep::anim::asset::{write_glb, Asset, AssetMesh};
    let s = SkeletonDesc {
        joints: vec![
            JointDesc::new("a", None, [0.0; 3]),
            JointDesc::new("b", Some(0), [1.0, 0.0, 0.0]),
        ],
    }
    .build()
    .unwrap();
    let mesh = AssetMesh {
        positions: vec![0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        normals: Vec::new(),
        triangles: vec![[0, 1, 2]],
    };
    let mut bind = Vec::new();
    s.model(s.rest(), &mut bind);
    let skin = SkinDesc {
        positions: mesh.positions.clone(),
        normals: Vec::new(),
        joints: vec![[0, 1, 0, 0]; 3],
        weights: vec![[0.5, 0.5, 0.0, 0.0]; 3],
        bind,
    };
    let clip = largestep::anim::clip::Clip::from_poses(0.1, &[s.rest().clone(), s.rest().clone()]);
    let mut glb = Vec::new();
    write_glb(
        &mut glb,
        &s,
        Some(&mesh),
        Some(&skin),
        None,
        Some(("c", &clip)),
    )
    .unwrap();
    let dir = temp_dir("glb-fuzz");
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let mut x = 0x1234_5678_9abc_def1u64;
    for case in 0..300 {
        let mut m = glb.clone();
        for _ in 0..1 + case % 4 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let at = 20 + (x as usize) % json_len;
            m[at] = b"0123456789-,:[]{}\"e."[(x >> 32) as usize % 20];
        }
        let p = dir.join("m.glb");
        std::fs::write(&p, &m).unwrap();
        let _ = Asset::read(&p, 1 << 20, 30.0);
    }
}
