//! Rig types: joints in topological order, per-vertex skinning weights, named markers.
//!
//! The JSON form is the one of SPEC §3:
//! `{"joints": [{"name", "parent", "rest_position"}], "weights": [[[joint, w], ...]], "markers": [{"name", "vertex"}]}`.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};

/// Most influences a model-file vertex may have (the JSON rig allows 4).
pub const MAX_FILE_INFLUENCES: usize = 64;

/// Index of a joint in [`Rig::joints`].
pub type JointIndex = usize;

/// Most influences a vertex may have.
pub const MAX_INFLUENCES: usize = 4;

/// Tolerance on the sum of a vertex's weights (SPEC §3: weights sum to 1).
pub const WEIGHT_SUM_TOLERANCE: f64 = 1e-4;

/// One joint of the skeleton.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Joint {
    pub name: String,
    /// Parent joint; `None` only for the root, which must be joint 0.
    pub parent: Option<JointIndex>,
    /// Position of the joint centre in the rest pose, metres.
    pub rest_position: [f64; 3],
}

impl Joint {
    pub fn rest(&self) -> DVec3 {
        DVec3::from_array(self.rest_position)
    }
}

/// A named marker attached to a template vertex.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Marker {
    pub name: String,
    pub vertex: u32,
}

/// Skeleton, skinning weights and markers of a template.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rig {
    pub joints: Vec<Joint>,
    /// One list of `(joint, weight)` pairs per vertex, at most [`MAX_INFLUENCES`] each.
    pub weights: Vec<Vec<(JointIndex, f64)>>,
    pub markers: Vec<Marker>,
}

impl Rig {
    pub fn num_joints(&self) -> usize {
        self.joints.len()
    }

    /// Index of the joint called `name`.
    pub fn joint_index(&self, name: &str) -> Option<JointIndex> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Children of every joint.
    pub fn children(&self) -> Vec<Vec<JointIndex>> {
        let mut children = vec![Vec::new(); self.joints.len()];
        for (j, joint) in self.joints.iter().enumerate() {
            if let Some(p) = joint.parent {
                children[p].push(j);
            }
        }
        children
    }

    /// Checks SPEC §3's rules against a mesh of `num_vertices` vertices: joints in topological order
    /// with one root first, finite rest positions, unique names, weights non-negative, finite,
    /// in range and summing to 1 ± [`WEIGHT_SUM_TOLERANCE`], markers on existing vertices.
    pub fn validate(&self, num_vertices: usize) -> Result<()> {
        self.validate_with(num_vertices, MAX_INFLUENCES)
    }

