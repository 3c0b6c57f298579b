//! glTF 2.0 assets (the `gltf` crate for reading and the binary container; the JSON
//! written here): a skeleton from a skin's joints, the skinned mesh with its four
//! influences, morph targets as blendshapes, and animations as clips.
//!
//! **Reading.** `.glb` files, and `.gltf` files whose buffers are external files beside
//! them (within the input limit) or base64 data URIs. Every accessor
//! read is checked first against its buffer view and buffer (offset, stride, count), so
//! a file with missing buffers or ranges past their ends is an error naming the
//! accessor, never a panic; mesh indices and joint indices are checked against their
//! counts. The skeleton is the first skin's joints (or every node without a skin), each
//! parented to its nearest ancestor among them; nodes above the root joint (Blender's
//! armature object) are folded into the root's transform. Inverse bind matrices give
//! the bind transforms. Animations are sampled at a fixed rate into clips: LINEAR
//! through [`super::keyframe`]'s linear and SLERP tracks, STEP held, CUBICSPLINE with
//! its tangents as Hermite segments (rotations: SLERP between the keys).
//!
//! **Writing.** A `.glb` with the skeleton as nodes, the mesh (positions, normals,
//! `JOINTS_0`, `WEIGHTS_0`, indices, morph targets), the skin with its inverse bind
//! matrices, and a clip as one animation (LINEAR, a key per frame).

use super::blendshape::{BlendshapeDesc, ShapeDesc};
use super::clip::Clip;
use super::keyframe::{
    Cursor, Interpolation, Key, RotationInterpolation, RotationTrack, Tangent, VectorTrack,
};
use super::skin::SkinDesc;
use super::{Affine, JointDesc, Pose, Skeleton, SkeletonDesc};
use crate::io::ReadError;
use largestep_kernels::anim::{
    affine_decompose, affine_from_trs, affine_inverse, affine_mul, AFFINE_IDENTITY,
};
use largestep_kernels::quat;
use std::path::Path;

/// The most joint frames (frames times joints) an animation is sampled into (4 million:
/// about 320 MB of poses).
pub const MAX_JOINT_FRAMES: usize = 4_000_000;

/// A mesh read from or written to an asset: component-major positions and normals,
/// triangles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AssetMesh {
    /// Positions (3n).
    pub positions: Vec<f64>,
    /// Normals (3n, or empty).
    pub normals: Vec<f64>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
}

/// What a glTF file holds that animation uses.
#[derive(Clone, Debug, Default)]
pub struct Asset {
    /// The skeleton.
    pub skeleton: SkeletonDesc,
    /// The (first) mesh, if any.
    pub mesh: Option<AssetMesh>,
    /// Its skin (influences and bind transforms), if it has one.
    pub skin: Option<SkinDesc>,
    /// Its morph targets, if any.
    pub morphs: Option<BlendshapeDesc>,
    /// The animations sampled into clips, with their names.
    pub clips: Vec<(String, Clip)>,
}

/// The affine transform of a node.
fn node_affine(n: &gltf::Node) -> Affine {
    let (t, r, s) = n.transform().decomposed();
    affine_from_trs(
        t.map(|v| v as f64),
        [r[3] as f64, r[0] as f64, r[1] as f64, r[2] as f64],
        s.map(|v| v as f64),
    )
}

/// Checks that accessor `a` lies inside its data: count at least 1, the view and buffer
/// ranges inside the buffers' data (which `data` gives per buffer index).
fn check_accessor(a: &gltf::Accessor, data: &[Vec<u8>], name: &str) -> Result<(), String> {
    let what = format!("accessor {}{}", a.index(), name);
    if a.count() == 0 {
        return Err(format!("{what} has no elements"));
    }
    let size = a.size();
    let mut ranges = Vec::new();
    if let Some(v) = a.view() {
        let stride = v.stride().unwrap_or(size);
        let end = a
            .offset()
            .checked_add(
                stride
                    .checked_mul(a.count() - 1)
                    .ok_or_else(|| format!("{what} is too large"))?,
            )
            .and_then(|e| e.checked_add(size))
            .ok_or_else(|| format!("{what} is too large"))?;
        if end > v.length() {
            return Err(format!(
                "{what} runs past the end of buffer view {}",
                v.index()
            ));
        }
        ranges.push(v);
    }
    if let Some(sp) = a.sparse() {
        if sp.count() == 0 {
            return Err(format!("{what} has an empty sparse part"));
        }
        ranges.push(sp.indices().view());
        ranges.push(sp.values().view());
    }
    for v in ranges {
        let b = v.buffer().index();
        let len = data.get(b).map_or(0, |d| d.len());
        match v.offset().checked_add(v.length()) {
            Some(e) if e <= len => {}
            _ => {
                return Err(format!(
                    "{what}: buffer view {} runs past the end of buffer {b} ({len} bytes)",
                    v.index()
                ))
            }
        }
    }
    Ok(())
}

