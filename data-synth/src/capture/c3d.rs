//! A strict reader and a writer of C3D motion-capture files (the format documented by c3d.org:
//! "The C3D File Format User Guide").
//!
//! A C3D file is a sequence of 512-byte blocks:
//! - block 1, the header: byte 1 points to the first block of the parameter section, byte 2 is
//!   the key 0x50; then 16-bit words: the number of 3D points, analog samples per 3D frame, the
//!   first and last frame, the maximum interpolation gap, the scale factor (a float; negative:
//!   the point data are floats), the first block of the data section (DATA_START), analog samples
//!   per channel and frame, and the frame rate (a float);
//! - the parameter section: a 4-byte header (two reserved bytes, read and ignored as the format
//!   guide says, typically 0x01 0x50; the number of blocks in byte 3 and the processor type in
//!   byte 4: 84 Intel, 85 DEC, 86 MIPS), then groups and parameters,
//!   each with its name, its group id (negative for a group), a 16-bit offset to the next entry
//!   counted from that offset word, and for a parameter its type (-1 char, 1 byte, 2 int16,
//!   4 float), its dimensions and its data;
//! - the data section from block DATA_START: per frame, per point X, Y, Z and a residual word
//!   (16-bit integers times `POINT:SCALE`, or 32-bit floats when the scale is negative), then the
//!   frame's analog samples. A residual word below zero marks an invalid sample (a gap); otherwise
//!   its high byte holds the cameras that saw the point and its low byte the residual in units of
//!   `|POINT:SCALE|`.
//!
//! The reader checks what it uses (keys, processor, pointers, `POINT:USED`/`SCALE`/`RATE`/
//! `DATA_START` (0: no pointer, the header's read)/`FRAMES` against the header, the data after
//! the parameter entries (not necessarily after the block count the section claims), labels for every point, units, enough bytes for every
//! frame, finite coordinates in valid samples) and refuses anything else with a one-line error.
//! Intel (little-endian IEEE), DEC (little-endian integers, VAX F-floating floats: what Vicon's
//! 370 and other VAX-era systems wrote) and MIPS (big-endian IEEE) files are read; the writer
//! writes all three, with integer or float points and no analog data.

use std::path::Path;

use crate::capture::ImportError;

/// Bytes per block.
pub const BLOCK: usize = 512;
/// The key in byte 2 of the header and of the parameter section.
const KEY: u8 = 0x50;

/// The processor (byte order and float format) a file was written for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Processor {
    /// Little-endian, IEEE floats (type 84).
    Intel,
    /// Little-endian integers, VAX floats (type 85): refused by the reader.
    Dec,
    /// Big-endian, IEEE floats (type 86).
    Mips,
}

impl Processor {
    fn code(self) -> u8 {
        match self {
            Processor::Intel => 84,
            Processor::Dec => 85,
            Processor::Mips => 86,
        }
    }
}

/// One valid point sample: its coordinates in the file's units, its residual (same units) and the
/// bit mask of the cameras that saw it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct C3dPoint {
    pub position: [f64; 3],
    pub residual: f64,
    pub cameras: u8,
}

/// The point data of a C3D file (analog data are skipped).
#[derive(Debug, Clone, PartialEq)]
pub struct C3d {
    pub processor: Processor,
    /// `POINT:LABELS` (then `LABELS2`, ...), trailing blanks removed, one per point.
    pub labels: Vec<String>,
    /// `POINT:UNITS` (`mm` when absent).
    pub units: String,
    /// `POINT:SCALE`: the factor of integer data; negative when the points are floats (then its
    /// magnitude scales the residuals only).
    pub scale: f64,
    /// `POINT:RATE`, frames per second.
    pub rate: f64,
    /// Number of the first frame (header word 4; from 1 in the format guide, 0 in some files).
    pub first_frame: u32,
    /// Analog samples per 3D frame (all channels; header word 3), skipped by the reader.
    pub analog_per_frame: usize,
    /// Per frame, per point: the sample, or `None` for a gap (residual word < 0, or coordinates
    /// that are not finite).
    pub frames: Vec<Vec<Option<C3dPoint>>>,
    /// Samples read as gaps because their coordinates were not finite (with a valid residual).
    pub non_finite: usize,
}

fn fail<T>(msg: impl Into<String>) -> Result<T, ImportError> {
    Err(ImportError::Invalid(msg.into()))
}

/// Byte order and float format of a file.
#[derive(Clone, Copy)]
struct Order {
    big: bool,
    /// VAX F-floating floats (DEC files).
    dec: bool,
}

/// A VAX F-floating number from its four bytes as a DEC file stores them: two little-endian
/// 16-bit words, the first holding the sign, the 8-bit exponent (excess 128) and the top 7
/// fraction bits, the second the low 16; the value is `0.1f × 2^(e − 128)` with a hidden leading
/// bit (the VAX Architecture Reference Manual, §1.3.5). The same bits in IEEE order read as IEEE
/// single `1.f × 2^(e − 127)`, four times the value: the exponent less 2 is the IEEE number
/// (exponents 1 and 2 fall below IEEE's normal range: divided by 4 there, to its precision). An
/// exponent of 0 is zero (or, with the sign set, VAX's reserved operand: NaN here).
fn dec_f32(b: [u8; 4]) -> f32 {
    let high = u32::from(u16::from_le_bytes([b[0], b[1]]));
    let low = u32::from(u16::from_le_bytes([b[2], b[3]]));
    let bits = (high << 16) | low;
    match (bits >> 23) & 0xff {
        0 if bits & 0x8000_0000 == 0 => 0.0,
        0 => f32::NAN,
        1 | 2 => f32::from_bits(bits) / 4.0,
        _ => f32::from_bits(bits - (2 << 23)),
    }
}

