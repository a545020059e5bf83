//! OpenSim's TRC marker files (`.trc`, as OpenCap, OptiTrack Motive, Cortex and OpenSim write
//! them) read into the point data a C3D file holds ([`C3d`]), so that `lfit data import --trc`
//! maps and fits them as it does a C3D's.
//!
//! The format is tab-separated text: line 1 `PathFileType 4 (X/Y/Z) NAME`; line 2 the names of
//! line 3's values (`DataRate CameraRate NumFrames NumMarkers Units OrigDataRate
//! OrigDataStartFrame OrigNumFrames`; `DataRate`, `NumFrames`, `NumMarkers` and `Units` are
//! read); line 4 `Frame#`, `Time` and one name per marker (each followed by two empty columns);
//! line 5 the coordinate names (`X1 Y1 Z1 X2 …`); then one row per frame: its number, its time
//! and X Y Z per marker, in `Units` (mm, cm or m). A marker whose three fields are not all
//! numbers (empty, `NaN`) is a gap in that frame; a row may stop early, its last markers gaps.

use std::path::Path;

use crate::capture::ImportError;
use crate::capture::c3d::{C3d, C3dPoint, Processor, units_to_metres};

fn fail<T>(msg: impl Into<String>) -> Result<T, ImportError> {
    Err(ImportError::Invalid(msg.into()))
}

/// Reads a TRC file ([module docs](self)).
pub fn read_trc(path: &Path) -> Result<C3d, ImportError> {
    let bytes = std::fs::read(path).map_err(|source| ImportError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    // Lossy: a binary file (a C3D given as TRC) is then refused by its first line.
    parse_trc(&String::from_utf8_lossy(&bytes))
}

/// Parses the text of a TRC file ([module docs](self)).
pub fn parse_trc(text: &str) -> Result<C3d, ImportError> {
    // Fields by tab, trailing empty ones dropped (writers end rows with a tab or not).
    let lines: Vec<Vec<&str>> = text
        .lines()
        .map(|l| {
            let mut f: Vec<&str> = l
                .trim_end_matches('\r')
                .split('\t')
                .map(str::trim)
                .collect();
            while f.len() > 1 && f.last().is_some_and(|x| x.is_empty()) {
                f.pop();
            }
            f
        })
        .collect();
    if lines.len() < 5 || !lines[0][0].eq_ignore_ascii_case("PathFileType") {
        return fail(
            "not a TRC file: the first line does not start with PathFileType, or the five header lines are missing",
        );
    }
    let (keys, values) = (&lines[1], &lines[2]);
    let value = |key: &str| -> Result<&str, ImportError> {
        keys.iter()
            .position(|k| k.eq_ignore_ascii_case(key))
            .and_then(|i| values.get(i).copied())
            .filter(|v| !v.is_empty())
            .ok_or_else(|| {
                ImportError::Invalid(format!(
                    "TRC header: no {key} (line 2 names the values of line 3)"
                ))
            })
    };
    let number = |key: &str| -> Result<f64, ImportError> {
        let v = value(key)?;
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| {
                ImportError::Invalid(format!("TRC header: {key} is '{v}', not a number"))
            })
    };
    let rate = number("DataRate")?;
    if rate <= 0.0 {
        return fail(format!("TRC header: DataRate is {rate}, not positive"));
    }
    let declared_frames = number("NumFrames")?;
    let declared_markers = number("NumMarkers")?;
    let units = value("Units")?.to_string();
    units_to_metres(&units).map_err(|_| {
        ImportError::Invalid(format!(
            "TRC header: Units is '{units}' (expected mm, cm or m)"
        ))
    })?;
    let names = &lines[3];
    if names.len() < 2 || !names[0].eq_ignore_ascii_case("Frame#") {
        return fail("TRC line 4 must start with Frame# and Time, then the marker names");
    }
    let labels: Vec<String> = names[2..]
        .iter()
        .filter(|n| !n.is_empty())
        .map(|n| n.to_string())
        .collect();
    if labels.is_empty() {
        return fail("TRC line 4 names no marker");
    }
    if labels.len() as f64 != declared_markers {
        return fail(format!(
            "TRC header: NumMarkers is {declared_markers} but line 4 names {} markers",
            labels.len()
        ));
    }
    let m = labels.len();
    let mut frames = Vec::new();
    let mut first_frame = None;
    let mut non_finite = 0;
    for (r, row) in lines.iter().enumerate().skip(5) {
        if row.iter().all(|f| f.is_empty()) {
            continue;
        }
        let line = r + 1;
        if row.len() > 2 + 3 * m {
            return fail(format!(
                "TRC line {line}: {} fields for {m} markers (expected at most {})",
                row.len(),
                2 + 3 * m
            ));
        }
        if first_frame.is_none() {
            let f: f64 = row[0].parse().map_err(|_| {
                ImportError::Invalid(format!(
                    "TRC line {line}: frame number '{}' is not a number",
                    row[0]
                ))
            })?;
            first_frame = Some(f.max(0.0) as u32);
        }
        let mut points = Vec::with_capacity(m);
        for k in 0..m {
            let mut xyz = [0.0; 3];
            let mut seen = true;
            for (a, x) in xyz.iter_mut().enumerate() {
                let field = row.get(2 + 3 * k + a).copied().unwrap_or("");
                if field.is_empty() {
                    seen = false;
                    continue;
                }
                match field.parse::<f64>() {
                    Ok(v) if v.is_finite() => *x = v,
                    Ok(_) => {
                        seen = false;
                        non_finite += 1;
                    }
                    Err(_) => {
                        return fail(format!(
                            "TRC line {line}: '{field}' ({}'s {}) is not a number",
                            labels[k],
                            ["X", "Y", "Z"][a]
                        ));
                    }
                }
            }
            points.push(seen.then_some(C3dPoint {
                position: xyz,
                residual: 0.0,
                cameras: 0,
            }));
        }
        frames.push(points);
    }
    if frames.is_empty() {
        return fail("the TRC file holds no frame");
    }
    if frames.len() as f64 != declared_frames {
        return fail(format!(
            "TRC header: NumFrames is {declared_frames} but the file has {} rows of data (truncated?)",
            frames.len()
        ));
    }
    Ok(C3d {
        processor: Processor::Intel,
        labels,
        units,
        scale: -1.0,
        rate,
        first_frame: first_frame.unwrap_or(1),
        analog_per_frame: 0,
        frames,
        non_finite,
    })
}

