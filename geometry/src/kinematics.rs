//! Forward kinematics of a serial arm, described either by standard
//! Denavit-Hartenberg parameters or by a general chain of joints as a
//! robot description (URDF) gives it.
//!
//! - DH: joint `i` contributes `Rz(theta) Tz(d) Tx(a) Rx(alpha)` with
//!   `theta = q_i + theta_offset_i + joint_offset_i`.
//! - Chain: joint `i` contributes `origin_i * motion_i(value)`, a rotation
//!   about (revolute) or a translation along (prismatic) its unit axis, then
//!   the fixed `tip` transform; fixed joints are folded into the origins.
//!
//! The end-effector (marker centre) is `world_from_base * T_1 ... T_n * [tool, 1]`.
//! Joint offsets are added to the joint values (`q + offset`) and follow a
//! joint into the joints that mimic it.

use nalgebra::{Isometry3, Matrix4, Point3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::GeometryError;

/// One joint's standard DH parameters and limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DhJoint {
    /// Link length along the new x axis, mm.
    pub a: f64,
    /// Link twist about the new x axis, rad.
    pub alpha: f64,
    /// Link offset along the previous z axis, mm.
    pub d: f64,
    /// Constant added to the joint angle, rad.
    pub theta_offset: f64,
    /// Lower joint limit, rad.
    pub min: f64,
    /// Upper joint limit, rad.
    pub max: f64,
}

impl DhJoint {
    /// The joint's homogeneous transform for `theta` (offsets already added).
    pub fn transform(&self, theta: f64) -> Matrix4<f64> {
        let (st, ct) = theta.sin_cos();
        let (sa, ca) = self.alpha.sin_cos();
        Matrix4::new(
            ct,
            -st * ca,
            st * sa,
            self.a * ct, //
            st,
            ct * ca,
            -ct * sa,
            self.a * st, //
            0.0,
            sa,
            ca,
            self.d, //
            0.0,
            0.0,
            0.0,
            1.0,
        )
    }
}

/// What moves at a chain joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// Rotation about the axis, radians.
    Revolute,
    /// Translation along the axis, mm.
    Prismatic,
}

/// Where a chain joint's value comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum JointValue {
    /// Its own entry of `q`.
    Own(usize),
    /// `multiplier * (q[of] + joint_offset[of]) + offset` (a URDF mimic joint).
    Mimic {
        /// The entry of `q` it follows.
        of: usize,
        /// Gain on the followed value.
        multiplier: f64,
        /// Added after the gain (rad or mm).
        offset: f64,
    },
}

/// One joint of a general chain.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainJoint {
    /// The joint's name in the robot description.
    pub name: String,
    /// Rotation or translation.
    pub kind: JointKind,
    /// Fixed transform from the previous joint's moving frame (or the base) to this joint's frame.
    pub origin: Isometry3<f64>,
    /// Unit axis in this joint's frame.
    pub axis: Unit<Vector3<f64>>,
    /// Where the value comes from.
    pub value: JointValue,
}

/// One entry of `q`: an independently driven joint.
#[derive(Debug, Clone, PartialEq)]
pub struct JointInfo {
    /// Its name.
    pub name: String,
    /// Rotation (rad) or translation (mm).
    pub kind: JointKind,
    /// Lower limit.
    pub min: f64,
    /// Upper limit.
    pub max: f64,
}

/// A general serial chain, base to tip.
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    /// The joints that move, base to tip.
    pub joints: Vec<ChainJoint>,
    /// Fixed transform from the last joint's moving frame to the tip link.
    pub tip: Isometry3<f64>,
    /// The entries of `q`, base to tip.
    pub inputs: Vec<JointInfo>,
    /// The robot description it was read from, if any.
    pub source: Option<ChainSource>,
}

/// Where a chain was read from: a URDF file and the links it spans.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainSource {
    /// The URDF file.
    pub urdf: String,
    /// The link the chain starts at.
    pub base_link: String,
    /// The link the chain ends at (the tool is in its frame).
    pub tip_link: String,
}