    /// [`Rig::validate`] with another cap on influences per vertex (model files may have more).
    pub fn validate_with(&self, num_vertices: usize, max_influences: usize) -> Result<()> {
        if self.joints.is_empty() {
            return Err(ModelError::Joint {
                index: 0,
                name: String::new(),
                reason: "the rig has no joints".into(),
            });
        }
        for (index, joint) in self.joints.iter().enumerate() {
            let fail = |reason: String| ModelError::Joint {
                index,
                name: joint.name.clone(),
                reason,
            };
            if joint.name.is_empty() {
                return Err(fail("empty name".into()));
            }
            if self.joints[..index].iter().any(|j| j.name == joint.name) {
                return Err(fail("duplicate name".into()));
            }
            if let Some(axis) = joint.rest_position.iter().position(|v| !v.is_finite()) {
                return Err(fail(format!("rest_position[{axis}] is not finite")));
            }
            match (index, joint.parent) {
                (0, None) => {}
                (0, Some(p)) => {
                    return Err(fail(format!(
                        "the first joint must be the root, but it has parent {p}"
                    )));
                }
                (_, None) => return Err(fail("only the first joint may have no parent".into())),
                (_, Some(p)) if p == index => return Err(fail("is its own parent (cycle)".into())),
                (_, Some(p)) if p > index => {
                    return Err(fail(format!(
                        "parent {p} comes after it: joints must be in topological order (a cycle or a misordered list)"
                    )));
                }
                _ => {}
            }
        }
        if self.weights.len() != num_vertices {
            return Err(ModelError::Weights {
                vertex: self.weights.len().min(num_vertices),
                reason: format!(
                    "the rig has {} weight lists but the mesh has {num_vertices} vertices",
                    self.weights.len()
                ),
            });
        }
        for (vertex, list) in self.weights.iter().enumerate() {
            let fail = |reason: String| ModelError::Weights { vertex, reason };
            if list.is_empty() {
                return Err(fail("no influences".into()));
            }
            if list.len() > max_influences {
                return Err(fail(format!(
                    "{} influences, at most {max_influences} allowed",
                    list.len()
                )));
            }
            let mut sum = 0.0;
            for &(joint, w) in list {
                if joint >= self.joints.len() {
                    return Err(fail(format!(
                        "joint index {joint} out of range (the rig has {} joints)",
                        self.joints.len()
                    )));
                }
                if !w.is_finite() {
                    return Err(fail(format!("weight for joint {joint} is not finite")));
                }
                if w < 0.0 {
                    return Err(fail(format!("negative weight {w} for joint {joint}")));
                }
                sum += w;
            }
            if (sum - 1.0).abs() > WEIGHT_SUM_TOLERANCE {
                return Err(fail(format!(
                    "weights sum to {sum}, not 1 ± {WEIGHT_SUM_TOLERANCE}"
                )));
            }
        }
        for (i, marker) in self.markers.iter().enumerate() {
            if marker.vertex as usize >= num_vertices {
                return Err(ModelError::Marker {
                    name: marker.name.clone(),
                    reason: format!(
                        "vertex {} out of range (the mesh has {num_vertices} vertices)",
                        marker.vertex
                    ),
                });
            }
            if self.markers[..i].iter().any(|m| m.name == marker.name) {
                return Err(ModelError::Marker {
                    name: marker.name.clone(),
                    reason: "duplicate name".into(),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_joint_rig() -> Rig {
        Rig {
            joints: vec![
                Joint {
                    name: "root".into(),
                    parent: None,
                    rest_position: [0.0, 1.0, 0.0],
                },
                Joint {
                    name: "child".into(),
                    parent: Some(0),
                    rest_position: [0.0, 0.5, 0.0],
                },
            ],
            weights: vec![vec![(0, 1.0)], vec![(0, 0.25), (1, 0.75)]],
            markers: vec![Marker {
                name: "m".into(),
                vertex: 1,
            }],
        }
    }

    #[test]
    fn valid_rig_passes() {
        assert!(two_joint_rig().validate(2).is_ok());
    }

    #[test]
    fn cycle_and_order_are_named() {
        let mut rig = two_joint_rig();
        rig.joints[1].parent = Some(1);
        let e = rig.validate(2).unwrap_err().to_string();
        assert!(e.contains("child") && e.contains("cycle"), "{e}");
        let mut rig = two_joint_rig();
        rig.joints.push(Joint {
            name: "x".into(),
            parent: Some(3),
            rest_position: [0.0; 3],
        });
        rig.joints.push(Joint {
            name: "y".into(),
            parent: Some(2),
            rest_position: [0.0; 3],
        });
        let e = rig.validate(2).unwrap_err().to_string();
        assert!(e.contains("'x'") && e.contains("topological"), "{e}");
    }

    #[test]
    fn bad_weights_name_the_vertex() {
        let mut rig = two_joint_rig();
        rig.weights[1] = vec![(0, 0.5), (1, 0.6)];
        let e = rig.validate(2).unwrap_err().to_string();
        assert!(e.contains("vertex 1") && e.contains("sum"), "{e}");
        rig.weights[1] = vec![(0, 1.5), (1, -0.5)];
        assert!(
            rig.validate(2)
                .unwrap_err()
                .to_string()
                .contains("negative")
        );
        rig.weights[1] = vec![(7, 1.0)];
        assert!(
            rig.validate(2)
                .unwrap_err()
                .to_string()
                .contains("out of range")
        );
        rig.weights[1] = vec![(0, f64::NAN)];
        assert!(
            rig.validate(2)
                .unwrap_err()
                .to_string()
                .contains("not finite")
        );
    }

    #[test]
    fn nan_rest_position_and_bad_marker() {
        let mut rig = two_joint_rig();
        rig.joints[1].rest_position[2] = f64::NAN;
        assert!(
            rig.validate(2)
                .unwrap_err()
                .to_string()
                .contains("rest_position[2]")
        );
        let mut rig = two_joint_rig();
        rig.markers[0].vertex = 9;
        assert!(
            rig.validate(2)
                .unwrap_err()
                .to_string()
                .contains("marker 'm'")
        );
    }
}
