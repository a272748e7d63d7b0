//! Rigid (SE(3)) and similarity (Sim(3)) transforms.

use crate::{Mat3, Quat, Vec3};
use nalgebra::{Matrix3x4, Matrix4};

/// A rigid transform `x -> R x + t`, named `a_from_b` by its users.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid3 {
    /// Rotation part.
    pub rotation: Quat,
    /// Translation part.
    pub translation: Vec3,
}

impl Default for Rigid3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl Rigid3 {
    /// The identity transform.
    pub fn identity() -> Self {
        Self { rotation: Quat::identity(), translation: Vec3::zeros() }
    }

    /// Builds from a rotation and a translation.
    pub fn new(rotation: Quat, translation: Vec3) -> Self {
        Self { rotation, translation }
    }

    /// Builds from a quaternion given as (w, x, y, z) (COLMAP order); the
    /// quaternion is normalised.
    pub fn from_wxyz(q: [f64; 4], t: [f64; 3]) -> Self {
        let quat = nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]);
        Self { rotation: Quat::from_quaternion(quat), translation: Vec3::new(t[0], t[1], t[2]) }
    }

    /// The rotation as (w, x, y, z), COLMAP order.
    pub fn quat_wxyz(&self) -> [f64; 4] {
        let q = self.rotation.quaternion();
        [q.w, q.i, q.j, q.k]
    }

    /// The rotation as (x, y, z, w), TUM order.
    pub fn quat_xyzw(&self) -> [f64; 4] {
        let q = self.rotation.quaternion();
        [q.i, q.j, q.k, q.w]
    }

    /// Builds from a rotation matrix (re-orthonormalised) and a translation.
    pub fn from_rotation_matrix(r: &Mat3, t: Vec3) -> Self {
        let rot = nalgebra::Rotation3::from_matrix(r);
        Self { rotation: Quat::from_rotation_matrix(&rot), translation: t }
    }

    /// Rotation matrix.
    pub fn rotation_matrix(&self) -> Mat3 {
        self.rotation.to_rotation_matrix().into_inner()
    }

    /// The 3x4 matrix `[R | t]`.
    pub fn matrix3x4(&self) -> Matrix3x4<f64> {
        let mut m = Matrix3x4::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation_matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// The homogeneous 4x4 matrix.
    pub fn matrix4(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 4>(0, 0).copy_from(&self.matrix3x4());
        m
    }

    /// Inverse transform.
    pub fn inverse(&self) -> Self {
        let inv = self.rotation.inverse();
        Self { rotation: inv, translation: -(inv * self.translation) }
    }

    /// Applies the transform to a point.
    pub fn transform_point(&self, p: &Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    /// For a `cam_from_world` pose: the camera centre in world coordinates.
    pub fn center(&self) -> Vec3 {
        -(self.rotation.inverse() * self.translation)
    }
}

impl std::ops::Mul for Rigid3 {
    type Output = Rigid3;
    /// `a_from_b * b_from_c = a_from_c`.
    fn mul(self, rhs: Rigid3) -> Rigid3 {
        Rigid3 {
            rotation: self.rotation * rhs.rotation,
            translation: self.rotation * rhs.translation + self.translation,
        }
    }
}

/// A similarity transform `x -> s R x + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    /// Positive scale.
    pub scale: f64,
    /// Rotation part.
    pub rotation: Quat,
    /// Translation part.
    pub translation: Vec3,
}

impl Default for Sim3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl Sim3 {
    /// The identity transform.
    pub fn identity() -> Self {
        Self { scale: 1.0, rotation: Quat::identity(), translation: Vec3::zeros() }
    }

    /// Applies the transform to a point.
    pub fn transform_point(&self, p: &Vec3) -> Vec3 {
        self.scale * (self.rotation * p) + self.translation
    }

    /// Inverse transform.
    pub fn inverse(&self) -> Self {
        let inv = self.rotation.inverse();
        let s = 1.0 / self.scale;
        Self { scale: s, rotation: inv, translation: -(s * (inv * self.translation)) }
    }

    /// Applies the similarity to a `world_from_cam` pose (the camera moves with
    /// the world): rotation is composed, the centre is transformed.
    pub fn transform_world_from_cam(&self, world_from_cam: &Rigid3) -> Rigid3 {
        Rigid3 {
            rotation: self.rotation * world_from_cam.rotation,
            translation: self.transform_point(&world_from_cam.translation),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Rigid3 {
        Rigid3::new(Quat::from_euler_angles(0.3, -0.2, 1.1), Vec3::new(1.0, -2.0, 0.5))
    }

    #[test]
    fn inverse_and_compose() {
        let a = sample();
        let id = a * a.inverse();
        assert!(id.translation.norm() < 1e-12);
        assert!(id.rotation.angle() < 1e-12);
        let p = Vec3::new(0.1, 0.2, 0.3);
        let q = a.transform_point(&p);
        assert!((a.inverse().transform_point(&q) - p).norm() < 1e-12);
        let m = a.matrix4() * nalgebra::Vector4::new(p.x, p.y, p.z, 1.0);
        assert!((m.xyz() - q).norm() < 1e-12);
    }

    #[test]
    fn center_is_inverse_translation() {
        let a = sample();
        assert!((a.center() - a.inverse().translation).norm() < 1e-12);
        assert!(a.transform_point(&a.center()).norm() < 1e-12);
    }

    #[test]
    fn quaternion_orders() {
        let a = sample();
        let w = a.quat_wxyz();
        let x = a.quat_xyzw();
        assert_eq!([w[1], w[2], w[3], w[0]], x);
        let b = Rigid3::from_wxyz(w, [1.0, -2.0, 0.5]);
        assert!((b.rotation_matrix() - a.rotation_matrix()).norm() < 1e-12);
    }

    #[test]
    fn sim3_inverse() {
        let s = Sim3 {
            scale: 2.5,
            rotation: Quat::from_euler_angles(0.1, 0.2, 0.3),
            translation: Vec3::new(1.0, 2.0, 3.0),
        };
        let p = Vec3::new(-1.0, 0.5, 4.0);
        assert!((s.inverse().transform_point(&s.transform_point(&p)) - p).norm() < 1e-12);
    }
}