impl ChainJoint {
    /// The joint's transform for its value.
    pub fn transform(&self, value: f64) -> Isometry3<f64> {
        let motion = match self.kind {
            JointKind::Revolute => Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&self.axis, value),
            ),
            JointKind::Prismatic => Isometry3::from_parts(
                Translation3::from(self.axis.into_inner() * value),
                UnitQuaternion::identity(),
            ),
        };
        self.origin * motion
    }
}

impl Chain {
    /// Tip link in the base frame for `q` plus `offsets` (empty for none).
    pub fn base_from_tip(&self, q: &[f64], offsets: &[f64]) -> Isometry3<f64> {
        self.base_from_joints(q, offsets)
            .last()
            .copied()
            .unwrap_or_else(Isometry3::identity)
            * self.tip
    }

    /// Each joint's moving frame in the base frame, base to tip.
    fn base_from_joints(&self, q: &[f64], offsets: &[f64]) -> Vec<Isometry3<f64>> {
        let input = |i: usize| q[i] + offsets.get(i).copied().unwrap_or(0.0);
        let mut t = Isometry3::identity();
        self.joints
            .iter()
            .map(|j| {
                let value = match j.value {
                    JointValue::Own(i) => input(i),
                    JointValue::Mimic {
                        of,
                        multiplier,
                        offset,
                    } => multiplier * input(of) + offset,
                };
                t *= j.transform(value);
                t
            })
            .collect()
    }
}

/// How an arm's kinematics are described.
#[derive(Debug, Clone, PartialEq)]
pub enum ArmModel {
    /// A standard DH table, one row per joint.
    Dh(Vec<DhJoint>),
    /// A general chain, as from a URDF.
    Chain(Chain),
}

/// A serial arm: base placement, kinematic model and tool (marker) offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Arm {
    /// Rigid transform from the arm base to the world (stereo) frame.
    pub world_from_base: Isometry3<f64>,
    /// The kinematics from the base to the last link (tip).
    pub model: ArmModel,
    /// Marker centre in the last link's (tip's) frame, mm.
    pub tool: Vector3<f64>,
}

impl Arm {
    /// An arm described by a DH table.
    pub fn dh(world_from_base: Isometry3<f64>, joints: Vec<DhJoint>, tool: Vector3<f64>) -> Self {
        Self {
            world_from_base,
            model: ArmModel::Dh(joints),
            tool,
        }
    }

    /// Number of joint values `q` the arm takes.
    pub fn dof(&self) -> usize {
        match &self.model {
            ArmModel::Dh(joints) => joints.len(),
            ArmModel::Chain(c) => c.inputs.len(),
        }
    }

    /// Lower and upper limit of each entry of `q`.
    pub fn limits(&self) -> Vec<(f64, f64)> {
        match &self.model {
            ArmModel::Dh(joints) => joints.iter().map(|j| (j.min, j.max)).collect(),
            ArmModel::Chain(c) => c.inputs.iter().map(|j| (j.min, j.max)).collect(),
        }
    }

    /// The names of the entries of `q`: the description's joint names, or
    /// `joint1`, `joint2`, … for a DH table.
    pub fn joint_names(&self) -> Vec<String> {
        match &self.model {
            ArmModel::Dh(joints) => (1..=joints.len()).map(|i| format!("joint{i}")).collect(),
            ArmModel::Chain(c) => c.inputs.iter().map(|j| j.name.clone()).collect(),
        }
    }

    /// The kind of each entry of `q` (a DH table's joints are revolute).
    pub fn joint_kinds(&self) -> Vec<JointKind> {
        match &self.model {
            ArmModel::Dh(joints) => vec![JointKind::Revolute; joints.len()],
            ArmModel::Chain(c) => c.inputs.iter().map(|j| j.kind).collect(),
        }
    }

