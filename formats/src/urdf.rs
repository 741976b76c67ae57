//! Robot descriptions in URDF: the serial chain from a base link to a tip
//! link, in millimetres, as a [`geometry::Chain`].
//!
//! Follows the URDF specification as vendors' files use it:
//!
//! - a missing `<origin>`, `xyz` or `rpy` is zero; a missing `<axis>` is
//!   `1 0 0`; `rpy` is roll about x, pitch about y, yaw about z, in fixed axes;
//! - revolute, continuous and prismatic joints move; fixed joints are folded
//!   into the next joint's origin (or the tip); floating and planar joints on
//!   the chain are refused;
//! - links above `base_link` and side branches are ignored;
//! - a `<mimic>` joint on the chain follows the joint it names: the chain's
//!   input is that joint, wherever it is in the tree;
//! - limits come from `<limit lower upper>` (continuous joints: ±π);
//! - meshes, inertials, transmissions, gazebo tags and everything else are
//!   ignored.
//!
//! [`corrected`] folds estimated joint offsets into the joints' origins and
//! returns the file's text otherwise unchanged.

use std::collections::HashMap;
use std::path::Path;

use geometry::{Chain, ChainJoint, ChainSource, JointInfo, JointKind, JointValue};
use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use roxmltree::{Document, Node};

use crate::{FormatError, read_text};

/// URDF lengths are metres; ours are millimetres.
const MM_PER_M: f64 = 1000.0;

/// Our units per URDF unit of a joint's value: mm per m for a prismatic
/// joint, 1 for a revolute one (radians either way).
fn value_scale(kind: JointKind) -> f64 {
    match kind {
        JointKind::Prismatic => MM_PER_M,
        JointKind::Revolute => 1.0,
    }
}

/// Reads the chain from `base_link` to `tip_link` of the URDF at `path`.
pub fn read(path: impl AsRef<Path>, base_link: &str, tip_link: &str) -> Result<Chain, FormatError> {
    let path = path.as_ref();
    parse(path, &read_text(path)?, base_link, tip_link)
}

/// One `<joint>` as the file gives it (lengths still in metres).
struct UrdfJoint<'a, 'input> {
    node: Node<'a, 'input>,
    name: &'a str,
    kind: &'a str,
    parent: &'a str,
    child: &'a str,
    xyz: Vector3<f64>,
    rpy: Vector3<f64>,
    axis: Vector3<f64>,
    limit: Option<(f64, f64)>,
    mimic: Option<(&'a str, f64, f64)>,
}

impl UrdfJoint<'_, '_> {
    fn origin_m(&self) -> Isometry3<f64> {
        origin(self.xyz, self.rpy)
    }
}

fn origin(xyz: Vector3<f64>, rpy: Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(xyz),
        UnitQuaternion::from_euler_angles(rpy.x, rpy.y, rpy.z),
    )
}

/// An isometry with its translation converted from metres to millimetres.
fn to_mm(t: Isometry3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(t.translation.vector * MM_PER_M),
        t.rotation,
    )
}

struct Parser<'d, 'input> {
    path: &'d Path,
    doc: &'d Document<'input>,
}

impl<'d, 'input> Parser<'d, 'input> {
    fn error(&self, node: Node<'_, '_>, message: impl Into<String>) -> FormatError {
        let at = self.doc.text_pos_at(node.range().start);
        FormatError::new(self.path, Some(format!("line {}", at.row)), message)
    }

    fn vector(
        &self,
        node: Node<'_, '_>,
        attr: &str,
        default: Vector3<f64>,
    ) -> Result<Vector3<f64>, FormatError> {
        let Some(text) = node.attribute(attr) else {
            return Ok(default);
        };
        let v: Vec<f64> = text
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()
            .map_err(|_| self.error(node, format!("{attr}=\"{text}\" is not three numbers")))?;
        if v.len() != 3 || !v.iter().all(|x| x.is_finite()) {
            return Err(self.error(
                node,
                format!("{attr}=\"{text}\" is not three finite numbers"),
            ));
        }
        Ok(Vector3::new(v[0], v[1], v[2]))
    }

