//! A strict reader and writer of BVH motion files (Biovision hierarchy).
//!
//! Written here rather than taken from a crate: the Rust BVH parsers on crates.io are either
//! unmaintained alpha software (`bvh_anim` 0.4.0, last released 2019, "alpha quality") or pull in
//! heavy unrelated dependencies (`bvh_anim_parser` depends on the `cargo` crate and, optionally,
//! Bevy), and lfit needs every malformed file refused with its line and cause, never a panic.
//!
//! Grammar accepted (whitespace-tolerant: any mix of spaces, tabs, blank lines and CR/LF):
//!
//! ```text
//! HIERARCHY
//! ROOT name            (the rest of the line is the name)
//! {
//!   OFFSET x y z
//!   CHANNELS n c1 ... cn          n = 3 (three rotations) or 6 (three positions, three rotations),
//!                                 channels Xposition Yposition Zposition Xrotation Yrotation
//!                                 Zrotation in any order, each at most once
//!   JOINT name { ... }            any number of children
//!   End Site { OFFSET x y z }     optional leaf marker
//! }
//! MOTION
//! Frames: F
//! Frame Time: dt
//! F lines of numbers, each with exactly the total channel count
//! ```
//!
//! Every error names the (1-based) line and the cause: unknown keywords or channels, channel
//! counts other than 3 or 6, repeated channels, duplicate joint names, missing or extra braces,
//! non-numbers, NaN/inf anywhere, fewer or more frames or values than declared.
//!
//! **Semantics.** Angles are in degrees. A joint's rotation channels listed as `A B C` give the
//! local rotation `R = R_A(a) R_B(b) R_C(c)` (the first listed is the outermost), with
//! right-handed rotations about the joint's axes. The rest pose is all channels zero: every
//! joint's world rotation is the identity and its world position is the sum of the OFFSETs down
//! the chain. In a frame, `world_rot(j) = world_rot(parent) R_j` and
//! `world_pos(j) = world_pos(parent) + world_rot(parent) (OFFSET_j + P_j)`, where `P_j` are the
//! joint's position channels (zero without them); the root has `world_pos = OFFSET + P`.

use std::fmt::Write as _;

use glam::{DMat3, DVec3};

/// A parse error: 1-based line and cause.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {cause}")]
pub struct BvhError {
    pub line: usize,
    pub cause: String,
}

fn err<T>(line: usize, cause: impl Into<String>) -> Result<T, BvhError> {
    Err(BvhError {
        line,
        cause: cause.into(),
    })
}

/// An axis of the BVH frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }

    fn letter(self) -> char {
        match self {
            Axis::X => 'X',
            Axis::Y => 'Y',
            Axis::Z => 'Z',
        }
    }

    /// The rotation by `angle` radians about this axis (right-handed).
    pub fn rotation(self, angle: f64) -> DMat3 {
        match self {
            Axis::X => DMat3::from_rotation_x(angle),
            Axis::Y => DMat3::from_rotation_y(angle),
            Axis::Z => DMat3::from_rotation_z(angle),
        }
    }
}

/// One channel of a joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Channel {
    Position(Axis),
    Rotation(Axis),
}

impl Channel {
    fn parse(token: &str) -> Option<Self> {
        let axis = match token.as_bytes().first()? {
            b'X' | b'x' => Axis::X,
            b'Y' | b'y' => Axis::Y,
            b'Z' | b'z' => Axis::Z,
            _ => return None,
        };
        match &token[1..] {
            "position" | "Position" => Some(Channel::Position(axis)),
            "rotation" | "Rotation" => Some(Channel::Rotation(axis)),
            _ => None,
        }
    }

    pub fn name(self) -> String {
        match self {
            Channel::Position(a) => format!("{}position", a.letter()),
            Channel::Rotation(a) => format!("{}rotation", a.letter()),
        }
    }
}

/// An Euler order: the three axes of `R = R_a R_b R_c`, all different.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EulerOrder(pub [Axis; 3]);