    fn check_lengths(&self, q: &[f64], offsets: &[f64]) -> Result<(), GeometryError> {
        let n = self.dof();
        if q.len() != n {
            return Err(GeometryError::Degenerate(format!(
                "{} joint values given for an arm with {n} joints",
                q.len()
            )));
        }
        if !offsets.is_empty() && offsets.len() != n {
            return Err(GeometryError::Degenerate(format!(
                "{} joint offsets given for an arm with {n} joints",
                offsets.len()
            )));
        }
        Ok(())
    }

    /// The tip link's frame in the world for `q` plus per-joint `offsets`
    /// (an empty slice for none), as a homogeneous matrix.
    pub fn world_from_tip(
        &self,
        q: &[f64],
        offsets: &[f64],
    ) -> Result<Matrix4<f64>, GeometryError> {
        self.check_lengths(q, offsets)?;
        let t = match &self.model {
            ArmModel::Dh(joints) => {
                let mut t = self.world_from_base.to_homogeneous();
                for (i, joint) in joints.iter().enumerate() {
                    let extra = offsets.get(i).copied().unwrap_or(0.0);
                    t *= joint.transform(q[i] + joint.theta_offset + extra);
                }
                t
            }
            ArmModel::Chain(c) => {
                (self.world_from_base * c.base_from_tip(q, offsets)).to_homogeneous()
            }
        };
        if t.iter().all(|v| v.is_finite()) {
            Ok(t)
        } else {
            Err(GeometryError::NonFinite("joint values"))
        }
    }

    /// End-effector position in the world for joint values `q` plus
    /// per-joint `offsets` (pass an empty slice for none).
    pub fn end_effector(&self, q: &[f64], offsets: &[f64]) -> Result<Vector3<f64>, GeometryError> {
        let t = self.world_from_tip(q, offsets)?;
        Ok(t.transform_point(&Point3::from(self.tool)).coords)
    }

    /// The points the arm's links run between, in the world: the base, each
    /// joint's frame after its motion (a point repeats where joints share an
    /// origin), the tip and the end-effector. For drawing the arm.
    pub fn skeleton(&self, q: &[f64], offsets: &[f64]) -> Result<Vec<Vector3<f64>>, GeometryError> {
        self.check_lengths(q, offsets)?;
        let origin = |t: &Matrix4<f64>| Vector3::new(t[(0, 3)], t[(1, 3)], t[(2, 3)]);
        let base = self.world_from_base.to_homogeneous();
        let mut points = vec![origin(&base)];
        match &self.model {
            ArmModel::Dh(joints) => {
                let mut t = base;
                for (i, joint) in joints.iter().enumerate() {
                    let extra = offsets.get(i).copied().unwrap_or(0.0);
                    t *= joint.transform(q[i] + joint.theta_offset + extra);
                    points.push(origin(&t));
                }
            }
            ArmModel::Chain(c) => {
                let frames = c.base_from_joints(q, offsets);
                points.extend(
                    frames
                        .iter()
                        .map(|t| (self.world_from_base * t).translation.vector),
                );
                let last = frames.last().copied().unwrap_or_else(Isometry3::identity);
                points.push((self.world_from_base * last * c.tip).translation.vector);
            }
        }
        points.push(self.end_effector(q, offsets)?);
        if points.iter().all(|p| p.iter().all(|v| v.is_finite())) {
            Ok(points)
        } else {
            Err(GeometryError::NonFinite("joint values"))
        }
    }

