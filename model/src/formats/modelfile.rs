//! Model files in the SMPL-family `.npz` layout (SPEC §3a), read with `npyz` (members may be
//! stored or deflated, C or Fortran order) and written the same way.
//!
//! | key | shape | |
//! |---|---|---|
//! | `v_template` | (V, 3) | rest vertices, metres |
//! | `f` | (F, 3) | triangles (any integer type) |
//! | `weights` | (V, J) | skinning weights; rows sum to 1 |
//! | `kintree_table` | (2, J) | row 0 parents (root: −1 or 2³²−1), row 1 joint ids 0..J−1 |
//! | `J_regressor` | (J, V) | dense, or scipy-sparse as `J_regressor.{format,shape,data,indices,indptr}` (CSR or CSC, the keys `scipy.sparse.save_npz` writes) |
//! | `shapedirs` | (V, 3, B′) | optional: shape columns, then expression columns (see below) |
//! | `exprdirs` | (V, 3, E) | optional: expression columns kept apart |
//! | `posedirs` | (V, 3, 9(J−1)) | optional pose correctives |
//!
//! **Shape/expression split.** SMPL-X and FLAME keep shape and expression in one `shapedirs`.
//! The lfit key `num_expression` (scalar integer) says how many of its *last* columns are
//! expression; `num_betas` (scalar integer) keeps only the first β columns of the shape part.
//! Without them all of `shapedirs` is shape (and `exprdirs`, if present, is expression).
//!
//! **Optional lfit keys** (fallbacks of [`ModelInfo::fallback`] otherwise): `joint_names` (J,)
//! strings (SMPL's 24 names when J = 24, `joint_<j>` otherwise), `joint_limits_deg` (J, 3, 2)
//! (±180°), `part_labels` (J,) strings, `mirror` (J,) integers, `joint_map` (18,) model joint
//! names standing for the papers/000 joints (empty string: none), `marker_names` (M,) +
//! `marker_vertices` (M,), `hmd_offset` (3,), `hand_tips` (2,) vertices, `provenance` string,
//! and for a face model `landmark_vertices` (P,) (the `landmarks2d` modality's vertices) and
//! `face_region` (N,) (the vertices of the face errors).
//!
//! Pickled `.pkl` (chumpy) files are refused with a conversion hint (`python -m lfit.convert_pkl`,
//! the Python package's); so are object arrays.

use std::collections::BTreeMap;
use std::io::{Cursor, Read, Write};
use std::path::Path;

use glam::{DVec3, Vec3};
use npyz::WriterBuilder;

use crate::error::{ModelError, Result};
use crate::info::{ModelInfo, SMPL_JOINT_NAMES};
use crate::morph::{Morph, SparseRows};
use crate::rig::{Joint, JointIndex, Marker, Rig};
use crate::skeleton;
use crate::template::{Template, write_atomic};

pub use crate::rig::MAX_FILE_INFLUENCES;

/// How to turn a pickled SMPL-family file into this layout.
pub const PKL_HINT: &str = "pickled .pkl model files are not read; convert it once with lfit's Python package: \
`python -m lfit.convert_pkl MODEL.pkl MODEL.npz` (numpy and scipy; chumpy, which SMPL, MANO and FLAME pickles need, is not)";

/// One array of the archive, its values widened.
#[derive(Debug, Clone)]
enum Values {
    Float(Vec<f64>),
    Int(Vec<i64>),
    Text(Vec<String>),
}

#[derive(Debug, Clone)]
struct Array {
    shape: Vec<usize>,
    values: Values,
}

