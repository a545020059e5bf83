//! OpenCV FileStorage YAML (`%YAML:1.0`, `!!opencv-matrix`) as OpenCV's and EasyMocap's
//! writers emit it, and EasyMocap's camera folders (`intri.yml` + `extri.yml`, the layout of
//! ZJU-MoCap and of EasyMocap's own calibrations).
//!
//! The `%YAML:1.0` directive is not valid YAML (YAML writes `%YAML 1.0`), so general YAML
//! readers refuse these files; the subset read here is the one those writers produce: top-level
//! `key: value` entries whose value is a scalar, a list (`- item` lines or `[a, b]`), or an
//! `!!opencv-matrix` (`rows`, `cols`, `dt`, `data: [...]`, the data possibly over several lines).

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

/// One top-level entry's value.
#[derive(Debug, Clone, PartialEq)]
pub enum CvNode {
    Scalar(String),
    List(Vec<String>),
    Matrix {
        rows: usize,
        cols: usize,
        data: Vec<f64>,
    },
}

fn unquote(s: &str) -> String {
    let s = s.trim();
    let q = s.len() >= 2
        && ((s.starts_with('"') && s.ends_with('"')) || (s.starts_with('\'') && s.ends_with('\'')));
    if q { &s[1..s.len() - 1] } else { s }.to_string()
}

/// The items of a flow list `[a, b, ...]` (the text from `[` on).
fn flow_items(text: &str, what: &str) -> Result<Vec<String>, String> {
    let inner = text
        .trim()
        .strip_prefix('[')
        .and_then(|t| t.trim_end().strip_suffix(']'))
        .ok_or_else(|| format!("{what}: expected a list [ ... ]"))?;
    Ok(inner
        .split(',')
        .map(unquote)
        .filter(|s| !s.is_empty())
        .collect())
}

/// The top-level entries of an OpenCV FileStorage YAML text, in order.
pub fn parse(text: &str) -> Result<Vec<(String, CvNode)>, String> {
    let mut entries: Vec<(String, String, Vec<(usize, String)>)> = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let line = raw.trim_end_matches('\r');
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') || t == "---" || (n == 0 && t.starts_with("%YAML")) {
            continue;
        }
        if !line.starts_with([' ', '\t', '-']) {
            let Some((key, rest)) = line.split_once(':') else {
                return Err(format!("line {}: expected 'key: value', got '{t}'", n + 1));
            };
            entries.push((key.trim().to_string(), rest.trim().to_string(), Vec::new()));
        } else {
            let Some(last) = entries.last_mut() else {
                return Err(format!("line {}: indented line before any key", n + 1));
            };
            last.2.push((n + 1, t.to_string()));
        }
    }
    let mut out = Vec::with_capacity(entries.len());
    for (key, rest, body) in entries {
        let node = if let Some(tag) = rest.strip_prefix("!!") {
            if tag.trim() != "opencv-matrix" {
                return Err(format!("{key}: unsupported type !!{}", tag.trim()));
            }
            matrix(&key, &body)?
        } else if rest.is_empty() {
            let mut items = Vec::with_capacity(body.len());
            for (n, l) in &body {
                let Some(item) = l.strip_prefix('-') else {
                    return Err(format!(
                        "line {n}: expected a list item '- value' under {key}"
                    ));
                };
                items.push(unquote(item));
            }
            CvNode::List(items)
        } else if rest.starts_with('[') {
            let all = std::iter::once(rest.as_str())
                .chain(body.iter().map(|b| b.1.as_str()))
                .collect::<Vec<_>>()
                .join(" ");
            CvNode::List(flow_items(&all, &key)?)
        } else {
            if let Some((n, _)) = body.first() {
                return Err(format!("line {n}: unexpected indented line under {key}"));
            }
            CvNode::Scalar(unquote(&rest))
        };
        out.push((key, node));
    }
    Ok(out)
}

