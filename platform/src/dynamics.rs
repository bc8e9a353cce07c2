//! Rigid-body dynamics of a vehicle's floating-base tree, the way robotics engines compute it:
//! the joint-space mass matrix by the composite-rigid-body algorithm (CRBA), the bias forces
//! (Coriolis, centrifugal, gravity) and inverse dynamics by recursive Newton–Euler (RNEA),
//! forward dynamics through the factorisation M = Lᵀ·D·L of the symmetric positive-definite
//! mass matrix in the tree's own sparsity (Featherstone's LTDL, as MuJoCo and Pinocchio
//! factor it: `crate::tree_factor`). Fixed-size 3 × 3 and 6-vector spatial algebra (the
//! joint transforms by Rodrigues' formula, no quaternions), one body per group of links
//! joined by fixed joints; the mass matrix, the bias forces, forward dynamics and the
//! implicit-drive stepper allocate nothing once a [`Workspace`] exists.
//!
//! Conventions (Pinocchio's, so its numbers compare one for one):
//! - generalised velocity ν = [v_B, ω_B, q̇]: the base origin's velocity and the base's angular
//!   velocity, both in base axes (the free-flyer's local twist), then the joint rates in
//!   configuration order; ν̇ is its time derivative (for the base: the spatial acceleration in
//!   base axes, not the classical acceleration of the origin, which is v̇_B + ω_B × v_B);
//! - spatial vectors are [linear; angular]; a body's velocity and the forces on it are
//!   expressed in its frame, at its origin;
//! - the equation of motion is M(q) ν̇ + b(q, ν) = τ, with τ = [base force and torque about the
//!   base origin, in base axes; joint efforts]; gravity (0, 0, −g) in world axes enters b
//!   through the base's attitude.
//!
//! Sources: R. Featherstone, *Rigid Body Dynamics Algorithms* (2008), ch. 5–6 (RNEA, CRBA,
//! LTDL);
//! the spatial algebra rewritten for the [linear; angular] order.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};

use crate::model::{JointKind, KinematicModel, LinkId};
use crate::tree_factor::{NO_PARENT, TreeFactor};
use crate::vehicle::GRAVITY_MPS2;

/// How a body moves against its parent.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Motion {
    /// Rotation about the unit axis (joint frame = body frame axes).
    Revolute(Vector3<f64>),
    /// Translation along the unit axis.
    Prismatic(Vector3<f64>),
}

/// One rigid body: a link and every link fixed to it.
#[derive(Debug, Clone, PartialEq)]
struct Body {
    /// Parent body (None for the base).
    parent: Option<usize>,
    /// Index of the joint rate in ν (6 + configuration index); unused for the base.
    column: usize,
    /// Configuration index of the joint.
    dof: usize,
    /// The joint frame in the parent body's frame (the body frame is the joint frame moved).
    parent_from_joint: Isometry3<f64>,
    /// The same as a rotation matrix and a translation (the recursions' form).
    parent_from_joint_xf: Transform,
    motion: Motion,
    /// Spatial inertia about the body origin, body axes.
    inertia: Inertia,
}

/// A spatial inertia about a frame's origin as mass m, first moment h = m·c and rotational
/// inertia I_o about the origin: the 6 × 6 matrix [[m·1, −[h]×], [[h]×, I_o]] in 10 numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Inertia {
    m: f64,
    h: Vector3<f64>,
    i: Matrix3<f64>,
}

impl Inertia {
    const ZERO: Self = Self {
        m: 0.0,
        h: Vector3::new(0.0, 0.0, 0.0),
        i: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };

    /// Mass `m` at `c` with rotational inertia `i_c` about the centre of mass (frame axes).
    fn new(m: f64, c: &Vector3<f64>, i_c: &Matrix3<f64>) -> Self {
        let cx = skew(c);
        Self {
            m,
            h: c * m,
            i: i_c - cx * cx * m,
        }
    }

    /// I·v, a force.
    fn apply(&self, v: &Vector6<f64>) -> Vector6<f64> {
        let (vl, va) = (v.fixed_rows::<3>(0), v.fixed_rows::<3>(3));
        let lin = vl * self.m - self.h.cross(&va);
        let ang = self.h.cross(&vl) + self.i * va;
        Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
    }

    /// The same inertia in the parent frame (Xᵀ I X with X the motion transform child ←
    /// parent): h' = R h + m p, I' = R I Rᵀ − m[p]×[p]× − [p]×[Rh]× − [Rh]×[p]×.
    ///
    /// With [a]×[b]× = b·aᵀ − (a·b)·1 the last three terms are
    /// m(|p|²·1 − p·pᵀ) + 2(p·Rh)·1 − Rh·pᵀ − p·(Rh)ᵀ, written out entry by entry (each
    /// product ordered so that this term is symmetric to the bit).
    fn in_parent(&self, x: &Transform) -> Self {
        let (p, q, m) = (&x.p, x.r * self.h, self.m);
        let mut i = x.r * self.i * x.r.transpose();
        let diagonal = m * p.norm_squared() + 2.0 * p.dot(&q);
        for c in 0..3 {
            for r in 0..3 {
                i[(r, c)] -= m * (p[r] * p[c]) + (q[r] * p[c] + p[r] * q[c]);
            }
            i[(c, c)] += diagonal;
        }
        Self { m, h: q + p * m, i }
    }

    fn add(&mut self, other: &Self) {
        self.m += other.m;
        self.h += other.h;
        self.i += other.i;
    }

    fn matrix(&self) -> Matrix6<f64> {
        let hx = skew(&self.h);
        let mut out = Matrix6::zeros();
        out.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(Matrix3::identity() * self.m));
        out.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-hx));
        out.fixed_view_mut::<3, 3>(3, 0).copy_from(&hx);
        out.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.i);
        out
    }
}

/// A body's frame in its parent's, parent_from_child = (R, p); as a motion transform
/// child ← parent it is X = [[Rᵀ, −Rᵀ[p]×], [0, Rᵀ]], applied without forming it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Transform {
    r: Matrix3<f64>,
    p: Vector3<f64>,
}

impl Transform {
    const IDENTITY: Self = Self {
        r: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        p: Vector3::new(0.0, 0.0, 0.0),
    };

    fn of(parent_from_child: &Isometry3<f64>) -> Self {
        Self {
            r: parent_from_child.rotation.to_rotation_matrix().into_inner(),
            p: parent_from_child.translation.vector,
        }
    }

    /// X·m: a motion of the parent in the child's frame, [Rᵀ(m_l − p × m_a); Rᵀ m_a].
    fn motion_to_child(&self, m: &Vector6<f64>) -> Vector6<f64> {
        let (ml, ma) = (m.fixed_rows::<3>(0), m.fixed_rows::<3>(3));
        let rt = self.r.transpose();
        let lin = rt * (ml - self.p.cross(&ma));
        let ang = rt * ma;
        Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
    }

    /// Xᵀ·f: a force on the child in the parent's frame, [R f_l; R f_a + p × R f_l].
    fn force_to_parent(&self, f: &Vector6<f64>) -> Vector6<f64> {
        let (fl, fa) = (f.fixed_rows::<3>(0), f.fixed_rows::<3>(3));
        let lin = self.r * fl;
        let ang = self.r * fa + self.p.cross(&lin);
        Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
    }
}

/// The floating-base tree of a [`KinematicModel`], ready for the recursive algorithms.
#[derive(Debug, Clone, PartialEq)]
pub struct ArticulatedBody {
    /// Bodies with parents before children; body 0 is the base (its `motion` unused).
    bodies: Vec<Body>,
    /// (body, body_from_link) of every link, by link id.
    link_body: Vec<(usize, Isometry3<f64>)>,
    dof: usize,
    /// Every body's inertia from its links alone (a payload adds to `Body::inertia`).
    link_inertia: Vec<Inertia>,
    /// Each joint's position limits (lower, upper), configuration order; None for a joint
    /// without (a continuous one): [`Self::step`] holds them.
    limits: Vec<Option<(f64, f64)>>,
    /// The tree of ν's entries for M's factor, parents first: the base's six in a chain, then
    /// one per body (body order), each under its parent body's last; and the ν column of each.
    factor_parent: Vec<usize>,
    factor_order: Vec<usize>,
}

/// Buffers of the recursions, sized for one [`ArticulatedBody`].
#[derive(Debug, Clone)]
pub struct Workspace {
    /// Every body's frame in its parent's.
    x: Vec<Transform>,
    /// Composite inertias.
    ic: Vec<Inertia>,
    v: Vec<Vector6<f64>>,
    a: Vec<Vector6<f64>>,
    f: Vec<Vector6<f64>>,
    /// Motion subspace of every body's joint (body axes).
    s: Vec<Vector6<f64>>,
    /// The mass matrix.
    m: DMatrix<f64>,
    rhs: DVector<f64>,
    /// The stepper's accelerations; the factors of its matrix M̃ (M, the implicit drives'
    /// terms and the held joints' weights on the diagonal) with every drive implicit and
    /// with some at their limits; the effort of each drive pushing at its limit (None: the
    /// drive acts implicitly).
    acc: DVector<f64>,
    factor: TreeFactor,
    capped_factor: TreeFactor,
    capped: Vec<Option<f64>>,
    /// The joint limits a step holds: (ν column, the acceleration that lands the joint on
    /// its bound, +1 for an upper bound / −1 for a lower one); the accelerations before them,
    /// and M̃⁻¹ times each one's unit column.
    limit_rows: Vec<(usize, f64, f64)>,
    free_acc: DVector<f64>,
    limit_cols: DMatrix<f64>,
    limit_force: Vec<f64>,
    /// The joints the last step held on a bound ((ν column, +1 upper / −1 lower)): the next
    /// step's factor holds them from the start; and the buffer the step fills (swapped with
    /// it, so that no step allocates).
    locked: Vec<(usize, f64)>,
    locked_next: Vec<(usize, f64)>,
}