impl EulerOrder {
    pub const XYZ: Self = Self([Axis::X, Axis::Y, Axis::Z]);
    pub const XZY: Self = Self([Axis::X, Axis::Z, Axis::Y]);
    pub const YXZ: Self = Self([Axis::Y, Axis::X, Axis::Z]);
    pub const YZX: Self = Self([Axis::Y, Axis::Z, Axis::X]);
    pub const ZXY: Self = Self([Axis::Z, Axis::X, Axis::Y]);
    pub const ZYX: Self = Self([Axis::Z, Axis::Y, Axis::X]);
    pub const ALL: [Self; 6] = [
        Self::XYZ,
        Self::XZY,
        Self::YXZ,
        Self::YZX,
        Self::ZXY,
        Self::ZYX,
    ];

    /// Parses `"ZXY"` and the like.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.name() == s.to_uppercase())
    }

    pub fn name(self) -> String {
        self.0.iter().map(|a| a.letter()).collect()
    }

    /// `R_a(angles[0]) R_b(angles[1]) R_c(angles[2])`, angles in radians.
    pub fn to_matrix(self, angles: [f64; 3]) -> DMat3 {
        self.0[0].rotation(angles[0])
            * self.0[1].rotation(angles[1])
            * self.0[2].rotation(angles[2])
    }

    /// Angles (radians) with `to_matrix(angles) == r` for a rotation matrix `r`; the middle angle
    /// lies in [−π/2, π/2]. At gimbal lock (middle angle ±π/2) the last angle is set to zero.
    pub fn from_matrix(self, r: DMat3) -> [f64; 3] {
        let [i, j, k] = self.0.map(Axis::index);
        // Even permutations of (x, y, z) have i × j = k.
        let s = if (j + 3 - i) % 3 == 1 { 1.0 } else { -1.0 };
        // m(row, col)
        let m = |row: usize, col: usize| r.col(col)[row];
        let cos_b = m(i, i).hypot(m(i, j));
        let b = (s * m(i, k)).atan2(cos_b);
        if cos_b > 1e-12 {
            let a = (-s * m(j, k)).atan2(m(k, k));
            let c = (-s * m(i, j)).atan2(m(i, i));
            [a, b, c]
        } else {
            // R = R_i(a) R_j(±π/2): its j-th column is R_i(a) e_j.
            let a = (s * m(k, j)).atan2(m(j, j));
            [a, b, 0.0]
        }
    }
}

/// One joint of the hierarchy.
#[derive(Debug, Clone, PartialEq)]
pub struct BvhJoint {
    pub name: String,
    pub parent: Option<usize>,
    pub offset: DVec3,
    pub channels: Vec<Channel>,
    /// OFFSET of the joint's `End Site`, if it has one.
    pub end_site: Option<DVec3>,
    /// Index of the joint's first channel in a frame's values.
    pub first_channel: usize,
}

impl BvhJoint {
    /// The Euler order of the joint's rotation channels.
    pub fn euler_order(&self) -> Option<EulerOrder> {
        let axes: Vec<Axis> = self
            .channels
            .iter()
            .filter_map(|c| match c {
                Channel::Rotation(a) => Some(*a),
                Channel::Position(_) => None,
            })
            .collect();
        (axes.len() == 3).then(|| EulerOrder([axes[0], axes[1], axes[2]]))
    }

    pub fn has_position(&self) -> bool {
        self.channels
            .iter()
            .any(|c| matches!(c, Channel::Position(_)))
    }
}

/// A parsed BVH file: joints in file order (parents before children) and the motion.
#[derive(Debug, Clone, PartialEq)]
pub struct Bvh {
    pub joints: Vec<BvhJoint>,
    pub frame_time: f64,
    /// One row of `num_channels()` values per frame (degrees and file units).
    pub frames: Vec<Vec<f64>>,
}

/// World transforms of a BVH pose.
#[derive(Debug, Clone)]
pub struct BvhPose {
    pub rotations: Vec<DMat3>,
    pub positions: Vec<DVec3>,
}

impl Bvh {
    pub fn num_channels(&self) -> usize {
        self.joints.iter().map(|j| j.channels.len()).sum()
    }

    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Local rotation (matrix) and position channels of joint `j` in `frame`.
    pub fn local(&self, j: usize, frame: &[f64]) -> (DMat3, DVec3) {
        let joint = &self.joints[j];
        let mut rot = DMat3::IDENTITY;
        let mut pos = DVec3::ZERO;
        for (c, &v) in joint.channels.iter().zip(&frame[joint.first_channel..]) {
            match c {
                Channel::Rotation(a) => rot *= a.rotation(v.to_radians()),
                Channel::Position(a) => pos[a.index()] = v,
            }
        }
        (rot, pos)
    }

