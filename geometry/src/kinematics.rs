//! Standard Denavit-Hartenberg forward kinematics.
//!
//! Joint `i` contributes `Rz(theta) Tz(d) Tx(a) Rx(alpha)` with
//! `theta = q_i + theta_offset_i + joint_offset_i`; the end-effector (marker
//! centre) is `world_from_base * T_1 ... T_n * [tool, 1]`.

use nalgebra::{Isometry3, Matrix4, Point3, Vector3};

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

/// A serial arm: base placement, DH chain and tool (marker) offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Arm {
    /// Rigid transform from the arm base to the world (stereo) frame.
    pub world_from_base: Isometry3<f64>,
    /// The joints in order from the base.
    pub joints: Vec<DhJoint>,
    /// Marker centre in the last link's frame, mm.
    pub tool: Vector3<f64>,
}

impl Arm {
    /// Number of joints.
    pub fn dof(&self) -> usize {
        self.joints.len()
    }

    /// End-effector position in the world for joint angles `q` plus
    /// per-joint `offsets` (pass an empty slice for none).
    pub fn end_effector(&self, q: &[f64], offsets: &[f64]) -> Result<Vector3<f64>, GeometryError> {
        if q.len() != self.joints.len() {
            return Err(GeometryError::Degenerate(format!(
                "{} joint angles given for an arm with {} joints",
                q.len(),
                self.joints.len()
            )));
        }
        if !offsets.is_empty() && offsets.len() != self.joints.len() {
            return Err(GeometryError::Degenerate(format!(
                "{} joint offsets given for an arm with {} joints",
                offsets.len(),
                self.joints.len()
            )));
        }
        let mut t = self.world_from_base.to_homogeneous();
        for (i, joint) in self.joints.iter().enumerate() {
            let extra = offsets.get(i).copied().unwrap_or(0.0);
            t *= joint.transform(q[i] + joint.theta_offset + extra);
        }
        let p = t.transform_point(&Point3::from(self.tool)).coords;
        if p.iter().all(|v| v.is_finite()) {
            Ok(p)
        } else {
            Err(GeometryError::NonFinite("joint angles"))
        }
    }

    /// Whether every joint angle lies within its limits.
    pub fn within_limits(&self, q: &[f64]) -> bool {
        q.len() == self.joints.len()
            && self
                .joints
                .iter()
                .zip(q)
                .all(|(j, &v)| v >= j.min && v <= j.max)
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
        Arm {
            world_from_base: base,
            joints: vec![j(130.0), j(127.0)],
            tool: Vector3::zeros(),
        }
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
        let arm = Arm {
            world_from_base: Isometry3::identity(),
            joints: vec![joint],
            tool: Vector3::new(1.0, 2.0, 3.0),
        };
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
}