/// A position drive of [`ArticulatedBody::step`] on one joint: the effort
/// `stiffness·(target − q) − damping·q̇`, evaluated at the end of the step (implicit, as
/// PhysX's articulation drives), capped at `effort_limit`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drive {
    /// Configuration index of the joint.
    pub dof: usize,
    /// N·m/rad or N/m.
    pub stiffness: f64,
    /// N·m·s/rad or N·s/m.
    pub damping: f64,
    /// Target position, rad or m.
    pub target: f64,
    /// Largest effort, N·m or N.
    pub effort_limit: f64,
}

/// The weight on the diagonal of M̃ that holds a joint on its bound (see
/// [`ArticulatedBody::steps`]): against M̃'s entries of 1e-3…10 and generalised forces under
/// ~1e3, it leaves the joint's acceleration within ~1e-9 of the landing one, 3e-16 rad at
/// the twin's 1/1920 s steps.
const LOCK_WEIGHT: f64 = 1e12;

/// How near its bound a joint held on the last step must start the next to be held from
/// the start, rad or m.
const LOCK_REACH: f64 = 1e-9;

/// Solves of a step's drive efforts at most (see [`ArticulatedBody::steps`]): the implicit
/// law, then the drives at their limits, then any freed or newly capped.
const DRIVE_PASSES: usize = 4;

/// The state [`ArticulatedBody::step`] advances: the base's pose in the world, the joint
/// positions and ν.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeState {
    /// World from base.
    pub world_from_base: Isometry3<f64>,
    /// Joint positions, configuration order.
    pub q: Vec<f64>,
    /// Generalised velocity [v_B, ω_B, q̇].
    pub nu: DVector<f64>,
}

/// [·]×: the cross-product matrix.
fn skew(p: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -p.z, p.y, p.z, 0.0, -p.x, -p.y, p.x, 0.0)
}

/// v ×ₘ m, the spatial cross product of motions ([linear; angular]).
fn cross_motion(v: &Vector6<f64>, m: &Vector6<f64>) -> Vector6<f64> {
    let (vl, va) = (v.fixed_rows::<3>(0), v.fixed_rows::<3>(3));
    let (ml, ma) = (m.fixed_rows::<3>(0), m.fixed_rows::<3>(3));
    let lin = va.cross(&ml) + vl.cross(&ma);
    let ang = va.cross(&ma);
    Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
}

/// v ×_f f, the spatial cross product of a motion and a force.
fn cross_force(v: &Vector6<f64>, f: &Vector6<f64>) -> Vector6<f64> {
    let (vl, va) = (v.fixed_rows::<3>(0), v.fixed_rows::<3>(3));
    let (fl, fa) = (f.fixed_rows::<3>(0), f.fixed_rows::<3>(3));
    let lin = va.cross(&fl);
    let ang = va.cross(&fa) + vl.cross(&fl);
    Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
}

impl Motion {
    fn subspace(&self) -> Vector6<f64> {
        match self {
            Self::Revolute(a) => Vector6::new(0.0, 0.0, 0.0, a.x, a.y, a.z),
            Self::Prismatic(a) => Vector6::new(a.x, a.y, a.z, 0.0, 0.0, 0.0),
        }
    }

    /// The body frame in the parent's, the joint frame being `parent_from_joint`, at joint
    /// position q (as [`Self::joint_from_body`], without quaternions: a revolute joint's
    /// rotation by Rodrigues' formula, cos q·1 + sin q·[a]× + (1 − cos q)·a·aᵀ).
    fn parent_from_body(&self, parent_from_joint: &Transform, q: f64) -> Transform {
        let (r0, p0) = (&parent_from_joint.r, &parent_from_joint.p);
        match self {
            Self::Revolute(a) => {
                let (s, c) = q.sin_cos();
                let t = 1.0 - c;
                let joint = Matrix3::new(
                    c + t * a.x * a.x,
                    t * a.x * a.y - s * a.z,
                    t * a.x * a.z + s * a.y,
                    t * a.x * a.y + s * a.z,
                    c + t * a.y * a.y,
                    t * a.y * a.z - s * a.x,
                    t * a.x * a.z - s * a.y,
                    t * a.y * a.z + s * a.x,
                    c + t * a.z * a.z,
                );
                Transform {
                    r: r0 * joint,
                    p: *p0,
                }
            }
            Self::Prismatic(a) => Transform {
                r: *r0,
                p: p0 + r0 * (a * q),
            },
        }
    }

    /// The body frame in the joint frame at joint position q.
    fn joint_from_body(&self, q: f64) -> Isometry3<f64> {
        match self {
            Self::Revolute(a) => Isometry3::from_parts(
                nalgebra::Translation3::identity(),
                UnitQuaternion::from_scaled_axis(a * q),
            ),
            Self::Prismatic(a) => Isometry3::translation(a.x * q, a.y * q, a.z * q),
        }
    }
}

impl ArticulatedBody {
    /// The tree of `model` with its root as the floating base. Links with no inertial add no
    /// mass; a body with no mass at all is kept (its joint then has a zero row in M only if
    /// nothing moves with it, which [`Self::forward_dynamics`] reports as a failed
    /// factorisation).
    pub fn new(model: &KinematicModel) -> Self {
        let mut link_body = vec![(0usize, Isometry3::identity()); model.links.len()];
        let mut bodies = vec![Body {
            parent: None,
            column: 0,
            dof: 0,
            parent_from_joint: Isometry3::identity(),
            parent_from_joint_xf: Transform::IDENTITY,
            motion: Motion::Revolute(Vector3::z()),
            inertia: Inertia::ZERO,
        }];
        link_body[model.root] = (0, Isometry3::identity());
        for &j in &model.topological {
            let joint = &model.joints[j];
            let (parent_body, body_from_parent) = link_body[joint.parent];
            match (joint.kind, joint.dof) {
                (JointKind::Fixed, _) | (_, None) => {
                    link_body[joint.child] =
                        (parent_body, body_from_parent * joint.parent_from_child(0.0));
                }
                (kind, Some(dof)) => {
                    let axis = joint.axis.into_inner();
                    let motion = if kind == JointKind::Prismatic {
                        Motion::Prismatic(axis)
                    } else {
                        Motion::Revolute(axis)
                    };
                    bodies.push(Body {
                        parent: Some(parent_body),
                        column: 6 + dof,
                        dof,
                        parent_from_joint: body_from_parent * joint.parent_from_joint,
                        parent_from_joint_xf: Transform::of(
                            &(body_from_parent * joint.parent_from_joint),
                        ),
                        motion,
                        inertia: Inertia::ZERO,
                    });
                    link_body[joint.child] = (bodies.len() - 1, Isometry3::identity());
                }
            }
        }
        for (link, &(body, body_from_link)) in model.links.iter().zip(&link_body) {
            if let Some(i) = link.inertial {
                let body_from_inertial = body_from_link * i.link_from_inertial;
                let r = body_from_inertial
                    .rotation
                    .to_rotation_matrix()
                    .into_inner();
                bodies[body].inertia.add(&Inertia::new(
                    i.mass_kg,
                    &body_from_inertial.translation.vector,
                    &(r * i.inertia_kgm2 * r.transpose()),
                ));
            }
        }
        // The twin's rapier multibody limits the same joints (not a continuous one).
        let limits = (0..model.dof())
            .map(|d| {
                let joint = model.dof_joint(d);
                joint
                    .limits
                    .filter(|_| joint.kind != JointKind::Continuous)
                    .map(|l| (l.lower, l.upper))
            })
            .collect();
        // The factor's tree: ν's base entries 0…5 in a chain, body i ≥ 1 at 5 + i.
        let mut factor_parent: Vec<usize> = (0..6usize)
            .map(|k| k.checked_sub(1).unwrap_or(NO_PARENT))
            .collect();
        let mut factor_order: Vec<usize> = (0..6).collect();
        for body in bodies.iter().skip(1) {
            factor_parent.push(5 + body.parent.unwrap_or(0));
            factor_order.push(body.column);
        }
        Self {
            link_inertia: bodies.iter().map(|b| b.inertia).collect(),
            bodies,
            link_body,
            dof: model.dof(),
            limits,
            factor_parent,
            factor_order,
        }
    }

    /// Welds a rigid payload to `body` (an object held in a gripper): mass `mass_kg` with its
    /// centre of mass at `com_in_body` and rotational inertia `inertia_about_com` (body axes)
    /// joins the body's, as one more link fixed to it would. Payloads add up until
    /// [`Self::clear_payloads`].
    ///
    /// # Panics
    /// If `body` is not a body of the tree (a caller bug).
    pub fn add_payload(
        &mut self,
        body: usize,
        mass_kg: f64,
        com_in_body: &Vector3<f64>,
        inertia_about_com: &Matrix3<f64>,
    ) {
        self.bodies[body]
            .inertia
            .add(&Inertia::new(mass_kg, com_in_body, inertia_about_com));
    }