/// [`dec_f32`]'s inverse for a finite `v`: exact where a VAX float holds it (2^-128 ≤ |v| <
/// 2^127); smaller magnitudes are written as zero, larger ones as the largest VAX float.
fn f32_dec(v: f32) -> [u8; 4] {
    let bits = v.to_bits();
    let vax = match (bits >> 23) & 0xff {
        // Zero and IEEE's subnormals: four times them, where that is normal.
        0 => {
            let x = v * 4.0;
            if x.is_normal() { x.to_bits() } else { 0 }
        }
        e if e >= 254 => (bits & 0x8000_0000) | 0x7fff_ffff,
        _ => bits + (2 << 23),
    };
    let (h, l) = ((vax >> 16) as u16, vax as u16);
    let (h, l) = (h.to_le_bytes(), l.to_le_bytes());
    [h[0], h[1], l[0], l[1]]
}

impl Order {
    fn u16(self, b: &[u8], at: usize) -> u16 {
        let x = [b[at], b[at + 1]];
        if self.big {
            u16::from_be_bytes(x)
        } else {
            u16::from_le_bytes(x)
        }
    }
    fn i16(self, b: &[u8], at: usize) -> i16 {
        self.u16(b, at) as i16
    }
    fn f32(self, b: &[u8], at: usize) -> f32 {
        let x = [b[at], b[at + 1], b[at + 2], b[at + 3]];
        if self.dec {
            dec_f32(x)
        } else if self.big {
            f32::from_be_bytes(x)
        } else {
            f32::from_le_bytes(x)
        }
    }
    fn put_u16(self, out: &mut Vec<u8>, v: u16) {
        out.extend(if self.big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        });
    }
    fn put_i16(self, out: &mut Vec<u8>, v: i16) {
        self.put_u16(out, v as u16);
    }
    fn put_f32(self, out: &mut Vec<u8>, v: f32) {
        out.extend(if self.dec {
            f32_dec(v)
        } else if self.big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        });
    }
}

/// One parameter of the parameter section.
#[derive(Debug, Clone)]
struct Param {
    group_id: u8,
    name: String,
    /// -1 char, 1 byte, 2 int16, 4 float.
    kind: i8,
    dims: Vec<usize>,
    data: Vec<u8>,
}

impl Param {
    fn count(&self) -> usize {
        self.dims.iter().product()
    }

    fn ints(&self, o: Order, what: &str) -> Result<Vec<i64>, ImportError> {
        let n = self.count();
        match self.kind {
            1 => Ok(self.data.iter().map(|&b| i64::from(b)).collect()),
            2 => Ok((0..n)
                .map(|i| i64::from(o.i16(&self.data, 2 * i)))
                .collect()),
            4 => (0..n)
                .map(|i| {
                    let f = o.f32(&self.data, 4 * i);
                    if f.is_finite() && f.fract() == 0.0 {
                        Ok(f as i64)
                    } else {
                        fail(format!("parameter {what} holds {f}, not an integer"))
                    }
                })
                .collect(),
            _ => fail(format!("parameter {what} holds text, not a number")),
        }
    }

    fn floats(&self, o: Order, what: &str) -> Result<Vec<f64>, ImportError> {
        match self.kind {
            4 => Ok((0..self.count())
                .map(|i| f64::from(o.f32(&self.data, 4 * i)))
                .collect()),
            _ => Ok(self.ints(o, what)?.into_iter().map(|v| v as f64).collect()),
        }
    }

    /// Text entries: the first dimension is the length of each string.
    fn strings(&self, what: &str) -> Result<Vec<String>, ImportError> {
        if self.kind != -1 {
            return fail(format!("parameter {what} is not text"));
        }
        let len = self.dims.first().copied().unwrap_or(1).max(1);
        if self.dims.is_empty() {
            return Ok(vec![self.text(&self.data)]);
        }
        Ok(self.data.chunks(len).map(|c| self.text(c)).collect())
    }

    fn text(&self, bytes: &[u8]) -> String {
        String::from_utf8_lossy(bytes)
            .trim_end_matches([' ', '\0'])
            .to_string()
    }
}

/// The parsed parameter section.
struct Params {
    groups: Vec<(u8, String)>,
    params: Vec<Param>,
    /// The byte just past the last entry read: where the parameters end, whatever block count
    /// the section's header claims.
    end: usize,
}

impl Params {
    fn get(&self, group: &str, name: &str) -> Option<&Param> {
        let id = self
            .groups
            .iter()
            .find(|(_, g)| g == group)
            .map(|(id, _)| *id)?;
        self.params
            .iter()
            .find(|p| p.group_id == id && p.name == name)
    }
}

