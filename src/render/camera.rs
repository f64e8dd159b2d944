//! A pinhole camera: world → view → clip space.
//!
//! Clip space here is `(x·f/aspect, y·f, −, w)` with `w` the distance along the view axis; the renderer
//! needs no z/far plane because it depth-tests with 1/w (larger is nearer), which is affine in screen space.

use glam::{DMat4, DVec3, DVec4};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: DVec3,
    pub look_at: DVec3,
    pub up: DVec3,
    /// Vertical field of view, degrees.
    pub fov_deg: f64,
}

impl Camera {
    /// Checks the camera is usable; the message names what is wrong.
    pub(crate) fn validate(&self) -> Result<(), String> {
        let dir = self.look_at - self.position;
        if !(self.position.is_finite() && self.look_at.is_finite() && self.up.is_finite()) {
            return Err("camera vectors must be finite".into());
        }
        if dir.length() < 1e-12 {
            return Err("`look_at` equals `position`: the camera has no viewing direction".into());
        }
        if self.up.length() < 1e-12 {
            return Err("`up` must be a non-zero vector".into());
        }
        if dir.normalize().cross(self.up).length() < 1e-9 {
            return Err("`up` is parallel to the viewing direction".into());
        }
        if !(self.fov_deg > 0.1 && self.fov_deg < 179.0) {
            return Err(format!("fov {} is outside 0.1..179 degrees", self.fov_deg));
        }
        Ok(())
    }

    /// World → view matrix (right-handed, looking down −z, `up` projected to +y).
    pub(crate) fn view(&self) -> DMat4 {
        let f = (self.look_at - self.position).normalize();
        let s = f.cross(self.up).normalize();
        let u = s.cross(f);
        let e = self.position;
        DMat4::from_cols(
            DVec4::new(s.x, u.x, -f.x, 0.0),
            DVec4::new(s.y, u.y, -f.y, 0.0),
            DVec4::new(s.z, u.z, -f.z, 0.0),
            DVec4::new(-s.dot(e), -u.dot(e), f.dot(e), 1.0),
        )
    }

    /// World → clip transform for an image of the given aspect (width/height).
    pub(crate) fn clip_transform(&self, aspect: f64) -> ClipTransform {
        let f = 1.0 / (self.fov_deg.to_radians() / 2.0).tan();
        ClipTransform { view: self.view(), sx: f / aspect, sy: f }
    }
}

/// World → clip, cached per render.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ClipTransform {
    view: DMat4,
    sx: f64,
    sy: f64,
}

impl ClipTransform {
    /// `(x_clip, y_clip, unused, w)`; a point is in front of the camera when `w > 0`.
    pub(crate) fn apply(&self, p: DVec3) -> DVec4 {
        let v = self.view.transform_point3(p);
        DVec4::new(v.x * self.sx, v.y * self.sy, 0.0, -v.z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_projects_to_the_axis_and_edge_of_fov_to_one() {
        let c = Camera { position: DVec3::new(0.0, 0.0, 6.0), look_at: DVec3::ZERO, up: DVec3::Y, fov_deg: 90.0 };
        c.validate().unwrap();
        let t = c.clip_transform(1.0);
        let o = t.apply(DVec3::ZERO);
        assert!(o.x.abs() < 1e-12 && o.y.abs() < 1e-12 && (o.w - 6.0).abs() < 1e-12);
        // At 90° the frustum edge is at |y| = distance.
        let e = t.apply(DVec3::new(0.0, 6.0, 0.0));
        assert!((e.y / e.w - 1.0).abs() < 1e-12);
        let bad = Camera { up: DVec3::Z, ..c };
        assert!(bad.validate().is_err());
    }
}
