//! Camera paths shared by the benchmarks and the experiment runner: an orbit about the volume,
//! or a key-framed path through chosen views.

use glam::Vec3;
use serde::{Deserialize, Serialize};
use splat_raster::Camera;

pub use render_session::orbit::{image_up, orbit};

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