fn parse_params(
    bytes: &[u8],
    start: usize,
    blocks: usize,
    o: Order,
) -> Result<Params, ImportError> {
    let end = start + blocks * BLOCK;
    if end > bytes.len() {
        return fail(format!(
            "truncated: the parameter section has {blocks} blocks from byte {start}, the file has {} bytes",
            bytes.len()
        ));
    }
    let b = &bytes[..end];
    let mut groups = Vec::new();
    let mut params = Vec::new();
    // Every entry starts at least 2 bytes before the section's end: the first (the section has
    // ≥ 1 block) and each next one (an offset past that ends the section, below).
    let mut at = start + 4;
    let last;
    loop {
        let name_len = (b[at] as i8).unsigned_abs() as usize;
        if name_len == 0 {
            last = at + 1;
            break;
        }
        let id = b[at + 1] as i8;
        if id == 0 {
            return fail(format!(
                "parameter section entry at byte {at} has group id 0"
            ));
        }
        let word = at + 2 + name_len;
        if word + 2 > end {
            return fail(format!(
                "the parameter section ends inside the entry at byte {at}"
            ));
        }
        let raw = &b[at + 2..word];
        // Printable: Qualisys names a parameter "Uncropped Measurement Length" (spaces); control
        // characters mean the walk has left the entries.
        if raw.iter().any(|&c| c < 0x20 || c == 0x7f) {
            return fail(format!(
                "parameter section entry at byte {at} has a name with control characters"
            ));
        }
        let name = String::from_utf8_lossy(raw).to_ascii_uppercase();
        let offset = o.i16(b, word);
        let mut p = word + 2;
        let need = |p: usize, n: usize| -> Result<(), ImportError> {
            if p + n > end {
                fail(format!(
                    "the parameter section ends inside '{name}' (byte {at})"
                ))
            } else {
                Ok(())
            }
        };
        if id < 0 {
            groups.push((id.unsigned_abs(), name.clone()));
        } else {
            need(p, 2)?;
            let kind = b[p] as i8;
            let ndims = b[p + 1] as usize;
            p += 2;
            if ![-1, 1, 2, 4].contains(&kind) {
                return fail(format!(
                    "parameter '{name}' has data type {kind} (expected -1, 1, 2 or 4)"
                ));
            }
            need(p, ndims)?;
            let dims: Vec<usize> = b[p..p + ndims].iter().map(|&d| d as usize).collect();
            p += ndims;
            let size = dims.iter().product::<usize>() * kind.unsigned_abs() as usize;
            need(p, size)?;
            params.push(Param {
                group_id: id as u8,
                name: name.clone(),
                kind,
                dims,
                data: b[p..p + size].to_vec(),
            });
            p += size;
        }
        need(p, 1)?;
        let desc = b[p] as usize;
        need(p + 1, desc)?;
        if offset == 0 {
            last = p + 1 + desc;
            break;
        }
        let next = word as i64 + i64::from(offset);
        if next <= at as i64 || next < (p + 1 + desc) as i64 - 1 {
            return fail(format!(
                "parameter section entry '{name}' points backwards (offset {offset})"
            ));
        }
        // An entry read whole whose offset points past the section is its last: c3d.org's own
        // SGI sample (Sample02's sgi_int.c3d and sgi_real.c3d) ends on POINT:LABELS with an
        // offset of 16129 instead of 0.
        if next as usize + 2 > end {
            last = p + 1 + desc;
            break;
        }
        at = next as usize;
    }
    Ok(Params {
        groups,
        params,
        end: last,
    })
}

impl C3d {
    /// Reads and checks a C3D file.
    pub fn read(path: &Path) -> Result<Self, ImportError> {
        let bytes = std::fs::read(path).map_err(|source| ImportError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes)
    }

    /// Parses and checks the bytes of a C3D file.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ImportError> {
        if bytes.len() < BLOCK {
            return fail(format!(
                "truncated: {} bytes, less than the 512-byte header",
                bytes.len()
            ));
        }
        if bytes[1] != KEY {
            return fail(format!(
                "not a C3D file: header byte 2 is 0x{:02x}, expected 0x50",
                bytes[1]
            ));
        }
        let pblock = bytes[0] as usize;
        if pblock < 2 {
            return fail(format!(
                "the header points to parameter block {pblock} (expected ≥ 2)"
            ));
        }
        let pstart = (pblock - 1) * BLOCK;
        if pstart + 4 > bytes.len() {
            return fail(format!(
                "truncated: the parameter section (block {pblock}) lies past the end of the file"
            ));
        }
        // Bytes 1–2 of the parameter section are reserved and "always ignored" (the C3D User
        // Guide; 0x01 0x50 is typical, the `c3d` package on PyPI writes 0x00 0x00).
        let processor = match bytes[pstart + 3] {
            84 => Processor::Intel,
            85 => Processor::Dec,
            86 => Processor::Mips,
            other => {
                return fail(format!(
                    "unknown processor type {other} (expected 84 Intel, 85 DEC or 86 MIPS)"
                ));
            }
        };
        let o = Order {
            big: processor == Processor::Mips,
            dec: processor == Processor::Dec,
        };
        let pblocks = bytes[pstart + 2] as usize;
        if pblocks == 0 {
            return fail("the parameter section has 0 blocks");
        }
        let params = parse_params(bytes, pstart, pblocks, o)?;

        // Header words (1-based word n at bytes 2(n−1)..2n).
        let h_points = o.u16(bytes, 2) as usize;
        let h_analog = o.u16(bytes, 4) as usize;
        let first = o.u16(bytes, 6) as u32;
        let last = o.u16(bytes, 8) as u32;
        let h_scale = f64::from(o.f32(bytes, 12));
        let h_data_start = o.u16(bytes, 16) as usize;
        let h_rate = f64::from(o.f32(bytes, 20));