fn fail(path: &Path, reason: impl Into<String>) -> ModelError {
    ModelError::ModelFile {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// C-order indices of a Fortran-order array.
fn fortran_to_c<T: Clone>(data: Vec<T>, shape: &[usize]) -> Vec<T> {
    if shape.len() < 2 {
        return data;
    }
    let n = data.len();
    let mut out = Vec::with_capacity(n);
    let mut idx = vec![0usize; shape.len()];
    for _ in 0..n {
        // Fortran offset of the C-order multi-index.
        let mut off = 0;
        let mut stride = 1;
        for (i, &d) in idx.iter().zip(shape) {
            off += i * stride;
            stride *= d;
        }
        out.push(data[off].clone());
        for a in (0..shape.len()).rev() {
            idx[a] += 1;
            if idx[a] < shape[a] {
                break;
            }
            idx[a] = 0;
        }
    }
    out
}

fn parse_npy(path: &Path, name: &str, bytes: &[u8]) -> Result<Array> {
    let bad = |reason: String| fail(path, format!("array '{name}': {reason}"));
    let npy =
        npyz::NpyFile::new(bytes).map_err(|e| bad(format!("not a valid .npy member ({e})")))?;
    if npy.header().uses_pickled_array() || npy.dtype().descr().contains('O') {
        return Err(bad("is a pickled object array; save it as a numeric array (for a scipy-sparse matrix: .toarray(), or the J_regressor.* keys of scipy.sparse.save_npz)".into()));
    }
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    let fortran = npy.order() == npyz::Order::Fortran;
    let npyz::DType::Plain(ty) = npy.dtype() else {
        return Err(bad(format!("unsupported dtype {}", npy.dtype().descr())));
    };
    let io = |e: std::io::Error| bad(format!("cannot read its data ({e})"));
    let size = ty.size_field();
    let values = match (ty.type_char(), size) {
        (npyz::TypeChar::Float, 8) => Values::Float(npy.into_vec::<f64>().map_err(io)?),
        (npyz::TypeChar::Float, 4) => Values::Float(
            npy.into_vec::<f32>()
                .map_err(io)?
                .into_iter()
                .map(f64::from)
                .collect(),
        ),
        (npyz::TypeChar::Int, 8) => Values::Int(npy.into_vec::<i64>().map_err(io)?),
        (npyz::TypeChar::Int, 4) => Values::Int(
            npy.into_vec::<i32>()
                .map_err(io)?
                .into_iter()
                .map(i64::from)
                .collect(),
        ),
        (npyz::TypeChar::Int, 2) => Values::Int(
            npy.into_vec::<i16>()
                .map_err(io)?
                .into_iter()
                .map(i64::from)
                .collect(),
        ),
        (npyz::TypeChar::Int, 1) => Values::Int(
            npy.into_vec::<i8>()
                .map_err(io)?
                .into_iter()
                .map(i64::from)
                .collect(),
        ),
        // 2^64 − 1 (SMPL's "no parent" in a uint64 table) wraps to −1; 2^32 − 1 is read as it
        // is, in every integer type, and taken as the root by `parents`.
        (npyz::TypeChar::Uint, 8) => Values::Int(
            npy.into_vec::<u64>()
                .map_err(io)?
                .into_iter()
                .map(|v| v as i64)
                .collect(),
        ),
        (npyz::TypeChar::Uint, 4) => Values::Int(
            npy.into_vec::<u32>()
                .map_err(io)?
                .into_iter()
                .map(i64::from)
                .collect(),
        ),
        (npyz::TypeChar::Uint, 2) => Values::Int(
            npy.into_vec::<u16>()
                .map_err(io)?
                .into_iter()
                .map(i64::from)
                .collect(),
        ),
        (npyz::TypeChar::Uint, 1) => Values::Int(
            npy.into_vec::<u8>()
                .map_err(io)?
                .into_iter()
                .map(i64::from)
                .collect(),
        ),
        (npyz::TypeChar::Bool, _) => Values::Int(
            npy.into_vec::<bool>()
                .map_err(io)?
                .into_iter()
                .map(i64::from)
                .collect(),
        ),
        (npyz::TypeChar::UnicodeStr | npyz::TypeChar::ByteStr, _) => Values::Text(
            npy.into_vec::<String>()
                .map_err(io)?
                .into_iter()
                .map(|s| s.trim_end_matches('\0').to_string())
                .collect(),
        ),
        _ => return Err(bad(format!("unsupported dtype {}", ty))),
    };
    let values = if fortran {
        match values {
            Values::Float(v) => Values::Float(fortran_to_c(v, &shape)),
            Values::Int(v) => Values::Int(fortran_to_c(v, &shape)),
            Values::Text(v) => Values::Text(fortran_to_c(v, &shape)),
        }
    } else {
        values
    };
    Ok(Array { shape, values })
}

fn read_archive(path: &Path) -> Result<BTreeMap<String, Array>> {
    let bytes = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
    if bytes.first() == Some(&0x80)
        || path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("pkl"))
    {
        return Err(fail(path, PKL_HINT));
    }
    let mut zip = zip::ZipArchive::new(Cursor::new(bytes))
        .map_err(|e| fail(path, format!("not an .npz (zip) archive: {e}")))?;
    let mut out = BTreeMap::new();
    for i in 0..zip.len() {
        let mut member = zip
            .by_index(i)
            .map_err(|e| fail(path, format!("member {i}: {e}")))?;
        let Some(name) = member.name().strip_suffix(".npy").map(str::to_string) else {
            continue;
        };
        let mut data = Vec::with_capacity(member.size() as usize);
        member
            .read_to_end(&mut data)
            .map_err(|e| fail(path, format!("array '{name}': {e}")))?;
        let array = parse_npy(path, &name, &data)?;
        out.insert(name, array);
    }
    Ok(out)
}

/// Typed access to the arrays, with errors naming the file and key.
struct Arrays<'a> {
    path: &'a Path,
    map: BTreeMap<String, Array>,
}