    /// World rotations and positions of every joint for one frame's values.
    pub fn pose(&self, frame: &[f64]) -> BvhPose {
        let n = self.joints.len();
        let mut rotations = Vec::with_capacity(n);
        let mut positions = Vec::with_capacity(n);
        for (j, joint) in self.joints.iter().enumerate() {
            let (rot, pos) = self.local(j, frame);
            let (w, p) = match joint.parent {
                None => (rot, joint.offset + pos),
                Some(p) => (
                    rotations[p] * rot,
                    positions[p] + rotations[p] * (joint.offset + pos),
                ),
            };
            rotations.push(w);
            positions.push(p);
        }
        BvhPose {
            rotations,
            positions,
        }
    }

    /// World positions of the joints in the rest pose (all channels zero).
    pub fn rest_positions(&self) -> Vec<DVec3> {
        let mut out: Vec<DVec3> = Vec::with_capacity(self.joints.len());
        for joint in &self.joints {
            let p = match joint.parent {
                None => joint.offset,
                Some(p) => out[p] + joint.offset,
            };
            out.push(p);
        }
        out
    }

    /// Children of joint `j`, in file order.
    pub fn children(&self, j: usize) -> Vec<usize> {
        (0..self.joints.len())
            .filter(|&k| self.joints[k].parent == Some(j))
            .collect()
    }

    /// Whether `a` is a proper ancestor of `b`.
    pub fn is_ancestor(&self, a: usize, b: usize) -> bool {
        let mut k = self.joints[b].parent;
        while let Some(p) = k {
            if p == a {
                return true;
            }
            k = self.joints[p].parent;
        }
        false
    }

    /// Parses a BVH file's text.
    pub fn parse(text: &str) -> Result<Self, BvhError> {
        Parser::new(text).parse()
    }

    /// Writes the file: tabs for indentation, numbers with 6 decimals in OFFSETs and `decimals`
    /// decimals in the motion.
    pub fn write(&self, decimals: usize) -> String {
        let mut out = String::from("HIERARCHY\n");
        let mut depth_of = vec![0usize; self.joints.len()];
        // Close the blocks of joints that end before joint k starts.
        let mut open: Vec<usize> = Vec::new();
        for (j, joint) in self.joints.iter().enumerate() {
            while let Some(&top) = open.last() {
                if Some(top) == joint.parent {
                    break;
                }
                open.pop();
                self.close_joint(&mut out, top, depth_of[top]);
            }
            let depth = open.len();
            depth_of[j] = depth;
            let pad = "\t".repeat(depth);
            let kind = if joint.parent.is_none() {
                "ROOT"
            } else {
                "JOINT"
            };
            let _ = writeln!(out, "{pad}{kind} {}", joint.name);
            let _ = writeln!(out, "{pad}{{");
            let _ = writeln!(
                out,
                "{pad}\tOFFSET {:.6} {:.6} {:.6}",
                joint.offset.x, joint.offset.y, joint.offset.z
            );
            let names: Vec<String> = joint.channels.iter().map(|c| c.name()).collect();
            let _ = writeln!(
                out,
                "{pad}\tCHANNELS {} {}",
                joint.channels.len(),
                names.join(" ")
            );
            open.push(j);
        }
        while let Some(top) = open.pop() {
            self.close_joint(&mut out, top, depth_of[top]);
        }
        let _ = writeln!(out, "MOTION");
        let _ = writeln!(out, "Frames: {}", self.frames.len());
        let _ = writeln!(out, "Frame Time: {:.10}", self.frame_time);
        for frame in &self.frames {
            let row: Vec<String> = frame.iter().map(|v| format!("{v:.decimals$}")).collect();
            let _ = writeln!(out, "{}", row.join(" "));
        }
        out
    }

    fn close_joint(&self, out: &mut String, j: usize, depth: usize) {
        let pad = "\t".repeat(depth);
        if let Some(e) = self.joints[j].end_site {
            let _ = writeln!(out, "{pad}\tEnd Site");
            let _ = writeln!(out, "{pad}\t{{");
            let _ = writeln!(out, "{pad}\t\tOFFSET {:.6} {:.6} {:.6}", e.x, e.y, e.z);
            let _ = writeln!(out, "{pad}\t}}");
        }
        let _ = writeln!(out, "{pad}}}");
    }
}

