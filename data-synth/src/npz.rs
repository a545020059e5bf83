//! Minimal `.npz` I/O: a zip archive (stored, fixed timestamps, so the same arrays give the same
//! bytes) of `.npy` v1.0 arrays, readable with `numpy.load(path)` (no pickle).

use std::io::{Cursor, Read, Write};

use zip::write::SimpleFileOptions;
use zip::{CompressionMethod, DateTime, ZipArchive, ZipWriter};

use crate::error::SynthError;

/// Element types written and read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DType {
    F64,
    F32,
    U8,
    U32,
    Bool,
    /// Little-endian UTF-32 string of the given length in characters (`<U{n}`).
    Unicode(usize),
}

impl DType {
    fn descr(self) -> String {
        match self {
            DType::F64 => "<f8".into(),
            DType::F32 => "<f4".into(),
            DType::U8 => "|u1".into(),
            DType::U32 => "<u4".into(),
            DType::Bool => "|b1".into(),
            DType::Unicode(n) => format!("<U{n}"),
        }
    }

    fn parse(descr: &str) -> Option<Self> {
        Some(match descr {
            "<f8" => DType::F64,
            "<f4" => DType::F32,
            "|u1" => DType::U8,
            "<u4" => DType::U32,
            "|b1" => DType::Bool,
            s if s.starts_with("<U") => DType::Unicode(s[2..].parse().ok()?),
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            DType::F64 => 8,
            DType::F32 | DType::U32 => 4,
            DType::U8 | DType::Bool => 1,
            DType::Unicode(n) => 4 * n,
        }
    }
}

/// One array: dtype, shape (C order) and raw little-endian bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    pub dtype: DType,
    pub shape: Vec<usize>,
    pub data: Vec<u8>,
}

impl Array {
    pub fn f64(shape: Vec<usize>, values: &[f64]) -> Self {
        Self {
            dtype: DType::F64,
            shape,
            data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    pub fn f32(shape: Vec<usize>, values: &[f32]) -> Self {
        Self {
            dtype: DType::F32,
            shape,
            data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    pub fn u8(shape: Vec<usize>, values: Vec<u8>) -> Self {
        Self {
            dtype: DType::U8,
            shape,
            data: values,
        }
    }
    pub fn u32(shape: Vec<usize>, values: &[u32]) -> Self {
        Self {
            dtype: DType::U32,
            shape,
            data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    pub fn bool(shape: Vec<usize>, values: &[bool]) -> Self {
        Self {
            dtype: DType::Bool,
            shape,
            data: values.iter().map(|&b| u8::from(b)).collect(),
        }
    }
    /// A 0-d unicode string array (`numpy.load(...)["meta"].item()` gives the string back).
    pub fn string(text: &str) -> Self {
        let chars: Vec<char> = text.chars().collect();
        Self {
            dtype: DType::Unicode(chars.len().max(1)),
            shape: vec![],
            data: chars_to_utf32(&chars),
        }
    }

    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn expect(&self, name: &str, dtype: DType) -> Result<(), SynthError> {
        if self.dtype != dtype {
            return Err(SynthError::Dataset(format!(
                "array '{name}' has dtype {}, expected {}",
                self.dtype.descr(),
                dtype.descr()
            )));
        }
        Ok(())
    }

    pub fn to_f64(&self, name: &str) -> Result<Vec<f64>, SynthError> {
        self.expect(name, DType::F64)?;
        Ok(self
            .data
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect())
    }
    pub fn to_f32(&self, name: &str) -> Result<Vec<f32>, SynthError> {
        self.expect(name, DType::F32)?;
        Ok(self
            .data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap_or([0; 4])))
            .collect())
    }
    pub fn to_u32(&self, name: &str) -> Result<Vec<u32>, SynthError> {
        self.expect(name, DType::U32)?;
        Ok(self
            .data
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap_or([0; 4])))
            .collect())
    }
    pub fn to_u8(&self, name: &str) -> Result<Vec<u8>, SynthError> {
        self.expect(name, DType::U8)?;
        Ok(self.data.clone())
    }
    pub fn to_bool(&self, name: &str) -> Result<Vec<bool>, SynthError> {
        self.expect(name, DType::Bool)?;
        Ok(self.data.iter().map(|&b| b != 0).collect())
    }
    pub fn to_string(&self, name: &str) -> Result<String, SynthError> {
        let DType::Unicode(_) = self.dtype else {
            return Err(SynthError::Dataset(format!(
                "array '{name}' is not a string"
            )));
        };
        let s: String = self
            .data
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap_or([0; 4])))
            .take_while(|&u| u != 0)
            .map(|u| {
                char::from_u32(u).ok_or_else(|| {
                    SynthError::Dataset(format!("array '{name}' holds an invalid character"))
                })
            })
            .collect::<Result<_, _>>()?;
        Ok(s)
    }
}

fn chars_to_utf32(chars: &[char]) -> Vec<u8> {
    if chars.is_empty() {
        return vec![0; 4];
    }
    chars
        .iter()
        .flat_map(|&c| (c as u32).to_le_bytes())
        .collect()
}

/// Serialises one array as `.npy` v1.0.
pub fn npy_bytes(array: &Array) -> Vec<u8> {
    let shape = match array.shape.len() {
        0 => "()".to_string(),
        1 => format!("({},)", array.shape[0]),
        _ => format!(
            "({})",
            array
                .shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {shape}, }}",
        array.dtype.descr()
    );
    // Magic (6) + version (2) + length (2) + header + '\n' is padded to a multiple of 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + array.data.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(&array.data);
    out
}

