//! Primitives tessellated once into light triangle meshes, in their own frame with their
//! sizes baked in (so an object's transform is a rigid motion and normals turn with it).
//!
//! Counts (triangles): box 12, sphere 2·S·(R−1) with S = 24 segments and R = 12 rings (528),
//! cylinder 4·S (96), capsule 2·S + 2·S·(R−1) (576), plane 2. A vehicle of ~25 shapes and a task
//! scene of ~20 stay under ~10k triangles, where llvmpipe renders 384×384 at hundreds of fps.
//! Triangles are wound counter-clockwise seen from outside.

use bytemuck::{Pod, Zeroable};
use nalgebra::Vector3;
use platform::Shape;
use sim_twin::VisualShape;

/// Segments around a round shape.
pub const ROUND_SEGMENTS: u32 = 24;
/// Rings from pole to pole of a sphere (and of a capsule's two caps together).
pub const SPHERE_RINGS: u32 = 12;
/// Half side of the drawn ground plane, m (the physics' half-space is infinite).
pub const FLOOR_HALF_SIZE_M: f32 = 60.0;

/// One vertex: position and unit normal in the shape frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    /// Position, m.
    pub position: [f32; 3],
    /// Unit outward normal.
    pub normal: [f32; 3],
}

/// A triangle mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertices.
    pub vertices: Vec<Vertex>,
    /// Triangles, three indices each, counter-clockwise from outside.
    pub indices: Vec<u32>,
}

fn v3(v: Vector3<f64>) -> [f32; 3] {
    // Render precision: f32 is what the GPU draws with.
    #[allow(clippy::cast_possible_truncation)]
    [v.x as f32, v.y as f32, v.z as f32]
}

impl Mesh {
    fn push(&mut self, position: Vector3<f64>, normal: Vector3<f64>) -> u32 {
        let index = u32::try_from(self.vertices.len()).unwrap_or(u32::MAX);
        self.vertices.push(Vertex {
            position: v3(position),
            normal: v3(normal),
        });
        index
    }

    fn triangle(&mut self, a: u32, b: u32, c: u32) {
        self.indices.extend_from_slice(&[a, b, c]);
    }

    /// Triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// A box of half extents `h`.
    pub fn cuboid(h: &Vector3<f64>) -> Self {
        let mut m = Self::default();
        for axis in 0..3 {
            for sign in [1.0, -1.0] {
                let mut n = Vector3::zeros();
                n[axis] = sign;
                // Two tangents t1 × t2 = n.
                let mut t1 = Vector3::zeros();
                t1[(axis + 1) % 3] = 1.0;
                let mut t2 = Vector3::zeros();
                t2[(axis + 2) % 3] = sign;
                let corner = |a: f64, b: f64| {
                    Vector3::new(
                        h.x * (n.x + a * t1.x + b * t2.x),
                        h.y * (n.y + a * t1.y + b * t2.y),
                        h.z * (n.z + a * t1.z + b * t2.z),
                    )
                };
                let i0 = m.push(corner(-1.0, -1.0), n);
                let i1 = m.push(corner(1.0, -1.0), n);
                let i2 = m.push(corner(1.0, 1.0), n);
                let i3 = m.push(corner(-1.0, 1.0), n);
                m.triangle(i0, i1, i2);
                m.triangle(i0, i2, i3);
            }
        }
        m
    }

    /// Unit direction at azimuth index `k` of `ROUND_SEGMENTS`.
    fn around(k: u32) -> (f64, f64) {
        let a = std::f64::consts::TAU * f64::from(k) / f64::from(ROUND_SEGMENTS);
        (a.cos(), a.sin())
    }