/// A token with its line.
#[derive(Debug, Clone, Copy)]
struct Token<'a> {
    text: &'a str,
    line: usize,
}

struct Parser<'a> {
    /// Hierarchy tokens (up to and including `MOTION`), braces split off.
    tokens: Vec<Token<'a>>,
    pos: usize,
    /// The lines after the one holding `MOTION` (line number, text).
    rest: Vec<(usize, &'a str)>,
    last_line: usize,
}

impl<'a> Parser<'a> {
    fn new(text: &'a str) -> Self {
        let mut tokens = Vec::new();
        let mut rest = Vec::new();
        let mut in_motion = false;
        let mut last_line = 1;
        for (i, line) in text.lines().enumerate() {
            let n = i + 1;
            last_line = n;
            if in_motion {
                rest.push((n, line));
                continue;
            }
            for word in line.split_whitespace() {
                // Braces may touch names: split them off.
                let mut w = word;
                while !w.is_empty() {
                    if let Some(r) = w.strip_prefix(['{', '}']) {
                        tokens.push(Token {
                            text: &w[..1],
                            line: n,
                        });
                        w = r;
                        continue;
                    }
                    let end = w.find(['{', '}']).unwrap_or(w.len());
                    tokens.push(Token {
                        text: &w[..end],
                        line: n,
                    });
                    w = &w[end..];
                }
                if word == "MOTION" {
                    in_motion = true;
                }
            }
        }
        Self {
            tokens,
            pos: 0,
            rest,
            last_line,
        }
    }