/// The text of a TRC file holding `c3d`'s points (gaps as empty fields): what [`parse_trc`]
/// reads back, to the printed digits.
pub fn to_trc(c3d: &C3d, name: &str) -> String {
    let m = c3d.labels.len();
    let n = c3d.frames.len();
    let mut out = format!("PathFileType\t4\t(X/Y/Z)\t{name}\n");
    out.push_str("DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n");
    out.push_str(&format!(
        "{r}\t{r}\t{n}\t{m}\t{u}\t{r}\t{f}\t{n}\n",
        r = c3d.rate,
        u = c3d.units,
        f = c3d.first_frame
    ));
    out.push_str("Frame#\tTime");
    for l in &c3d.labels {
        out.push_str(&format!("\t{l}\t\t"));
    }
    out.push_str("\n\t");
    for k in 1..=m {
        out.push_str(&format!("\tX{k}\tY{k}\tZ{k}"));
    }
    out.push_str("\n\n");
    for (i, row) in c3d.frames.iter().enumerate() {
        out.push_str(&format!(
            "{}\t{}",
            c3d.first_frame as usize + i,
            i as f64 / c3d.rate
        ));
        for p in row {
            match p {
                Some(p) => out.push_str(&format!(
                    "\t{}\t{}\t{}",
                    p.position[0], p.position[1], p.position[2]
                )),
                None => out.push_str("\t\t\t"),
            }
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn sample() -> C3d {
        let labels: Vec<String> = ["LASI", "RASI", "LKNE"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let frames = (0..4)
            .map(|f| {
                (0..3)
                    .map(|k| {
                        (!(f == 2 && k == 1)).then_some(C3dPoint {
                            position: [
                                100.5 * k as f64 + f as f64,
                                900.25 - k as f64,
                                -3.0 * f as f64,
                            ],
                            residual: 0.0,
                            cameras: 0,
                        })
                    })
                    .collect()
            })
            .collect();
        C3d {
            processor: Processor::Intel,
            labels,
            units: "mm".into(),
            scale: -1.0,
            rate: 60.0,
            first_frame: 1,
            analog_per_frame: 0,
            frames,
            non_finite: 0,
        }
    }

    /// A TRC file reads back the markers, gaps and header it was written with; NaN fields and
    /// a row that stops early are gaps; every malformed part is a one-line error naming it.
    #[test]
    fn a_trc_file_reads_its_markers_and_gaps() {
        let c = sample();
        let text = to_trc(&c, "walk.trc");
        assert_eq!(parse_trc(&text).unwrap(), c);
        // Windows line ends, NaN for a gap, a row cut after its second marker, rows ending in a
        // tab (MATLAB writers' `%f\t` per value), no blank line before the data.
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        lines[7].push('\t');
        lines[9].push_str("\t\t");
        lines[6] = lines[6].replacen("\t100.5\t", "\tNaN\t", 1);
        let cut: Vec<&str> = lines[8].split('\t').take(2 + 6).collect();
        lines[8] = cut.join("\t");
        lines.remove(5);
        let read = parse_trc(&(lines.join("\r\n") + "\r\n")).unwrap();
        assert_eq!(read.frames[0][1], None);
        assert_eq!(read.non_finite, 1);
        assert_eq!(read.frames[2][2], None);
        assert_eq!(read.frames[2][0], c.frames[2][0]);
        assert_eq!(read.frames[3], c.frames[3]);
        let bad = |edit: &dyn Fn(&mut Vec<String>), needle: &str| {
            let mut l: Vec<String> = text.lines().map(str::to_string).collect();
            edit(&mut l);
            let e = parse_trc(&l.join("\n")).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
            assert!(!e.contains('\n'));
        };
        bad(&|l| l[0] = "Frame#".into(), "not a TRC file");
        bad(&|l| l.truncate(3), "not a TRC file");
        bad(
            &|l| l[2] = l[2].replacen("60", "abc", 1),
            "DataRate is 'abc'",
        );
        bad(
            &|l| l[2] = l[2].replace("\tmm\t", "\tin\t"),
            "Units is 'in'",
        );
        bad(
            &|l| l[1] = l[1].replace("NumMarkers", "Markers"),
            "no NumMarkers",
        );
        bad(
            &|l| l[2] = l[2].replacen("\t3\t", "\t4\t", 1),
            "NumMarkers is 4 but line 4 names 3",
        );
        bad(
            &|l| l[2] = l[2].replacen("\t4\t", "\t5\t", 1),
            "NumFrames is 5 but the file has 4 rows",
        );
        bad(
            &|l| l[7] = l[7].replacen("\t900.25", "\tx", 1),
            "'x' (LASI's Y) is not a number",
        );
        bad(&|l| l[7].push_str("\t1\t2\t3"), "fields for 3 markers");
        bad(&|l| l.truncate(6), "holds no frame");
    }
}
