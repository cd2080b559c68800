//! Camera paths shared by the benchmarks and the experiment runner.

use glam::{Quat, Vec3};
use splat_raster::Camera;

/// Frame `f` of `total` on an orbit of `degrees` about the camera's up axis through `centre`,
/// ending (f = total - 1) at `camera` itself.
pub fn orbit(camera: &Camera, centre: Vec3, degrees: f32, f: u32, total: u32) -> Camera {
    let t = if total > 1 {
        1.0 - f as f32 / (total - 1) as f32
    } else {
        0.0
    };
    let up = -(camera.rotation * Vec3::Y);
    let q = Quat::from_axis_angle(up.normalize(), (degrees * t).to_radians());
    Camera {
        position: centre + q * (camera.position - centre),
        rotation: (q * camera.rotation).normalize(),
        ..*camera
    }
}