    fn number(&self, node: Node<'_, '_>, attr: &str, default: f64) -> Result<f64, FormatError> {
        match node.attribute(attr) {
            None => Ok(default),
            Some(text) => text
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    self.error(node, format!("{attr}=\"{text}\" is not a finite number"))
                }),
        }
    }

    fn link_of(
        &self,
        node: Node<'d, 'input>,
        tag: &str,
        joint: &str,
    ) -> Result<&'d str, FormatError> {
        node.children()
            .find(|c| c.has_tag_name(tag))
            .and_then(|c| c.attribute("link"))
            .ok_or_else(|| self.error(node, format!("joint {joint:?} has no <{tag} link=\"…\"/>")))
    }

    fn joint(&self, node: Node<'d, 'input>) -> Result<UrdfJoint<'d, 'input>, FormatError> {
        let name = node
            .attribute("name")
            .ok_or_else(|| self.error(node, "a <joint> has no name"))?;
        let kind = node
            .attribute("type")
            .ok_or_else(|| self.error(node, format!("joint {name:?} has no type")))?;
        let child = |tag: &str| node.children().find(|c| c.has_tag_name(tag));
        let (xyz, rpy) = match child("origin") {
            Some(o) => (
                self.vector(o, "xyz", Vector3::zeros())?,
                self.vector(o, "rpy", Vector3::zeros())?,
            ),
            None => (Vector3::zeros(), Vector3::zeros()),
        };
        let axis = match child("axis") {
            Some(a) => self.vector(a, "xyz", Vector3::x())?,
            None => Vector3::x(),
        };
        let limit = child("limit")
            .map(|l| {
                Ok::<_, FormatError>((self.number(l, "lower", 0.0)?, self.number(l, "upper", 0.0)?))
            })
            .transpose()?;
        let mimic = child("mimic")
            .map(|m| {
                let of = m.attribute("joint").ok_or_else(|| {
                    self.error(m, format!("joint {name:?}: <mimic> names no joint"))
                })?;
                Ok::<_, FormatError>((
                    of,
                    self.number(m, "multiplier", 1.0)?,
                    self.number(m, "offset", 0.0)?,
                ))
            })
            .transpose()?;
        Ok(UrdfJoint {
            node,
            name,
            kind,
            parent: self.link_of(node, "parent", name)?,
            child: self.link_of(node, "child", name)?,
            xyz,
            rpy,
            axis,
            limit,
            mimic,
        })
    }
}

/// The joints of the chain from `base_link` to `tip_link`, base first.
fn chain_joints<'j, 'a, 'input>(
    parser: &Parser<'_, '_>,
    root: Node<'_, '_>,
    joints: &'j [UrdfJoint<'a, 'input>],
    base_link: &str,
    tip_link: &str,
) -> Result<Vec<&'j UrdfJoint<'a, 'input>>, FormatError> {
    let links: Vec<&str> = root
        .children()
        .filter(|c| c.has_tag_name("link"))
        .filter_map(|c| c.attribute("name"))
        .collect();
    for link in [base_link, tip_link] {
        if !links.contains(&link) {
            return Err(parser.error(root, format!("no link named {link:?}")));
        }
    }
    let mut by_child: HashMap<&str, &UrdfJoint<'a, 'input>> = HashMap::new();
    for j in joints {
        if by_child.insert(j.child, j).is_some() {
            return Err(parser.error(
                j.node,
                format!("link {:?} is the child of two joints", j.child),
            ));
        }
    }
    let mut chain = Vec::new();
    let mut link = tip_link;
    while link != base_link {
        let Some(j) = by_child.get(link) else {
            return Err(parser.error(
                root,
                format!("link {tip_link:?} is not below {base_link:?}: the chain up from it ends at {link:?}"),
            ));
        };
        if chain.len() > joints.len() {
            return Err(parser.error(j.node, "the joints form a loop"));
        }
        chain.push(*j);
        link = j.parent;
    }
    chain.reverse();
    Ok(chain)
}

