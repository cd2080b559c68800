//! The one sampling rule.
//!
//! Frame `k` of a session with `s` samples per pixel renders sample indices `k*s .. (k+1)*s` of
//! every pixel with the scene's seed (volume-pt's streams are indexed by seed, pixel and sample
//! index). So:
//! - successive frames have independent noise, and a cache is never trained twice on the same
//!   random paths;
//! - a film accumulated over frames `0..n` at a still camera is the same film as one render of
//!   `n*s` samples, bit for bit (the film's sums are exact);
//! - whoever renders frame `k` (the program, the experiment runner, Python, the viewer) renders
//!   the same samples, so a report's command line reproduces any budget's image bit for bit.
//!
//! Sample indices are u32; a frame whose last index would pass `u32::MAX` is refused rather
//! than wrapped (a wrapped index would repeat earlier samples and silently bias the image).

use crate::error::{Result, SessionError};
use std::ops::Range;

/// The sample indices frame `frame` of `spp` samples per pixel renders.
pub fn frame_samples(frame: u32, spp: u32) -> Result<Range<u32>> {
    let start = frame.checked_mul(spp);
    let end = start.and_then(|s| s.checked_add(spp));
    match (start, end) {
        (Some(start), Some(end)) if spp > 0 => Ok(start..end),
        _ if spp == 0 => Err(SessionError::Invalid(
            "spp 0: expected at least 1 sample per pixel".into(),
        )),
        _ => Err(SessionError::Invalid(format!(
            "frame {frame} of {spp} spp would pass sample index 2^32: every pixel has 2^32 \
             samples in all (frames x spp, warm-up included); use fewer frames or fewer samples \
             per frame"
        ))),
    }
}

/// Checks before any work that `frames` more frames from frame `first` fit the sample indices.
pub fn check_frames(first: u32, frames: u32, spp: u32) -> Result<()> {
    if frames == 0 {
        return Ok(());
    }
    let last = first.checked_add(frames - 1).ok_or_else(|| {
        SessionError::Invalid(format!(
            "{frames} frames after frame {first} pass frame 2^32: use fewer frames"
        ))
    })?;
    frame_samples(last, spp).map(|_| ())
}

/// The neural cache's weight seed for a scene seed: the settings' own seed mixed with the
/// scene's, so seeds give independent networks (the splitmix64 finaliser of `scene_seed` times
/// the golden ratio).
pub fn neural_cache_seed(config_seed: u64, scene_seed: u64) -> u64 {
    config_seed
        ^ render_base::hash::splitmix64_finalize(
            scene_seed.wrapping_mul(render_base::hash::GOLDEN_GAMMA),
        )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_tile_the_sample_indices() {
        assert_eq!(frame_samples(0, 4).unwrap(), 0..4);
        assert_eq!(frame_samples(3, 4).unwrap(), 12..16);
        assert!(
            frame_samples(u32::MAX, 1)
                .unwrap_err()
                .to_string()
                .contains("2^32")
        );
        assert_eq!(
            frame_samples(u32::MAX - 1, 1).unwrap(),
            u32::MAX - 1..u32::MAX
        );
        assert!(frame_samples(0, 0).is_err());
    }

    #[test]
    fn a_wrapping_warm_up_is_refused_before_any_work() {
        // 2^32 - 1 frames of 1 spp are exactly the indices there are; one more is not.
        assert!(check_frames(0, u32::MAX, 1).is_ok());
        assert!(check_frames(1, u32::MAX, 1).is_err());
        assert!(check_frames(u32::MAX, 2, 1).is_err());
        assert!(check_frames(0, 1 << 16, 1 << 16).is_err());
        assert!(check_frames(0, 1 << 16, (1 << 16) - 1).is_ok());
    }
}