/// An `!!opencv-matrix` body: `rows`, `cols`, `dt`, `data: [...]` (data over several lines).
fn matrix(key: &str, body: &[(usize, String)]) -> Result<CvNode, String> {
    let (mut rows, mut cols, mut data): (Option<usize>, Option<usize>, Option<String>) =
        (None, None, None);
    for (n, l) in body {
        if let Some(d) = data.as_mut().filter(|d| !d.contains(']')) {
            d.push(' ');
            d.push_str(l);
            continue;
        }
        let Some((k, v)) = l.split_once(':') else {
            return Err(format!(
                "line {n}: expected rows, cols, dt or data under {key}"
            ));
        };
        let v = v.trim();
        match k.trim() {
            "rows" => rows = v.parse().ok(),
            "cols" => cols = v.parse().ok(),
            "dt" => {}
            "data" => data = Some(v.to_string()),
            other => {
                return Err(format!(
                    "line {n}: unknown matrix field '{other}' under {key}"
                ));
            }
        }
    }
    let (Some(rows), Some(cols), Some(data)) = (rows, cols, data) else {
        return Err(format!("{key}: a matrix needs rows, cols and data"));
    };
    let data = flow_items(&data, key)?
        .iter()
        .map(|x| x.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<Vec<f64>>>()
        .ok_or_else(|| format!("{key}: data holds a value that is not a finite number"))?;
    if data.len() != rows * cols {
        return Err(format!(
            "{key}: {} values for a {rows}×{cols} matrix",
            data.len()
        ));
    }
    Ok(CvNode::Matrix { rows, cols, data })
}

/// The EasyMocap folder a camera path names: the folder itself, or the one holding the
/// `intri.yml` / `extri.yml` named; `None` for any other path.
pub fn easymocap_dir(path: &Path) -> Option<PathBuf> {
    if path.is_dir() {
        return Some(path.to_path_buf());
    }
    let name = path.file_name()?.to_str()?.to_ascii_lowercase();
    ["intri.yml", "extri.yml", "intri.yaml", "extri.yaml"]
        .contains(&name.as_str())
        .then(|| path.parent().map(Path::to_path_buf).unwrap_or_default())
}

fn read_entries(path: &Path) -> Result<Vec<(String, CvNode)>, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    parse(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// The file of `stem` (`intri` or `extri`) in `dir`: `.yml`, else `.yaml`.
fn yml(dir: &Path, stem: &str) -> Result<PathBuf, String> {
    let a = dir.join(format!("{stem}.yml"));
    let b = dir.join(format!("{stem}.yaml"));
    if a.is_file() {
        Ok(a)
    } else if b.is_file() {
        Ok(b)
    } else {
        Err(format!(
            "no {stem}.yml in {} (an EasyMocap camera folder holds intri.yml and extri.yml)",
            dir.display()
        ))
    }
}

/// An EasyMocap camera folder's cameras, in `names` order, as camera-file JSON entries (`name`,
/// `K`, `dist`, `rvec` (its `R_`; `Rot_` where there is none), `t` (its `T_`, metres), and
/// `resolution` from `W_`/`H_`), and per camera whether it lacks `W_`/`H_`, its image size then
/// taken as twice the principal point (EasyMocap does not need it; ZJU-MoCap's files leave it out).
pub fn easymocap_cameras(dir: &Path) -> Result<(Vec<Value>, Vec<bool>), String> {
    let intri = read_entries(&yml(dir, "intri")?)?;
    let extri = read_entries(&yml(dir, "extri")?)?;
    let get = |entries: &[(String, CvNode)], key: &str| {
        entries.iter().find(|e| e.0 == key).map(|e| e.1.clone())
    };
    let names = match get(&intri, "names") {
        Some(CvNode::List(names)) if !names.is_empty() => names,
        _ => return Err("intri.yml has no list of camera names ('names')".into()),
    };
    let mat = |entries: &[(String, CvNode)],
               key: &str,
               shapes: &[(usize, usize)]|
     -> Result<Option<Vec<f64>>, String> {
        match get(entries, key) {
            None => Ok(None),
            Some(CvNode::Matrix { rows, cols, data }) if shapes.contains(&(rows, cols)) => {
                Ok(Some(data))
            }
            Some(CvNode::Matrix { rows, cols, .. }) => Err(format!(
                "{key} is {rows}×{cols}, expected {}",
                shapes
                    .iter()
                    .map(|(r, c)| format!("{r}×{c}"))
                    .collect::<Vec<_>>()
                    .join(" or ")
            )),
            Some(_) => Err(format!("{key} is not a matrix")),
        }
    };
    let int = |key: &str| -> Result<Option<u32>, String> {
        match get(&intri, key) {
            None => Ok(None),
            Some(CvNode::Scalar(s)) => s
                .parse::<f64>()
                .ok()
                .filter(|v| v.fract() == 0.0 && *v > 0.0 && *v < 1e6)
                .map(|v| Some(v as u32))
                .ok_or_else(|| format!("{key} is '{s}', not a positive whole number of pixels")),
            Some(_) => Err(format!("{key} is not a number")),
        }
    };
    let mut cameras = Vec::with_capacity(names.len());
    let mut guessed = Vec::with_capacity(names.len());
    for n in &names {
        let k = mat(&intri, &format!("K_{n}"), &[(3, 3)])?
            .ok_or_else(|| format!("intri.yml has no K_{n} for camera '{n}'"))?;
        let dist = match mat(
            &intri,
            &format!("dist_{n}"),
            &[(1, 4), (4, 1), (1, 5), (5, 1), (1, 8), (8, 1)],
        )? {
            Some(d) => Some(d),
            None => mat(
                &intri,
                &format!("D_{n}"),
                &[(1, 4), (4, 1), (1, 5), (5, 1), (1, 8), (8, 1)],
            )?,
        };
        let rvec = mat(&extri, &format!("R_{n}"), &[(3, 1), (1, 3)])?;
        let rot = if rvec.is_none() {
            mat(&extri, &format!("Rot_{n}"), &[(3, 3)])?
        } else {
            None
        };
        let t = mat(&extri, &format!("T_{n}"), &[(3, 1), (1, 3)])?
            .ok_or_else(|| format!("extri.yml has no T_{n} for camera '{n}'"))?;
        let (w, h) = match (int(&format!("W_{n}"))?, int(&format!("H_{n}"))?) {
            (Some(w), Some(h)) => {
                guessed.push(false);
                (w, h)
            }
            (None, None) => {
                guessed.push(true);
                let round = |c: f64| (2.0 * c).round().max(1.0) as u32;
                (round(k[2]), round(k[5]))
            }
            _ => return Err(format!("intri.yml gives one of W_{n} and H_{n}: give both")),
        };
        let mut cam = json!({
            "name": n,
            "K": [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]],
            "t": t,
            "resolution": [w, h],
        });
        match (rvec, rot) {
            (Some(r), _) => cam["rvec"] = json!(r),
            (None, Some(r)) => {
                cam["R"] = json!([[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]])
            }
            (None, None) => {
                return Err(format!(
                    "extri.yml has no R_{n} (or Rot_{n}) for camera '{n}'"
                ));
            }
        }
        if let Some(d) = dist {
            cam["dist"] = json!(d);
        }
        cameras.push(cam);
    }
    Ok((cameras, guessed))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::keypoints::{Distortion, read_camera_file};
    use lfit_model::camera::{Camera, default_ring};

    fn rvec(c: &Camera) -> [f64; 3] {
        let (axis, angle) = glam::DQuat::from_mat3(&c.rot()).to_axis_angle();
        (axis * angle).to_array()
    }

    fn nums(v: &[f64]) -> String {
        v.iter()
            .map(|x| format!("{x:e}"))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// A camera folder written as EasyMocap writes it (CRLF, `names` as `- "01"` lines, one-line
    /// data, `W_`/`H_`, `R_` and `Rot_`) for camera "01", and as OpenCV's own writer does for
    /// camera "02" (data over two lines, `0.`-style numbers, `Rot_` only, no image size) reads
    /// as the ring's cameras: names in order, the rotation from `R_` where given, the size
    /// from `W_`/`H_` or twice the principal point (reported), the distortion; the folder, its
    /// `intri.yml` and its `extri.yml` name the same rig; broken files are one-line errors.
    #[test]
    fn an_easymocap_folder_reads_as_its_cameras() {
        let d = tempfile::tempdir().unwrap();
        let ring = default_ring(2);
        let (a, b) = (&ring[0], &ring[1]);
        let ka = [a.fx, 0.0, a.cx, 0.0, a.fy, a.cy, 0.0, 0.0, 1.0];
        let kb = [b.fx, 0.0, b.cx, 0.0, b.fy, b.cy, 0.0, 0.0, 1.0];
        let m = |key: &str, r: usize, c: usize, v: &[f64]| {
            format!(
                "{key}: !!opencv-matrix\r\n  rows: {r}\r\n  cols: {c}\r\n  dt: d\r\n  data: [{}]\r\n",
                nums(v)
            )
        };
        let intri = format!(
            "%YAML:1.0\r\n---\r\nnames:\r\n  - \"01\"\r\n  - \"02\"\r\n{}{}W_01: {}\r\nH_01: {}\r\n\
             K_02: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {}, 0., {},\n       0., {}, {}, 0., 0., 1. ]\n",
            m("K_01", 3, 3, &ka),
            m("dist_01", 1, 5, &[-0.2, 0.05, 0.001, -0.002, 0.0]),
            a.width,
            a.height,
            nums(&[kb[0]]),
            nums(&[kb[2]]),
            nums(&[kb[4]]),
            nums(&[kb[5]]),
        );
        let flat = |r: &[[f64; 3]; 3]| r.iter().flatten().copied().collect::<Vec<f64>>();
        let extri = format!(
            "%YAML:1.0\r\n---\r\nnames:\r\n  - \"01\"\r\n  - \"02\"\r\n{}{}{}{}{}",
            m("R_01", 3, 1, &rvec(a)),
            m("Rot_01", 3, 3, &flat(&[[9.0; 3]; 3])),
            m("T_01", 3, 1, &a.translation),
            m("Rot_02", 3, 3, &flat(&b.rotation)),
            m("T_02", 3, 1, &b.translation),
        );
        std::fs::write(d.path().join("intri.yml"), &intri).unwrap();
        std::fs::write(d.path().join("extri.yml"), &extri).unwrap();
        for path in [
            d.path().to_path_buf(),
            d.path().join("intri.yml"),
            d.path().join("extri.yml"),
        ] {
            let rig = read_camera_file(&path).unwrap();
            assert_eq!(rig.names, [Some("01".to_string()), Some("02".into())]);
            assert_eq!(rig.sizes_from_principal_point, [false, true]);
            assert_eq!(rig.size_guessed_names(), ["02"]);
            for (got, want) in rig.cameras.iter().zip(&ring) {
                assert_eq!((got.fx, got.cx, got.cy), (want.fx, want.cx, want.cy));
                assert_eq!(got.translation, want.translation);
                for (x, y) in got
                    .rotation
                    .iter()
                    .flatten()
                    .zip(want.rotation.iter().flatten())
                {
                    assert!((x - y).abs() < 1e-12, "{got:?} vs {want:?}");
                }
            }
            assert_eq!(
                (rig.cameras[0].width, rig.cameras[0].height),
                (a.width, a.height)
            );
            let twice = |c: f64| (2.0 * c).round() as u32;
            assert_eq!(
                (rig.cameras[1].width, rig.cameras[1].height),
                (twice(b.cx), twice(b.cy))
            );
            assert_eq!(
                rig.distortion,
                [
                    Some(Distortion {
                        k: [-0.2, 0.05, 0.0, 0.0, 0.0, 0.0],
                        p: [0.001, -0.002]
                    }),
                    None
                ]
            );
        }
        // (file broken, its text, the error's words)
        let broken = [
            (
                "intri",
                intri.replace("K_01", "K_09"),
                "intri.yml has no K_01 for camera '01'",
            ),
            (
                "extri",
                extri.replace("T_02", "T_x"),
                "extri.yml has no T_02 for camera '02'",
            ),
            (
                "extri",
                extri.replace("Rot_02", "Rot_x"),
                "extri.yml has no R_02 (or Rot_02)",
            ),
            (
                "intri",
                intri.replace("rows: 1", "rows: 2"),
                "dist_01: 5 values for a 2×5 matrix",
            ),
            (
                "intri",
                intri.replace("H_01", "Hx_01"),
                "gives one of W_01 and H_01",
            ),
            (
                "intri",
                intri.replacen("-2e-1", "nan", 1),
                "not a finite number",
            ),
            (
                "intri",
                intri.replace("names:\r\n", ""),
                "line 3: indented line before any key",
            ),
            (
                "intri",
                intri.replace("- \"01\"\r\n  - \"02\"", ""),
                "no list of camera names",
            ),
            (
                "extri",
                extri.replace("!!opencv-matrix", "!!opencv-nd-matrix"),
                "unsupported type !!opencv-nd-matrix",
            ),
        ];
        for (name, text, needle) in broken {
            let e = tempfile::tempdir().unwrap();
            let (i, x) = if name == "intri" {
                (text, extri.clone())
            } else {
                (intri.clone(), text)
            };
            std::fs::write(e.path().join("intri.yml"), i).unwrap();
            std::fs::write(e.path().join("extri.yml"), x).unwrap();
            let err = read_camera_file(e.path()).unwrap_err().to_string();
            assert!(err.contains(needle), "{needle}: {err}");
            assert!(!err.contains('\n'), "{err}");
        }
        let e = tempfile::tempdir().unwrap();
        let err = read_camera_file(e.path()).unwrap_err().to_string();
        assert!(err.contains("no intri.yml in"), "{err}");
    }

    /// The parser's forms: a flow list, quoted and bare scalars, comments.
    #[test]
    fn opencv_yaml_reads_its_forms() {
        let text =
            "%YAML:1.0\n---\n# a comment\nnames: [ \"a\", 'b', c ]\nrows: 3\nlabel: \"x y\"\n";
        assert_eq!(
            parse(text).unwrap(),
            [
                (
                    "names".to_string(),
                    CvNode::List(vec!["a".into(), "b".into(), "c".into()])
                ),
                ("rows".to_string(), CvNode::Scalar("3".into())),
                ("label".to_string(), CvNode::Scalar("x y".into())),
            ]
        );
        assert!(
            parse("just text\n")
                .unwrap_err()
                .contains("line 1: expected 'key: value'")
        );
    }
}