/// Parses URDF text; `path` is only used in error messages.
pub fn parse(
    path: &Path,
    text: &str,
    base_link: &str,
    tip_link: &str,
) -> Result<Chain, FormatError> {
    let doc = Document::parse(text).map_err(|e| {
        FormatError::new(path, Some(format!("line {}", e.pos().row)), e.to_string())
    })?;
    let parser = Parser { path, doc: &doc };
    let root = doc.root_element();
    if !root.has_tag_name("robot") {
        return Err(parser.error(
            root,
            format!(
                "the root element is <{}>, not <robot>",
                root.tag_name().name()
            ),
        ));
    }
    let joints: Vec<UrdfJoint<'_, '_>> = root
        .children()
        .filter(|c| c.has_tag_name("joint"))
        .map(|n| parser.joint(n))
        .collect::<Result<_, _>>()?;
    let on_chain = chain_joints(&parser, root, &joints, base_link, tip_link)?;

    // The chain's inputs: its own movable joints, and for each mimic joint
    // the joint it follows, in the order they are first met from the base.
    let mut inputs: Vec<JointInfo> = Vec::new();
    let mut input_of =
        |parser: &Parser<'_, '_>, j: &UrdfJoint<'_, '_>| -> Result<usize, FormatError> {
            if let Some(i) = inputs.iter().position(|x| x.name == j.name) {
                return Ok(i);
            }
            let kind = kind_of(parser, j)?.ok_or_else(|| {
                parser.error(
                    j.node,
                    format!("joint {:?} is fixed and cannot drive a mimic joint", j.name),
                )
            })?;
            let (min, max) = match (j.kind, j.limit) {
                ("continuous", _) => (-std::f64::consts::PI, std::f64::consts::PI),
                (_, Some((lo, hi))) if lo <= hi => (lo, hi),
                (_, Some(_)) => {
                    return Err(parser.error(
                        j.node,
                        format!("joint {:?}: limit lower is above upper", j.name),
                    ));
                }
                (_, None) => {
                    return Err(parser.error(
                        j.node,
                        format!("joint {:?} ({}) has no <limit>", j.name, j.kind),
                    ));
                }
            };
            let scale = value_scale(kind);
            inputs.push(JointInfo {
                name: j.name.to_string(),
                kind,
                min: min * scale,
                max: max * scale,
            });
            Ok(inputs.len() - 1)
        };

    let mut chain_out = Vec::new();
    let mut fixed = Isometry3::identity();
    for j in on_chain {
        let Some(kind) = kind_of(&parser, j)? else {
            fixed *= to_mm(j.origin_m());
            continue;
        };
        let value = match j.mimic {
            None => JointValue::Own(input_of(&parser, j)?),
            Some((of, multiplier, offset)) => {
                let master = joints.iter().find(|m| m.name == of).ok_or_else(|| {
                    parser.error(
                        j.node,
                        format!("joint {:?} mimics {of:?}, which does not exist", j.name),
                    )
                })?;
                if master.mimic.is_some() {
                    return Err(parser.error(
                        j.node,
                        format!("joint {:?} mimics {of:?}, itself a mimic joint", j.name),
                    ));
                }
                let scale = value_scale(kind);
                let master_scale = kind_of(&parser, master)?.map_or(1.0, value_scale);
                JointValue::Mimic {
                    of: input_of(&parser, master)?,
                    multiplier: multiplier * scale / master_scale,
                    offset: offset * scale,
                }
            }
        };
        let axis = Unit::try_new(j.axis, 1e-9)
            .ok_or_else(|| parser.error(j.node, format!("joint {:?} has a zero axis", j.name)))?;
        chain_out.push(ChainJoint {
            name: j.name.to_string(),
            kind,
            origin: fixed * to_mm(j.origin_m()),
            axis,
            value,
        });
        fixed = Isometry3::identity();
    }
    if inputs.is_empty() {
        return Err(parser.error(
            root,
            format!("no movable joint between {base_link:?} and {tip_link:?}"),
        ));
    }
    Ok(Chain {
        joints: chain_out,
        tip: fixed,
        inputs,
        source: Some(ChainSource {
            urdf: path.display().to_string(),
            base_link: base_link.to_string(),
            tip_link: tip_link.to_string(),
        }),
    })
}

/// The joint's motion, `None` for a fixed joint.
fn kind_of(
    parser: &Parser<'_, '_>,
    j: &UrdfJoint<'_, '_>,
) -> Result<Option<JointKind>, FormatError> {
    match j.kind {
        "revolute" | "continuous" => Ok(Some(JointKind::Revolute)),
        "prismatic" => Ok(Some(JointKind::Prismatic)),
        "fixed" => Ok(None),
        other => Err(parser.error(
            j.node,
            format!("joint {:?} is {other}; a chain can hold revolute, continuous, prismatic and fixed joints", j.name),
        )),
    }
}