impl Asset {
    /// Reads a `.glb` or `.gltf` file (see the module docs), sampling animations at
    /// `rate` frames per second.
    pub fn read(path: &Path, max_bytes: u64, rate: f64) -> Result<Asset, ReadError> {
        let name = path.display().to_string();
        let err = |message: String| ReadError {
            path: name.clone(),
            line: 0,
            message,
        };
        let meta = std::fs::metadata(path).map_err(|e| err(e.to_string()))?;
        if meta.len() > max_bytes {
            return Err(err(format!(
                "{} bytes is over the input limit of {max_bytes}",
                meta.len()
            )));
        }
        let bytes = std::fs::read(path).map_err(|e| err(e.to_string()))?;
        let g = gltf::Gltf::from_slice(&bytes)
            .map_err(|e| err(format!("not a valid glTF file: {e}")))?;
        let mut data: Vec<Vec<u8>> = Vec::new();
        for b in g.buffers() {
            let d = match b.source() {
                gltf::buffer::Source::Bin => g.blob.clone().ok_or_else(|| {
                    err(format!(
                        "buffer {} names the binary chunk, which the file lacks",
                        b.index()
                    ))
                })?,
                gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                    // data:[<type>];base64,<data> (the text is within the file's bound).
                    let data = uri.split_once(";base64,").map(|(_, d)| d).ok_or_else(|| {
                        err(format!(
                            "buffer {} is a data URI that is not base64",
                            b.index()
                        ))
                    })?;
                    use base64::Engine as _;
                    base64::engine::general_purpose::STANDARD
                        .decode(data)
                        .map_err(|e| err(format!("buffer {}: bad base64 data: {e}", b.index())))?
                }
                gltf::buffer::Source::Uri(uri) => {
                    let file = path.parent().unwrap_or(Path::new("")).join(uri);
                    let m = std::fs::metadata(&file)
                        .map_err(|e| err(format!("buffer {} ({uri}): {e}", b.index())))?;
                    if m.len() > max_bytes {
                        return Err(err(format!(
                            "buffer {} ({uri}) is over the input limit",
                            b.index()
                        )));
                    }
                    std::fs::read(&file)
                        .map_err(|e| err(format!("buffer {} ({uri}): {e}", b.index())))?
                }
            };
            if d.len() < b.length() {
                return Err(err(format!(
                    "buffer {} holds {} bytes, the file says {}",
                    b.index(),
                    d.len(),
                    b.length()
                )));
            }
            data.push(d);
        }
        Asset::from_document(&g, &data, rate).map_err(err)
    }

    fn from_document(g: &gltf::Gltf, data: &[Vec<u8>], rate: f64) -> Result<Asset, String> {
        if !(rate > 0.0 && rate.is_finite()) {
            return Err(format!("sampling rate {rate} must be a finite number > 0"));
        }
        let buf = |b: gltf::Buffer| data.get(b.index()).map(|d| d.as_slice());
        let nodes: Vec<gltf::Node> = g.nodes().collect();
        let mut parent_node = vec![None; nodes.len()];
        for n in &nodes {
            for c in n.children() {
                parent_node[c.index()] = Some(n.index());
            }
        }
        let skin = g.skins().next();
        // The joints: the skin's, or every node.
        let joint_nodes: Vec<usize> = match &skin {
            Some(s) => s.joints().map(|n| n.index()).collect(),
            None => (0..nodes.len()).collect(),
        };
        let is_joint = |n: usize| joint_nodes.iter().position(|&j| j == n);
        // Parents first: order by depth.
        let depth = |mut n: usize| {
            let mut d = 0;
            while let Some(p) = parent_node[n] {
                n = p;
                d += 1;
                if d > nodes.len() {
                    break;
                }
            }
            d
        };
        let mut order: Vec<usize> = (0..joint_nodes.len()).collect();
        order.sort_by_key(|&k| depth(joint_nodes[k]));
        let mut new_of = vec![0; joint_nodes.len()];
        for (i, &k) in order.iter().enumerate() {
            new_of[k] = i;
        }
        let mut joints = Vec::with_capacity(order.len());
        for &k in &order {
            let n = &nodes[joint_nodes[k]];
            // Nearest joint ancestor; the other ancestors fold into the local transform.
            let mut local = node_affine(n);
            let mut up = parent_node[n.index()];
            let mut parent = None;
            while let Some(p) = up {
                if let Some(pk) = is_joint(p) {
                    parent = Some(new_of[pk]);
                    break;
                }
                local = affine_mul(&node_affine(&nodes[p]), &local);
                up = parent_node[p];
            }
            let (t, r, s) = affine_decompose(&local);
            let name = n
                .name()
                .map_or_else(|| format!("node{}", n.index()), str::to_string);
            joints.push(JointDesc {
                name,
                parent,
                translation: t,
                rotation: r,
                scale: s,
            });
        }
        let skeleton = SkeletonDesc { joints };
        let built = skeleton.build().map_err(|e| e.to_string())?;
        let mut asset = Asset {
            skeleton,
            ..Asset::default()
        };
        // The first mesh's first primitive.
        if let Some(prim) = g.meshes().next().and_then(|m| m.primitives().next()) {
            for (_, a) in prim.attributes() {
                check_accessor(&a, data, "")?;
            }
            if let Some(a) = prim.indices() {
                check_accessor(&a, data, " (indices)")?;
            }
            let r = prim.reader(buf);
            let pos: Vec<[f32; 3]> = r
                .read_positions()
                .ok_or("the mesh has no positions")?
                .collect();
            let n = pos.len();
            let comp = |v: &[[f32; 3]]| -> Vec<f64> {
                (0..3)
                    .flat_map(|c| v.iter().map(move |p| p[c] as f64))
                    .collect()
            };
            let normals: Vec<[f32; 3]> =
                r.read_normals().map(|it| it.collect()).unwrap_or_default();
            if !normals.is_empty() && normals.len() != n {
                return Err(format!("{} normals for {n} positions", normals.len()));
            }
            let idx: Vec<u32> = match r.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            if !idx.len().is_multiple_of(3) {
                return Err(format!("{} indices: not whole triangles", idx.len()));
            }
            if let Some(&bad) = idx.iter().find(|&&i| i as usize >= n) {
                return Err(format!("index {bad} past the mesh's {n} vertices"));
            }
            let mesh = AssetMesh {
                positions: comp(&pos),
                normals: comp(&normals),
                triangles: idx.chunks(3).map(|t| [t[0], t[1], t[2]]).collect(),
            };
            // Morph targets: full positions from the deltas.
            let mut shapes = Vec::new();
            for target in prim.morph_targets() {
                for a in [target.positions(), target.normals(), target.tangents()]
                    .into_iter()
                    .flatten()
                {
                    check_accessor(&a, data, " (morph target)")?;
                }
            }
            for (k, (dp, _, _)) in r.read_morph_targets().enumerate() {
                let Some(dp) = dp else { continue };
                let d: Vec<[f32; 3]> = dp.collect();
                if d.len() != n {
                    return Err(format!(
                        "morph target {k} has {} positions for {n}",
                        d.len()
                    ));
                }
                let delta = comp(&d);
                shapes.push(ShapeDesc {
                    name: format!("target{k}"),
                    positions: mesh
                        .positions
                        .iter()
                        .zip(&delta)
                        .map(|(p, d)| p + d)
                        .collect(),
                    combines: Vec::new(),
                });
            }
            if !shapes.is_empty() {
                asset.morphs = Some(BlendshapeDesc {
                    neutral: mesh.positions.clone(),
                    shapes,
                });
            }
            if let Some(s) = &skin {
                let j: Vec<[u16; 4]> = r
                    .read_joints(0)
                    .ok_or("a skinned mesh without JOINTS_0")?
                    .into_u16()
                    .collect();
                let w: Vec<[f32; 4]> = r
                    .read_weights(0)
                    .ok_or("a skinned mesh without WEIGHTS_0")?
                    .into_f32()
                    .collect();
                if j.len() != n || w.len() != n {
                    return Err(format!(
                        "{} joint sets and {} weight sets for {n} vertices",
                        j.len(),
                        w.len()
                    ));
                }
                let nj = joint_nodes.len();
                if let Some((v, js)) = j
                    .iter()
                    .enumerate()
                    .find(|(_, js)| js.iter().any(|&x| x as usize >= nj))
                {
                    return Err(format!(
                        "vertex {v} names joint {:?}, past the skin's {nj}",
                        js
                    ));
                }
                // Inverse bind matrices (column-major 4x4), in skin joint order.
                let ibm: Vec<[[f32; 4]; 4]> = match s.inverse_bind_matrices() {
                    Some(a) => {
                        check_accessor(&a, data, " (inverse bind matrices)")?;
                        s.reader(buf)
                            .read_inverse_bind_matrices()
                            .ok_or("unreadable inverse bind matrices")?
                            .collect()
                    }
                    None => vec![
                        [
                            [1.0, 0.0, 0.0, 0.0],
                            [0.0, 1.0, 0.0, 0.0],
                            [0.0, 0.0, 1.0, 0.0],
                            [0.0; 4]
                        ];
                        nj
                    ],
                };
                if ibm.len() < nj {
                    return Err(format!(
                        "{} inverse bind matrices for {nj} joints",
                        ibm.len()
                    ));
                }
                let mut bind = vec![AFFINE_IDENTITY; nj];
                for (k, m) in ibm.iter().take(nj).enumerate() {
                    let a: Affine = std::array::from_fn(|e| m[e % 4][e / 4] as f64);
                    bind[new_of[k]] = affine_inverse(&a);
                }
                asset.skin = Some(SkinDesc {
                    positions: mesh.positions.clone(),
                    normals: mesh.normals.clone(),
                    joints: j
                        .iter()
                        .map(|js| js.map(|x| new_of[x as usize] as u16))
                        .collect(),
                    weights: w.iter().map(|ws| ws.map(|x| x as f64)).collect(),
                    bind,
                });
            }
            asset.mesh = Some(mesh);
        }
        // Animations.
        for anim in g.animations() {
            let mut t_tracks: Vec<Option<VectorTrack>> = vec![None; order.len()];
            let mut s_tracks: Vec<Option<VectorTrack>> = vec![None; order.len()];
            let mut r_tracks: Vec<Option<RotationTrack>> = vec![None; order.len()];
            let mut end: f64 = 0.0;
            for ch in anim.channels() {
                let Some(k) = is_joint(ch.target().node().index()) else {
                    continue;
                };
                let j = new_of[k];
                let smp = ch.sampler();
                check_accessor(&smp.input(), data, " (animation input)")?;
                check_accessor(&smp.output(), data, " (animation output)")?;
                let r = ch.reader(buf);
                let times: Vec<f64> = r
                    .read_inputs()
                    .ok_or("unreadable animation times")?
                    .map(|t| t as f64)
                    .collect();
                end = end.max(times.last().copied().unwrap_or(0.0));
                let cubic = smp.interpolation() == gltf::animation::Interpolation::CubicSpline;
                let kind = match smp.interpolation() {
                    gltf::animation::Interpolation::Step => Interpolation::Step,
                    gltf::animation::Interpolation::Linear => Interpolation::Linear,
                    gltf::animation::Interpolation::CubicSpline => Interpolation::Hermite,
                };
                let per = if cubic { 3 } else { 1 };
                let vec_track = |vals: Vec<[f32; 3]>| -> Result<VectorTrack, String> {
                    if vals.len() != per * times.len() {
                        return Err(format!(
                            "channel of {} keys has {} values",
                            times.len(),
                            vals.len()
                        ));
                    }
                    let keys = times
                        .iter()
                        .enumerate()
                        .map(|(i, &t)| {
                            let v = vals[per * i + per / 2].map(|x| x as f64);
                            let mut key = Key::new(t, v, kind);
                            if cubic {
                                key.tangent = Tangent::User(
                                    vals[3 * i].map(|x| x as f64),
                                    vals[3 * i + 2].map(|x| x as f64),
                                );
                            }
                            key
                        })
                        .collect();
                    VectorTrack::new(keys)
                        .map_err(|e| format!("animation '{}': {e}", anim.name().unwrap_or("")))
                };
                match r.read_outputs().ok_or("unreadable animation values")? {
                    gltf::animation::util::ReadOutputs::Translations(v) => {
                        t_tracks[j] = Some(vec_track(v.collect())?)
                    }
                    gltf::animation::util::ReadOutputs::Scales(v) => {
                        s_tracks[j] = Some(vec_track(v.collect())?)
                    }
                    gltf::animation::util::ReadOutputs::Rotations(v) => {
                        let vals: Vec<[f32; 4]> = v.into_f32().collect();
                        if vals.len() != per * times.len() {
                            return Err(format!(
                                "rotation channel of {} keys has {} values",
                                times.len(),
                                vals.len()
                            ));
                        }
                        let keys: Vec<(f64, quat::Quat)> = times
                            .iter()
                            .enumerate()
                            .map(|(i, &t)| {
                                let q = vals[per * i + per / 2];
                                (t, [q[3] as f64, q[0] as f64, q[1] as f64, q[2] as f64])
                            })
                            .collect();
                        let ri = if kind == Interpolation::Step {
                            RotationInterpolation::Step
                        } else {
                            RotationInterpolation::Slerp
                        };
                        r_tracks[j] =
                            Some(RotationTrack::new(&keys, ri).map_err(|e| e.to_string())?);
                    }
                    gltf::animation::util::ReadOutputs::MorphTargetWeights(_) => {}
                }
            }
            // Sampled poses take about 80 bytes a joint a frame: at most
            // MAX_JOINT_FRAMES of them, checked before allocating.
            let frames = (end * rate).ceil() as usize + 1;
            if !end.is_finite() || frames.saturating_mul(order.len().max(1)) > MAX_JOINT_FRAMES {
                return Err(format!(
                    "animation '{}' lasts {end} s: {frames} frames of {} joints at {rate} per second is more than {MAX_JOINT_FRAMES} joint frames",
                    anim.name().unwrap_or(""),
                    order.len()
                ));
            }
            let mut poses = Vec::with_capacity(frames);
            let mut cur = Cursor::default();
            for f in 0..frames {
                let t = f as f64 / rate;
                let mut p = built.rest().clone();
                for j in 0..order.len() {
                    let tr = t_tracks[j]
                        .as_ref()
                        .map_or(p.translation(j), |tr| tr.sample(t, &mut cur));
                    let rq = r_tracks[j]
                        .as_ref()
                        .map_or(p.rotation(j), |tr| tr.sample(t, &mut cur));
                    let sc = s_tracks[j]
                        .as_ref()
                        .map_or(p.scale(j), |tr| tr.sample(t, &mut cur));
                    p.set(j, tr, rq, sc);
                }
                poses.push(p);
            }
            asset.clips.push((
                anim.name().unwrap_or("animation").to_string(),
                Clip::from_poses(1.0 / rate, &poses),
            ));
        }
        Ok(asset)
    }
}

