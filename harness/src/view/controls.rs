//! The viewer's camera: it starts at a dataset camera (rendered exactly as
//! `tgs render` renders it) and moves by orbit, pan, zoom and fly steps.

use glam::{DMat3, DQuat, DVec3, Vec3};
use tgs_pipelines::Camera;

/// A free camera around an orbit target.
#[derive(Clone, Debug)]
pub struct Nav {
    /// The dataset camera it stands at, while nothing moved it.
    at: Option<Camera>,
    /// Intrinsics (and their image size) of the camera it started from.
    lens: Camera,
    eye: DVec3,
    /// Rows: the view's x (right), y (down) and z (forward) axes in world space.
    rot: DMat3,
    target: DVec3,
    /// The scene's up (the training cameras' mean up).
    up: DVec3,
}

/// Radians per pixel of an orbit drag.
const ORBIT_RAD_PER_PX: f64 = 0.005;

impl Nav {
    /// At `cam`, orbiting `target` (the point the training cameras look at).
    pub fn at(cam: &Camera, target: DVec3, up: DVec3) -> Nav {
        let r = |i: usize| DVec3::from([0, 1, 2].map(|j| cam.world_to_view[i][j] as f64));
        let rot = DMat3::from_cols(r(0), r(1), r(2)).transpose();
        let eye = Vec3::from(cam.centre()).as_dvec3();
        // A target behind the camera (or on it) orbits a point ahead of it instead.
        let ahead = (target - eye).dot(r(2));
        let target = if ahead > 1e-6 { eye + r(2) * ahead } else { eye + r(2) };
        Nav { at: Some(*cam), lens: *cam, eye, rot, target, up: if up.length() > 0.5 { up.normalize() } else { -r(1) } }
    }

    /// The dataset camera it stands at unmoved, if any.
    pub fn unmoved(&self) -> Option<&Camera> {
        self.at.as_ref()
    }

    fn axis(&self, i: usize) -> DVec3 {
        self.rot.row(i)
    }

    /// Rotate eye and view about the target: `dx`, `dy` pixels of a drag
    /// (yaw about the scene's up, pitch about the view's right axis).
    pub fn orbit(&mut self, dx: f64, dy: f64) {
        let yaw = DQuat::from_axis_angle(self.up, -dx * ORBIT_RAD_PER_PX);
        let pitch = DQuat::from_axis_angle(self.axis(0), -dy * ORBIT_RAD_PER_PX);
        let q = yaw * pitch;
        self.eye = self.target + q * (self.eye - self.target);
        let m = DMat3::from_quat(q);
        self.rot = (m * self.rot.transpose()).transpose();
        self.at = None;
    }

    /// Move eye and target in the view's plane by `dx`, `dy` pixels (the
    /// target's point follows the cursor).
    pub fn pan(&mut self, dx: f64, dy: f64) {
        let dist = (self.target - self.eye).length();
        let per_px = dist / self.lens.fx as f64;
        let d = (self.axis(0) * -dx + self.axis(1) * -dy) * per_px;
        self.eye += d;
        self.target += d;
        self.at = None;
    }

    /// Move toward the target by `steps` wheel steps (10% of the distance
    /// each; negative steps move away).
    pub fn zoom(&mut self, steps: f64) {
        let off = self.eye - self.target;
        self.eye = self.target + off * 0.9f64.powf(steps);
        self.at = None;
    }

    /// Fly: move eye and target along the view's right, down and forward
    /// axes by `d` (in units of 5% of the distance to the target).
    pub fn fly(&mut self, d: DVec3) {
        let step = 0.05 * (self.target - self.eye).length();
        let m = (self.axis(0) * d.x + self.axis(1) * d.y + self.axis(2) * d.z) * step;
        self.eye += m;
        self.target += m;
        self.at = None;
    }

    /// The camera for a `width` x `height` view: the dataset camera itself
    /// when unmoved at its own size, else the pose with the starting
    /// camera's field of view fitted into the view.
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        let l = &self.lens;
        if let Some(c) = self.at.filter(|c| (c.width, c.height) == (width, height)) {
            return c;
        }
        let s = (width as f32 / l.width as f32).min(height as f32 / l.height as f32);
        let centre = |c: f32, size: u32, own: u32| (c + 0.5) * s - 0.5 + 0.5 * (size as f32 - own as f32 * s);
        let rows = self.rot;
        let row = |i: usize| {
            let a = rows.row(i);
            [a.x as f32, a.y as f32, a.z as f32, -a.dot(self.eye) as f32]
        };
        Camera { width, height, fx: l.fx * s, fy: l.fy * s, cx: centre(l.cx, width, l.width), cy: centre(l.cy, height, l.height), world_to_view: [row(0), row(1), row(2)] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera::look_at([0.0, -4.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.8, 40, 30)
    }

    #[test]
    fn unmoved_is_the_dataset_camera_and_moves_keep_a_rotation() {
        let c = cam();
        let mut n = Nav::at(&c, DVec3::ZERO, DVec3::Z);
        assert_eq!(n.camera(40, 30), c);
        let big = n.camera(80, 60);
        assert_eq!((big.fx, big.cx, big.cy), (2.0 * c.fx, 2.0 * c.cx + 0.5, 2.0 * c.cy + 0.5));
        n.orbit(100.0, -40.0);
        n.pan(3.0, 2.0);
        n.zoom(2.0);
        n.fly(DVec3::new(1.0, 0.0, -1.0));
        assert!(n.unmoved().is_none());
        let m = n.camera(40, 30);
        let r = DMat3::from_cols_array_2d(&[0, 1, 2].map(|i| [0, 1, 2].map(|j| m.world_to_view[i][j] as f64)));
        assert!((r * r.transpose() - DMat3::IDENTITY).to_cols_array().iter().all(|v| v.abs() < 1e-6), "not a rotation: {r:?}");
        assert!(m.validate().is_ok());
    }

    #[test]
    fn orbit_keeps_the_distance_to_the_target_and_a_full_turn_returns() {
        let c = cam();
        let mut n = Nav::at(&c, DVec3::ZERO, DVec3::Z);
        let d0 = (n.eye - n.target).length();
        let steps = (std::f64::consts::TAU / ORBIT_RAD_PER_PX / 100.0).round() as usize;
        let turn = std::f64::consts::TAU / ORBIT_RAD_PER_PX / steps as f64;
        for _ in 0..steps {
            n.orbit(turn, 0.0);
            assert!(((n.eye - n.target).length() - d0).abs() < 1e-9);
        }
        let back = n.camera(40, 30);
        for i in 0..3 {
            for j in 0..4 {
                assert!((back.world_to_view[i][j] - c.world_to_view[i][j]).abs() < 1e-4, "row {i} col {j}: {back:?} vs {c:?}");
            }
        }
        // The target stays where the camera looks.
        let fwd = n.axis(2);
        assert!(((n.target - n.eye).normalize() - fwd).length() < 1e-6);
    }

    #[test]
    fn zoom_moves_toward_the_target_and_back() {
        let mut n = Nav::at(&cam(), DVec3::ZERO, DVec3::Z);
        let d0 = (n.eye - n.target).length();
        n.zoom(3.0);
        assert!(((n.eye - n.target).length() - d0 * 0.729).abs() < 1e-9);
        n.zoom(-3.0);
        assert!(((n.eye - n.target).length() - d0).abs() < 1e-9);
    }
}