impl Arrays<'_> {
    fn has(&self, key: &str) -> bool {
        self.map.contains_key(key)
    }

    fn get(&self, key: &str) -> Result<&Array> {
        self.map.get(key).ok_or_else(|| {
            fail(
                self.path,
                format!(
                    "missing key '{key}' (keys: {})",
                    self.map.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            )
        })
    }

    fn check_shape(&self, key: &str, a: &Array, expected: &[Option<usize>]) -> Result<()> {
        let ok = a.shape.len() == expected.len()
            && a.shape
                .iter()
                .zip(expected)
                .all(|(&d, e)| e.is_none_or(|e| e == d));
        if !ok {
            let want: Vec<String> = expected
                .iter()
                .map(|e| e.map_or_else(|| "_".to_string(), |v| v.to_string()))
                .collect();
            return Err(fail(
                self.path,
                format!(
                    "'{key}' has shape {:?}, expected ({})",
                    a.shape,
                    want.join(", ")
                ),
            ));
        }
        Ok(())
    }

    /// A float array of the given shape (`None`: any size), all finite.
    fn floats(&self, key: &str, expected: &[Option<usize>]) -> Result<(Vec<usize>, Vec<f64>)> {
        let a = self.get(key)?;
        self.check_shape(key, a, expected)?;
        let values = match &a.values {
            Values::Float(v) => v.clone(),
            Values::Int(v) => v.iter().map(|&x| x as f64).collect(),
            Values::Text(_) => {
                return Err(fail(
                    self.path,
                    format!("'{key}' holds strings, expected numbers"),
                ));
            }
        };
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(fail(
                self.path,
                format!("'{key}' value {i} is not finite ({})", values[i]),
            ));
        }
        Ok((a.shape.clone(), values))
    }

    fn ints(&self, key: &str, expected: &[Option<usize>]) -> Result<(Vec<usize>, Vec<i64>)> {
        let a = self.get(key)?;
        self.check_shape(key, a, expected)?;
        match &a.values {
            Values::Int(v) => Ok((a.shape.clone(), v.clone())),
            Values::Float(v) => {
                if let Some(i) = v.iter().position(|x| !x.is_finite() || x.fract() != 0.0) {
                    return Err(fail(
                        self.path,
                        format!("'{key}' value {i} ({}) is not an integer", v[i]),
                    ));
                }
                Ok((a.shape.clone(), v.iter().map(|&x| x as i64).collect()))
            }
            Values::Text(_) => Err(fail(
                self.path,
                format!("'{key}' holds strings, expected integers"),
            )),
        }
    }

    fn texts(&self, key: &str, len: Option<usize>) -> Result<Vec<String>> {
        let a = self.get(key)?;
        match &a.values {
            Values::Text(v) if a.shape.len() <= 1 => {
                if let Some(n) = len
                    && v.len() != n
                {
                    return Err(fail(
                        self.path,
                        format!("'{key}' has {} strings, expected {n}", v.len()),
                    ));
                }
                Ok(v.clone())
            }
            _ => Err(fail(
                self.path,
                format!("'{key}' must be a 1-D array of strings"),
            )),
        }
    }

    fn scalar_int(&self, key: &str) -> Result<Option<usize>> {
        if !self.has(key) {
            return Ok(None);
        }
        let (_, v) = self.ints(key, &[])?;
        match v.first() {
            Some(&x) if x >= 0 => Ok(Some(x as usize)),
            _ => Err(fail(
                self.path,
                format!("'{key}' must be a non-negative integer"),
            )),
        }
    }
}