    /// A sphere of radius `r` centred at `(0, 0, z0)`, or, with `half` = Some(+1 / −1), only
    /// its upper / lower half (a capsule's caps).
    fn sphere_part(m: &mut Self, r: f64, z0: f64, half: Option<f64>) {
        let rings = SPHERE_RINGS;
        let (first, last) = match half {
            None => (0, rings),
            Some(s) if s > 0.0 => (0, rings / 2),
            Some(_) => (rings / 2, rings),
        };
        let base = u32::try_from(m.vertices.len()).unwrap_or(u32::MAX);
        for i in first..=last {
            let polar = std::f64::consts::PI * f64::from(i) / f64::from(rings);
            let (s, c) = polar.sin_cos();
            for k in 0..=ROUND_SEGMENTS {
                let (x, y) = Self::around(k);
                let n = Vector3::new(s * x, s * y, c);
                m.push(Vector3::new(0.0, 0.0, z0) + r * n, n);
            }
        }
        let stride = ROUND_SEGMENTS + 1;
        for i in 0..(last - first) {
            for k in 0..ROUND_SEGMENTS {
                let a = base + i * stride + k;
                let b = a + stride;
                // Ring i is above ring i + 1; seen from outside, counter-clockwise.
                let (top, bottom) = (first + i, first + i + 1);
                if top != 0 {
                    m.triangle(a, b, a + 1);
                }
                if bottom != rings {
                    m.triangle(a + 1, b, b + 1);
                }
            }
        }
    }

    /// A sphere of radius `r`.
    pub fn sphere(r: f64) -> Self {
        let mut m = Self::default();
        Self::sphere_part(&mut m, r, 0.0, None);
        m
    }

    /// The side of a cylinder of radius `r` from z = −hl to z = +hl (smooth normals).
    fn tube(m: &mut Self, r: f64, hl: f64) {
        let base = u32::try_from(m.vertices.len()).unwrap_or(u32::MAX);
        for k in 0..=ROUND_SEGMENTS {
            let (x, y) = Self::around(k);
            let n = Vector3::new(x, y, 0.0);
            m.push(Vector3::new(r * x, r * y, hl), n);
            m.push(Vector3::new(r * x, r * y, -hl), n);
        }
        for k in 0..ROUND_SEGMENTS {
            let top = base + 2 * k;
            let (bottom, next_top, next_bottom) = (top + 1, top + 2, top + 3);
            m.triangle(top, bottom, next_bottom);
            m.triangle(top, next_bottom, next_top);
        }
    }

    /// A cylinder of radius `r` along z, from −hl to +hl, with flat caps.
    pub fn cylinder(r: f64, hl: f64) -> Self {
        let mut m = Self::default();
        Self::tube(&mut m, r, hl);
        for sign in [1.0, -1.0] {
            let n = Vector3::new(0.0, 0.0, sign);
            let centre = m.push(Vector3::new(0.0, 0.0, sign * hl), n);
            let first = u32::try_from(m.vertices.len()).unwrap_or(u32::MAX);
            for k in 0..ROUND_SEGMENTS {
                let (x, y) = Self::around(k);
                m.push(Vector3::new(r * x, r * y, sign * hl), n);
            }
            for k in 0..ROUND_SEGMENTS {
                let a = first + k;
                let b = first + (k + 1) % ROUND_SEGMENTS;
                if sign > 0.0 {
                    m.triangle(centre, a, b);
                } else {
                    m.triangle(centre, b, a);
                }
            }
        }
        m
    }

    /// A capsule of radius `r` along z: a tube from −hl to +hl and two hemispherical caps.
    pub fn capsule(r: f64, hl: f64) -> Self {
        let mut m = Self::default();
        Self::tube(&mut m, r, hl);
        Self::sphere_part(&mut m, r, hl, Some(1.0));
        Self::sphere_part(&mut m, r, -hl, Some(-1.0));
        m
    }

    /// A convex polyhedron, flat-shaded: each triangle gets its own vertices and the normal
    /// of its plane, turned away from the centroid (the input winding is not trusted).
    pub fn convex(vertices: &[Vector3<f64>], triangles: &[[u32; 3]]) -> Option<Self> {
        if vertices.is_empty() {
            return None;
        }
        #[allow(clippy::cast_precision_loss)]
        let centroid = vertices.iter().sum::<Vector3<f64>>() / vertices.len() as f64;
        let mut m = Self::default();
        for t in triangles {
            let [a, b, c] = t.map(|i| vertices.get(i as usize).copied());
            let (Some(a), Some(mut b), Some(mut c)) = (a, b, c) else {
                return None;
            };
            let Some(mut n) = (b - a).cross(&(c - a)).try_normalize(1e-15) else {
                continue; // a degenerate sliver draws nothing
            };
            if n.dot(&(a - centroid)) < 0.0 {
                std::mem::swap(&mut b, &mut c);
                n = -n;
            }
            let i = m.push(a, n);
            m.push(b, n);
            m.push(c, n);
            m.triangle(i, i + 1, i + 2);
        }
        Some(m)
    }