    fn next(&mut self, what: &str) -> Result<Token<'a>, BvhError> {
        match self.tokens.get(self.pos) {
            Some(&t) => {
                self.pos += 1;
                Ok(t)
            }
            None => err(
                self.last_line,
                format!("file ends where {what} was expected"),
            ),
        }
    }

    fn expect(&mut self, word: &str) -> Result<Token<'a>, BvhError> {
        let t = self.next(&format!("'{word}'"))?;
        if t.text != word {
            return err(t.line, format!("expected '{word}', found '{}'", t.text));
        }
        Ok(t)
    }

    fn number(&mut self, what: &str) -> Result<f64, BvhError> {
        let t = self.next(what)?;
        parse_number(t.text, t.line, what)
    }

    fn offset(&mut self) -> Result<DVec3, BvhError> {
        self.expect("OFFSET")?;
        Ok(DVec3::new(
            self.number("an OFFSET x value")?,
            self.number("an OFFSET y value")?,
            self.number("an OFFSET z value")?,
        ))
    }

    /// The name of a ROOT/JOINT: the rest of its line (braces excluded).
    fn name(&mut self, keyword: Token<'a>) -> Result<String, BvhError> {
        let mut parts = Vec::new();
        while let Some(&t) = self.tokens.get(self.pos) {
            if t.line != keyword.line || t.text == "{" || t.text == "}" {
                break;
            }
            parts.push(t.text);
            self.pos += 1;
        }
        if parts.is_empty() {
            return err(keyword.line, format!("{} without a name", keyword.text));
        }
        Ok(parts.join(" "))
    }

    fn parse(mut self) -> Result<Bvh, BvhError> {
        self.expect("HIERARCHY")?;
        let root = self.expect("ROOT")?;
        let mut joints: Vec<BvhJoint> = Vec::new();
        let mut channel_count = 0;
        self.joint(root, None, &mut joints, &mut channel_count)?;
        let t = self.next("'MOTION'")?;
        if t.text != "MOTION" {
            let cause = if t.text == "ROOT" {
                "a second ROOT: only one hierarchy is supported".to_string()
            } else if t.text == "}" {
                "unmatched '}'".to_string()
            } else {
                format!("expected 'MOTION' after the hierarchy, found '{}'", t.text)
            };
            return err(t.line, cause);
        }
        let motion_line = t.line;
        if let Some(extra) = self.tokens.get(self.pos) {
            return err(
                extra.line,
                format!("unexpected '{}' after MOTION on its line", extra.text),
            );
        }
        let (frames, frame_time) = self.motion(motion_line, channel_count)?;
        Ok(Bvh {
            joints,
            frame_time,
            frames,
        })
    }

    fn joint(
        &mut self,
        keyword: Token<'a>,
        parent: Option<usize>,
        joints: &mut Vec<BvhJoint>,
        channel_count: &mut usize,
    ) -> Result<(), BvhError> {
        let name = self.name(keyword)?;
        if joints.iter().any(|j| j.name == name) {
            return err(keyword.line, format!("duplicate joint name '{name}'"));
        }
        let open = self.next("'{'")?;
        if open.text != "{" {
            return err(
                open.line,
                format!(
                    "expected '{{' after {} {name}, found '{}'",
                    keyword.text, open.text
                ),
            );
        }
        let offset = self.offset()?;
        let ct = self.expect("CHANNELS")?;
        let count_token = self.next("the channel count")?;
        let count: usize = count_token.text.parse().map_err(|_| BvhError {
            line: count_token.line,
            cause: format!("channel count '{}' is not a whole number", count_token.text),
        })?;
        if count != 3 && count != 6 {
            return err(
                ct.line,
                format!(
                    "joint '{name}' has {count} channels; expected 3 (rotations) or 6 (positions and rotations)"
                ),
            );
        }
        let mut channels = Vec::with_capacity(count);
        for _ in 0..count {
            let t = self.next("a channel name")?;
            if t.line != ct.line {
                return err(
                    ct.line,
                    format!(
                        "CHANNELS of joint '{name}' declares {count} channels but lists {}",
                        channels.len()
                    ),
                );
            }
            let Some(c) = Channel::parse(t.text) else {
                return err(
                    t.line,
                    format!(
                        "unknown channel '{}' (expected Xposition, Yposition, Zposition, Xrotation, Yrotation or Zrotation)",
                        t.text
                    ),
                );
            };
            if channels.contains(&c) {
                return err(
                    t.line,
                    format!("channel {} repeated in joint '{name}'", c.name()),
                );
            }
            channels.push(c);
        }
        if let Some(t) = self.tokens.get(self.pos)
            && t.line == ct.line
        {
            return err(
                t.line,
                format!("CHANNELS of joint '{name}' declares {count} channels but lists more"),
            );
        }
        let rotations = channels
            .iter()
            .filter(|c| matches!(c, Channel::Rotation(_)))
            .count();
        if rotations != 3 {
            return err(
                ct.line,
                format!(
                    "joint '{name}' must have the three rotation channels X, Y and Z (it has {rotations})"
                ),
            );
        }
        let index = joints.len();
        joints.push(BvhJoint {
            name,
            parent,
            offset,
            channels,
            end_site: None,
            first_channel: *channel_count,
        });
        *channel_count += count;
        loop {
            let t = self.next("'}', JOINT or End Site")?;
            match t.text {
                "}" => return Ok(()),
                "JOINT" => self.joint(t, Some(index), joints, channel_count)?,
                "End" => {
                    let site = self.next("'Site'")?;
                    if site.text != "Site" {
                        return err(
                            site.line,
                            format!("expected 'End Site', found 'End {}'", site.text),
                        );
                    }
                    if joints[index].end_site.is_some() {
                        return err(
                            t.line,
                            format!("joint '{}' has two End Sites", joints[index].name),
                        );
                    }
                    let open = self.next("'{'")?;
                    if open.text != "{" {
                        return err(
                            open.line,
                            format!("expected '{{' after End Site, found '{}'", open.text),
                        );
                    }
                    let e = self.offset()?;
                    let close = self.next("'}'")?;
                    if close.text != "}" {
                        return err(
                            close.line,
                            format!("expected '}}' closing the End Site, found '{}'", close.text),
                        );
                    }
                    joints[index].end_site = Some(e);
                }
                "MOTION" => {
                    return err(
                        t.line,
                        format!("MOTION inside joint '{}': missing '}}'", joints[index].name),
                    );
                }
                other => {
                    return err(
                        t.line,
                        format!(
                            "unexpected '{other}' in joint '{}' (expected JOINT, End Site or '}}')",
                            joints[index].name
                        ),
                    );
                }
            }
        }
    }

    fn motion(
        &self,
        motion_line: usize,
        channel_count: usize,
    ) -> Result<(Vec<Vec<f64>>, f64), BvhError> {
        let mut lines = self
            .rest
            .iter()
            .filter(|(_, l)| !l.trim().is_empty())
            .copied();
        let Some((n, l)) = lines.next() else {
            return err(motion_line, "MOTION without 'Frames:'");
        };
        let Some(value) = l.trim().strip_prefix("Frames:") else {
            return err(n, format!("expected 'Frames: N', found '{}'", l.trim()));
        };
        let declared: usize = value.trim().parse().map_err(|_| BvhError {
            line: n,
            cause: format!("frame count '{}' is not a whole number", value.trim()),
        })?;
        let frames_line = n;
        let Some((n, l)) = lines.next() else {
            return err(frames_line, "'Frames:' without 'Frame Time:' after it");
        };
        let words: Vec<&str> = l.split_whitespace().collect();
        let dt_text = match words.as_slice() {
            ["Frame", "Time:", v] => *v,
            ["Frame", "Time:"] => return err(n, "'Frame Time:' without a value"),
            _ => {
                return err(
                    n,
                    format!("expected 'Frame Time: dt', found '{}'", l.trim()),
                );
            }
        };
        let frame_time = parse_number(dt_text, n, "the frame time")?;
        if frame_time <= 0.0 {
            return err(n, format!("frame time {frame_time} is not positive"));
        }
        let mut frames = Vec::with_capacity(declared);
        let mut last = n;
        for (n, l) in lines {
            last = n;
            if frames.len() == declared {
                return err(
                    n,
                    format!("more motion lines than the {declared} frames declared"),
                );
            }
            let mut row = Vec::with_capacity(channel_count);
            for w in l.split_whitespace() {
                row.push(parse_number(w, n, "a motion value")?);
            }
            if row.len() != channel_count {
                return err(
                    n,
                    format!(
                        "frame {} has {} values; the hierarchy has {channel_count} channels",
                        frames.len(),
                        row.len()
                    ),
                );
            }
            frames.push(row);
        }
        if frames.len() < declared {
            return err(
                last,
                format!(
                    "truncated motion: {declared} frames declared, {} present",
                    frames.len()
                ),
            );
        }
        Ok((frames, frame_time))
    }
}