        let int_param = |name: &str| -> Result<Option<i64>, ImportError> {
            match params.get("POINT", name) {
                Some(p) if p.count() == 0 => fail(format!("POINT:{name} is empty")),
                Some(p) => Ok(Some(p.ints(o, &format!("POINT:{name}"))?[0])),
                None => Ok(None),
            }
        };
        let float_param = |name: &str| -> Result<Option<f64>, ImportError> {
            match params.get("POINT", name) {
                Some(p) if p.count() == 0 => fail(format!("POINT:{name} is empty")),
                Some(p) => Ok(Some(p.floats(o, &format!("POINT:{name}"))?[0])),
                None => Ok(None),
            }
        };
        let Some(used) = int_param("USED")? else {
            return fail("missing parameter POINT:USED");
        };
        // POINT:USED is a 16-bit word; files with more than 32767 points store it unsigned.
        let used = (used as u16) as usize;
        if used != h_points {
            return fail(format!(
                "POINT:USED is {used} but the header has {h_points} points"
            ));
        }
        let scale = float_param("SCALE")?.unwrap_or(h_scale);
        if !(scale.is_finite() && scale != 0.0) {
            return fail(format!(
                "POINT:SCALE is {scale}: must be finite and non-zero"
            ));
        }
        if scale.signum() != h_scale.signum()
            || (scale - h_scale).abs() > 1e-6 * scale.abs().max(1.0)
        {
            return fail(format!(
                "POINT:SCALE is {scale} but the header's scale factor is {h_scale}"
            ));
        }
        let rate = float_param("RATE")?.unwrap_or(h_rate);
        if !(rate.is_finite() && rate > 0.0) {
            return fail(format!("the point rate is {rate} Hz: must be positive"));
        }
        if (rate - h_rate).abs() > 1e-3 * rate {
            return fail(format!(
                "POINT:RATE is {rate} Hz but the header's frame rate is {h_rate} Hz"
            ));
        }
        let data_start = match int_param("DATA_START")? {
            // Blocks count from 1: a 0 here is no pointer (OptiTrack Motive's exports write it;
            // kineticstoolkit's walkingOptiTrack.c3d), and the header's is the one to read.
            Some(0) | None => h_data_start,
            Some(d) => {
                let d = (d as u16) as usize;
                if d != h_data_start {
                    return fail(format!(
                        "POINT:DATA_START is block {d} but the header says block {h_data_start}"
                    ));
                }
                d
            }
        };
        // The data may start inside the block count the parameter section claims, after its
        // last entry: OptiTrack Motive's DEC exports claim 8 blocks and hold their entries in one
        // (kineticstoolkit's walkingOptiTrack.c3d, its data at block 4, POINT:DATA_START 0).
        if data_start == 0 || (data_start - 1) * BLOCK < params.end {
            return fail(format!(
                "the data section (block {data_start}) overlaps the parameter section's entries (blocks {pblock}–{})",
                params.end.div_ceil(BLOCK)
            ));
        }
        // Frames count from 1 in the format guide; some writers start at 0 (a recording
        // kineticstoolkit ships).
        if last < first {
            return fail(format!(
                "the header's frames run from {first} to {last}: the first frame is after the last"
            ));
        }
        let n = (last - first + 1) as usize;
        if let Some(f) = int_param("FRAMES")? {
            let f = (f as u16) as usize;
            if f != n {
                return fail(format!(
                    "POINT:FRAMES is {f} but the header's frames {first}–{last} are {n}"
                ));
            }
        }
        let mut labels = Vec::with_capacity(used);
        for k in 1.. {
            let name = if k == 1 {
                "LABELS".to_string()
            } else {
                format!("LABELS{k}")
            };
            let Some(p) = params.get("POINT", &name) else {
                break;
            };
            labels.extend(p.strings(&format!("POINT:{name}"))?);
            if labels.len() >= used {
                break;
            }
        }
        if labels.len() < used {
            return fail(format!(
                "POINT:LABELS names {} points, the file has {used}",
                labels.len()
            ));
        }
        labels.truncate(used);
        let units = match params.get("POINT", "UNITS") {
            Some(p) => p
                .strings("POINT:UNITS")?
                .into_iter()
                .next()
                .unwrap_or_default()
                .trim()
                .to_string(),
            None => "mm".to_string(),
        };
        units_to_metres(&units)?;