    /// The ground: a square of half side [`FLOOR_HALF_SIZE_M`] in z = 0, facing +z.
    pub fn plane() -> Self {
        let h = f64::from(FLOOR_HALF_SIZE_M);
        let n = Vector3::z();
        let mut m = Self::default();
        let a = m.push(Vector3::new(-h, -h, 0.0), n);
        let b = m.push(Vector3::new(h, -h, 0.0), n);
        let c = m.push(Vector3::new(h, h, 0.0), n);
        let d = m.push(Vector3::new(-h, h, 0.0), n);
        m.triangle(a, b, c);
        m.triangle(a, c, d);
        m
    }

    /// A URDF visual shape of a vehicle.
    pub fn from_urdf_shape(shape: &Shape) -> Self {
        match *shape {
            Shape::Box { size_m } => Self::cuboid(&(0.5 * size_m)),
            Shape::Cylinder { radius_m, length_m } => Self::cylinder(radius_m, 0.5 * length_m),
            Shape::Capsule { radius_m, length_m } => Self::capsule(radius_m, 0.5 * length_m),
            Shape::Sphere { radius_m } => Self::sphere(radius_m),
        }
    }

    /// A twin scene shape; None for a polyhedron with out-of-range indices.
    pub fn from_scene_shape(shape: &VisualShape) -> Option<Self> {
        Some(match shape {
            VisualShape::Box { half_extents_m } => Self::cuboid(half_extents_m),
            VisualShape::Sphere { radius_m } => Self::sphere(*radius_m),
            VisualShape::Cylinder {
                radius_m,
                half_length_m,
            } => Self::cylinder(*radius_m, *half_length_m),
            VisualShape::Capsule {
                radius_m,
                half_length_m,
            } => Self::capsule(*radius_m, *half_length_m),
            VisualShape::ConvexMesh {
                vertices_m,
                triangles,
            } => Self::convex(vertices_m, triangles)?,
            VisualShape::Plane => Self::plane(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every triangle faces away from the shape's centre (outward, counter-clockwise) and its
    /// vertex normals agree with its face normal.
    fn assert_outward(m: &Mesh) {
        for t in m.indices.chunks(3) {
            let p = |i: u32| {
                let v = m.vertices[i as usize].position;
                Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
            };
            let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
            let face = (b - a).cross(&(c - a));
            let mid = (a + b + c) / 3.0;
            assert!(face.dot(&mid) > 0.0, "inward triangle at {mid:?}");
            let n = m.vertices[t[0] as usize].normal;
            let n = Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
            assert!(face.dot(&n) > 0.0, "normal against the face at {mid:?}");
        }
    }

    #[test]
    fn primitives_are_closed_outward_and_light() {
        let cube = Mesh::cuboid(&Vector3::new(0.1, 0.2, 0.3));
        assert_eq!(cube.triangle_count(), 12);
        assert_outward(&cube);
        let sphere = Mesh::sphere(0.5);
        assert_eq!(sphere.triangle_count(), 2 * 24 * 11);
        assert_outward(&sphere);
        let cylinder = Mesh::cylinder(0.1, 0.4);
        assert_eq!(cylinder.triangle_count(), 4 * 24);
        assert_outward(&cylinder);
        let capsule = Mesh::capsule(0.1, 0.3);
        assert_eq!(capsule.triangle_count(), 2 * 24 + 2 * 24 * 11);
        assert_outward(&capsule);
        // A box's extent is its size.
        let max_x = cube
            .vertices
            .iter()
            .map(|v| v.position[0])
            .fold(f32::MIN, f32::max);
        assert!((max_x - 0.1).abs() < 1e-7);
    }

    #[test]
    fn convex_mesh_is_turned_outward_whatever_the_input_winding() {
        let v = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        // A tetrahedron with mixed windings.
        let tris = [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 2, 3]];
        let m = Mesh::convex(&v, &tris).unwrap_or_default();
        assert_eq!(m.triangle_count(), 4);
        for t in m.indices.chunks(3) {
            let p = |i: u32| {
                let q = m.vertices[i as usize].position;
                Vector3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]))
            };
            let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
            let centroid = Vector3::new(0.25, 0.25, 0.25);
            assert!((b - a).cross(&(c - a)).dot(&(a - centroid)) > 0.0);
        }
        assert!(Mesh::convex(&v, &[[0, 1, 9]]).is_none());
    }
}