fn parse_number(text: &str, line: usize, what: &str) -> Result<f64, BvhError> {
    let v: f64 = text.parse().map_err(|_| BvhError {
        line,
        cause: format!("'{text}' is not a number ({what})"),
    })?;
    if !v.is_finite() {
        return err(line, format!("{what} is {text}: not a finite number"));
    }
    Ok(v)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    const SMALL: &str = "HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Chest
\t{
\t\tOFFSET 0 10 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 5 0
\t\t}
\t}
\tJOINT Leg
\t{
\t\tOFFSET 5 -10 0
\t\tCHANNELS 3 Yrotation Xrotation Zrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -10 0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.0333333
1 90 2 0 0 0 0 0 0 0 0 0
0 90 0 90 0 0 0 0 0 0 0 90
";

    fn error_of(text: &str) -> BvhError {
        match Bvh::parse(text) {
            Ok(_) => panic!("parsed: {text}"),
            Err(e) => e,
        }
    }

    #[test]
    fn parses_hierarchy_and_motion() {
        let bvh = Bvh::parse(SMALL).unwrap();
        assert_eq!(bvh.joints.len(), 3);
        assert_eq!(bvh.joints[1].parent, Some(0));
        assert_eq!(bvh.joints[2].parent, Some(0));
        assert_eq!(bvh.joints[2].first_channel, 9);
        assert_eq!(bvh.joints[2].euler_order(), Some(EulerOrder::YXZ));
        assert_eq!(bvh.joints[0].euler_order(), Some(EulerOrder::ZXY));
        assert_eq!(bvh.frames.len(), 2);
        assert!((bvh.frame_time - 0.0333333).abs() < 1e-12);
        let rest = bvh.rest_positions();
        assert!((rest[2] - DVec3::new(5.0, -10.0, 0.0)).length() < 1e-12);
        // Frame 1: root yawed... Zrotation 90 at the root turns the chest's +y offset to −x.
        let pose = bvh.pose(&bvh.frames[1]);
        assert!((pose.positions[0] - DVec3::new(0.0, 90.0, 0.0)).length() < 1e-12);
        assert!((pose.positions[1] - DVec3::new(-10.0, 90.0, 0.0)).length() < 1e-9);
        // Leg: root Rz(90) then leg Rz(90): world rotation Rz(180).
        let w = pose.rotations[2];
        assert!((w * DVec3::X - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-12);
    }

    #[test]
    fn write_then_parse_is_identity() {
        let bvh = Bvh::parse(SMALL).unwrap();
        let text = bvh.write(6);
        let again = Bvh::parse(&text).unwrap();
        assert_eq!(bvh, again);
    }

    #[test]
    fn whitespace_tolerant() {
        let squeezed = SMALL
            .replace('\t', "   ")
            .replace("\n{", "{")
            .replace('\n', "\r\n");
        let bvh = Bvh::parse(&squeezed).unwrap();
        assert_eq!(bvh, Bvh::parse(SMALL).unwrap());
        let extra_blank = SMALL.replace("MOTION\n", "\n\nMOTION\n\n");
        assert_eq!(Bvh::parse(&extra_blank).unwrap().frames.len(), 2);
    }

    #[test]
    fn euler_orders_round_trip_including_gimbal_lock() {
        let angles = [
            [0.3, -0.7, 1.1],
            [-2.9, 1.2, 3.0],
            [0.1, std::f64::consts::FRAC_PI_2, 0.4],
            [0.5, -std::f64::consts::FRAC_PI_2, -0.2],
            [0.0, 0.0, 0.0],
            [3.1, 0.0, -3.1],
        ];
        for order in EulerOrder::ALL {
            for a in angles {
                let r = order.to_matrix(a);
                let back = order.from_matrix(r);
                let r2 = order.to_matrix(back);
                let diff = (r2 - r)
                    .to_cols_array()
                    .iter()
                    .fold(0.0f64, |m, v| m.max(v.abs()));
                assert!(diff < 1e-12, "{} {a:?} -> {back:?}: {diff}", order.name());
                assert!(back[1].abs() <= std::f64::consts::FRAC_PI_2 + 1e-12);
            }
        }
        // The order matters: ZXY and XYZ differ for the same angles.
        let a = [0.3, 0.5, 0.7];
        assert!(
            !(EulerOrder::ZXY.to_matrix(a) - EulerOrder::XYZ.to_matrix(a))
                .abs_diff_eq(DMat3::ZERO, 1e-3)
        );
        // R = R_Z R_X R_Y: a pure Z angle is the first factor.
        let r = EulerOrder::ZXY.to_matrix([0.4, 0.0, 0.0]);
        assert!((r - DMat3::from_rotation_z(0.4)).abs_diff_eq(DMat3::ZERO, 1e-15));
    }

    #[test]
    fn bad_channel_count() {
        let e = error_of(&SMALL.replace(
            "CHANNELS 3 Zrotation Xrotation Yrotation",
            "CHANNELS 4 Zrotation Xrotation Yrotation Xposition",
        ));
        assert_eq!(e.line, 9);
        assert!(e.cause.contains("4 channels"), "{e}");
        // Count says 3 but 2 are listed.
        let e = error_of(&SMALL.replace(
            "CHANNELS 3 Zrotation Xrotation Yrotation",
            "CHANNELS 3 Zrotation Xrotation",
        ));
        assert_eq!(e.line, 9);
        assert!(e.cause.contains("lists 2"), "{e}");
        // Count says 3 but 4 are listed.
        let e = error_of(&SMALL.replace(
            "CHANNELS 3 Zrotation Xrotation Yrotation",
            "CHANNELS 3 Zrotation Xrotation Yrotation Xposition",
        ));
        assert!(e.cause.contains("lists more"), "{e}");
        let e = error_of(&SMALL.replace("CHANNELS 3 Zrotation", "CHANNELS three Zrotation"));
        assert!(e.cause.contains("not a whole number"), "{e}");
        // Three position channels and no rotations.
        let e = error_of(&SMALL.replace(
            "CHANNELS 3 Zrotation Xrotation Yrotation",
            "CHANNELS 3 Xposition Yposition Zposition",
        ));
        assert!(e.cause.contains("three rotation channels"), "{e}");
    }

    #[test]
    fn unknown_and_repeated_channels() {
        let e = error_of(&SMALL.replace(
            "CHANNELS 3 Zrotation Xrotation Yrotation",
            "CHANNELS 3 Zrotation Wrotation Yrotation",
        ));
        assert_eq!(e.line, 9);
        assert!(e.cause.contains("unknown channel 'Wrotation'"), "{e}");
        let e = error_of(&SMALL.replace(
            "CHANNELS 3 Zrotation Xrotation Yrotation",
            "CHANNELS 3 Zrotation Zrotation Yrotation",
        ));
        assert!(e.cause.contains("repeated"), "{e}");
    }

    #[test]
    fn truncated_motion() {
        // One frame line missing.
        let text = SMALL.trim_end().rsplit_once('\n').unwrap().0.to_string();
        let e = error_of(&text);
        assert!(e.cause.contains("2 frames declared, 1 present"), "{e}");
        // A value missing in a frame.
        let e = error_of(&SMALL.replace("1 90 2 0 0 0 0 0 0 0 0 0", "1 90 2 0 0 0 0 0 0 0 0"));
        assert_eq!(e.line, 28);
        assert!(
            e.cause.contains("11 values") && e.cause.contains("12 channels"),
            "{e}"
        );
        // The file stops in the hierarchy.
        let cut: String = SMALL.lines().take(12).collect::<Vec<_>>().join("\n");
        let e = error_of(&cut);
        assert!(e.cause.contains("file ends"), "{e}");
        // No Frame Time.
        let e = error_of(&SMALL.replace("Frame Time: 0.0333333\n", ""));
        assert!(e.cause.contains("Frame Time"), "{e}");
        // More lines than frames.
        let e = error_of(&format!("{SMALL}0 0 0 0 0 0 0 0 0 0 0 0\n"));
        assert!(e.cause.contains("more motion lines"), "{e}");
    }

    #[test]
    fn nan_and_inf_are_refused() {
        let e = error_of(&SMALL.replace("1 90 2 0 0 0", "1 NaN 2 0 0 0"));
        assert_eq!(e.line, 28);
        assert!(e.cause.contains("not a finite number"), "{e}");
        let e = error_of(&SMALL.replace("OFFSET 5 -10 0", "OFFSET 5 inf 0"));
        assert_eq!(e.line, 17);
        assert!(e.cause.contains("not a finite number"), "{e}");
        let e = error_of(&SMALL.replace("Frame Time: 0.0333333", "Frame Time: nan"));
        assert!(e.cause.contains("not a finite number"), "{e}");
        let e = error_of(&SMALL.replace("1 90 2", "1 9O 2"));
        assert!(e.cause.contains("'9O' is not a number"), "{e}");
    }

    #[test]
    fn duplicate_joint_names() {
        let e = error_of(&SMALL.replace("JOINT Leg", "JOINT Chest"));
        assert_eq!(e.line, 15);
        assert!(e.cause.contains("duplicate joint name 'Chest'"), "{e}");
    }

    #[test]
    fn missing_braces() {
        // The root's closing brace is missing: MOTION arrives inside the root.
        let text = SMALL.replacen("\t}\n}\nMOTION", "\t}\nMOTION", 1);
        let e = error_of(&text);
        assert!(e.cause.contains("missing '}'"), "{e}");
        // A joint without its opening brace.
        let e = error_of(&SMALL.replacen("JOINT Chest\n\t{", "JOINT Chest", 1));
        assert!(e.cause.contains("expected '{'"), "{e}");
        // One '}' too many.
        let e = error_of(&SMALL.replace("}\nMOTION", "}\n}\nMOTION"));
        assert!(e.cause.contains("unmatched '}'"), "{e}");
        // End Site without braces.
        let e = error_of(&SMALL.replacen("End Site\n\t\t{", "End Site", 1));
        assert!(e.cause.contains("expected '{'"), "{e}");
    }

    #[test]
    fn other_malformed_headers() {
        assert!(error_of("").cause.contains("file ends"));
        let e = error_of(&SMALL.replace("HIERARCHY", "HIERARCHIE"));
        assert_eq!(e.line, 1);
        let e = error_of(&SMALL.replace("Frames: 2", "Frames: -2"));
        assert!(e.cause.contains("not a whole number"), "{e}");
        let e = error_of(&SMALL.replace("Frame Time: 0.0333333", "Frame Time: 0"));
        assert!(e.cause.contains("not positive"), "{e}");
        let e = error_of(&SMALL.replace("End Site", "End Sight"));
        assert!(e.cause.contains("End Site"), "{e}");
        let e = error_of(&SMALL.replace("ROOT Hips", "ROOT"));
        assert!(e.cause.contains("without a name"), "{e}");
    }
}