/// The J_regressor, dense or scipy-sparse.
fn regressor(a: &Arrays<'_>, j: usize, v: usize) -> Result<SparseRows> {
    if a.has("J_regressor") {
        let arr = a.get("J_regressor")?;
        if arr.shape.len() != 2 || arr.shape[0] != j || arr.shape[1] != v {
            return Err(fail(
                a.path,
                format!(
                    "'J_regressor' has shape {:?}, expected ({j}, {v}) (joints of kintree_table, vertices of v_template)",
                    arr.shape
                ),
            ));
        }
        let (_, dense) = a.floats("J_regressor", &[Some(j), Some(v)])?;
        return Ok(SparseRows::from_dense(j, v, &dense));
    }
    if !a.has("J_regressor.format") {
        return Err(fail(
            a.path,
            "missing key 'J_regressor' (dense (J, V), or scipy-sparse as J_regressor.format/shape/data/indices/indptr)",
        ));
    }
    let format = a
        .texts("J_regressor.format", None)?
        .first()
        .cloned()
        .unwrap_or_default();
    let (_, shape) = a.ints("J_regressor.shape", &[Some(2)])?;
    if shape != [j as i64, v as i64] {
        return Err(fail(
            a.path,
            format!(
                "sparse J_regressor has shape {shape:?}, expected [{j}, {v}] (joints of kintree_table, vertices of v_template)"
            ),
        ));
    }
    let (_, data) = a.floats("J_regressor.data", &[None])?;
    let (_, indices) = a.ints("J_regressor.indices", &[Some(data.len())])?;
    let (major, minor) = match format.as_str() {
        "csr" => (j, v),
        "csc" => (v, j),
        other => {
            return Err(fail(
                a.path,
                format!("sparse J_regressor format '{other}' is not supported (csr or csc)"),
            ));
        }
    };
    let (_, indptr) = a.ints("J_regressor.indptr", &[Some(major + 1)])?;
    if indptr[0] != 0
        || indptr.windows(2).any(|w| w[1] < w[0])
        || indptr[major] as usize != data.len()
    {
        return Err(fail(
            a.path,
            "sparse J_regressor: indptr is not a non-decreasing 0..nnz sequence",
        ));
    }
    if let Some(&bad) = indices.iter().find(|&&i| i < 0 || i as usize >= minor) {
        return Err(fail(
            a.path,
            format!("sparse J_regressor: index {bad} out of range 0..{minor}"),
        ));
    }
    let mut dense = vec![0.0; j * v];
    for m in 0..major {
        for k in indptr[m] as usize..indptr[m + 1] as usize {
            let n = indices[k] as usize;
            let (row, col) = if format == "csr" { (m, n) } else { (n, m) };
            dense[row * v + col] += data[k];
        }
    }
    Ok(SparseRows::from_dense(j, v, &dense))
}

/// Parents from the kintree table, with cycle and order checks.
fn parents(a: &Arrays<'_>) -> Result<Vec<Option<JointIndex>>> {
    let (shape, k) = a.ints("kintree_table", &[Some(2), None])?;
    let j = shape[1];
    if j == 0 {
        return Err(fail(a.path, "'kintree_table' has no joints"));
    }
    for c in 0..j {
        if k[j + c] != c as i64 {
            return Err(fail(
                a.path,
                format!(
                    "'kintree_table' row 1 must list joints 0..{} in order; column {c} holds {}",
                    j - 1,
                    k[j + c]
                ),
            ));
        }
    }
    // SMPL's "no parent", 2³² − 1, in whatever integer type the file holds it (uint32, or an
    // int64 kintree_table as numpy widens SMPL's): the one place it is read as the root.
    let raw: Vec<i64> = k[..j]
        .iter()
        .map(|&p| if p == i64::from(u32::MAX) { -1 } else { p })
        .collect();
    for (c, &p) in raw.iter().enumerate() {
        if p >= j as i64 || p < -1 {
            return Err(fail(
                a.path,
                format!("'kintree_table': parent {p} of joint {c} out of range"),
            ));
        }
    }
    // A cycle: following parents from some joint comes back to it.
    for start in 0..j {
        let mut seen = vec![false; j];
        let mut at = start;
        let mut chain = vec![start];
        while raw[at] >= 0 {
            seen[at] = true;
            at = raw[at] as usize;
            chain.push(at);
            if seen[at] {
                let names: Vec<String> = chain.iter().map(|c| c.to_string()).collect();
                return Err(fail(
                    a.path,
                    format!(
                        "'kintree_table' has a cycle through joints {}",
                        names.join(" → ")
                    ),
                ));
            }
        }
    }
    let roots: Vec<usize> = (0..j).filter(|&c| raw[c] < 0).collect();
    if roots != [0] {
        return Err(fail(
            a.path,
            format!("'kintree_table' must have exactly one root, joint 0; roots: {roots:?}"),
        ));
    }
    if let Some(c) = (1..j).find(|&c| raw[c] as usize >= c) {
        return Err(fail(
            a.path,
            format!(
                "'kintree_table': parent {} of joint {c} comes after it (joints must be in topological order)",
                raw[c]
            ),
        ));
    }
    Ok(raw
        .iter()
        .map(|&p| (p >= 0).then_some(p as usize))
        .collect())
}