    /// Every body back to its links' inertia alone (exactly, not by subtraction).
    pub fn clear_payloads(&mut self) {
        for (b, i) in self.bodies.iter_mut().zip(&self.link_inertia) {
            b.inertia = *i;
        }
    }

    /// The spatial velocity of `body` at `state`: [linear velocity of the body's origin;
    /// angular velocity], both in the body's axes.
    ///
    /// # Panics
    /// If `body` is not a body of the tree or `state` has the wrong size (a caller bug).
    pub fn body_velocity(
        &self,
        state: &TreeState,
        body: usize,
        ws: &mut Workspace,
    ) -> Vector6<f64> {
        assert_eq!(state.nu.len(), self.nv(), "ν size");
        self.kinematics(&state.q, ws);
        ws.v[0] = state.nu.fixed_rows::<6>(0).into_owned();
        for i in 1..=body {
            let b = &self.bodies[i];
            let p = b.parent.unwrap_or(0);
            ws.v[i] = ws.x[i].motion_to_child(&ws.v[p]) + ws.s[i] * state.nu[b.column];
        }
        ws.v[body]
    }

    /// Entries of ν (6 + the configuration's).
    pub fn nv(&self) -> usize {
        6 + self.dof
    }

    /// Rigid bodies the tree has (links joined by fixed joints count once).
    pub fn body_count(&self) -> usize {
        self.bodies.len()
    }

    /// The body a link belongs to and the link's frame in that body's frame.
    pub fn link_body(&self, link: LinkId) -> (usize, Isometry3<f64>) {
        self.link_body[link]
    }

    /// Buffers for this tree.
    pub fn workspace(&self) -> Workspace {
        let n = self.bodies.len();
        Workspace {
            x: vec![Transform::IDENTITY; n],
            ic: vec![Inertia::ZERO; n],
            v: vec![Vector6::zeros(); n],
            a: vec![Vector6::zeros(); n],
            f: vec![Vector6::zeros(); n],
            s: vec![Vector6::zeros(); n],
            m: DMatrix::zeros(self.nv(), self.nv()),
            rhs: DVector::zeros(self.nv()),
            acc: DVector::zeros(self.nv()),
            factor: TreeFactor::new(&self.factor_parent, &self.factor_order),
            capped_factor: TreeFactor::new(&self.factor_parent, &self.factor_order),
            capped: Vec::new(),
            limit_rows: Vec::with_capacity(self.dof),
            free_acc: DVector::zeros(self.nv()),
            limit_cols: DMatrix::zeros(self.nv(), self.dof),
            limit_force: Vec::with_capacity(self.dof),
            locked: Vec::with_capacity(self.dof),
            locked_next: Vec::with_capacity(self.dof),
        }
    }

    /// Joint transforms and subspaces at q.
    fn kinematics(&self, q: &[f64], ws: &mut Workspace) {
        assert_eq!(
            q.len(),
            self.dof,
            "configuration length must equal the model's DoF"
        );
        for (i, body) in self.bodies.iter().enumerate().skip(1) {
            ws.x[i] = body
                .motion
                .parent_from_body(&body.parent_from_joint_xf, q[body.dof]);
            ws.s[i] = body.motion.subspace();
        }
    }

    /// The mass matrix M(q) (nv × nv, symmetric) into `out`, by CRBA.
    ///
    /// # Panics
    /// If `q` or `out` have the wrong size (a caller bug).
    pub fn mass_matrix(&self, q: &[f64], ws: &mut Workspace, out: &mut DMatrix<f64>) {
        assert_eq!(out.shape(), (self.nv(), self.nv()), "mass matrix size");
        self.kinematics(q, ws);
        for (ic, body) in ws.ic.iter_mut().zip(&self.bodies) {
            *ic = body.inertia;
        }
        for i in (1..self.bodies.len()).rev() {
            let p = self.bodies[i].parent.unwrap_or(0);
            let carried = ws.ic[i].in_parent(&ws.x[i]);
            ws.ic[p].add(&carried);
        }
        out.as_mut_slice().fill(0.0);
        out.fixed_view_mut::<6, 6>(0, 0)
            .copy_from(&ws.ic[0].matrix());
        for i in 1..self.bodies.len() {
            let col = self.bodies[i].column;
            let mut f = ws.ic[i].apply(&ws.s[i]);
            out[(col, col)] = ws.s[i].dot(&f);
            let mut j = i;
            while let Some(p) = self.bodies[j].parent {
                f = ws.x[j].force_to_parent(&f);
                j = p;
                if j == 0 {
                    for r in 0..6 {
                        out[(r, col)] = f[r];
                        out[(col, r)] = f[r];
                    }
                } else {
                    let row = self.bodies[j].column;
                    let v = ws.s[j].dot(&f);
                    out[(row, col)] = v;
                    out[(col, row)] = v;
                }
            }
        }
    }

    /// Inverse dynamics by RNEA: the generalised forces τ = M ν̇ + b that give ν̇ at (q, ν),
    /// with the base at attitude `world_from_base` under gravity, minus the external spatial
    /// forces `external` (one per body, body axes at the body origin; empty for none).
    ///
    /// # Panics
    /// On wrong sizes (a caller bug).
    #[allow(clippy::too_many_arguments)]
    pub fn inverse_dynamics(
        &self,
        world_from_base: &UnitQuaternion<f64>,
        q: &[f64],
        nu: &DVector<f64>,
        nu_dot: &DVector<f64>,
        external: &[Vector6<f64>],
        ws: &mut Workspace,
        tau: &mut DVector<f64>,
    ) {
        assert_eq!(nu_dot.len(), self.nv(), "ν̇ size");
        self.rnea(world_from_base, q, nu, Some(nu_dot), external, ws, tau);
    }

    /// RNEA with ν̇ (None: zero).
    #[allow(clippy::too_many_arguments)]
    fn rnea(
        &self,
        world_from_base: &UnitQuaternion<f64>,
        q: &[f64],
        nu: &DVector<f64>,
        nu_dot: Option<&DVector<f64>>,
        external: &[Vector6<f64>],
        ws: &mut Workspace,
        tau: &mut DVector<f64>,
    ) {
        self.kinematics(q, ws);
        self.rnea_at_kinematics(world_from_base, nu, nu_dot, external, ws, tau);
    }

    /// RNEA on the joint transforms and subspaces already in `ws` (`kinematics` at this q).
    fn rnea_at_kinematics(
        &self,
        world_from_base: &UnitQuaternion<f64>,
        nu: &DVector<f64>,
        nu_dot: Option<&DVector<f64>>,
        external: &[Vector6<f64>],
        ws: &mut Workspace,
        tau: &mut DVector<f64>,
    ) {
        let nv = self.nv();
        assert!(nu.len() == nv && tau.len() == nv, "ν sizes");
        assert!(
            external.is_empty() || external.len() == self.bodies.len(),
            "one external force per body"
        );
        let acc = |k: usize| nu_dot.map_or(0.0, |a| a[k]);
        // Gravity as an upward acceleration of the whole tree.
        let up = world_from_base.inverse() * Vector3::new(0.0, 0.0, GRAVITY_MPS2);
        ws.v[0] = nu.fixed_rows::<6>(0).into_owned();
        ws.a[0] = Vector6::new(
            acc(0) + up.x,
            acc(1) + up.y,
            acc(2) + up.z,
            acc(3),
            acc(4),
            acc(5),
        );
        for i in 1..self.bodies.len() {
            let body = &self.bodies[i];
            let p = body.parent.unwrap_or(0);
            let vj = ws.s[i] * nu[body.column];
            let v = ws.x[i].motion_to_child(&ws.v[p]) + vj;
            ws.a[i] = ws.x[i].motion_to_child(&ws.a[p])
                + ws.s[i] * acc(body.column)
                + cross_motion(&v, &vj);
            ws.v[i] = v;
        }
        for i in 0..self.bodies.len() {
            let inertia = &self.bodies[i].inertia;
            let h = inertia.apply(&ws.v[i]);
            ws.f[i] = inertia.apply(&ws.a[i]) + cross_force(&ws.v[i], &h);
            if let Some(fx) = external.get(i) {
                ws.f[i] -= fx;
            }
        }
        for i in (1..self.bodies.len()).rev() {
            let body = &self.bodies[i];
            tau[body.column] = ws.s[i].dot(&ws.f[i]);
            let p = body.parent.unwrap_or(0);
            let carried = ws.x[i].force_to_parent(&ws.f[i]);
            ws.f[p] += carried;
        }
        tau.fixed_rows_mut::<6>(0).copy_from(&ws.f[0]);
    }

    /// The bias forces b(q, ν) (Coriolis, centrifugal and gravity): M ν̇ + b = τ.
    pub fn bias(
        &self,
        world_from_base: &UnitQuaternion<f64>,
        q: &[f64],
        nu: &DVector<f64>,
        ws: &mut Workspace,
        out: &mut DVector<f64>,
    ) {
        self.rnea(world_from_base, q, nu, None, &[], ws, out);
    }