/// The URDF's text with `offsets` (one per input of the chain from
/// `base_link` to `tip_link`, rad or mm) folded into the origins of the
/// chain's joints, so that the new file at `q` gives what the old one gave
/// at `q + offsets`. Everything else in the file is kept as it was.
pub fn corrected(
    path: &Path,
    text: &str,
    base_link: &str,
    tip_link: &str,
    offsets: &[f64],
) -> Result<String, FormatError> {
    let chain = parse(path, text, base_link, tip_link)?;
    if offsets.len() != chain.inputs.len() {
        return Err(FormatError::new(
            path,
            None,
            format!(
                "{} joint offsets for a chain of {} joints",
                offsets.len(),
                chain.inputs.len()
            ),
        ));
    }
    let doc = Document::parse(text).map_err(|e| FormatError::new(path, None, e.to_string()))?;
    let parser = Parser { path, doc: &doc };
    let joints: Vec<UrdfJoint<'_, '_>> = doc
        .root_element()
        .children()
        .filter(|c| c.has_tag_name("joint"))
        .map(|n| parser.joint(n))
        .collect::<Result<_, _>>()?;
    // Edits as (byte range to replace, new text), applied back to front.
    let mut edits: Vec<(std::ops::Range<usize>, String)> = Vec::new();
    for cj in &chain.joints {
        let shift = match cj.value {
            JointValue::Own(i) => offsets[i],
            JointValue::Mimic { of, multiplier, .. } => multiplier * offsets[of],
        };
        if shift == 0.0 {
            continue;
        }
        let j = joints
            .iter()
            .find(|j| j.name == cj.name)
            .expect("the chain's joints are in the file");
        let (xyz, rpy) = match cj.kind {
            JointKind::Revolute => {
                let r = j.origin_m().rotation * UnitQuaternion::from_axis_angle(&cj.axis, shift);
                let (roll, pitch, yaw) = r.euler_angles();
                (j.xyz, Vector3::new(roll, pitch, yaw))
            }
            JointKind::Prismatic => (
                j.xyz + j.origin_m().rotation * (cj.axis.into_inner() * shift / MM_PER_M),
                j.rpy,
            ),
        };
        let tag = format!(
            "<origin xyz=\"{:?} {:?} {:?}\" rpy=\"{:?} {:?} {:?}\"/>",
            xyz.x, xyz.y, xyz.z, rpy.x, rpy.y, rpy.z
        );
        match j.node.children().find(|c| c.has_tag_name("origin")) {
            Some(o) => edits.push((o.range(), tag)),
            None => {
                let parent = j
                    .node
                    .children()
                    .find(|c| c.has_tag_name("parent"))
                    .expect("checked on parse");
                let at = parent.range().start;
                edits.push((at..at, format!("{tag}\n    ")));
            }
        }
    }
    edits.sort_by_key(|(r, _)| std::cmp::Reverse(r.start));
    let mut out = text.to_string();
    for (range, new) in edits {
        out.replace_range(range, &new);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    /// Two revolute joints and a fixed tool frame, with a side branch, a
    /// root above the base, and every optional element left out somewhere.
    const ARM: &str = r#"<?xml version="1.0"?>
<robot name="two_link">
  <link name="world"/>
  <link name="base"><visual><geometry><mesh filename="package://x/base.dae"/></geometry></visual></link>
  <link name="upper"/>
  <link name="fore"/>
  <link name="tool"/>
  <link name="camera"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/>
    <origin xyz="1 2 3"/></joint>
  <joint name="shoulder" type="continuous"><parent link="base"/><child link="upper"/>
    <axis xyz="0 0 1"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/>
    <origin xyz="0.2 0 0" rpy="0 0 0"/><limit lower="-1.5" upper="1.5" effort="1" velocity="1"/></joint>
  <joint name="flange" type="fixed"><parent link="fore"/><child link="tool"/>
    <origin rpy="0 0 1.5707963267948966" xyz="0.1 0 0"/></joint>
  <joint name="head" type="fixed"><parent link="base"/><child link="camera"/></joint>
  <transmission name="t"><joint name="elbow"/></transmission>
  <gazebo reference="fore"><material>Gazebo/Grey</material></gazebo>
</robot>"#;

    fn p() -> &'static Path {
        Path::new("arm.urdf")
    }

    #[test]
    fn defaults_units_limits_and_folding_follow_the_specification() {
        let chain = parse(p(), ARM, "base", "tool").unwrap();
        assert_eq!(chain.joints.len(), 2);
        assert_eq!(chain.inputs.len(), 2);
        // Continuous: +-pi; revolute: from <limit>.
        assert_eq!(chain.inputs[0].min, -std::f64::consts::PI);
        assert_eq!((chain.inputs[1].min, chain.inputs[1].max), (-1.5, 1.5));
        // The elbow has no <axis>: x. Metres become mm; the fixed flange is the tip.
        assert_eq!(chain.joints[1].axis.into_inner(), Vector3::x());
        assert_eq!(
            chain.joints[1].origin.translation.vector,
            Vector3::new(200.0, 0.0, 0.0)
        );
        assert!((chain.tip.translation.vector - Vector3::new(100.0, 0.0, 0.0)).norm() < 1e-12);
        // Shoulder at 90 deg: the arm points along y, 300 mm out.
        let t = chain.base_from_tip(&[FRAC_PI_2, 0.0], &[]);
        assert!((t.translation.vector - Vector3::new(0.0, 300.0, 0.0)).norm() < 1e-9);
        // The elbow's x axis does not move a point on it.
        let t2 = chain.base_from_tip(&[0.0, 0.7], &[]);
        assert!((t2.translation.vector - Vector3::new(300.0, 0.0, 0.0)).norm() < 1e-9);
        // From the world root, the mount's (1, 2, 3) m comes first.
        let from_world = parse(p(), ARM, "world", "tool").unwrap();
        let t3 = from_world.base_from_tip(&[0.0, 0.0], &[]);
        assert!((t3.translation.vector - Vector3::new(1300.0, 2000.0, 3000.0)).norm() < 1e-9);
    }

    #[test]
    fn bad_descriptions_get_one_line_errors() {
        let cases = [
            (
                ARM.to_string(),
                "base",
                "nowhere",
                "arm.urdf: line 2: no link named \"nowhere\"",
            ),
            (
                ARM.to_string(),
                "tool",
                "base",
                "link \"base\" is not below \"tool\"",
            ),
            (
                ARM.to_string(),
                "upper",
                "camera",
                "link \"camera\" is not below \"upper\"",
            ),
            (
                ARM.replace("type=\"continuous\"", "type=\"floating\""),
                "base",
                "tool",
                "joint \"shoulder\" is floating",
            ),
            (
                ARM.replace(
                    "<limit lower=\"-1.5\" upper=\"1.5\" effort=\"1\" velocity=\"1\"/>",
                    "",
                ),
                "base",
                "tool",
                "joint \"elbow\" (revolute) has no <limit>",
            ),
            (
                ARM.replace("<axis xyz=\"0 0 1\"/>", "<axis xyz=\"0 0 0\"/>"),
                "base",
                "tool",
                "joint \"shoulder\" has a zero axis",
            ),
            (
                ARM.replace("xyz=\"0.2 0 0\"", "xyz=\"0.2 0\""),
                "base",
                "tool",
                "arm.urdf: line 14: xyz=\"0.2 0\" is not three",
            ),
            (
                ARM.replace("<parent link=\"upper\"/>", ""),
                "base",
                "tool",
                "joint \"elbow\" has no <parent",
            ),
            (
                ARM.replace("</robot>", ""),
                "base",
                "tool",
                "arm.urdf: line ",
            ),
            (
                "<robt/>".to_string(),
                "base",
                "tool",
                "the root element is <robt>",
            ),
            (
                ARM.replace("type=\"revolute\"", "type=\"fixed\""),
                "fore",
                "tool",
                "no movable joint",
            ),
        ];
        for (text, base, tip, expect) in cases {
            let e = parse(p(), &text, base, tip).unwrap_err().to_string();
            assert!(e.contains(expect), "{e}\n  expected: {expect}");
            assert!(!e.contains('\n'), "{e}");
        }
    }

    #[test]
    fn a_mimic_joint_on_the_chain_follows_its_leader() {
        let text = ARM.replace(
            "<limit lower=\"-1.5\"",
            "<mimic joint=\"shoulder\" multiplier=\"-2\" offset=\"0.1\"/><limit lower=\"-1.5\"",
        );
        let chain = parse(p(), &text, "base", "tool").unwrap();
        assert_eq!(chain.inputs.len(), 1);
        let plain = parse(p(), ARM, "base", "tool").unwrap();
        let q = 0.3;
        let a = chain.base_from_tip(&[q], &[0.05]);
        let b = plain.base_from_tip(&[q + 0.05, -2.0 * (q + 0.05) + 0.1], &[]);
        assert!((a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-12);
    }
}