        let float = scale < 0.0;
        let word = if float { 4 } else { 2 };
        let frame_bytes = (4 * used + h_analog) * word;
        let start = (data_start - 1) * BLOCK;
        let need = start + n * frame_bytes;
        if need > bytes.len() {
            return fail(format!(
                "truncated: {n} frames of {used} points need {need} bytes from block {data_start}, the file has {}",
                bytes.len()
            ));
        }
        let abs_scale = scale.abs();
        let mut non_finite = 0;
        let mut frames = Vec::with_capacity(n);
        for f in 0..n {
            let base = start + f * frame_bytes;
            let mut row = Vec::with_capacity(used);
            for (k, label) in labels.iter().enumerate() {
                let at = base + 4 * k * word;
                let (xyz, w) = if float {
                    (
                        [0, 1, 2].map(|i| f64::from(o.f32(bytes, at + 4 * i))),
                        f64::from(o.f32(bytes, at + 12)),
                    )
                } else {
                    (
                        [0, 1, 2].map(|i| f64::from(o.i16(bytes, at + 2 * i)) * scale),
                        f64::from(o.i16(bytes, at + 6)),
                    )
                };
                if w.is_nan() {
                    return fail(format!(
                        "frame {} point '{label}': the residual word is NaN",
                        first as usize + f
                    ));
                }
                if w < 0.0 {
                    row.push(None);
                    continue;
                }
                // NaN coordinates are how several writers mark a gap (kineticstoolkit, and so
                // the files it ships); a gap here too, counted.
                if xyz.iter().any(|v| !v.is_finite()) {
                    non_finite += 1;
                    row.push(None);
                    continue;
                }
                let bits = w as i64;
                row.push(Some(C3dPoint {
                    position: xyz,
                    residual: (bits & 0xff) as f64 * abs_scale,
                    cameras: ((bits >> 8) & 0xff) as u8,
                }));
            }
            frames.push(row);
        }
        Ok(Self {
            processor,
            labels,
            units,
            scale,
            rate,
            first_frame: first,
            analog_per_frame: h_analog,
            frames,
            non_finite,
        })
    }

    /// Metres per unit of the point data.
    pub fn metres_per_unit(&self) -> Result<f64, ImportError> {
        units_to_metres(&self.units)
    }

    /// Index of a label (exact match after trimming), `Err` when it is missing or repeated.
    pub fn label_index(&self, label: &str) -> Result<Option<usize>, ImportError> {
        let mut hits = self
            .labels
            .iter()
            .enumerate()
            .filter(|(_, l)| l.trim() == label);
        let first = hits.next().map(|(i, _)| i);
        if let (Some(a), Some((b, _))) = (first, hits.next()) {
            return fail(format!(
                "label '{label}' appears more than once in POINT:LABELS (points #{a} and #{b}, counted from 0): map each by its index in a label map (\"#{a}\": \"MARKER\")"
            ));
        }
        Ok(first)
    }

    /// The file's bytes (Intel, DEC or MIPS; integer points when `scale > 0`, floats when `< 0`).
    /// No analog data (`analog_per_frame` must be 0).
    pub fn to_bytes(&self) -> Result<Vec<u8>, ImportError> {
        let o = Order {
            big: self.processor == Processor::Mips,
            dec: self.processor == Processor::Dec,
        };
        let n = self.frames.len();
        let used = self.labels.len();
        if self.analog_per_frame != 0 {
            return fail("the writer does not write analog data");
        }
        if n == 0 || n > 65535 || used > 65535 {
            return fail(format!(
                "{n} frames of {used} points: the writer needs 1–65535 frames and ≤ 65535 points"
            ));
        }
        if self.first_frame == 0 || self.first_frame as usize + n - 1 > 65535 {
            return fail(format!(
                "first frame {} with {n} frames does not fit 16-bit frame numbers",
                self.first_frame
            ));
        }
        if let Some(i) = self.frames.iter().position(|r| r.len() != used) {
            return fail(format!("frame {i} does not have {used} points"));
        }
        if !(self.scale.is_finite()
            && self.scale != 0.0
            && self.rate.is_finite()
            && self.rate > 0.0)
        {
            return fail("scale must be finite and non-zero, rate positive");
        }
        units_to_metres(&self.units)?;
        let label_len = self
            .labels
            .iter()
            .map(String::len)
            .max()
            .unwrap_or(0)
            .max(4);
        if label_len > 255 || self.units.len() > 255 {
            return fail("labels and units are at most 255 characters");
        }

        // Parameter section: entries, then padded to whole blocks.
        let mut entries: Vec<Vec<u8>> = Vec::new();
        let group = |id: i8, name: &str, desc: &str| -> Vec<u8> {
            let mut e = vec![name.len() as u8, id as u8];
            e.extend(name.as_bytes());
            e.extend([0, 0]); // offset, filled in below
            e.push(desc.len() as u8);
            e.extend(desc.as_bytes());
            e
        };
        let param = |group: u8, name: &str, kind: i8, dims: &[usize], data: Vec<u8>| {
            let mut e = vec![name.len() as u8, group];
            e.extend(name.as_bytes());
            e.extend([0, 0]);
            e.push(kind as u8);
            e.push(dims.len() as u8);
            e.extend(dims.iter().map(|&d| d as u8));
            e.extend(data);
            e.push(0); // no description
            e
        };
        let i16_data = |v: u16| {
            let mut d = Vec::new();
            o.put_u16(&mut d, v);
            d
        };
        let f32_data = |v: f64| {
            let mut d = Vec::new();
            o.put_f32(&mut d, v as f32);
            d
        };
        let text = |items: &[String], len: usize| -> Vec<u8> {
            items
                .iter()
                .flat_map(|s| {
                    let mut b = s.as_bytes().to_vec();
                    b.resize(len, b' ');
                    b
                })
                .collect()
        };
        entries.push(group(-1, "POINT", "3-D point parameters"));
        entries.push(param(1, "USED", 2, &[], i16_data(used as u16)));
        entries.push(param(1, "SCALE", 4, &[], f32_data(self.scale)));
        entries.push(param(1, "RATE", 4, &[], f32_data(self.rate)));
        let data_start_at = entries.len();
        entries.push(param(1, "DATA_START", 2, &[], i16_data(0)));
        entries.push(param(1, "FRAMES", 2, &[], i16_data(n as u16)));
        for (k, chunk) in self.labels.chunks(255).enumerate() {
            let name = if k == 0 {
                "LABELS".to_string()
            } else {
                format!("LABELS{}", k + 1)
            };
            entries.push(param(
                1,
                &name,
                -1,
                &[label_len, chunk.len()],
                text(chunk, label_len),
            ));
        }
        entries.push(param(
            1,
            "UNITS",
            -1,
            &[self.units.len()],
            self.units.as_bytes().to_vec(),
        ));
        entries.push(group(-2, "ANALOG", "analog parameters"));
        // No analog channels, so no ANALOG:RATE: readers take the header's samples per frame
        // (0) times the point rate. (A rate equal to the point rate, written before, contradicts
        // the header's 0 and the `c3d` package on PyPI refused the file.)
        entries.push(param(2, "USED", 2, &[], i16_data(0)));
        let section_len = 4 + entries.iter().map(Vec::len).sum::<usize>();
        let pblocks = section_len.div_ceil(BLOCK);
        if pblocks > 255 {
            return fail("the parameter section would need more than 255 blocks");
        }
        let data_start = 2 + pblocks;
        if data_start > 65535 {
            return fail("the data section would start past block 65535");
        }
        // DATA_START's value now that the section size is known.
        {
            let e = &mut entries[data_start_at];
            let len = e.len();
            let mut v = Vec::new();
            o.put_u16(&mut v, data_start as u16);
            e[len - 3..len - 1].copy_from_slice(&v);
        }
        let count = entries.len();
        for (i, e) in entries.iter_mut().enumerate() {
            let name_len = e[0] as usize;
            let offset = if i + 1 == count {
                0
            } else {
                (e.len() - 2 - name_len) as i16
            };
            let mut v = Vec::new();
            o.put_i16(&mut v, offset);
            e[2 + name_len..4 + name_len].copy_from_slice(&v);
        }

        let mut out = Vec::new();
        // Header block.
        out.push(2);
        out.push(KEY);
        o.put_u16(&mut out, used as u16);
        o.put_u16(&mut out, 0); // analog samples per frame
        o.put_u16(&mut out, self.first_frame as u16);
        o.put_u16(&mut out, (self.first_frame as usize + n - 1) as u16);
        o.put_u16(&mut out, 0); // maximum interpolation gap
        o.put_f32(&mut out, self.scale as f32);
        o.put_u16(&mut out, data_start as u16);
        o.put_u16(&mut out, 0); // analog samples per channel and frame
        o.put_f32(&mut out, self.rate as f32);
        out.resize(BLOCK, 0);
        // Parameter section.
        out.extend([1, KEY, pblocks as u8, self.processor.code()]);
        for e in &entries {
            out.extend(e);
        }
        out.resize((data_start - 1) * BLOCK, 0);
        // Data section.
        let abs_scale = self.scale.abs();
        let float = self.scale < 0.0;
        for (f, row) in self.frames.iter().enumerate() {
            for (k, sample) in row.iter().enumerate() {
                let word = |s: &C3dPoint| -> f64 {
                    let res = (s.residual / abs_scale).round().clamp(0.0, 255.0);
                    f64::from(s.cameras & 0x7f) * 256.0 + res
                };
                match (sample, float) {
                    (None, true) => {
                        for _ in 0..3 {
                            o.put_f32(&mut out, 0.0);
                        }
                        o.put_f32(&mut out, -1.0);
                    }
                    (None, false) => {
                        for _ in 0..3 {
                            o.put_i16(&mut out, 0);
                        }
                        o.put_i16(&mut out, -1);
                    }
                    (Some(s), true) => {
                        if s.position.iter().any(|v| !v.is_finite()) {
                            return fail(format!("frame {f} point {k}: coordinate not finite"));
                        }
                        for v in s.position {
                            o.put_f32(&mut out, v as f32);
                        }
                        o.put_f32(&mut out, word(s) as f32);
                    }
                    (Some(s), false) => {
                        for v in s.position {
                            // Quantised with the scale as stored (an f32).
                            let q = (v / f64::from(self.scale as f32)).round();
                            if !(q.is_finite() && (-32768.0..=32767.0).contains(&q)) {
                                return fail(format!(
                                    "frame {f} point {k}: coordinate {v} does not fit a 16-bit integer at scale {}",
                                    self.scale
                                ));
                            }
                            o.put_i16(&mut out, q as i16);
                        }
                        o.put_i16(&mut out, word(s) as i16);
                    }
                }
            }
        }
        out.resize(out.len().div_ceil(BLOCK) * BLOCK, 0);
        Ok(out)
    }
}