/// Loads a model file (see the module documentation).
pub fn load(path: &Path) -> Result<Template> {
    let map = read_archive(path)?;
    let a = Arrays { path, map };
    let (vshape, vt) = a.floats("v_template", &[None, Some(3)])?;
    let v = vshape[0];
    if v == 0 {
        return Err(fail(path, "'v_template' has no vertices"));
    }
    let parents = parents(&a)?;
    let j = parents.len();
    let (_, weights) = a.floats("weights", &[Some(v), Some(j)])?;
    let (fshape, f) = a.ints("f", &[None, Some(3)])?;
    let faces: Vec<[u32; 3]> = (0..fshape[0])
        .map(|i| {
            let tri = [f[3 * i], f[3 * i + 1], f[3 * i + 2]];
            match tri.iter().find(|&&x| x < 0 || x as usize >= v) {
                Some(bad) => Err(fail(
                    path,
                    format!("'f' triangle {i} has vertex index {bad}, out of range 0..{v}"),
                )),
                None => Ok(tri.map(|x| x as u32)),
            }
        })
        .collect::<Result<_>>()?;
    let reg = regressor(&a, j, v)?;
    let rest: Vec<DVec3> = vt
        .chunks_exact(3)
        .map(|c| DVec3::new(c[0], c[1], c[2]))
        .collect();
    let rest_joints = reg.apply(&rest);

    // Shape and expression columns.
    let mut shape_cols = 0;
    let mut expr_cols = 0;
    let mut columns: Vec<Vec<f64>> = Vec::new(); // each (3V)
    let mut take = |dirs: &[f64], total: usize, range: std::ops::Range<usize>| {
        for c in range {
            columns.push((0..3 * v).map(|r| dirs[r * total + c]).collect());
        }
    };
    if a.has("shapedirs") {
        let (s, dirs) = a.floats("shapedirs", &[Some(v), Some(3), None])?;
        let total = s[2];
        let n_expr = a.scalar_int("num_expression")?.unwrap_or(0);
        if n_expr > total {
            return Err(fail(
                path,
                format!("'num_expression' = {n_expr} exceeds the {total} columns of 'shapedirs'"),
            ));
        }
        let shape_part = total - n_expr;
        let n_shape = a.scalar_int("num_betas")?.unwrap_or(shape_part);
        if n_shape > shape_part {
            return Err(fail(
                path,
                format!(
                    "'num_betas' = {n_shape} exceeds the {shape_part} shape columns of 'shapedirs'"
                ),
            ));
        }
        take(&dirs, total, 0..n_shape);
        shape_cols = n_shape;
        if n_expr > 0 {
            if a.has("exprdirs") {
                return Err(fail(
                    path,
                    "'num_expression' and 'exprdirs' both give expression columns; keep one",
                ));
            }
            take(&dirs, total, shape_part..total);
            expr_cols = n_expr;
        }
    }
    if a.has("exprdirs") {
        let (s, dirs) = a.floats("exprdirs", &[Some(v), Some(3), None])?;
        take(&dirs, s[2], 0..s[2]);
        expr_cols = s[2];
    }
    let k = shape_cols + expr_cols;
    let mut dirs = vec![0.0; 3 * v * k];
    for (c, col) in columns.iter().enumerate() {
        for (r, &x) in col.iter().enumerate() {
            dirs[r * k + c] = x;
        }
    }
    let posedirs = if a.has("posedirs") {
        let (_, pd) = a.floats("posedirs", &[Some(v), Some(3), Some(9 * (j - 1))])?;
        Some(pd)
    } else {
        None
    };

    // Joint names and the rig.
    let names: Vec<String> = if a.has("joint_names") {
        a.texts("joint_names", Some(j))?
    } else if j == SMPL_JOINT_NAMES.len() {
        SMPL_JOINT_NAMES.iter().map(|s| s.to_string()).collect()
    } else {
        (0..j).map(|i| format!("joint_{i}")).collect()
    };
    let joints: Vec<Joint> = names
        .iter()
        .zip(&parents)
        .zip(&rest_joints)
        .map(|((n, &p), c)| Joint {
            name: n.clone(),
            parent: p,
            rest_position: c.to_array(),
        })
        .collect();
    let weight_lists: Vec<Vec<(JointIndex, f64)>> = (0..v)
        .map(|i| {
            weights[i * j..(i + 1) * j]
                .iter()
                .enumerate()
                .filter(|(_, w)| **w != 0.0)
                .map(|(c, &w)| (c, w))
                .collect()
        })
        .collect();
    let mut markers = Vec::new();
    if a.has("marker_names") || a.has("marker_vertices") {
        let mn = a.texts("marker_names", None)?;
        let (_, mv) = a.ints("marker_vertices", &[Some(mn.len())])?;
        for (n, &vi) in mn.iter().zip(&mv) {
            if vi < 0 || vi as usize >= v {
                return Err(fail(
                    path,
                    format!("marker '{n}' is on vertex {vi}, out of range 0..{v}"),
                ));
            }
            markers.push(Marker {
                name: n.clone(),
                vertex: vi as u32,
            });
        }
    }
    let rig = Rig {
        joints,
        weights: weight_lists,
        markers,
    };
    rig.validate_with(v, MAX_FILE_INFLUENCES)
        .map_err(|e| fail(path, e.to_string()))?;

    // Model information: the file's keys over the fallbacks.
    let mut info = ModelInfo::fallback(&rig);
    if a.has("joint_limits_deg") {
        let (_, l) = a.floats("joint_limits_deg", &[Some(j), Some(3), Some(2)])?;
        info.limits_deg = l
            .chunks_exact(6)
            .map(|c| [[c[0], c[1]], [c[2], c[3]], [c[4], c[5]]])
            .collect();
    }
    if a.has("part_labels") {
        info.parts = a.texts("part_labels", Some(j))?;
    }
    if a.has("mirror") {
        let (_, m) = a.ints("mirror", &[Some(j)])?;
        if let Some(bad) = m.iter().find(|&&x| x < 0 || x as usize >= j) {
            return Err(fail(
                path,
                format!("'mirror' holds joint {bad}, out of range 0..{j}"),
            ));
        }
        info.mirror = m.iter().map(|&x| x as usize).collect();
    }
    if a.has("joint_map") {
        let map = a.texts("joint_map", Some(skeleton::NUM_JOINTS))?;
        info.joint_map = map
            .iter()
            .map(|n| {
                if n.is_empty() {
                    Ok(None)
                } else {
                    names.iter().position(|m| m == n).map(Some).ok_or_else(|| {
                        fail(
                            path,
                            format!("'joint_map' names joint '{n}', which the model does not have"),
                        )
                    })
                }
            })
            .collect::<Result<_>>()?;
    }
    if a.has("hmd_offset") {
        let (_, o) = a.floats("hmd_offset", &[Some(3)])?;
        info.hmd_offset = [o[0], o[1], o[2]];
    }
    if a.has("hand_tips") {
        let (_, t) = a.ints("hand_tips", &[Some(2)])?;
        if let Some(bad) = t.iter().find(|&&x| x < 0 || x as usize >= v) {
            return Err(fail(
                path,
                format!("'hand_tips' holds vertex {bad}, out of range 0..{v}"),
            ));
        }
        info.hand_tips = Some([t[0] as u32, t[1] as u32]);
    }
    for key in ["landmark_vertices", "face_region"] {
        if !a.has(key) {
            continue;
        }
        let (_, t) = a.ints(key, &[None])?;
        if let Some(bad) = t.iter().find(|&&x| x < 0 || x as usize >= v) {
            return Err(fail(
                path,
                format!("'{key}' holds vertex {bad}, out of range 0..{v}"),
            ));
        }
        let list: Vec<u32> = t.iter().map(|&x| x as u32).collect();
        if key == "landmark_vertices" {
            info.landmark_vertices = list;
        } else {
            info.face_region = list;
        }
    }
    info.provenance = if a.has("provenance") {
        a.texts("provenance", None)?.join("\n")
    } else {
        format!("model file {}", path.display())
    };

    let id = path
        .file_stem()
        .map_or_else(|| "model".to_string(), |s| s.to_string_lossy().into_owned());
    let vertices: Vec<Vec3> = rest.iter().map(|p| p.as_vec3()).collect();
    let template =
        Template::new(id, vertices, faces, rig).map_err(|e| fail(path, e.to_string()))?;
    let morph = Morph::new(rest, shape_cols, expr_cols, dirs, posedirs, Some(reg));
    template
        .with_morph(morph, info)
        .map_err(|e| fail(path, e.to_string()))
}

