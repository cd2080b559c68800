//! Camera paths: the warm-up's and fly-throughs' orbit that ends at the camera, a movie's
//! turntable about the scene's up, and key-framed paths through chosen views. Shared by the
//! session's warm-up, the experiment runner, the benches and `gscache movie`.

use glam::{Quat, Vec3};
use render_base::Camera;
use serde::{Deserialize, Serialize};

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
    turned(camera, centre, image_up(camera), degrees * t)
}

/// Frame `f` of a turntable: `camera` turned by `degrees * f / frames` about `axis` through
/// `centre`, starting at the camera. A whole turn (360) loops: the frame after the last is the
/// first. `axis` is the scene's up (its camera table's `up`), so the volume turns as it stands,
/// not about the image's tilted up. A zero or non-finite axis leaves the camera where it is.
pub fn turntable(
    camera: &Camera,
    centre: Vec3,
    axis: Vec3,
    degrees: f32,
    f: u32,
    frames: u32,
) -> Camera {
    let t = if frames > 0 {
        f as f32 / frames as f32
    } else {
        0.0
    };
    turned(camera, centre, axis, degrees * t)
}

/// `camera` rotated by `degrees` about `axis` through `centre` (right-handed).
fn turned(camera: &Camera, centre: Vec3, axis: Vec3, degrees: f32) -> Camera {
    let Some(axis) = axis.try_normalize() else {
        return *camera;
    };
    let q = Quat::from_axis_angle(axis, degrees.to_radians());
    Camera {
        position: centre + q * (camera.position - centre),
        rotation: (q * camera.rotation).normalize(),
        ..*camera
    }
}

/// A view the path passes through at a frame.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    pub frame: u32,
    pub eye: [f32; 3],
    pub target: [f32; 3],
}

/// Why a list of keyframes cannot make a path.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PathError {
    #[error("no keyframes: expected at least one")]
    Empty,
    #[error(
        "keyframe at frame {frame} follows frame {previous}: expected frames in increasing order"
    )]
    NotIncreasing { previous: u32, frame: u32 },
    #[error(
        "keyframe at frame {frame}: eye {eye:?} and target {target:?} must be finite and distinct"
    )]
    BadView {
        frame: u32,
        eye: [f32; 3],
        target: [f32; 3],
    },
    #[error("frame {frame}: the view is parallel to the scene camera's up axis")]
    Degenerate { frame: u32 },
}

/// Checks that `keys` make a path: at least one, frames increasing, every eye and target finite
/// and distinct.
pub fn check_keyframes(keys: &[Keyframe]) -> Result<(), PathError> {
    if keys.is_empty() {
        return Err(PathError::Empty);
    }
    for pair in keys.windows(2) {
        if pair[1].frame <= pair[0].frame {
            return Err(PathError::NotIncreasing {
                previous: pair[0].frame,
                frame: pair[1].frame,
            });
        }
    }
    for k in keys {
        let (eye, target) = (Vec3::from_array(k.eye), Vec3::from_array(k.target));
        // Written so that NaN fails it.
        if !(eye.is_finite() && target.is_finite() && eye.distance(target) > 0.0) {
            return Err(PathError::BadView {
                frame: k.frame,
                eye: k.eye,
                target: k.target,
            });
        }
    }
    Ok(())
}

/// The camera at frame `f` of a path through `keys` (checked by [`check_keyframes`]): eye and
/// target follow Catmull-Rom splines in frame time, so the motion has no kink at a keyframe and
/// two keys give a straight line at constant speed. Before the first key and after the last the
/// camera holds still. The field of view, image size and up axis are `camera`'s.
pub fn keyframed(camera: &Camera, keys: &[Keyframe], f: u32) -> Result<Camera, PathError> {
    check_keyframes(keys)?;
    let eye = spline(keys, f as f32, |k| Vec3::from_array(k.eye));
    let target = spline(keys, f as f32, |k| Vec3::from_array(k.target));
    Camera::look_at(
        eye,
        target,
        image_up(camera),
        camera.fov_y_degrees,
        camera.width,
        camera.height,
    )
    .map_err(|_| PathError::Degenerate { frame: f })
}

