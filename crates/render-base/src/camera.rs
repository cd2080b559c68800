//! The pinhole camera shared by the path tracer, the rasteriser and the ray tracer.
//!
//! Pixel convention (docs/architecture.md, Pixels): pixel `(x, y)` covers `[x, x+1) x [y, y+1)`, its centre is
//! `(x + 0.5, y + 0.5)`, and `y` grows downwards (row 0 is the top of the image). Camera space
//! follows the OpenCV / 3DGS convention: +X right, +Y down, +Z forward, so that projection and
//! ray generation are exact inverses of each other with no sign flips hidden in either.

use glam::{Mat3, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// Why a camera could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraError {
    /// Width or height was zero.
    ZeroImageSize { width: u32, height: u32 },
    /// The vertical field of view was not in (0, 180) degrees (or was NaN).
    BadFieldOfView(f32),
    /// Eye and target coincide, or `up` is parallel to the viewing direction, or a value is not finite.
    DegenerateFrame,
    /// Width or height is more than [`MAX_IMAGE_SIDE`].
    ImageTooLarge { width: u32, height: u32 },
}

/// The largest image side a camera accepts: 32768 pixels (a 1-gigapixel square). Larger sizes are
/// far more often a typo than an intent, and every per-pixel buffer is sized from them.
pub const MAX_IMAGE_SIDE: u32 = 32_768;

/// The smallest angle, in degrees, between `up` and the viewing direction: closer than this, the
/// image's roll is set by rounding error rather than by `up`.
pub const MIN_UP_ANGLE_DEGREES: f32 = 0.1;

impl std::fmt::Display for CameraError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CameraError::ZeroImageSize { width, height } => write!(
                f,
                "image size {width}x{height} is empty: width and height must both be at least 1"
            ),
            CameraError::BadFieldOfView(v) => write!(
                f,
                "vertical field of view {v} degrees is invalid: expected a value in (0, 180)"
            ),
            CameraError::DegenerateFrame => write!(
                f,
                "camera frame is degenerate: eye, target and up must be finite, eye != target, \
                 and up must be at least {MIN_UP_ANGLE_DEGREES} degrees from the viewing direction"
            ),
            CameraError::ImageTooLarge { width, height } => write!(
                f,
                "image size {width}x{height} is too large: width and height must be at most \
                 {MAX_IMAGE_SIDE}"
            ),
        }
    }
}

impl std::error::Error for CameraError {}

/// Refuses an empty image and one with a side over [`MAX_IMAGE_SIDE`].
fn check_image_size(width: u32, height: u32) -> Result<(), CameraError> {
    if width == 0 || height == 0 {
        return Err(CameraError::ZeroImageSize { width, height });
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(CameraError::ImageTooLarge { width, height });
    }
    Ok(())
}

/// What [`Camera::ray_direction`] needs, computed once for a loop over many rays: the path
/// tracer makes one a sample, and the focal length's tangent was 1.4% of a render's time.
#[derive(Debug, Clone, Copy)]
pub struct RayDirections {
    rotation: Quat,
    focal: f32,
    half_width: f32,
    half_height: f32,
}

impl RayDirections {
    /// [`Camera::ray_direction`] at `(px, py)`, bit for bit.
    #[inline]
    pub fn at(&self, px: f32, py: f32) -> Vec3 {
        let [cx, cy] = self.on_plane(px, py);
        (self.rotation * Vec3::new(cx, cy, 1.0)).normalize()
    }

    /// Where the ray through `(px, py)` crosses the camera-space plane z = 1: the direction
    /// `(x, y, 1)` that [`RayDirections::at`] rotates and normalises.
    #[inline]
    pub fn on_plane(&self, px: f32, py: f32) -> [f32; 2] {
        [
            (px - self.half_width) / self.focal,
            (py - self.half_height) / self.focal,
        ]
    }
}