/// Metres per unit of `POINT:UNITS` (`mm`, `cm`, `m`; case-insensitive).
pub fn units_to_metres(units: &str) -> Result<f64, ImportError> {
    match units.trim().to_ascii_lowercase().as_str() {
        "mm" => Ok(1e-3),
        "cm" => Ok(1e-2),
        "m" => Ok(1.0),
        other => fail(format!("POINT:UNITS is '{other}' (expected mm, cm or m)")),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Three markers over four frames with gaps, in millimetres.
    fn sample(scale: f64, processor: Processor) -> C3d {
        let frames = (0..4)
            .map(|f| {
                (0..3)
                    .map(|k| {
                        if (f + k) % 3 == 2 {
                            None
                        } else {
                            Some(C3dPoint {
                                position: [
                                    100.0 * k as f64 + 1.5 * f as f64,
                                    -250.25 + 10.0 * f as f64,
                                    1234.5 - k as f64,
                                ],
                                residual: 0.5,
                                cameras: 0b101,
                            })
                        }
                    })
                    .collect()
            })
            .collect();
        C3d {
            processor,
            labels: vec!["LFHD".into(), "RFHD".into(), "Subj:C7".into()],
            units: "mm".into(),
            scale,
            rate: 120.0,
            first_frame: 7,
            analog_per_frame: 0,
            frames,
            non_finite: 0,
        }
    }

    fn assert_close(a: &C3d, b: &C3d, tol: f64) {
        assert_eq!(a.labels, b.labels);
        assert_eq!(a.units, b.units);
        assert_eq!(a.first_frame, b.first_frame);
        assert_eq!(a.rate, b.rate);
        assert_eq!(a.frames.len(), b.frames.len());
        for (ra, rb) in a.frames.iter().zip(&b.frames) {
            for (sa, sb) in ra.iter().zip(rb) {
                match (sa, sb) {
                    (None, None) => {}
                    (Some(x), Some(y)) => {
                        for i in 0..3 {
                            assert!(
                                (x.position[i] - y.position[i]).abs() <= tol,
                                "{:?} vs {:?}",
                                x.position,
                                y.position
                            );
                        }
                        assert_eq!(x.cameras, y.cameras);
                        assert!((x.residual - y.residual).abs() <= a.scale.abs() / 2.0 + 1e-9);
                    }
                    _ => panic!("gap mismatch: {sa:?} vs {sb:?}"),
                }
            }
        }
    }

    #[test]
    fn float_round_trip_is_exact_to_f32() {
        for proc in [Processor::Intel, Processor::Dec, Processor::Mips] {
            let c = sample(-0.1, proc);
            let bytes = c.to_bytes().unwrap();
            assert_eq!(bytes.len() % BLOCK, 0);
            let back = C3d::from_bytes(&bytes).unwrap();
            assert_eq!(back.processor, proc);
            assert!(back.scale < 0.0);
            // f32 of values below 2000 mm: ≤ 1.2e-4 mm.
            assert_close(&c, &back, 1.2e-4);
            assert_eq!(back.frames[0][2], None);
            assert!(back.frames[0][0].is_some());
        }
    }

    /// VAX F-floating values of the VAX Architecture Reference Manual's layout, written out by
    /// hand: 1.0 is `0.1b × 2^1` (exponent 129, fraction 0: word 0x4080), −1.0 the same with the
    /// sign, 0.5 exponent 128 (0x4000), 3.0 `0.11b × 2^2` (0x4140), 0.1 0xCCCD 0x3ECC.
    #[test]
    fn dec_floats_read_and_write_as_the_vax_layout_says() {
        for (bytes, v) in [
            ([0x80, 0x40, 0x00, 0x00], 1.0f32),
            ([0x80, 0xC0, 0x00, 0x00], -1.0),
            ([0x00, 0x40, 0x00, 0x00], 0.5),
            ([0x40, 0x41, 0x00, 0x00], 3.0),
            ([0xCC, 0x3E, 0xCD, 0xCC], 0.1),
            ([0x00, 0x00, 0x00, 0x00], 0.0),
        ] {
            assert_eq!(dec_f32(bytes), v, "{bytes:02x?}");
            assert_eq!(f32_dec(v), bytes, "{v}");
        }
        // The reserved operand (sign set, exponent 0) is not a number.
        assert!(dec_f32([0x00, 0x80, 0x00, 0x00]).is_nan());
        // Every f32 a VAX float holds goes there and back exactly, from the smallest (2^-128,
        // below IEEE's normal range) to the largest (just under 2^127).
        for v in [1e-30f32, -2.5e-7, 1234.567, -9.87e20, 1.7e38, 2.938_736e-39] {
            assert_eq!(dec_f32(f32_dec(v)), v, "{v}");
        }
        // Beyond it: the largest VAX float; below it, zero.
        assert_eq!(dec_f32(f32_dec(3e38)), dec_f32([0xff, 0x7f, 0xff, 0xff]));
        assert_eq!(f32_dec(1e-40), [0; 4]);
    }

    /// A last parameter entry whose offset points past the section instead of being 0 (c3d.org's
    /// own SGI sample ends so) is the last one: the file reads as with the 0.
    #[test]
    fn a_last_entry_pointing_past_the_section_ends_it() {
        for proc in [Processor::Intel, Processor::Mips] {
            let c = sample(-0.1, proc);
            let good = c.to_bytes().unwrap();
            let o = Order {
                big: proc == Processor::Mips,
                dec: false,
            };
            // Walk the entries to the one whose offset is 0.
            let start = (usize::from(good[0]) - 1) * BLOCK;
            let mut at = start + 4;
            let word = loop {
                let word = at + 2 + (good[at] as i8).unsigned_abs() as usize;
                let offset = o.i16(&good, word);
                if offset == 0 {
                    break word;
                }
                at = (word as i64 + i64::from(offset)) as usize;
            };
            let mut b = good.clone();
            let past = if o.big {
                16129u16.to_be_bytes()
            } else {
                16129u16.to_le_bytes()
            };
            b[word..word + 2].copy_from_slice(&past);
            let back = C3d::from_bytes(&b).unwrap();
            assert_eq!(back.labels, c.labels);
            assert_eq!(back.frames, C3d::from_bytes(&good).unwrap().frames);
        }
    }

    #[test]
    fn integer_round_trip_within_half_a_scale_step() {
        let c = sample(0.1, Processor::Intel);
        let back = C3d::from_bytes(&c.to_bytes().unwrap()).unwrap();
        assert!(back.scale > 0.0);
        assert_close(&c, &back, 0.0501);
        // DEC: integers as Intel's, the scale and rate VAX floats.
        let c = sample(0.1, Processor::Dec);
        let back = C3d::from_bytes(&c.to_bytes().unwrap()).unwrap();
        assert_eq!(back.processor, Processor::Dec);
        assert_close(&c, &back, 0.0501);
        // Gaps survive in integer files too.
        assert_eq!(back.frames[1][1], None);
        // Out-of-range coordinates are refused by the writer.
        let mut big = c.clone();
        big.scale = 0.01;
        assert!(big.to_bytes().is_err());
    }

    #[test]
    fn many_labels_go_to_labels2() {
        let mut c = sample(-1.0, Processor::Intel);
        c.labels = (0..300).map(|i| format!("M{i}")).collect();
        c.frames = vec![
            (0..300)
                .map(|i| {
                    Some(C3dPoint {
                        position: [i as f64, 0.0, 1.0],
                        residual: 0.0,
                        cameras: 1,
                    })
                })
                .collect(),
        ];
        let back = C3d::from_bytes(&c.to_bytes().unwrap()).unwrap();
        assert_eq!(back.labels.len(), 300);
        assert_eq!(back.labels[299], "M299");
        assert_eq!(back.frames[0][299].unwrap().position[0], 299.0);
    }

    fn err(bytes: &[u8]) -> String {
        let e = C3d::from_bytes(bytes).unwrap_err().to_string();
        assert!(!e.contains('\n'), "one line: {e}");
        e
    }

    /// Byte offset of the parameter `name` (its name's first byte) in `bytes`.
    fn find(bytes: &[u8], name: &str) -> usize {
        bytes
            .windows(name.len())
            .position(|w| w == name.as_bytes())
            .unwrap()
    }

    #[test]
    fn malformed_files_are_refused_with_their_cause() {
        let good = sample(-0.1, Processor::Intel).to_bytes().unwrap();
        C3d::from_bytes(&good).unwrap();

        let mut b = good.clone();
        b[1] = 0x51;
        assert!(err(&b).contains("not a C3D file"));

        assert!(err(&good[..300]).contains("truncated"));
        // Data cut: the last frame is incomplete.
        let data_start = u16::from_le_bytes([good[16], good[17]]) as usize;
        let cut = (data_start - 1) * BLOCK + 3 * 3 * 16 + 5;
        assert!(
            err(&good[..cut]).contains("truncated"),
            "{}",
            err(&good[..cut])
        );

        // The parameter section's two reserved bytes are ignored: 0x00 0x00 (what the `c3d`
        // package on PyPI writes) reads exactly as the typical 0x01 0x50.
        let mut b = good.clone();
        b[BLOCK] = 0;
        b[BLOCK + 1] = 0;
        assert_eq!(
            C3d::from_bytes(&b).unwrap().frames,
            C3d::from_bytes(&good).unwrap().frames
        );

        let mut b = good.clone();
        b[BLOCK + 3] = 99;
        assert!(err(&b).contains("processor type 99"));

        let mut b = good.clone();
        b[0] = 40;
        assert!(err(&b).contains("parameter section"));

        // Header point count disagrees with POINT:USED.
        let mut b = good.clone();
        b[2] = 4;
        assert!(err(&b).contains("POINT:USED"));

        // NaN in a valid sample (frame 0, point 0, X): a gap, counted.
        let mut b = good.clone();
        let at = (data_start - 1) * BLOCK;
        b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        let nan = C3d::from_bytes(&b).unwrap();
        assert_eq!(nan.frames[0][0], None);
        assert_eq!(nan.non_finite, 1);
        assert_eq!(nan.frames[1..], C3d::from_bytes(&good).unwrap().frames[1..]);
        // Frames counted from 0 (some writers do): read, the same frames.
        let mut b = good.clone();
        let (first, last) = (
            u16::from_le_bytes([b[6], b[7]]),
            u16::from_le_bytes([b[8], b[9]]),
        );
        b[6..8].copy_from_slice(&0u16.to_le_bytes());
        b[8..10].copy_from_slice(&(last - first).to_le_bytes());
        let zero = C3d::from_bytes(&b).unwrap();
        assert_eq!(zero.first_frame, 0);
        assert_eq!(zero.frames, C3d::from_bytes(&good).unwrap().frames);
        // A group named with a space (Qualisys names a parameter "Uncropped Measurement
        // Length") reads; a control character in a name is refused.
        let analog = good.windows(6).position(|w| w == b"ANALOG").unwrap();
        let mut b = good.clone();
        b[analog + 3] = b' ';
        assert_eq!(
            C3d::from_bytes(&b).unwrap().frames,
            C3d::from_bytes(&good).unwrap().frames
        );
        b[analog + 3] = 0x01;
        assert!(err(&b).contains("control characters"), "{}", err(&b));
        // ... but NaN in a gap is a gap (frame 0, point 2).
        let mut b = good.clone();
        let at = (data_start - 1) * BLOCK + 2 * 16;
        b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(C3d::from_bytes(&b).unwrap().frames[0][2], None);

        // Unknown units.
        let mut c = sample(-0.1, Processor::Intel);
        c.units = "in".into();
        assert!(c.to_bytes().is_err());
        let mut b = good.clone();
        let u = find(&b, "UNITS");
        // name, offset (2), type, ndims, dim → data.
        let data = u + 5 + 2 + 1 + 1 + 1;
        b[data..data + 2].copy_from_slice(b"in");
        assert!(err(&b).contains("POINT:UNITS"));

        // POINT:FRAMES disagrees with the header.
        let mut b = good.clone();
        let f = find(&b, "FRAMES");
        let data = f + 6 + 2 + 2;
        b[data] = 9;
        assert!(err(&b).contains("POINT:FRAMES"));

        // POINT:DATA_START 0 (no pointer: blocks count from 1) reads the header's block; any
        // other value the header does not say is refused.
        let d = find(&good, "DATA_START") + 10 + 2 + 2;
        let mut b = good.clone();
        b[d..d + 2].copy_from_slice(&0u16.to_le_bytes());
        assert_eq!(
            C3d::from_bytes(&b).unwrap(),
            C3d::from_bytes(&good).unwrap()
        );
        b[d..d + 2].copy_from_slice(&(data_start as u16 + 1).to_le_bytes());
        assert!(err(&b).contains("POINT:DATA_START"));

        // A parameter section claiming more blocks than its entries fill, the data starting
        // after the entries inside that count (OptiTrack Motive's exports), reads as it is; data
        // pointed into the entries themselves is refused.
        let pstart = (good[0] as usize - 1) * BLOCK;
        let mut b = good.clone();
        b[pstart + 2] += 1;
        assert_eq!(
            C3d::from_bytes(&b).unwrap(),
            C3d::from_bytes(&good).unwrap()
        );
        let mut b = good.clone();
        b[16..18].copy_from_slice(&(good[0] as u16).to_le_bytes());
        b[d..d + 2].copy_from_slice(&0u16.to_le_bytes());
        assert!(
            err(&b).contains("overlaps the parameter section"),
            "{}",
            err(&b)
        );

        // Parameter data type outside -1/1/2/4.
        let mut b = good.clone();
        let s = find(&b, "SCALE");
        b[s + 5 + 2] = 3;
        assert!(err(&b).contains("data type"));

        // Fewer labels than points (LABELS renamed away).
        let mut b = good.clone();
        let l = find(&b, "LABELS");
        b[l..l + 6].copy_from_slice(b"LABELX");
        assert!(err(&b).contains("POINT:LABELS"));
    }

    #[test]
    fn units_convert_to_metres() {
        assert_eq!(units_to_metres("mm").unwrap(), 1e-3);
        assert_eq!(units_to_metres("M ").unwrap(), 1.0);
        assert_eq!(units_to_metres("cm").unwrap(), 1e-2);
        assert!(units_to_metres("ft").is_err());
    }
}