/// Cubic Hermite interpolation of `value` over the keys at time `t`, with Catmull-Rom tangents
/// for non-uniform key times (one-sided at the ends).
fn spline(keys: &[Keyframe], t: f32, value: impl Fn(&Keyframe) -> Vec3) -> Vec3 {
    let first = &keys[0];
    let last = &keys[keys.len() - 1];
    if t <= first.frame as f32 {
        return value(first);
    }
    if t >= last.frame as f32 {
        return value(last);
    }
    let i = keys.partition_point(|k| k.frame as f32 <= t) - 1;
    let time = |j: usize| keys[j].frame as f32;
    let tangent = |j: usize| {
        let (a, b) = (j.saturating_sub(1), (j + 1).min(keys.len() - 1));
        (value(&keys[b]) - value(&keys[a])) / (time(b) - time(a))
    };
    let h = time(i + 1) - time(i);
    let s = (t - time(i)) / h;
    let (s2, s3) = (s * s, s * s * s);
    value(&keys[i]) * (2.0 * s3 - 3.0 * s2 + 1.0)
        + tangent(i) * h * (s3 - 2.0 * s2 + s)
        + value(&keys[i + 1]) * (-2.0 * s3 + 3.0 * s2)
        + tangent(i + 1) * h * (s3 - s2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene_camera() -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 10.0), Vec3::ZERO, Vec3::Y, 40.0, 32, 18).unwrap()
    }

    fn key(frame: u32, eye: [f32; 3]) -> Keyframe {
        Keyframe {
            frame,
            eye,
            target: [0.0; 3],
        }
    }

    #[test]
    fn orbit_ends_at_the_camera_and_keeps_the_distance() {
        let cam = scene_camera();
        let end = orbit(&cam, Vec3::ZERO, 90.0, 9, 10);
        assert!(end.position.distance(cam.position) < 1e-5);
        let start = orbit(&cam, Vec3::ZERO, 90.0, 0, 10);
        assert!((start.position.length() - 10.0).abs() < 1e-4);
        // A quarter turn about +Y from +Z lands on +X.
        assert!(start.position.distance(Vec3::new(10.0, 0.0, 0.0)) < 1e-4);
    }

    #[test]
    fn a_turntable_starts_at_the_camera_turns_about_the_given_axis_and_loops() {
        // A camera tilted down at the volume: its image up is not the world's +Y.
        let cam =
            Camera::look_at(Vec3::new(0.0, 6.0, 8.0), Vec3::ZERO, Vec3::Y, 40.0, 32, 18).unwrap();
        assert!(image_up(&cam).dot(Vec3::Y) < 0.9);
        let at = |f| turntable(&cam, Vec3::ZERO, Vec3::Y, 360.0, f, 8);
        assert!(at(0).position.distance(cam.position) < 1e-5);
        for f in 0..=8 {
            // About the world's +Y the height and the distance from the axis stay.
            let p = at(f).position;
            assert!((p.y - 6.0).abs() < 1e-4, "frame {f}: {p}");
            assert!((p.x.hypot(p.z) - 8.0).abs() < 1e-4, "frame {f}: {p}");
        }
        // A quarter of the way round a whole turn: +Z to +X.
        assert!(at(2).position.distance(Vec3::new(8.0, 6.0, 0.0)) < 1e-4);
        // The frame after the last is the first again.
        assert!(at(8).position.distance(cam.position) < 1e-4);
        // It keeps looking at the centre.
        let forward = at(3).rotation * Vec3::Z;
        assert!(forward.dot(-at(3).position.normalize()) > 1.0 - 1e-5);
    }

    #[test]
    fn keyframes_are_passed_through_and_held_outside_the_path() {
        let cam = scene_camera();
        let keys = [
            key(2, [0.0, 0.0, 10.0]),
            key(6, [10.0, 0.0, 0.0]),
            key(12, [0.0, 5.0, -10.0]),
        ];
        for (f, k) in [(0, 0), (2, 0), (6, 1), (12, 2), (30, 2)] {
            let c = keyframed(&cam, &keys, f).unwrap();
            let want = Vec3::from_array(keys[k].eye);
            assert!(c.position.distance(want) < 1e-4, "frame {f}");
            // It looks at the target.
            let forward = c.rotation * Vec3::Z;
            assert!(forward.dot(-want.normalize()) > 1.0 - 1e-5, "frame {f}");
        }
    }

    #[test]
    fn two_keys_move_in_a_straight_line_at_constant_speed() {
        let keys = [key(0, [0.0, 0.0, 10.0]), key(8, [8.0, 0.0, 10.0])];
        for f in 0..=8 {
            let c = keyframed(&scene_camera(), &keys, f).unwrap();
            assert!(
                c.position.distance(Vec3::new(f as f32, 0.0, 10.0)) < 1e-4,
                "frame {f}: {}",
                c.position
            );
        }
    }

    #[test]
    fn the_path_has_no_kink_at_a_keyframe() {
        // Unevenly spaced keys on a bend: the velocity just before and just after the middle
        // key must agree (a piecewise-linear path would turn by 90 degrees there).
        let keys = [
            key(0, [0.0, 0.0, 10.0]),
            key(4, [4.0, 0.0, 10.0]),
            key(12, [4.0, 8.0, 10.0]),
        ];
        let eye = |t: f32| spline(&keys, t, |k| Vec3::from_array(k.eye));
        let d = 1e-2;
        let before = (eye(4.0) - eye(4.0 - d)) / d;
        let after = (eye(4.0 + d) - eye(4.0)) / d;
        assert!(
            before.distance(after) < 0.05 * before.length(),
            "{before} {after}"
        );
        assert!(
            before.y > 0.1,
            "the tangent at the middle key turns towards the next key"
        );
    }

    #[test]
    fn bad_keyframes_are_refused() {
        assert_eq!(check_keyframes(&[]), Err(PathError::Empty));
        let e = check_keyframes(&[key(3, [0.0, 0.0, 1.0]), key(3, [1.0, 0.0, 1.0])]);
        assert!(matches!(e, Err(PathError::NotIncreasing { .. })));
        let e = check_keyframes(&[key(0, [0.0; 3])]);
        assert!(matches!(e, Err(PathError::BadView { .. })));
        let e = check_keyframes(&[key(0, [f32::NAN, 0.0, 1.0])]);
        assert!(matches!(e, Err(PathError::BadView { .. })));
        let e = keyframed(&scene_camera(), &[key(0, [0.0, 5.0, 0.0])], 0);
        assert_eq!(e, Err(PathError::Degenerate { frame: 0 }));
    }
}
