//! The parameter layout of a model (SPEC §3a): named blocks of one flat vector,
//!
//! ```text
//! [ translation (3) | rotations (3 per joint, axis-angle relative to the parent) | shape β (B) | expression ψ (E) ]
//! ```
//!
//! Every entry has a name: `t_x`, `l_knee.rx`, `shape.3`, `expression.0`. On the default
//! template (18 joints, no shape or expression) this is the 57-number pose vector of SPEC §3.

use serde::{Deserialize, Serialize};

/// Index of the first number of joint `j`'s rotation in the pose vector.
pub const fn rot_offset(j: usize) -> usize {
    3 + 3 * j
}

/// A block of the parameter vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Block {
    Translation,
    Rotations,
    Shape,
    Expression,
}

impl Block {
    pub fn name(self) -> &'static str {
        match self {
            Block::Translation => "translation",
            Block::Rotations => "rotations",
            Block::Shape => "shape",
            Block::Expression => "expression",
        }
    }
}

/// Names of the joints, and the sizes of the shape and expression blocks.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Layout {
    pub joints: Vec<String>,
    pub shape: usize,
    pub expression: usize,
}

const AXES: [&str; 3] = ["x", "y", "z"];

impl Layout {
    pub fn num_joints(&self) -> usize {
        self.joints.len()
    }

    /// Length of the pose part (translation + rotations): `3 + 3J`.
    pub fn pose_dim(&self) -> usize {
        3 + 3 * self.joints.len()
    }

    /// Length of the whole vector: `3 + 3J + B + E`.
    pub fn dim(&self) -> usize {
        self.pose_dim() + self.shape + self.expression
    }

    /// Index of the first number of joint `j`'s rotation.
    pub fn rotation_offset(&self, j: usize) -> usize {
        rot_offset(j)
    }

    /// Index of β₀.
    pub fn shape_offset(&self) -> usize {
        self.pose_dim()
    }

    /// Index of ψ₀.
    pub fn expression_offset(&self) -> usize {
        self.pose_dim() + self.shape
    }

    /// The index range of a block.
    pub fn range(&self, block: Block) -> std::ops::Range<usize> {
        match block {
            Block::Translation => 0..3,
            Block::Rotations => 3..self.pose_dim(),
            Block::Shape => self.shape_offset()..self.expression_offset(),
            Block::Expression => self.expression_offset()..self.dim(),
        }
    }

    /// The block entry `i` belongs to.
    pub fn block_of(&self, i: usize) -> Option<Block> {
        [
            Block::Translation,
            Block::Rotations,
            Block::Shape,
            Block::Expression,
        ]
        .into_iter()
        .find(|&b| self.range(b).contains(&i))
    }

    /// The joint whose rotation entry `i` is, with its axis (0 = x, 1 = y, 2 = z).
    pub fn rotation_of(&self, i: usize) -> Option<(usize, usize)> {
        (i >= 3 && i < self.pose_dim()).then(|| ((i - 3) / 3, (i - 3) % 3))
    }

    /// Name of entry `i`: `t_x`, `l_knee.rx`, `shape.3`, `expression.0`.
    pub fn name(&self, i: usize) -> String {
        match self.block_of(i) {
            Some(Block::Translation) => format!("t_{}", AXES[i]),
            Some(Block::Rotations) => {
                format!("{}.r{}", self.joints[(i - 3) / 3], AXES[(i - 3) % 3])
            }
            Some(Block::Shape) => format!("shape.{}", i - self.shape_offset()),
            Some(Block::Expression) => format!("expression.{}", i - self.expression_offset()),
            None => format!("#{i}"),
        }
    }

    /// All entry names, in order.
    pub fn names(&self) -> Vec<String> {
        (0..self.dim()).map(|i| self.name(i)).collect()
    }

    /// Index of the entry called `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        if let Some(axis) = name.strip_prefix("t_") {
            return AXES.iter().position(|a| *a == axis);
        }
        if let Some(k) = name.strip_prefix("shape.") {
            return k
                .parse::<usize>()
                .ok()
                .filter(|&k| k < self.shape)
                .map(|k| self.shape_offset() + k);
        }
        if let Some(k) = name.strip_prefix("expression.") {
            return k
                .parse::<usize>()
                .ok()
                .filter(|&k| k < self.expression)
                .map(|k| self.expression_offset() + k);
        }
        let (joint, axis) = name.rsplit_once(".r")?;
        let a = AXES.iter().position(|x| *x == axis)?;
        let j = self.joints.iter().position(|n| n == joint)?;
        Some(self.rotation_offset(j) + a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> Layout {
        Layout {
            joints: vec!["pelvis".into(), "l_knee".into()],
            shape: 2,
            expression: 1,
        }
    }

    #[test]
    fn blocks_and_names_round_trip() {
        let l = layout();
        assert_eq!(l.dim(), 3 + 6 + 2 + 1);
        assert_eq!(l.range(Block::Shape), 9..11);
        assert_eq!(l.range(Block::Expression), 11..12);
        let names = l.names();
        assert_eq!(
            names,
            [
                "t_x",
                "t_y",
                "t_z",
                "pelvis.rx",
                "pelvis.ry",
                "pelvis.rz",
                "l_knee.rx",
                "l_knee.ry",
                "l_knee.rz",
                "shape.0",
                "shape.1",
                "expression.0"
            ]
        );
        for (i, n) in names.iter().enumerate() {
            assert_eq!(l.index_of(n), Some(i), "{n}");
        }
        assert_eq!(l.index_of("shape.2"), None);
        assert_eq!(l.index_of("hip.rx"), None);
        assert_eq!(l.rotation_of(7), Some((1, 1)));
        assert_eq!(l.block_of(11), Some(Block::Expression));
        assert_eq!(l.block_of(12), None);
    }
}