/// Appends `bytes` to the binary chunk (4-byte aligned) and returns its buffer view
/// JSON.
fn push_view(bin: &mut Vec<u8>, bytes: &[u8], views: &mut Vec<serde_json::Value>) -> usize {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    views
        .push(serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}));
    bin.extend_from_slice(bytes);
    views.len() - 1
}

/// Writes a `.glb` of `skeleton` (its rest pose as the nodes), with `mesh` skinned by
/// `skin` (its joints and weights; bind transforms from the skin's bind), morph targets
/// from `morphs` (their base shapes), and `clip` as one animation named `name`.
#[allow(clippy::too_many_arguments)]
pub fn write_glb(
    w: &mut dyn std::io::Write,
    skeleton: &Skeleton,
    mesh: Option<&AssetMesh>,
    skin: Option<&SkinDesc>,
    morphs: Option<&BlendshapeDesc>,
    clip: Option<(&str, &Clip)>,
) -> std::io::Result<()> {
    use serde_json::json;
    let n = skeleton.len();
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors: Vec<serde_json::Value> = Vec::new();
    let f32s = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
    let mut add = |bytes: Vec<u8>,
                   count: usize,
                   ctype: u32,
                   ty: &str,
                   minmax: Option<(Vec<f32>, Vec<f32>)>,
                   views: &mut Vec<serde_json::Value>,
                   bin: &mut Vec<u8>|
     -> usize {
        let view = push_view(bin, &bytes, views);
        let mut a = json!({"bufferView": view, "componentType": ctype, "count": count, "type": ty});
        if let Some((lo, hi)) = minmax {
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        accessors.push(a);
        accessors.len() - 1
    };
    let bounds = |pts: &[[f32; 3]]| {
        let mut lo = vec![f32::INFINITY; 3];
        let mut hi = vec![f32::NEG_INFINITY; 3];
        for p in pts {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        }
        (lo, hi)
    };
    // Nodes: joints, then the mesh.
    let mut nodes: Vec<serde_json::Value> = (0..n)
        .map(|j| {
            let (t, q, s) = (skeleton.rest().translation(j), skeleton.rest().rotation(j), skeleton.rest().scale(j));
            let children: Vec<usize> = (0..n).filter(|&c| skeleton.parent(c) == Some(j)).collect();
            let mut node = json!({"name": skeleton.names()[j], "translation": t, "rotation": [q[1], q[2], q[3], q[0]], "scale": s});
            if !children.is_empty() {
                node["children"] = json!(children);
            }
            node
        })
        .collect();
    let roots: Vec<usize> = (0..n).filter(|&j| skeleton.parent(j).is_none()).collect();
    let mut scene_nodes = roots.clone();
    let mut meshes = Vec::new();
    let mut skins = Vec::new();
    if let Some(m) = mesh {
        let v = m.positions.len() / 3;
        let pts: Vec<[f32; 3]> = (0..v)
            .map(|i| [0, 1, 2].map(|c| m.positions[c * v + i] as f32))
            .collect();
        let mut attributes = json!({});
        let pos = add(
            f32s(&pts.concat()),
            v,
            5126,
            "VEC3",
            Some(bounds(&pts)),
            &mut views,
            &mut bin,
        );
        attributes["POSITION"] = json!(pos);
        if m.normals.len() == 3 * v {
            let nr: Vec<f32> = (0..v)
                .flat_map(|i| [0, 1, 2].map(|c| m.normals[c * v + i] as f32))
                .collect();
            attributes["NORMAL"] =
                json!(add(f32s(&nr), v, 5126, "VEC3", None, &mut views, &mut bin));
        }
        let mut skin_index = None;
        if let Some(s) = skin {
            let js: Vec<u8> = s
                .joints
                .iter()
                .flat_map(|j| j.iter().flat_map(|x| x.to_le_bytes()))
                .collect();
            attributes["JOINTS_0"] = json!(add(js, v, 5123, "VEC4", None, &mut views, &mut bin));
            let ws: Vec<f32> = s.weights.iter().flat_map(|w| w.map(|x| x as f32)).collect();
            attributes["WEIGHTS_0"] =
                json!(add(f32s(&ws), v, 5126, "VEC4", None, &mut views, &mut bin));
            let ibm: Vec<f32> = s
                .bind
                .iter()
                .flat_map(|b| {
                    let a = affine_inverse(b);
                    (0..16).map(move |e| {
                        let (r, c) = (e % 4, e / 4);
                        if r == 3 {
                            if c == 3 {
                                1.0
                            } else {
                                0.0
                            }
                        } else {
                            a[4 * r + c] as f32
                        }
                    })
                })
                .collect();
            let acc = add(
                f32s(&ibm),
                s.bind.len(),
                5126,
                "MAT4",
                None,
                &mut views,
                &mut bin,
            );
            skins.push(json!({"joints": (0..n).collect::<Vec<_>>(), "inverseBindMatrices": acc}));
            skin_index = Some(0);
        }
        let idx: Vec<u8> = m
            .triangles
            .iter()
            .flat_map(|t| t.iter().flat_map(|x| x.to_le_bytes()))
            .collect();
        let indices = add(
            idx,
            3 * m.triangles.len(),
            5125,
            "SCALAR",
            None,
            &mut views,
            &mut bin,
        );
        let mut prim = json!({"attributes": attributes, "indices": indices, "mode": 4});
        if let Some(b) = morphs {
            let mut targets = Vec::new();
            for s in b.shapes.iter().filter(|s| s.combines.is_empty()) {
                let d: Vec<[f32; 3]> = (0..v)
                    .map(|i| {
                        [0, 1, 2].map(|c| (s.positions[c * v + i] - b.neutral[c * v + i]) as f32)
                    })
                    .collect();
                let a = add(
                    f32s(&d.concat()),
                    v,
                    5126,
                    "VEC3",
                    Some(bounds(&d)),
                    &mut views,
                    &mut bin,
                );
                targets.push(json!({"POSITION": a}));
            }
            prim["targets"] = json!(targets);
        }
        meshes.push(json!({"primitives": [prim]}));
        let mut node = json!({"name": "mesh", "mesh": 0});
        if let Some(s) = skin_index {
            node["skin"] = json!(s);
        }
        nodes.push(node);
        scene_nodes.push(nodes.len() - 1);
    }
    let mut animations = Vec::new();
    if let Some((name, c)) = clip {
        let frames = c.frames();
        let times: Vec<f32> = (0..frames)
            .map(|k| (k as f64 * c.frame_time()) as f32)
            .collect();
        let input = add(
            f32s(&times),
            frames,
            5126,
            "SCALAR",
            Some((vec![times[0]], vec![*times.last().unwrap_or(&0.0)])),
            &mut views,
            &mut bin,
        );
        let mut samplers = Vec::new();
        let mut channels = Vec::new();
        let mut pose = Pose::identity(n);
        let mut t_out = vec![Vec::new(); n];
        let mut r_out = vec![Vec::new(); n];
        for k in 0..frames {
            c.sample(k as f64 * c.frame_time(), false, &mut pose);
            for j in 0..n {
                t_out[j].extend(pose.translation(j).map(|x| x as f32));
                let q = pose.rotation(j);
                r_out[j].extend([q[1], q[2], q[3], q[0]].map(|x| x as f32));
            }
        }
        for j in 0..n {
            let ta = add(
                f32s(&t_out[j]),
                frames,
                5126,
                "VEC3",
                None,
                &mut views,
                &mut bin,
            );
            let ra = add(
                f32s(&r_out[j]),
                frames,
                5126,
                "VEC4",
                None,
                &mut views,
                &mut bin,
            );
            samplers.push(json!({"input": input, "output": ta, "interpolation": "LINEAR"}));
            channels.push(json!({"sampler": samplers.len() - 1, "target": {"node": j, "path": "translation"}}));
            samplers.push(json!({"input": input, "output": ra, "interpolation": "LINEAR"}));
            channels.push(
                json!({"sampler": samplers.len() - 1, "target": {"node": j, "path": "rotation"}}),
            );
        }
        animations.push(json!({"name": name, "samplers": samplers, "channels": channels}));
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut root = json!({
        "asset": {"version": "2.0", "generator": "largestep"},
        "scene": 0,
        "scenes": [{"nodes": scene_nodes}],
        "nodes": nodes,
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
    });
    if !meshes.is_empty() {
        root["meshes"] = json!(meshes);
    }
    if !skins.is_empty() {
        root["skins"] = json!(skins);
    }
    if !animations.is_empty() {
        root["animations"] = json!(animations);
    }
    let mut json_bytes = serde_json::to_vec(&root).map_err(std::io::Error::other)?;
    while json_bytes.len() % 4 != 0 {
        json_bytes.push(b' ');
    }
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: (12 + 8 + json_bytes.len() + 8 + bin.len()) as u32,
        },
        json: std::borrow::Cow::Owned(json_bytes),
        bin: Some(std::borrow::Cow::Owned(bin)),
    };
    glb.to_writer(w)
        .map_err(|e| std::io::Error::other(e.to_string()))
}