    /// Forward dynamics: ν̇ = M⁻¹(τ − b) with the external forces (as
    /// [`Self::inverse_dynamics`]). False if M is not positive definite (a body without mass
    /// moving on its own); ν̇ is then not written.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_dynamics(
        &self,
        world_from_base: &UnitQuaternion<f64>,
        q: &[f64],
        nu: &DVector<f64>,
        tau: &DVector<f64>,
        external: &[Vector6<f64>],
        ws: &mut Workspace,
        nu_dot: &mut DVector<f64>,
    ) -> bool {
        // b − Σ Jᵀf_ext: the recursion with ν̇ = 0. (0 × 0 placeholders do not allocate.)
        let mut rhs = std::mem::replace(&mut ws.rhs, DVector::zeros(0));
        self.rnea(world_from_base, q, nu, None, external, ws, &mut rhs);
        let mut m = std::mem::replace(&mut ws.m, DMatrix::zeros(0, 0));
        self.mass_matrix(q, ws, &mut m);
        rhs.neg_mut();
        rhs += tau;
        ws.factor.load(m.as_slice());
        let ok = ws.factor.factorize();
        if ok {
            ws.factor.solve_mut(rhs.as_mut_slice());
            nu_dot.copy_from(&rhs);
        }
        ws.m = m;
        ws.rhs = rhs;
        ok
    }

    /// Advances `state` by `h` seconds under the generalised forces `tau` (base wrench in base
    /// axes about its origin; joint efforts), the spatial forces `external` on the bodies (as
    /// [`Self::inverse_dynamics`]; empty for none) and the joint `drives`: semi-implicit Euler, the
    /// drives implicit, (M + h·(h·K + D)) a = τ − b + K(r − q − h·q̇) − D·q̇ on the driven
    /// rows, ν⁺ = ν + h·a, then q⁺ = q + h·q̇⁺ and the base pose moved by h·ν⁺ (the
    /// rotation by the exponential map). A drive whose effort at the end of the step would
    /// pass its limit pushes with the limit instead (an active set of at most
    /// [`DRIVE_PASSES`] solves). A joint whose step would
    /// carry it past a position limit lands on it instead (a unilateral constraint, no
    /// bounce: [`Self::hold_limits`]). False (the state untouched) if M is not positive
    /// definite or the step is not finite.
    ///
    /// # Panics
    /// On wrong sizes (a caller bug).
    pub fn step(
        &self,
        state: &mut TreeState,
        tau: &DVector<f64>,
        external: &[Vector6<f64>],
        drives: &[Drive],
        h: f64,
        ws: &mut Workspace,
    ) -> bool {
        self.steps(state, tau, external, drives, h, 1, ws)
    }

    /// `n` steps of `h` as [`Self::step`] takes them, but with the mass matrix of the first
    /// (and the factor of its drive-augmented form) kept for all `n`: the bias forces, the
    /// external forces' Jacobians and the drives' efforts are evaluated at every step, M is
    /// not (it moves little over a few milliseconds; rapier's multibody likewise keeps its
    /// mass matrix through a substep's constraint iterations). A step with a drive at its
    /// limit factors its own matrix. `n = 1` is [`Self::step`]. Keeping M costs the momentum
    /// balance (a bias at the current state against a stale M: 0.13 N s over a 10 s arm sweep
    /// at n = 4 against 0.006 N s at n = 1, docs/speed.md), so the twin steps with n = 1;
    /// n > 1 is for speed studies. False (the state as the
    /// steps before the failing one left it) if a factorisation fails or a step is not
    /// finite.
    ///
    /// # Panics
    /// On wrong sizes (a caller bug).
    #[allow(clippy::too_many_arguments)]
    pub fn steps(
        &self,
        state: &mut TreeState,
        tau: &DVector<f64>,
        external: &[Vector6<f64>],
        drives: &[Drive],
        h: f64,
        n: u32,
        ws: &mut Workspace,
    ) -> bool {
        let nv = self.nv();
        assert!(tau.len() == nv && state.nu.len() == nv, "ν sizes");
        // (0 × 0 placeholders do not allocate.)
        let mut m = std::mem::replace(&mut ws.m, DMatrix::zeros(0, 0));
        self.mass_matrix(&state.q, ws, &mut m);
        // Factors M̃: M with the implicit drives' terms and the held joints' weights.
        let augment = |f: &mut TreeFactor, capped: &[Option<f64>], locks: &[(usize, f64)]| {
            f.load(m.as_slice());
            for (d, c) in drives.iter().zip(capped) {
                if c.is_none() {
                    f.add_diagonal(6 + d.dof, h * (h * d.stiffness + d.damping));
                }
            }
            for &(col, _) in locks {
                f.add_diagonal(col, LOCK_WEIGHT);
            }
            f.factorize()
        };
        // A joint the last step left on a bound is held there from the start (a joint resting
        // on its bound, as a folded arm under gravity does at every step), by a weight on its
        // diagonal that the factor absorbs: no solve of its own, unless the bound turns out to
        // pull (then this step's factor is made again without it).
        let mut locks = std::mem::take(&mut ws.locked);
        std::mem::swap(&mut ws.locked, &mut ws.locked_next);
        locks.retain(|&(col, side)| {
            self.limits[col - 6].is_some_and(|(lo, hi)| {
                let bound = if side > 0.0 { hi } else { lo };
                (state.q[col - 6] - bound).abs() <= LOCK_REACH
            })
        });
        let mut capped = std::mem::take(&mut ws.capped);
        capped.clear();
        capped.resize(drives.len(), None);
        // The factor of M + h(hK + D) with every drive implicit, kept for the n steps.
        let mut factor = std::mem::take(&mut ws.factor);
        let mut factor_ok = augment(&mut factor, &capped, &locks);
        // The factor with drives at their limits, when `use_capped`.
        let mut capped_factor = std::mem::take(&mut ws.capped_factor);
        let mut rhs = std::mem::replace(&mut ws.rhs, DVector::zeros(0));
        let mut acc = std::mem::replace(&mut ws.acc, DVector::zeros(0));
        let mut ok = factor_ok;
        for k in 0..n {
            // τ − b + Σ Jᵀf_ext at this step's state (the first step's joint transforms are
            // the mass matrix's).
            let attitude = state.world_from_base.rotation;
            if k == 0 {
                self.rnea_at_kinematics(&attitude, &state.nu, None, external, ws, &mut rhs);
            } else {
                self.rnea(&attitude, &state.q, &state.nu, None, external, ws, &mut rhs);
            }
            for (r, t) in rhs.as_mut_slice().iter_mut().zip(tau.as_slice()) {
                *r = t - *r;
            }
            let mut use_capped = false;
            for round in 0..2 {
                if !factor_ok {
                    ok = false;
                    break;
                }
                capped.fill(None);
                // The drives' efforts are a box-constrained implicit law: each is its spring and
                // damper at the end of the step, K(r − q − h·q̇⁺) − D·q̇⁺, unless that passes its
                // limit, where it pushes with the limit in that law's direction. An active set:
                // solve, cap the drives whose law passes the limit, free the capped ones whose law
                // no longer reaches it at the new q̇⁺ (a coupled joint's cap can reverse it), solve
                // again — as a constraint solver clamps a motor's impulse (rapier's PGS, PhysX's
                // drives), and not with the sign of the law at the start of the step, whose stiff
                // damper (D·h/I ≫ 1 on a light wrist) then flips a saturated drive between ±limit
                // from one step to the next.
                for pass in 0..DRIVE_PASSES {
                    acc.as_mut_slice().copy_from_slice(rhs.as_slice());
                    for (d, c) in drives.iter().zip(&capped) {
                        let col = 6 + d.dof;
                        let (q, qd) = (state.q[d.dof], state.nu[col]);
                        acc[col] +=
                            c.unwrap_or(d.stiffness * (d.target - q - h * qd) - d.damping * qd);
                    }
                    // The held joints: the weight times the landing acceleration (the
                    // right-hand side without it kept, for the bounds' forces below).
                    ws.free_acc.as_mut_slice().copy_from_slice(acc.as_slice());
                    for &(col, side) in &locks {
                        acc[col] += LOCK_WEIGHT * self.landing(state, h, col, side);
                    }
                    if use_capped {
                        capped_factor.solve_mut(acc.as_mut_slice());
                    } else {
                        factor.solve_mut(acc.as_mut_slice());
                    }
                    if pass + 1 == DRIVE_PASSES {
                        break;
                    }
                    // The law at the end of the step.
                    let mut again = false;
                    for (d, c) in drives.iter().zip(capped.iter_mut()) {
                        let col = 6 + d.dof;
                        let (q, qd) = (state.q[d.dof], state.nu[col]);
                        let qd_next = qd + h * acc[col];
                        let law = d.stiffness * (d.target - q - h * qd_next) - d.damping * qd_next;
                        match *c {
                            None if law.abs() > d.effort_limit => {
                                *c = Some(d.effort_limit.copysign(law));
                                again = true;
                            }
                            Some(e) if law * e.signum() < d.effort_limit => {
                                *c = None;
                                again = true;
                            }
                            _ => {}
                        }
                    }
                    if !again {
                        break;
                    }
                    use_capped = false;
                    if capped.iter().all(Option::is_none) {
                        continue;
                    }
                    // Drives at their limit: this step's own factor.
                    if !augment(&mut capped_factor, &capped, &locks) {
                        ok = false;
                        break;
                    }
                    use_capped = true;
                }
                // A held joint whose bound would pull it (its force toward the bound's
                // outside) is let go: the step again, without the weights.
                let pulled = locks.iter().any(|&(col, side)| {
                    // The bound's force: row `col` of M̃·a (M̃ without the weight; M's row is
                    // its column) less the right-hand side, to the precision of a, not of
                    // a − a_bound ~ 1/weight.
                    let implicit = drives
                        .iter()
                        .zip(&capped)
                        .filter(|(d, c)| 6 + d.dof == col && c.is_none())
                        .map(|(d, _)| h * (h * d.stiffness + d.damping))
                        .sum::<f64>();
                    let force = m.column(col).dot(&acc) + implicit * acc[col] - ws.free_acc[col];
                    force * side > 0.0
                });
                if !pulled || round == 1 || !ok {
                    break;
                }
                locks.clear();
                use_capped = false;
                capped.fill(None);
                factor_ok = augment(&mut factor, &capped, &locks);
            }
            if ok {
                let f = if use_capped {
                    &mut capped_factor
                } else {
                    &mut factor
                };
                self.hold_limits(state, h, f, &mut acc, ws);
                // Held on this step: the weighted joints still on their bounds, and those
                // the limits caught.
                ws.locked.clear();
                ws.locked.extend(locks.iter().copied());
                for &(col, _, side) in &ws.limit_rows {
                    if ws.locked.iter().all(|l| l.0 != col) {
                        ws.locked.push((col, side));
                    }
                }
            }
            if !ok || !acc.iter().all(|a| a.is_finite()) {
                ok = false;
                break;
            }
            state.nu.axpy(h, &acc, 1.0);
            for (d, q) in state.q.iter_mut().enumerate() {
                *q += h * state.nu[6 + d];
            }
            let v = Vector3::new(state.nu[0], state.nu[1], state.nu[2]);
            let w = Vector3::new(state.nu[3], state.nu[4], state.nu[5]);
            let pose = &mut state.world_from_base;
            pose.translation.vector += pose.rotation * (v * h);
            pose.rotation *= UnitQuaternion::from_scaled_axis(w * h);
        }
        ws.factor = factor;
        ws.capped_factor = capped_factor;
        ws.rhs = rhs;
        ws.m = m;
        ws.acc = acc;
        ws.capped = capped;
        locks.clear();
        ws.locked_next = locks;
        ok
    }

    /// Holds the joint limits on a step's accelerations `acc` (solved with `factor`, the
    /// drive-augmented M̃ = M + h(hK + D)): a joint that `acc` would carry past a bound
    /// (q + h(q̇ + h·a) beyond it) lands on it — a joint already past one (a hand-over from
    /// another engine) goes no further out, and is not pulled back. The constraint forces λ
    /// act on the joints' own columns (an internal torque between a joint's two bodies, so
    /// the tree's momentum is untouched), solve (E ᵀM̃⁻¹E) λ = a_bound − a, and may only push
    /// away from a bound; one with the wrong sign is let go and the rest solved again, and
    /// a joint the corrected step carries past a bound joins (at most one pass per joint).
    /// Rapier's multibody holds the same limits with its own (stiff, slightly soft)
    /// constraint rows.
    fn hold_limits(
        &self,
        state: &TreeState,
        h: f64,
        factor: &mut TreeFactor,
        acc: &mut DVector<f64>,
        ws: &mut Workspace,
    ) {
        // Landing on the bound to the last 1e-12 needs no force.
        const SLACK: f64 = 1e-12;
        let past = |col: usize, a: f64| {
            let d = col - 6;
            let (lo, hi) = self.limits[d]?;
            let (q, qd) = (state.q[d], state.nu[col]);
            let next = q + h * (qd + h * a);
            if next > hi.max(q) + SLACK {
                Some((self.landing(state, h, col, 1.0), 1.0))
            } else if next < lo.min(q) - SLACK {
                Some((self.landing(state, h, col, -1.0), -1.0))
            } else {
                None
            }
        };
        let rows = &mut ws.limit_rows;
        rows.clear();
        for d in 0..self.dof {
            if let Some((target, side)) = past(6 + d, acc[6 + d]) {
                rows.push((6 + d, target, side));
            }
        }
        if rows.is_empty() {
            return;
        }
        ws.free_acc.copy_from(acc);
        for _pass in 0..=self.dof {
            // M̃⁻¹ e for each held joint, all in one solve.
            let k = rows.len();
            let nv = self.nv();
            let cols = &mut ws.limit_cols.as_mut_slice()[..nv * k];
            cols.fill(0.0);
            for (col, &(c, _, _)) in cols.chunks_exact_mut(nv).zip(rows.iter()) {
                col[c] = 1.0;
                factor.solve_mut(col);
            }
            let cols = ws.limit_cols.columns(0, k);
            let s = |i: usize, j: usize| cols[(rows[i].0, j)];
            let r = |i: usize| rows[i].1 - ws.free_acc[rows[i].0];
            // (E ᵀM̃⁻¹E) λ = r, SPD: one or two joints (the common cases: an arm resting on
            // its bounds) without a heap matrix.
            let lambda = &mut ws.limit_force;
            lambda.clear();
            match k {
                1 => lambda.push(r(0) / s(0, 0)),
                2 => {
                    let m = nalgebra::Matrix2::new(s(0, 0), s(0, 1), s(1, 0), s(1, 1));
                    let Some(f) = m.cholesky() else { return };
                    lambda.extend(f.solve(&nalgebra::Vector2::new(r(0), r(1))).iter());
                }
                _ => {
                    let m = DMatrix::from_fn(k, k, s);
                    let Some(f) = m.cholesky() else { return };
                    lambda.extend(f.solve(&DVector::from_fn(k, |i, _| r(i))).iter());
                }
            }
            acc.copy_from(&ws.free_acc);
            for (j, l) in lambda.iter().enumerate() {
                acc.axpy(*l, &cols.column(j), 1.0);
            }
            // A bound only pushes the joint back (λ ≤ 0 at an upper bound, ≥ 0 at a lower).
            let before = rows.len();
            let mut i = 0;
            rows.retain(|&(_, _, side)| {
                let keep = lambda[i] * side <= 0.0;
                i += 1;
                keep
            });
            let mut joined = false;
            for d in 0..self.dof {
                let c = 6 + d;
                if rows.iter().all(|r| r.0 != c)
                    && let Some((target, side)) = past(c, acc[c])
                {
                    rows.push((c, target, side));
                    joined = true;
                }
            }
            if rows.len() == before && !joined {
                return;
            }
            if rows.is_empty() {
                acc.copy_from(&ws.free_acc);
                return;
            }
        }
    }

    /// The acceleration of ν column `col` that lands its joint on its upper (`side` > 0) or
    /// lower bound at the end of a step of `h`: on the bound, or where it is if already past
    /// it (no pull back). Zero for a joint without limits (never asked).
    fn landing(&self, state: &TreeState, h: f64, col: usize, side: f64) -> f64 {
        let d = col - 6;
        let Some((lo, hi)) = self.limits[d] else {
            return 0.0;
        };
        let (q, qd) = (state.q[d], state.nu[col]);
        let bound = if side > 0.0 { hi.max(q) } else { lo.min(q) };
        ((bound - q) / h - qd) / h
    }

    /// Every body's frame in the world (body order: the base, then one per movable joint in
    /// the model's topological order), into `out`.
    pub fn body_poses(
        &self,
        world_from_base: &Isometry3<f64>,
        q: &[f64],
        out: &mut Vec<Isometry3<f64>>,
    ) {
        out.clear();
        out.push(*world_from_base);
        for body in self.bodies.iter().skip(1) {
            let parent = out[body.parent.unwrap_or(0)];
            out.push(parent * body.parent_from_joint * body.motion.joint_from_body(q[body.dof]));
        }
    }

    /// A state drawn from `rng` for checks against other dynamics code: joint positions
    /// uniform within their limits (±3 for a joint without), every entry of ν uniform in
    /// ±1.5, the base at the origin with roll and pitch uniform in ±0.5 rad and yaw in ±3 rad
    /// (drawn in that order).
    pub fn sample_state(&self, model: &KinematicModel, rng: &mut impl rand::Rng) -> TreeState {
        let q = (0..model.dof())
            .map(|d| {
                let (lower, upper) = model
                    .dof_joint(d)
                    .limits
                    .map_or((-3.0, 3.0), |l| (l.lower, l.upper));
                rng.random_range(lower..=upper)
            })
            .collect();
        let nu = DVector::from_fn(self.nv(), |_, _| rng.random_range(-1.5..1.5));
        let attitude = UnitQuaternion::from_euler_angles(
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(-3.0..3.0),
        );
        TreeState {
            world_from_base: Isometry3::from_parts(nalgebra::Translation3::identity(), attitude),
            q,
            nu,
        }
    }

    /// The tree's spatial momentum about the base origin in base axes: the first six rows of
    /// M ν (linear momentum; angular momentum about the base origin).
    pub fn momentum(&self, q: &[f64], nu: &DVector<f64>, ws: &mut Workspace) -> Vector6<f64> {
        let mut m = std::mem::replace(&mut ws.m, DMatrix::zeros(0, 0));
        self.mass_matrix(q, ws, &mut m);
        let h = (m.rows(0, 6) * nu).fixed_rows::<6>(0).into_owned();
        ws.m = m;
        h
    }

    /// Kinetic energy ½ νᵀ M ν, J.
    pub fn kinetic_energy(&self, q: &[f64], nu: &DVector<f64>, ws: &mut Workspace) -> f64 {
        let mut m = std::mem::replace(&mut ws.m, DMatrix::zeros(0, 0));
        self.mass_matrix(q, ws, &mut m);
        let e = 0.5 * nu.dot(&(&m * nu));
        ws.m = m;
        e
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DVector, Matrix3, Point3, Quaternion, UnitQuaternion, Vector3, Vector6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::{ArticulatedBody, skew};
    use crate::{BUILTIN_IDS, GRAVITY_MPS2, Vehicle};

    fn vehicles() -> Vec<Vehicle> {
        BUILTIN_IDS
            .iter()
            .map(|id| Vehicle::builtin(id).unwrap_or_else(|e| panic!("{id}: {e}")))
            .collect()
    }

    /// A configuration within the joint limits, a velocity, an attitude.
    fn random_state(
        v: &Vehicle,
        rng: &mut ChaCha8Rng,
    ) -> (Vec<f64>, DVector<f64>, UnitQuaternion<f64>) {
        let s = ArticulatedBody::new(&v.model).sample_state(&v.model, rng);
        (s.q, s.nu, s.world_from_base.rotation)
    }

    fn relative_gap(a: f64, b: f64) -> f64 {
        (a - b).abs() / a.abs().max(b.abs()).max(1.0)
    }

    #[test]
    fn the_base_block_of_the_mass_matrix_is_the_composite_rigid_body() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for v in vehicles() {
            let tree = ArticulatedBody::new(&v.model);
            let mut ws = tree.workspace();
            let mut m = nalgebra::DMatrix::zeros(tree.nv(), tree.nv());
            for _ in 0..5 {
                let (q, _, _) = random_state(&v, &mut rng);
                tree.mass_matrix(&q, &mut ws, &mut m);
                let props = v.model.mass_properties(&q);
                let (mass, c) = (props.mass_kg, props.com_in_root_m);
                let about_origin = props.inertia_about_com_kgm2 - skew(&c) * skew(&c) * mass;
                let expected_lin = Matrix3::identity() * mass;
                let expected_cross = -skew(&c) * mass;
                let gap = (m.fixed_view::<3, 3>(0, 0) - expected_lin).amax()
                    + (m.fixed_view::<3, 3>(0, 3) - expected_cross).amax()
                    + (m.fixed_view::<3, 3>(3, 3) - about_origin).amax();
                assert!(gap < 1e-12, "{}: base block off by {gap:e}", v.id);
                assert!(
                    (&m - m.transpose()).amax() < 1e-14,
                    "{}: M not symmetric",
                    v.id
                );
                assert!(
                    m.clone().cholesky().is_some(),
                    "{}: M not positive definite",
                    v.id
                );
            }
        }
    }

    #[test]
    fn kinetic_energy_equals_the_sum_over_links_through_the_jacobians() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for v in vehicles() {
            let tree = ArticulatedBody::new(&v.model);
            let mut ws = tree.workspace();
            for _ in 0..5 {
                let (q, nu, _) = random_state(&v, &mut rng);
                let vb = Vector3::new(nu[0], nu[1], nu[2]);
                let wb = Vector3::new(nu[3], nu[4], nu[5]);
                let qd = nu.rows(6, v.model.dof()).into_owned();
                let poses = v.model.forward_kinematics(&q);
                let mut expected = 0.0;
                for (id, link) in v.model.links.iter().enumerate() {
                    let Some(inertial) = link.inertial else {
                        continue;
                    };
                    let com_in_link = inertial.link_from_inertial.translation.vector;
                    let com = (poses[id] * Point3::from(com_in_link)).coords;
                    let jac = v.model.jacobian(&q, id, &com_in_link);
                    let lin = vb + wb.cross(&com) + jac.fixed_rows::<3>(0) * &qd;
                    let ang = wb + jac.fixed_rows::<3>(3) * &qd;
                    let r = (poses[id] * inertial.link_from_inertial)
                        .rotation
                        .to_rotation_matrix()
                        .into_inner();
                    let inertia = r * inertial.inertia_kgm2 * r.transpose();
                    expected += 0.5 * inertial.mass_kg * lin.norm_squared()
                        + 0.5 * ang.dot(&(inertia * ang));
                }
                let energy = tree.kinetic_energy(&q, &nu, &mut ws);
                assert!(
                    relative_gap(energy, expected) < 1e-12,
                    "{}: ½νᵀMν = {energy} J, links sum to {expected} J",
                    v.id
                );
            }
        }
    }

    /// A body's velocity is its origin's through the platform's Jacobian; a payload welded to
    /// it adds its own kinetic energy at that velocity (½ m |v + ω × c|² + ½ ωᵀ I ω) and its
    /// weight to the base block, and clearing it gives back M bit for bit.
    #[test]
    fn a_payload_moves_with_its_body_and_clears_exactly() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for v in vehicles() {
            let ee = v.ee_link;
            let mut tree = ArticulatedBody::new(&v.model);
            let mut ws = tree.workspace();
            let (body, body_from_link) = tree.link_body(ee);
            let link_from_body = body_from_link.inverse();
            for _ in 0..5 {
                let (q, nu, _) = random_state(&v, &mut rng);
                let state = super::TreeState {
                    world_from_base: nalgebra::Isometry3::identity(),
                    q: q.clone(),
                    nu: nu.clone(),
                };
                // The body's origin through the platform's kinematics (base axes).
                let poses = v.model.forward_kinematics(&q);
                let base_from_body = poses[ee] * link_from_body;
                let origin_in_link = link_from_body.translation.vector;
                let jac = v.model.jacobian(&q, ee, &origin_in_link);
                let qd = nu.rows(6, v.model.dof()).into_owned();
                let (vb, wb) = (
                    Vector3::new(nu[0], nu[1], nu[2]),
                    Vector3::new(nu[3], nu[4], nu[5]),
                );
                let origin = base_from_body.translation.vector;
                let lin = vb + wb.cross(&origin) + jac.fixed_rows::<3>(0) * &qd;
                let ang = wb + jac.fixed_rows::<3>(3) * &qd;
                let twist = tree.body_velocity(&state, body, &mut ws);
                let r = base_from_body.rotation;
                let (tl, ta) = (
                    r * Vector3::new(twist[0], twist[1], twist[2]),
                    r * Vector3::new(twist[3], twist[4], twist[5]),
                );
                assert!(
                    (tl - lin).norm() < 1e-12 && (ta - ang).norm() < 1e-12,
                    "{}: body velocity {tl:?} {ta:?} against {lin:?} {ang:?}",
                    v.id
                );
                // A 0.3 kg payload off the body's origin.
                let (m, c) = (0.3, Vector3::new(0.05, -0.02, 0.01));
                let rot = UnitQuaternion::from_euler_angles(0.3, -0.2, 0.5).to_rotation_matrix();
                let i_c = rot.matrix()
                    * Matrix3::from_diagonal(&Vector3::new(1e-3, 2e-3, 1.5e-3))
                    * rot.matrix().transpose();
                let before = tree.kinetic_energy(&q, &nu, &mut ws);
                let mut m_before = nalgebra::DMatrix::zeros(tree.nv(), tree.nv());
                tree.mass_matrix(&q, &mut ws, &mut m_before);
                tree.add_payload(body, m, &c, &i_c);
                let (bv, bw) = (
                    Vector3::new(twist[0], twist[1], twist[2]),
                    Vector3::new(twist[3], twist[4], twist[5]),
                );
                let expected = before
                    + 0.5 * m * (bv + bw.cross(&c)).norm_squared()
                    + 0.5 * bw.dot(&(i_c * bw));
                let after = tree.kinetic_energy(&q, &nu, &mut ws);
                assert!(
                    relative_gap(after, expected) < 1e-12,
                    "{}: with the payload {after} J, expected {expected} J",
                    v.id
                );
                let mut m_with = nalgebra::DMatrix::zeros(tree.nv(), tree.nv());
                tree.mass_matrix(&q, &mut ws, &mut m_with);
                assert!(
                    (m_with[(0, 0)] - m_before[(0, 0)] - m).abs() < 1e-12,
                    "{}: the base block does not carry the payload's mass",
                    v.id
                );
                tree.clear_payloads();
                let mut m_after = nalgebra::DMatrix::zeros(tree.nv(), tree.nv());
                tree.mass_matrix(&q, &mut ws, &mut m_after);
                assert_eq!(m_after, m_before, "{}: clearing left a trace", v.id);
            }
        }
    }

    #[test]
    fn the_gravity_bias_is_the_weight_carried_through_the_jacobians() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for v in vehicles() {
            let tree = ArticulatedBody::new(&v.model);
            let mut ws = tree.workspace();
            let mut b = DVector::zeros(tree.nv());
            for _ in 0..5 {
                let (q, _, attitude) = random_state(&v, &mut rng);
                tree.bias(&attitude, &q, &DVector::zeros(tree.nv()), &mut ws, &mut b);
                // Holding the tree still takes its weight upward at every centre of mass.
                let up = attitude.inverse() * Vector3::new(0.0, 0.0, GRAVITY_MPS2);
                let props = v.model.mass_properties(&q);
                let force = up * props.mass_kg;
                let torque = props.com_in_root_m.cross(&force);
                let mut joints = DVector::zeros(v.model.dof());
                for (id, link) in v.model.links.iter().enumerate() {
                    let Some(inertial) = link.inertial else {
                        continue;
                    };
                    let com_in_link = inertial.link_from_inertial.translation.vector;
                    let jac = v.model.jacobian(&q, id, &com_in_link);
                    joints += jac.fixed_rows::<3>(0).transpose() * (up * inertial.mass_kg);
                }
                let gap = (b.fixed_rows::<3>(0) - force).amax()
                    + (b.fixed_rows::<3>(3) - torque).amax()
                    + (b.rows(6, v.model.dof()) - &joints).amax();
                assert!(gap < 1e-11, "{}: gravity bias off by {gap:e}", v.id);
            }
        }
    }

    #[test]
    fn forward_dynamics_inverts_inverse_dynamics() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for v in vehicles() {
            let tree = ArticulatedBody::new(&v.model);
            let mut ws = tree.workspace();
            let (q, nu, attitude) = random_state(&v, &mut rng);
            let tau = DVector::from_fn(tree.nv(), |_, _| rng.random_range(-5.0..5.0));
            let external: Vec<Vector6<f64>> = (0..tree.body_count())
                .map(|_| Vector6::from_fn(|_, _| rng.random_range(-2.0..2.0)))
                .collect();
            let mut acc = DVector::zeros(tree.nv());
            assert!(tree.forward_dynamics(&attitude, &q, &nu, &tau, &external, &mut ws, &mut acc));
            let mut back = DVector::zeros(tree.nv());
            tree.inverse_dynamics(&attitude, &q, &nu, &acc, &external, &mut ws, &mut back);
            let gap = (&back - &tau).amax();
            assert!(gap < 1e-9, "{}: τ back off by {gap:e}", v.id);
        }
    }

    /// A URDF may list a child's joint before its parent's: the configuration then numbers
    /// the child first, and M's factor (which runs parents first) goes through the tree's
    /// order. The FA-Hexa with its first arm joint listed last gives the same accelerations,
    /// renumbered, as the FA-Hexa as shipped.
    #[test]
    fn a_urdf_listing_a_child_joint_before_its_parent_gives_the_same_dynamics() {
        use crate::model::KinematicModel;
        let text = include_str!("../vehicles/fa-hexa.urdf");
        let start = text
            .find("<joint name=\"arm_link1_pitch_joint\"")
            .unwrap_or_else(|| panic!("the first arm joint"));
        let end = start
            + text[start..]
                .find("</joint>")
                .unwrap_or_else(|| panic!("its end"))
            + "</joint>".len();
        let moved = &text[start..end];
        let close = text.rfind("</robot>").unwrap_or_else(|| panic!("</robot>"));
        let reordered = format!(
            "{}{}{moved}\n{}",
            &text[..start],
            &text[end..close],
            &text[close..]
        );
        let shipped =
            KinematicModel::from_urdf("fa-hexa.urdf", text).unwrap_or_else(|e| panic!("{e}"));
        let listed = KinematicModel::from_urdf("reordered.urdf", &reordered)
            .unwrap_or_else(|e| panic!("{e}"));
        // The shipped configuration index of each of the reordered model's.
        let to_shipped: Vec<usize> = (0..listed.dof())
            .map(|d| {
                let name = &listed.dof_joint(d).name;
                (0..shipped.dof())
                    .find(|&e| shipped.dof_joint(e).name == *name)
                    .unwrap_or_else(|| panic!("{name}: not in the shipped model"))
            })
            .collect();
        assert_ne!(
            to_shipped,
            (0..shipped.dof()).collect::<Vec<_>>(),
            "not reordered"
        );
        let column = |d: usize| 6 + to_shipped[d];
        let (a, b) = (
            ArticulatedBody::new(&shipped),
            ArticulatedBody::new(&listed),
        );
        let (mut wa, mut wb) = (a.workspace(), b.workspace());
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let attitude = UnitQuaternion::from_euler_angles(0.2, -0.1, 0.4);
        for _ in 0..5 {
            let qa: Vec<f64> = (0..shipped.dof())
                .map(|_| rng.random_range(-0.5..0.5))
                .collect();
            let nua = DVector::from_fn(a.nv(), |_, _| rng.random_range(-1.0..1.0));
            let taua = DVector::from_fn(a.nv(), |_, _| rng.random_range(-5.0..5.0));
            let qb: Vec<f64> = (0..listed.dof()).map(|d| qa[to_shipped[d]]).collect();
            let renumber = |x: &DVector<f64>| {
                DVector::from_fn(b.nv(), |k, _| if k < 6 { x[k] } else { x[column(k - 6)] })
            };
            let (mut acc_a, mut acc_b) = (DVector::zeros(a.nv()), DVector::zeros(b.nv()));
            assert!(a.forward_dynamics(&attitude, &qa, &nua, &taua, &[], &mut wa, &mut acc_a));
            assert!(b.forward_dynamics(
                &attitude,
                &qb,
                &renumber(&nua),
                &renumber(&taua),
                &[],
                &mut wb,
                &mut acc_b
            ));
            let gap = (renumber(&acc_a) - &acc_b).amax();
            assert!(
                gap < 1e-12 * acc_a.amax().max(1.0),
                "accelerations off by {gap:e}"
            );
        }
    }

    #[test]
    fn an_implicit_drive_settles_on_its_target_and_pushes_no_harder_than_its_limit() {
        use super::{Drive, TreeState};
        let v = Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
        let tree = ArticulatedBody::new(&v.model);
        let mut ws = tree.workspace();
        let dof = v.arm_dofs()[1];
        let start = TreeState {
            world_from_base: nalgebra::Isometry3::translation(0.0, 0.0, 100.0),
            q: v.initial_configuration(),
            nu: DVector::zeros(tree.nv()),
        };
        let target = start.q[dof] + 0.4;
        // The reference's arm drive (1e5 N·m/rad, 1e3 N·m·s/rad): a 10 ms lag, far stiffer
        // than an explicit step of 1/120 s could hold. In free fall gravity loads no joint,
        // so the joint ends on its target.
        let drive = Drive {
            dof,
            stiffness: 1e5,
            damping: 1e3,
            target,
            effort_limit: 1000.0,
        };
        // Every other joint held where it starts by the same drive.
        let drives: Vec<Drive> = (0..v.model.dof())
            .map(|d| Drive {
                dof: d,
                target: if d == dof { target } else { start.q[d] },
                ..drive
            })
            .collect();
        let zero = DVector::zeros(tree.nv());
        let mut s = start.clone();
        for _ in 0..120 {
            assert!(tree.step(&mut s, &zero, &[], &drives, 1.0 / 120.0, &mut ws));
        }
        assert!(
            (s.q[dof] - target).abs() < 1e-6,
            "joint at {} after 1 s, target {target}",
            s.q[dof]
        );
        // Capped at 0.5 N·m, the first step from rest pushes with exactly the cap: the same
        // velocity change as forward dynamics under that effort.
        let capped = Drive {
            effort_limit: 0.5,
            ..drive
        };
        let h = 1.0 / 480.0;
        let mut s = start.clone();
        assert!(tree.step(&mut s, &zero, &[], &[capped], h, &mut ws));
        let mut tau = DVector::zeros(tree.nv());
        tau[6 + dof] = 0.5;
        let gap = gap_to_forward_dynamics(&tree, &mut ws, (&start, &s), &tau, h);
        assert!(
            gap < 1e-12,
            "capped step differs from forward dynamics by {gap:e}"
        );
    }

    /// The largest gap between the velocity change of a step (`before`, `after`) and
    /// forward dynamics' over `h` under the generalised force `tau` (what the drives and
    /// bounds should have come to), no external forces.
    fn gap_to_forward_dynamics(
        tree: &ArticulatedBody,
        ws: &mut super::Workspace,
        (before, after): (&super::TreeState, &super::TreeState),
        tau: &DVector<f64>,
        h: f64,
    ) -> f64 {
        let mut acc = DVector::zeros(tree.nv());
        assert!(tree.forward_dynamics(
            &before.world_from_base.rotation,
            &before.q,
            &before.nu,
            tau,
            &[],
            ws,
            &mut acc
        ));
        (&after.nu - &before.nu - &acc * h).amax()
    }

    /// Every joint mid-way between its bounds (the initial configuration rests the shoulder
    /// and the fingers on theirs, where the limits would hold them too).
    fn mid_range(v: &Vehicle) -> Vec<f64> {
        (0..v.model.dof())
            .map(|d| {
                v.model
                    .dof_joint(d)
                    .limits
                    .map_or(0.0, |l| 0.5 * (l.lower + l.upper))
            })
            .collect()
    }

    #[test]
    fn a_saturated_drive_resists_the_load_that_saturates_it() {
        use super::{Drive, TreeState};
        let v = Vehicle::builtin("ua-hexa").unwrap_or_else(|e| panic!("{e}"));
        let tree = ArticulatedBody::new(&v.model);
        let mut ws = tree.workspace();
        // The wrist (the reference's 1e5 N·m/rad, 1e3 N·m·s/rad drive, 20 N·m) on its target,
        // turning at +0.1 rad/s, under a load of −200 N·m: at the start of the step the law
        // says −D·q̇ = −100 N·m, but the load turns the joint backwards within the step, and
        // at its end the law says a large positive effort. The drive resists the load with
        // its +20 N·m: the step's velocity change is forward dynamics under −200 + 20 N·m
        // (pushing with −20, the law's sign at the start, gives −220).
        let dof = v.arm_dofs()[2];
        let mut q = mid_range(&v);
        q[dof] = 0.2;
        let mut nu = DVector::zeros(tree.nv());
        nu[6 + dof] = 0.1;
        let start = TreeState {
            world_from_base: nalgebra::Isometry3::translation(0.0, 0.0, 100.0),
            q,
            nu,
        };
        let drive = Drive {
            dof,
            stiffness: 1e5,
            damping: 1e3,
            target: 0.2,
            effort_limit: 20.0,
        };
        let mut load = DVector::zeros(tree.nv());
        load[6 + dof] = -200.0;
        let h = 1.0 / 1920.0;
        let mut s = start.clone();
        assert!(tree.step(&mut s, &load, &[], &[drive], h, &mut ws));
        let mut tau = load.clone();
        tau[6 + dof] += 20.0;
        let gap = gap_to_forward_dynamics(&tree, &mut ws, (&start, &s), &tau, h);
        assert!(
            gap < 1e-12,
            "the saturated drive's step differs from +20 N·m by {gap:e}"
        );
    }

    #[test]
    fn a_joint_driven_into_its_limit_lands_on_it_and_the_tree_keeps_its_momentum() {
        use super::TreeState;
        let v = Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"));
        let tree = ArticulatedBody::new(&v.model);
        let mut ws = tree.workspace();
        // The elbow (arm_link2, limits [0, 2.268928] rad) turning at 2 rad/s toward its upper
        // bound, 0.069 rad away, pushed on by 5 N·m; the vehicle in free fall (gravity loads
        // no joint).
        let dof = v.arm_dofs()[1];
        let upper = 2.268928;
        let mut q = mid_range(&v);
        q[dof] = 2.2;
        let mut nu = DVector::zeros(tree.nv());
        nu[6 + dof] = 2.0;
        let start = TreeState {
            world_from_base: nalgebra::Isometry3::translation(0.0, 0.0, 100.0),
            q,
            nu,
        };
        // Angular momentum about the centre of mass, world axes: gravity leaves it alone and
        // the limit's torque acts between the joint's two bodies.
        let about_com = |s: &TreeState, ws: &mut super::Workspace| {
            let props = v.model.mass_properties(&s.q);
            let h = tree.momentum(&s.q, &s.nu, ws);
            let (lin, ang) = (h.fixed_rows::<3>(0), h.fixed_rows::<3>(3));
            s.world_from_base.rotation * (ang - props.com_in_root_m.cross(&lin))
        };
        let mut tau = DVector::zeros(tree.nv());
        tau[6 + dof] = 5.0;
        let h = 1.0 / 1920.0;
        let fly = |tau: &DVector<f64>, steps: usize, ws: &mut super::Workspace| {
            let mut s = start.clone();
            let mut highest = f64::MIN;
            for _ in 0..steps {
                assert!(tree.step(&mut s, tau, &[], &[], h, ws));
                highest = highest.max(s.q[dof]);
            }
            (s, highest)
        };
        let l0 = about_com(&start, &mut ws);
        // 0.25 s: free, the joint would be ~0.6 rad past the bound.
        let (end, highest) = fly(&tau, 480, &mut ws);
        assert!(
            highest <= upper + 1e-12,
            "the joint passed its bound: {highest} > {upper}"
        );
        assert!(
            (end.q[dof] - upper).abs() < 1e-12 && end.nu[6 + dof].abs() < 1e-9,
            "held at {} rad, {} rad/s",
            end.q[dof],
            end.nu[6 + dof]
        );
        // The bound stopped ~2 rad/s of a 0.1 kg·m² link (~0.2 N·m·s of impulse); the tree's
        // momentum about its centre of mass moves only by the stepper's own error, as with the
        // joint turning at 2 rad/s clear of its bounds (measured: 3.1e-5 at the bound, 6.4e-5
        // clear; a limit torque acting on one body alone would move it by ~0.2).
        let drift = (about_com(&end, &mut ws) - l0).norm();
        let mut away = start.clone();
        away.q[dof] = 0.5;
        let clear = {
            let mut s = away.clone();
            for _ in 0..480 {
                assert!(tree.step(&mut s, &DVector::zeros(tree.nv()), &[], &[], h, &mut ws));
            }
            assert!(s.q[dof] < upper, "the clear flight reached the bound");
            (about_com(&s, &mut ws) - about_com(&away, &mut ws)).norm()
        };
        assert!(
            drift < 1e-3 && drift < 10.0 * clear.max(1e-6),
            "momentum about the CoM moved by {drift:e} N·m·s at the bound, {clear:e} clear of it"
        );
        // A bound holds only one way: resting on it under the push (held from the start of
        // each step by `LOCK_WEIGHT`), then pulled away, the joint leaves at once, as forward
        // dynamics says.
        let mut s = start.clone();
        s.q[dof] = upper;
        s.nu[6 + dof] = 0.0;
        for _ in 0..10 {
            assert!(tree.step(&mut s, &tau, &[], &[], h, &mut ws));
        }
        assert!(
            (s.q[dof] - upper).abs() < 1e-12 && s.nu[6 + dof].abs() < 1e-9,
            "resting at {} rad, {} rad/s",
            s.q[dof],
            s.nu[6 + dof]
        );
        let at = s.clone();
        let mut pull = DVector::zeros(tree.nv());
        pull[6 + dof] = -5.0;
        assert!(tree.step(&mut s, &pull, &[], &[], h, &mut ws));
        assert!(s.nu[6 + dof] < 0.0, "the joint stayed on its bound");
        let gap = gap_to_forward_dynamics(&tree, &mut ws, (&at, &s), &pull, h);
        assert!(
            gap < 1e-12,
            "pulled off its bound: ν differs from forward dynamics by {gap:e}"
        );
    }

    /// The state of a free-falling tree: base position and attitude (world), q, ν.
    #[derive(Clone)]
    struct State {
        p: Vector3<f64>,
        r: Quaternion<f64>,
        q: DVector<f64>,
        nu: DVector<f64>,
    }

    fn derivative(tree: &ArticulatedBody, ws: &mut super::Workspace, s: &State) -> State {
        let attitude = UnitQuaternion::from_quaternion(s.r);
        let vb = Vector3::new(s.nu[0], s.nu[1], s.nu[2]);
        let wb = Vector3::new(s.nu[3], s.nu[4], s.nu[5]);
        let mut acc = DVector::zeros(tree.nv());
        let zero = DVector::zeros(tree.nv());
        assert!(tree.forward_dynamics(&attitude, s.q.as_slice(), &s.nu, &zero, &[], ws, &mut acc));
        State {
            p: attitude * vb,
            r: s.r * Quaternion::from_parts(0.0, wb) * 0.5,
            q: s.nu.rows(6, s.q.len()).into_owned(),
            nu: acc,
        }
    }

    fn advance(s: &State, d: &State, h: f64) -> State {
        State {
            p: s.p + d.p * h,
            r: s.r + d.r * h,
            q: &s.q + &d.q * h,
            nu: &s.nu + &d.nu * h,
        }
    }

    #[test]
    fn a_falling_tree_keeps_its_energy_and_its_angular_momentum_about_the_centre_of_mass() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for v in vehicles() {
            let tree = ArticulatedBody::new(&v.model);
            let mut ws = tree.workspace();
            let (q, nu, attitude) = random_state(&v, &mut rng);
            let mut s = State {
                p: Vector3::new(0.0, 0.0, 1.0),
                r: *attitude.quaternion(),
                q: DVector::from_vec(q),
                nu,
            };
            // Energy (kinetic + potential) and angular momentum about the centre of mass, in
            // world axes.
            let invariants = |s: &State, ws: &mut super::Workspace| {
                let attitude = UnitQuaternion::from_quaternion(s.r);
                let q = s.q.as_slice();
                let props = v.model.mass_properties(q);
                let height = (s.p + attitude * props.com_in_root_m).z;
                let energy =
                    tree.kinetic_energy(q, &s.nu, ws) + props.mass_kg * GRAVITY_MPS2 * height;
                let h = tree.momentum(q, &s.nu, ws);
                let (lin, ang) = (h.fixed_rows::<3>(0), h.fixed_rows::<3>(3));
                let about_com = ang - props.com_in_root_m.cross(&lin);
                (energy, attitude * about_com)
            };
            let (e0, l0) = invariants(&s, &mut ws);
            let h = 1e-3;
            for _ in 0..1000 {
                let k1 = derivative(&tree, &mut ws, &s);
                let k2 = derivative(&tree, &mut ws, &advance(&s, &k1, h / 2.0));
                let k3 = derivative(&tree, &mut ws, &advance(&s, &k2, h / 2.0));
                let k4 = derivative(&tree, &mut ws, &advance(&s, &k3, h));
                let step = |a: &State, b: &State, c: &State, d: &State| State {
                    p: (a.p + b.p * 2.0 + c.p * 2.0 + d.p) / 6.0,
                    r: (a.r + b.r * 2.0 + c.r * 2.0 + d.r) / 6.0,
                    q: (&a.q + &b.q * 2.0 + &c.q * 2.0 + &d.q) / 6.0,
                    nu: (&a.nu + &b.nu * 2.0 + &c.nu * 2.0 + &d.nu) / 6.0,
                };
                s = advance(&s, &step(&k1, &k2, &k3, &k4), h);
                s.r = s.r.normalize();
            }
            let (e1, l1) = invariants(&s, &mut ws);
            let scale = l0.norm().max(1e-3);
            assert!(
                relative_gap(e1, e0) < 1e-7,
                "{}: energy {e0} J → {e1} J over 1 s of free fall",
                v.id
            );
            assert!(
                (l1 - l0).norm() / scale < 1e-7,
                "{}: angular momentum about the CoM {l0:?} → {l1:?}",
                v.id
            );
        }
    }
}
