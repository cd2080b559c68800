//! The warm-up's camera path: an orbit about the volume's centre that ends at the camera.

use glam::{Quat, Vec3};
use render_base::Camera;

/// The camera's "up" as seen in its image (image rows grow down, along the rotation's +Y).
pub fn image_up(camera: &Camera) -> Vec3 {
    -(camera.rotation * Vec3::Y).normalize()
}

/// Frame `f` of `total` on an orbit of `degrees` about `centre` (about the image's up axis),
/// ending at `camera` on frame `total - 1`: frame 0 is `degrees` before it.
pub fn orbit(camera: &Camera, centre: Vec3, degrees: f32, f: u32, total: u32) -> Camera {
    let t = if total > 1 {
        1.0 - f as f32 / (total - 1) as f32
    } else {
        0.0
    };
    let up = image_up(camera);
    let q = Quat::from_axis_angle(up, (degrees * t).to_radians());
    Camera {
        position: centre + q * (camera.position - centre),
        rotation: (q * camera.rotation).normalize(),
        ..*camera
    }
}