/// Parses a `.npy` v1/v2 array of a supported dtype.
pub fn parse_npy(name: &str, bytes: &[u8]) -> Result<Array, SynthError> {
    let bad = |why: &str| SynthError::Dataset(format!("array '{name}': {why}"));
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("not an .npy array"));
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Err(bad("unsupported .npy version")),
    };
    let header = bytes
        .get(start..start + header_len)
        .ok_or_else(|| bad("truncated header"))?;
    let header = std::str::from_utf8(header).map_err(|_| bad("header is not text"))?;
    let field = |key: &str| -> Option<&str> {
        let at = header.find(&format!("'{key}':"))? + key.len() + 3;
        Some(header[at..].trim_start())
    };
    let descr = field("descr")
        .and_then(|s| s.strip_prefix('\''))
        .and_then(|s| s.split('\'').next())
        .ok_or_else(|| bad("no descr"))?;
    let dtype = DType::parse(descr).ok_or_else(|| bad(&format!("unsupported dtype {descr}")))?;
    if field("fortran_order").is_some_and(|s| s.starts_with("True")) {
        return Err(bad("Fortran-ordered arrays are not supported"));
    }
    let shape_text = field("shape")
        .and_then(|s| s.strip_prefix('('))
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| bad("no shape"))?;
    let shape = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| bad(&format!("bad shape entry '{s}'")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let count: usize = shape.iter().product();
    let data = &bytes[start + header_len..];
    if data.len() != count * dtype.size() {
        return Err(bad(&format!(
            "holds {} bytes, shape {shape:?} needs {}",
            data.len(),
            count * dtype.size()
        )));
    }
    Ok(Array {
        dtype,
        shape,
        data: data.to_vec(),
    })
}

/// Builds the bytes of an `.npz` archive of named arrays, in the given order.
pub fn npz_bytes(arrays: &[(&str, Array)]) -> Result<Vec<u8>, SynthError> {
    let mut zip = ZipWriter::new(Cursor::new(Vec::new()));
    let options = SimpleFileOptions::default()
        .compression_method(CompressionMethod::Stored)
        .last_modified_time(DateTime::default())
        .large_file(true)
        .unix_permissions(0o644);
    for (name, array) in arrays {
        zip.start_file(format!("{name}.npy"), options)
            .map_err(|e| SynthError::Dataset(e.to_string()))?;
        zip.write_all(&npy_bytes(array))
            .map_err(|e| SynthError::Dataset(e.to_string()))?;
    }
    let cursor = zip
        .finish()
        .map_err(|e| SynthError::Dataset(e.to_string()))?;
    Ok(cursor.into_inner())
}

/// Reads every array of an `.npz` archive.
pub fn read_npz(bytes: &[u8]) -> Result<Vec<(String, Array)>, SynthError> {
    let mut zip = ZipArchive::new(Cursor::new(bytes))
        .map_err(|e| SynthError::Dataset(format!("not an npz archive: {e}")))?;
    let mut out = Vec::with_capacity(zip.len());
    for i in 0..zip.len() {
        let mut file = zip
            .by_index(i)
            .map_err(|e| SynthError::Dataset(e.to_string()))?;
        let name = file.name().trim_end_matches(".npy").to_string();
        let mut data = Vec::with_capacity(file.size() as usize);
        file.read_to_end(&mut data)
            .map_err(|e| SynthError::Dataset(format!("array '{name}': {e}")))?;
        out.push((name.clone(), parse_npy(&name, &data)?));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_header_is_padded_and_roundtrips() {
        for a in [
            Array::f64(vec![2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.5]),
            Array::f32(vec![4], &[0.5, -1.0, 2.0, 1e-3]),
            Array::bool(vec![3], &[true, false, true]),
            Array::u32(vec![1, 1, 2], &[7, 9]),
            Array::string("{\"a\": 1, \"ü\": [2]}"),
        ] {
            let bytes = npy_bytes(&a);
            let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
            assert_eq!((10 + header_len) % 64, 0);
            assert_eq!(bytes[10 + header_len - 1], b'\n');
            assert_eq!(parse_npy("x", &bytes).unwrap(), a);
        }
        assert_eq!(Array::string("héllo").to_string("m").unwrap(), "héllo");
    }

    #[test]
    fn npz_is_deterministic_and_roundtrips() {
        let arrays = [
            ("a", Array::f64(vec![2], &[1.0, 2.0])),
            ("b", Array::u8(vec![3], vec![1, 2, 3])),
        ];
        let one = npz_bytes(&arrays).unwrap();
        let two = npz_bytes(&arrays).unwrap();
        assert_eq!(one, two);
        let back = read_npz(&one).unwrap();
        assert_eq!(back[0].0, "a");
        assert_eq!(back[0].1, arrays[0].1);
        assert_eq!(back[1].1.to_u8("b").unwrap(), vec![1, 2, 3]);
    }

    #[test]
    fn corrupt_inputs_are_errors() {
        assert!(read_npz(b"not a zip").is_err());
        let mut bytes = npy_bytes(&Array::f64(vec![4], &[1.0; 4]));
        bytes.truncate(bytes.len() - 3);
        assert!(
            parse_npy("x", &bytes)
                .unwrap_err()
                .to_string()
                .contains("bytes")
        );
        assert!(Array::f64(vec![1], &[1.0]).to_f32("x").is_err());
    }
}
