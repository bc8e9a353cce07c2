//! Forward kinematics and the geometric Jacobian of a kinematic tree.
//!
//! Poses are `root_from_link`: the link frame expressed in the root (base) frame. The
//! Jacobian of a point p fixed in link L maps joint rates to its twist in the root frame,
//! rows `[v_x, v_y, v_z, ω_x, ω_y, ω_z]`, one column per configuration entry:
//!
//! - revolute/continuous joint j with root-frame axis a_j through o_j: `[a_j × (p − o_j); a_j]`
//! - prismatic joint j: `[a_j; 0]`
//! - joints not between the root and L: zero columns.

use nalgebra::{Isometry3, Matrix6xX, Point3, Translation3, UnitQuaternion, Vector3};

use crate::model::{Joint, JointKind, KinematicModel, LinkId};

impl Joint {
    /// The child link frame in the parent link frame at joint position `q`.
    pub fn parent_from_child(&self, q: f64) -> Isometry3<f64> {
        let motion = match self.kind {
            JointKind::Fixed => Isometry3::identity(),
            JointKind::Revolute | JointKind::Continuous => Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&self.axis, q),
            ),
            JointKind::Prismatic => Isometry3::from_parts(
                Translation3::from(self.axis.into_inner() * q),
                UnitQuaternion::identity(),
            ),
        };
        self.parent_from_joint * motion
    }

    fn position(&self, q: &[f64]) -> f64 {
        self.dof.map_or(0.0, |d| q[d])
    }
}

impl KinematicModel {
    /// `root_from_link` of every link at configuration `q`, indexed by link id.
    ///
    /// # Panics
    /// If `q.len() != self.dof()` (a caller bug).
    pub fn forward_kinematics(&self, q: &[f64]) -> Vec<Isometry3<f64>> {
        let mut poses = Vec::with_capacity(self.links.len());
        self.forward_kinematics_into(q, &mut poses);
        poses
    }

    /// As [`Self::forward_kinematics`], reusing `poses`' storage.
    pub fn forward_kinematics_into(&self, q: &[f64], poses: &mut Vec<Isometry3<f64>>) {
        assert_eq!(
            q.len(),
            self.dof(),
            "configuration length must equal the model's DoF"
        );
        poses.clear();
        poses.resize(self.links.len(), Isometry3::identity());
        for &j in &self.topological {
            let joint = &self.joints[j];
            poses[joint.child] = poses[joint.parent] * joint.parent_from_child(joint.position(q));
        }
    }

    /// `root_from_link` of one link at configuration `q` (walks only its chain).
    ///
    /// # Panics
    /// If `q.len() != self.dof()`.
    pub fn root_from_link(&self, q: &[f64], link: LinkId) -> Isometry3<f64> {
        assert_eq!(
            q.len(),
            self.dof(),
            "configuration length must equal the model's DoF"
        );
        self.chain(link)
            .into_iter()
            .fold(Isometry3::identity(), |pose, j| {
                let joint = &self.joints[j];
                pose * joint.parent_from_child(joint.position(q))
            })
    }

    /// Geometric Jacobian (6 × dof) of the point `point_in_link` fixed in `link`, in the root
    /// frame, rows linear velocity then angular velocity.
    ///
    /// # Panics
    /// If `q.len() != self.dof()`.
    pub fn jacobian(
        &self,
        q: &[f64],
        link: LinkId,
        point_in_link: &Vector3<f64>,
    ) -> Matrix6xX<f64> {
        assert_eq!(
            q.len(),
            self.dof(),
            "configuration length must equal the model's DoF"
        );
        let mut jac = Matrix6xX::zeros(self.dof());
        let mut root_from_parent = Isometry3::identity();
        let chain = self.chain(link);
        // Joint frames along the chain, root first; then the point.
        let mut frames = Vec::with_capacity(chain.len());
        for &j in &chain {
            let joint = &self.joints[j];
            let root_from_joint = root_from_parent * joint.parent_from_joint;
            frames.push(root_from_joint);
            root_from_parent *= joint.parent_from_child(joint.position(q));
        }
        let p = root_from_parent * Point3::from(*point_in_link);
        for (&j, root_from_joint) in chain.iter().zip(&frames) {
            let joint = &self.joints[j];
            let Some(col) = joint.dof else { continue };
            let axis = root_from_joint.rotation * joint.axis.into_inner();
            match joint.kind {
                JointKind::Revolute | JointKind::Continuous => {
                    let lever = p.coords - root_from_joint.translation.vector;
                    jac.fixed_view_mut::<3, 1>(0, col)
                        .copy_from(&axis.cross(&lever));
                    jac.fixed_view_mut::<3, 1>(3, col).copy_from(&axis);
                }
                JointKind::Prismatic => {
                    jac.fixed_view_mut::<3, 1>(0, col).copy_from(&axis);
                }
                JointKind::Fixed => {}
            }
        }
        jac
    }
}