/// An array to write.
enum Out {
    F64(Vec<usize>, Vec<f64>),
    I64(Vec<usize>, Vec<i64>),
    Text(Vec<String>),
}

fn npy_bytes(out: &Out) -> std::io::Result<Vec<u8>> {
    let mut buf = Vec::new();
    match out {
        Out::F64(shape, v) => {
            let shape: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
            let mut w = npyz::WriteOptions::<f64>::new()
                .default_dtype()
                .shape(&shape)
                .writer(&mut buf)
                .begin_nd()?;
            w.extend(v.iter().copied())?;
            w.finish()?;
        }
        Out::I64(shape, v) => {
            let shape: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
            let mut w = npyz::WriteOptions::<i64>::new()
                .default_dtype()
                .shape(&shape)
                .writer(&mut buf)
                .begin_nd()?;
            w.extend(v.iter().copied())?;
            w.finish()?;
        }
        Out::Text(v) => {
            let n = v
                .iter()
                .map(|s| s.chars().count())
                .max()
                .unwrap_or(1)
                .max(1);
            let ty: npyz::TypeStr = format!("<U{n}")
                .parse()
                .map_err(|e| std::io::Error::other(format!("{e}")))?;
            let mut w = npyz::WriteOptions::<String>::new()
                .dtype(npyz::DType::Plain(ty))
                .shape(&[v.len() as u64])
                .writer(&mut buf)
                .begin_nd()?;
            w.extend(v.iter().cloned())?;
            w.finish()?;
        }
    }
    Ok(buf)
}