    /// Whether every joint value lies within its limits.
    pub fn within_limits(&self, q: &[f64]) -> bool {
        q.len() == self.dof()
            && self
                .limits()
                .iter()
                .zip(q)
                .all(|(&(min, max), &v)| v >= min && v <= max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use std::f64::consts::FRAC_PI_2;

    /// A planar two-link arm: the end-effector is known in closed form.
    fn planar_arm(base: Isometry3<f64>) -> Arm {
        let j = |a| DhJoint {
            a,
            alpha: 0.0,
            d: 0.0,
            theta_offset: 0.0,
            min: -3.0,
            max: 3.0,
        };
        Arm::dh(base, vec![j(130.0), j(127.0)], Vector3::zeros())
    }

    #[test]
    fn planar_two_link_matches_hand_computation() {
        let arm = planar_arm(Isometry3::identity());
        for &(q1, q2) in &[(0.0, 0.0), (0.3, -0.7), (1.2, 0.9), (-2.0, 2.5)] {
            let p = arm.end_effector(&[q1, q2], &[]).unwrap();
            let expect = Vector3::new(
                130.0 * f64::cos(q1) + 127.0 * f64::cos(q1 + q2),
                130.0 * f64::sin(q1) + 127.0 * f64::sin(q1 + q2),
                0.0,
            );
            assert!((p - expect).norm() < 1e-12, "{p} vs {expect}");
        }
    }

    #[test]
    fn the_skeleton_runs_from_the_base_through_the_joints_to_the_end_effector() {
        let mut arm = planar_arm(Isometry3::from_parts(
            Translation3::new(5.0, 0.0, 0.0),
            UnitQuaternion::identity(),
        ));
        arm.tool = Vector3::new(10.0, 0.0, 0.0);
        let (q1, q2) = (0.4, -0.9);
        let points = arm.skeleton(&[q1, q2], &[]).unwrap();
        let elbow = Vector3::new(5.0 + 130.0 * q1.cos(), 130.0 * q1.sin(), 0.0);
        assert_eq!(points.len(), 4);
        assert!((points[0] - Vector3::new(5.0, 0.0, 0.0)).norm() < 1e-12);
        assert!((points[1] - elbow).norm() < 1e-12, "{}", points[1]);
        let tip = elbow + 127.0 * Vector3::new((q1 + q2).cos(), (q1 + q2).sin(), 0.0);
        assert!((points[2] - tip).norm() < 1e-12);
        assert!((points[3] - arm.end_effector(&[q1, q2], &[]).unwrap()).norm() < 1e-12);
        assert!(arm.skeleton(&[0.0], &[]).is_err());
    }

    #[test]
    fn base_transform_tool_and_offsets_apply() {
        let base = Isometry3::from_parts(
            Translation3::new(100.0, 50.0, -20.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, FRAC_PI_2),
        );
        let mut arm = planar_arm(base);
        arm.tool = Vector3::new(10.0, 0.0, 5.0);
        // q = (0, 0) with offsets (0.2, 0): the same as q = (0.2, 0).
        let with_offsets = arm.end_effector(&[0.0, 0.0], &[0.2, 0.0]).unwrap();
        let plain = arm.end_effector(&[0.2, 0.0], &[]).unwrap();
        assert!((with_offsets - plain).norm() < 1e-12);
        // Hand computation: in the base, the stretched arm at angle 0.2 ends
        // at (267 cos, 267 sin, 5) with the tool's 10 mm along the link.
        let local = Vector3::new(267.0 * 0.2f64.cos(), 267.0 * 0.2f64.sin(), 5.0);
        // Base rotated +90 deg about z: (x, y, z) -> (-y, x, z), then translated.
        let expect = Vector3::new(100.0 - local.y, 50.0 + local.x, -20.0 + local.z);
        assert!((plain - expect).norm() < 1e-12, "{plain} vs {expect}");
    }

    #[test]
    fn spatial_dh_matches_rotation_composition() {
        // One joint with twist and offset: Rz(q) Tz(d) Tx(a) Rx(alpha) applied to the tool.
        let joint = DhJoint {
            a: 30.0,
            alpha: 0.4,
            d: 15.0,
            theta_offset: 0.1,
            min: -1.0,
            max: 1.0,
        };
        let arm = Arm::dh(
            Isometry3::identity(),
            vec![joint],
            Vector3::new(1.0, 2.0, 3.0),
        );
        let q = 0.5;
        let rz = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), q + 0.1);
        let rx = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 0.4);
        let expect = rz * (Vector3::new(0.0, 0.0, 15.0) + Vector3::new(30.0, 0.0, 0.0))
            + (rz * rx) * Vector3::new(1.0, 2.0, 3.0);
        // Rz(q) Tz(d) = Tz(d) Rz(q) since they share the axis.
        let got = arm.end_effector(&[q], &[]).unwrap();
        assert!((got - expect).norm() < 1e-12, "{got} vs {expect}");
    }

    #[test]
    fn wrong_joint_count_is_an_error() {
        let arm = planar_arm(Isometry3::identity());
        assert!(arm.end_effector(&[0.0], &[]).is_err());
        assert!(arm.end_effector(&[0.0, 0.0], &[0.0]).is_err());
        assert!(arm.end_effector(&[f64::NAN, 0.0], &[]).is_err());
    }

    /// The DH arm of `planar_arm` as a general chain: a joint about z, then
    /// `Tx(a)` into the next joint's frame.
    fn planar_chain(mimic: bool) -> Arm {
        let x = |a: f64| Isometry3::translation(a, 0.0, 0.0);
        let joint = |name: &str, origin, value| ChainJoint {
            name: name.into(),
            kind: JointKind::Revolute,
            origin,
            axis: Vector3::z_axis(),
            value,
        };
        let second = if mimic {
            JointValue::Mimic {
                of: 0,
                multiplier: 2.0,
                offset: 0.1,
            }
        } else {
            JointValue::Own(1)
        };
        let info = |name: &str| JointInfo {
            name: name.into(),
            kind: JointKind::Revolute,
            min: -3.0,
            max: 3.0,
        };
        let mut inputs = vec![info("shoulder"), info("elbow")];
        if mimic {
            inputs.pop();
        }
        Arm {
            world_from_base: Isometry3::identity(),
            model: ArmModel::Chain(Chain {
                joints: vec![
                    joint("shoulder", Isometry3::identity(), JointValue::Own(0)),
                    joint("elbow", x(130.0), second),
                ],
                tip: x(127.0),
                inputs,
                source: None,
            }),
            tool: Vector3::zeros(),
        }
    }

    #[test]
    fn a_chain_equals_the_dh_table_it_describes() {
        let dh = planar_arm(Isometry3::identity());
        let chain = planar_chain(false);
        assert_eq!(chain.dof(), 2);
        assert_eq!(chain.joint_names(), ["shoulder", "elbow"]);
        for &(q1, q2) in &[(0.0, 0.0), (0.3, -0.7), (1.2, 0.9)] {
            let a = dh.end_effector(&[q1, q2], &[0.05, -0.02]).unwrap();
            let b = chain.end_effector(&[q1, q2], &[0.05, -0.02]).unwrap();
            assert!((a - b).norm() < 1e-12, "{a} vs {b}");
        }
    }

    #[test]
    fn a_mimic_joint_follows_its_input_and_its_offset() {
        let dh = planar_arm(Isometry3::identity());
        let mimic = planar_chain(true);
        assert_eq!(mimic.dof(), 1);
        for q in [0.0, 0.4, -1.1] {
            // The elbow is 2 (q + offset) + 0.1.
            let a = dh
                .end_effector(&[q + 0.2, 2.0 * (q + 0.2) + 0.1], &[])
                .unwrap();
            let b = mimic.end_effector(&[q], &[0.2]).unwrap();
            assert!((a - b).norm() < 1e-12, "{a} vs {b}");
        }
    }

    #[test]
    fn a_prismatic_joint_translates_along_its_axis() {
        let mut arm = planar_chain(false);
        let ArmModel::Chain(c) = &mut arm.model else {
            unreachable!()
        };
        c.joints[1].kind = JointKind::Prismatic;
        c.joints[1].axis = Unit::new_normalize(Vector3::new(1.0, 1.0, 0.0));
        let p = arm.end_effector(&[0.0, 10.0], &[]).unwrap();
        let s = 10.0 / 2f64.sqrt();
        assert!((p - Vector3::new(257.0 + s, s, 0.0)).norm() < 1e-12, "{p}");
    }
}