/// A pinhole camera: position, orientation (camera-to-world rotation of the OpenCV frame),
/// vertical field of view and image size in pixels. Pixels are square.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub position: Vec3,
    /// Rotation taking camera-space axes (+X right, +Y down, +Z forward) to world space.
    pub rotation: Quat,
    /// Vertical field of view in degrees.
    pub fov_y_degrees: f32,
    pub width: u32,
    pub height: u32,
}

impl Camera {
    /// A camera at `eye` looking at `target`, with `up` giving the upward direction of the image.
    pub fn look_at(
        eye: Vec3,
        target: Vec3,
        up: Vec3,
        fov_y_degrees: f32,
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        check_image_size(width, height)?;
        // Written so that NaN fails the test.
        if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
            return Err(CameraError::BadFieldOfView(fov_y_degrees));
        }
        let forward = target - eye;
        if !(eye.is_finite() && target.is_finite() && up.is_finite()) {
            return Err(CameraError::DegenerateFrame);
        }
        let forward = forward
            .try_normalize()
            .ok_or(CameraError::DegenerateFrame)?;
        let up = up.try_normalize().ok_or(CameraError::DegenerateFrame)?;
        let sin_angle = forward.cross(up).length();
        // Written so that NaN fails.
        if !(sin_angle >= MIN_UP_ANGLE_DEGREES.to_radians().sin()) {
            return Err(CameraError::DegenerateFrame);
        }
        let right = forward
            .cross(up)
            .try_normalize()
            .ok_or(CameraError::DegenerateFrame)?;
        let down = forward.cross(right);
        let rotation = Quat::from_mat3(&Mat3::from_cols(right, down, forward)).normalize();
        Ok(Self {
            position: eye,
            rotation,
            fov_y_degrees,
            width,
            height,
        })
    }

    /// The same camera with another image size (the field of view is kept), checked as
    /// [`Camera::look_at`] checks it.
    pub fn with_size(&self, width: u32, height: u32) -> Result<Self, CameraError> {
        check_image_size(width, height)?;
        Ok(Self {
            width,
            height,
            ..*self
        })
    }

    /// Focal length in pixels (the same horizontally and vertically).
    pub fn focal_pixels(&self) -> f32 {
        0.5 * self.height as f32 / (0.5 * self.fov_y_degrees.to_radians()).tan()
    }

    /// World-space unit vectors of the camera's right, down and forward axes.
    pub fn axes(&self) -> (Vec3, Vec3, Vec3) {
        (
            self.rotation * Vec3::X,
            self.rotation * Vec3::Y,
            self.rotation * Vec3::Z,
        )
    }

    /// The unit direction of the ray through the continuous pixel position `(px, py)`;
    /// `(x + 0.5, y + 0.5)` is the centre of pixel `(x, y)`. Loops over many rays take
    /// [`Camera::ray_directions`] once instead (a tangent a ray less, the same bits).
    pub fn ray_direction(&self, px: f32, py: f32) -> Vec3 {
        self.ray_directions().at(px, py)
    }

    /// The camera's constants for [`Camera::ray_direction`], computed once.
    pub fn ray_directions(&self) -> RayDirections {
        RayDirections {
            rotation: self.rotation,
            focal: self.focal_pixels(),
            half_width: 0.5 * self.width as f32,
            half_height: 0.5 * self.height as f32,
        }
    }

    /// World point to camera space (+X right, +Y down, +Z forward).
    pub fn world_to_camera(&self, p: Vec3) -> Vec3 {
        self.rotation.inverse() * (p - self.position)
    }

    /// Continuous pixel position of a camera-space point in front of the camera (z > 0).
    pub fn project_camera_point(&self, c: Vec3) -> (f32, f32) {
        let f = self.focal_pixels();
        (
            0.5 * self.width as f32 + f * c.x / c.z,
            0.5 * self.height as f32 + f * c.y / c.z,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_set_by_rounding_and_absurd_sizes_are_refused() {
        let (eye, target) = (Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO);
        // `up` 1e-6 radians from the view: not exactly parallel, but the roll is noise.
        let up = Vec3::new(0.0, 1e-6, -1.0);
        assert_eq!(
            Camera::look_at(eye, target, up, 40.0, 8, 8),
            Err(CameraError::DegenerateFrame)
        );
        // 0.2 degrees away is a legitimate (if odd) frame.
        let up = Vec3::new(0.0, 0.2f32.to_radians().sin(), -1.0);
        assert!(Camera::look_at(eye, target, up, 40.0, 8, 8).is_ok());
        for up in [Vec3::NAN, Vec3::new(f32::NAN, 1.0, 0.0), Vec3::ZERO] {
            assert!(
                Camera::look_at(eye, target, up, 40.0, 8, 8).is_err(),
                "{up}"
            );
        }
        let big = CameraError::ImageTooLarge {
            width: 100_000,
            height: 8,
        };
        assert_eq!(
            Camera::look_at(eye, target, Vec3::Y, 40.0, 100_000, 8),
            Err(big)
        );
        assert_eq!(cam().with_size(100_000, 8), Err(big));
        assert!(
            cam()
                .with_size(32, 0)
                .unwrap_err()
                .to_string()
                .contains("empty")
        );
        assert_eq!(
            cam().with_size(32, 16).map(|c| (c.width, c.height)),
            Ok((32, 16))
        );
    }

    fn cam() -> Camera {
        Camera::look_at(
            Vec3::new(1.0, 2.0, 5.0),
            Vec3::new(0.0, 0.5, 0.0),
            Vec3::Y,
            40.0,
            64,
            48,
        )
        .unwrap()
    }

    #[test]
    fn centre_pixel_looks_at_target() {
        let c = cam();
        let d = c.ray_direction(32.0, 24.0);
        let want = (Vec3::new(0.0, 0.5, 0.0) - c.position).normalize();
        assert!((d - want).length() < 1e-6, "{d} vs {want}");
    }

    #[test]
    fn rows_grow_downwards_and_columns_rightwards() {
        let c = cam();
        let top = c.ray_direction(32.0, 0.0);
        let bottom = c.ray_direction(32.0, 48.0);
        assert!(top.y > bottom.y, "row 0 must be the top of the image");
        let (right, _, _) = c.axes();
        assert!(c.ray_direction(64.0, 24.0).dot(right) > 0.0);
    }

    #[test]
    fn projection_inverts_ray_generation() {
        let c = cam();
        for &(px, py) in &[(0.5f32, 0.5f32), (10.25, 40.75), (63.5, 47.5)] {
            let p = c.position + 7.0 * c.ray_direction(px, py);
            let (qx, qy) = c.project_camera_point(c.world_to_camera(p));
            assert!((qx - px).abs() < 1e-3 && (qy - py).abs() < 1e-3);
        }
    }

    #[test]
    fn vertical_fov_spans_the_image_height() {
        let c = cam();
        let a = c.ray_direction(32.0, 0.0);
        let b = c.ray_direction(32.0, 48.0);
        let angle = a.dot(b).clamp(-1.0, 1.0).acos().to_degrees();
        assert!((angle - 40.0).abs() < 1e-3, "{angle}");
    }

    #[test]
    fn bad_inputs_are_errors() {
        let e = Vec3::ZERO;
        assert!(Camera::look_at(e, Vec3::Z, Vec3::Y, 40.0, 0, 10).is_err());
        assert!(Camera::look_at(e, Vec3::Z, Vec3::Y, f32::NAN, 10, 10).is_err());
        assert!(Camera::look_at(e, Vec3::Z, Vec3::Y, 180.0, 10, 10).is_err());
        assert!(Camera::look_at(e, e, Vec3::Y, 40.0, 10, 10).is_err());
        assert!(Camera::look_at(e, Vec3::Y, Vec3::Y, 40.0, 10, 10).is_err());
    }
}