/// Writes `template` as a model file (see the module documentation), atomically, its members
/// deflated (as `numpy.savez_compressed` does). A template without a joint regressor gets one
/// from [`crate::body::procedural::fit_regressor`].
pub fn save(template: &Template, path: &Path) -> Result<()> {
    let v = template.num_vertices();
    let j = template.rig.num_joints();
    let morph = &template.morph;
    let rest: Vec<f64> = template
        .rest_positions()
        .iter()
        .flat_map(|p| p.to_array())
        .collect();
    let mut weights = vec![0.0; v * j];
    for (i, list) in template.rig.weights.iter().enumerate() {
        for &(jj, w) in list {
            weights[i * j + jj] += w;
        }
    }
    let mut kintree = vec![0i64; 2 * j];
    for (c, joint) in template.rig.joints.iter().enumerate() {
        kintree[c] = joint.parent.map_or(-1, |p| p as i64);
        kintree[j + c] = c as i64;
    }
    let reg = morph
        .regressor
        .clone()
        .unwrap_or_else(|| crate::body::procedural::fit_regressor(template));
    let info = &template.info;
    let names: Vec<String> = template
        .rig
        .joints
        .iter()
        .map(|jn| jn.name.clone())
        .collect();
    let mut arrays: Vec<(&str, Out)> = vec![
        ("v_template", Out::F64(vec![v, 3], rest)),
        (
            "f",
            Out::I64(
                vec![template.faces.len(), 3],
                template
                    .faces
                    .iter()
                    .flat_map(|f| f.map(i64::from))
                    .collect(),
            ),
        ),
        ("weights", Out::F64(vec![v, j], weights)),
        ("kintree_table", Out::I64(vec![2, j], kintree)),
        ("J_regressor", Out::F64(vec![j, v], reg.to_dense())),
        ("joint_names", Out::Text(names.clone())),
        (
            "joint_limits_deg",
            Out::F64(
                vec![j, 3, 2],
                info.limits_deg
                    .iter()
                    .flat_map(|l| l.iter().flat_map(|r| *r))
                    .collect(),
            ),
        ),
        ("part_labels", Out::Text(info.parts.clone())),
        (
            "mirror",
            Out::I64(vec![j], info.mirror.iter().map(|&m| m as i64).collect()),
        ),
        (
            "joint_map",
            Out::Text(
                info.joint_map
                    .iter()
                    .map(|m| m.map_or_else(String::new, |i| names[i].clone()))
                    .collect(),
            ),
        ),
        ("hmd_offset", Out::F64(vec![3], info.hmd_offset.to_vec())),
        (
            "provenance",
            Out::Text(vec![if info.provenance.is_empty() {
                format!("lfit template '{}'", template.id)
            } else {
                info.provenance.clone()
            }]),
        ),
    ];
    let k = morph.coefficients();
    if k > 0 {
        // Shape then expression columns, with num_expression saying where they split.
        arrays.push(("shapedirs", Out::F64(vec![v, 3, k], morph.dirs.clone())));
        arrays.push((
            "num_expression",
            Out::I64(vec![], vec![morph.expression as i64]),
        ));
    }
    if let Some(pd) = &morph.posedirs {
        arrays.push(("posedirs", Out::F64(vec![v, 3, 9 * (j - 1)], pd.clone())));
    }
    if !template.rig.markers.is_empty() {
        arrays.push((
            "marker_names",
            Out::Text(
                template
                    .rig
                    .markers
                    .iter()
                    .map(|m| m.name.clone())
                    .collect(),
            ),
        ));
        arrays.push((
            "marker_vertices",
            Out::I64(
                vec![template.rig.markers.len()],
                template
                    .rig
                    .markers
                    .iter()
                    .map(|m| i64::from(m.vertex))
                    .collect(),
            ),
        ));
    }
    if let Some(t) = info.hand_tips {
        arrays.push((
            "hand_tips",
            Out::I64(vec![2], t.iter().map(|&x| i64::from(x)).collect()),
        ));
    }
    for (key, list) in [
        ("landmark_vertices", &info.landmark_vertices),
        ("face_region", &info.face_region),
    ] {
        if !list.is_empty() {
            arrays.push((
                key,
                Out::I64(
                    vec![list.len()],
                    list.iter().map(|&x| i64::from(x)).collect(),
                ),
            ));
        }
    }
    let err = |e: String| fail(path, e);
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .last_modified_time(zip::DateTime::default());
    for (name, out) in &arrays {
        let bytes = npy_bytes(out).map_err(|e| err(format!("array '{name}': {e}")))?;
        zip.start_file(format!("{name}.npy"), options)
            .map_err(|e| err(e.to_string()))?;
        zip.write_all(&bytes).map_err(|e| err(e.to_string()))?;
    }
    let bytes = zip.finish().map_err(|e| err(e.to_string()))?.into_inner();
    write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fortran_order_becomes_c_order() {
        // A (2, 3) array [[0, 1, 2], [3, 4, 5]] stored column-major.
        let f = vec![0, 3, 1, 4, 2, 5];
        assert_eq!(fortran_to_c(f, &[2, 3]), vec![0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn the_default_template_round_trips_through_a_model_file() {
        let t = crate::default_template();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("default.npz");
        save(&t, &path).unwrap();
        let back = load(&path).unwrap();
        assert_eq!(back.rig.num_joints(), 18);
        assert_eq!(back.faces, t.faces);
        assert_eq!(back.rig.markers, t.rig.markers);
        assert_eq!(back.info.limits_deg, t.info.limits_deg);
        assert_eq!(back.info.joint_map, t.info.joint_map);
        for (a, b) in back.rig.joints.iter().zip(&t.rig.joints) {
            assert_eq!(a.name, b.name);
            assert!(
                (a.rest() - b.rest()).length() < 1e-9,
                "{}: {:?} vs {:?}",
                a.name,
                a.rest_position,
                b.rest_position
            );
        }
        let pose: Vec<f64> = (0..57)
            .map(|i| ((i * 37 % 19) as f64 / 19.0 - 0.5) * 1.2)
            .collect();
        let va = crate::skinning::pose_vertices(&t, &pose, crate::SkinningMethod::Linear);
        let vb = crate::skinning::pose_vertices(&back, &pose, crate::SkinningMethod::Linear);
        let max = va
            .iter()
            .zip(&vb)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0, f32::max);
        assert!(max < 1e-5, "{max}");
    }
}
