//! Initial levels from a point cloud (the GSCache paper's section 3.2): level `i` takes the first
//! `N / 2^i` points; each Gaussian is isotropic, its scale set by Eq. 2 from its three nearest
//! neighbours within its level, its colour the point's albedo, its opacity uniform.
//!
//! Eq. 2: `s_i = min(mu + 2 sd, mean_j d_ij) / 2`, where `d_ij` are the distances to the three
//! nearest neighbours and `mu`, `sd` the mean and standard deviation of their means over the
//! level. Without the size cap (the "-SC" ablation) `s_i = mean_j d_ij`, as in 3DGS.

use crate::config::CacheConfig;
use crate::error::{CacheError, Result};
use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use splat_raster::{ColorModel, GaussianCloud};
use std::num::NonZero;

/// The degree-0 spherical-harmonic basis constant (3DGS's `C0`).
pub use splat_raster::SH_C0;

/// Mean distance from each point to its three nearest neighbours (other than itself).
/// Duplicated points count as neighbours at distance 0.
pub fn mean_neighbour_distances(points: &[[f32; 3]]) -> Result<Vec<f32>> {
    if points.len() < 4 {
        return Err(CacheError::Init(format!(
            "{} points: at least 4 are needed to find three neighbours",
            points.len()
        )));
    }
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice_parallel(points)
        .map_err(|e| CacheError::Init(format!("k-d tree construction failed: {e:?}")))?;
    let found = tree
        .query_batch(points)
        .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(4).expect("4 > 0"))
        .execute();
    Ok(found
        .iter()
        .enumerate()
        .map(|(i, hits)| {
            let mut sum = 0.0f32;
            let mut n = 0;
            for h in hits.iter().filter(|h| h.item as usize != i).take(3) {
                sum += h.distance.max(0.0).sqrt();
                n += 1;
            }
            sum / n.max(1) as f32
        })
        .collect())
}

/// Isotropic scales from the mean neighbour distances (Eq. 2, or 3DGS's rule without the cap).
/// Every scale is at least 1e-3 of the mean spacing, so duplicated points still get a
/// Gaussian with a finite logarithm.
pub fn initial_scales(mean_distances: &[f32], size_cap: bool) -> Vec<f32> {
    let n = mean_distances.len().max(1) as f64;
    let mean = mean_distances.iter().map(|&d| d as f64).sum::<f64>() / n;
    let var = mean_distances
        .iter()
        .map(|&d| (d as f64 - mean).powi(2))
        .sum::<f64>()
        / n;
    let cap = (mean + 2.0 * var.sqrt()) as f32;
    let floor = (1e-3 * mean) as f32;
    mean_distances
        .iter()
        .map(|&d| {
            let s = if size_cap { d.min(cap) * 0.5 } else { d };
            s.max(floor).max(f32::MIN_POSITIVE)
        })
        .collect()
}

fn logit(p: f32) -> f32 {
    (p / (1.0 - p)).ln()
}

/// The initial levels for `config` from points with their albedos. Level `i` takes the first
/// `points.len() / 2^i` points, so the points should come in random order (as delta tracking of
/// random rays gives them).
pub fn initial_levels(
    points: &[Vec3],
    albedo: &[Vec3],
    config: &CacheConfig,
) -> Result<Vec<GaussianCloud<f32>>> {
    config.validate()?;
    if points.len() != albedo.len() {
        return Err(CacheError::Init(format!(
            "{} points but {} albedos: expected one albedo per point",
            points.len(),
            albedo.len()
        )));
    }
    if let Some(i) = points
        .iter()
        .zip(albedo)
        .position(|(p, a)| !(p.is_finite() && a.is_finite()))
    {
        return Err(CacheError::Init(format!(
            "point {i} or its albedo is not finite: expected finite positions and colours"
        )));
    }
    (0..config.levels)
        .map(|level| {
            let n = points.len() >> level;
            let positions: Vec<[f32; 3]> = points[..n].iter().map(|p| p.to_array()).collect();
            let scales = initial_scales(&mean_neighbour_distances(&positions)?, config.size_cap);
            let mut cloud = GaussianCloud::new(ColorModel::Sh(0));
            let opacity = logit(config.initial_opacity);
            for i in 0..n {
                // Colour = 0.5 + C0 * coefficient (3DGS's degree-0 convention).
                let a = albedo[i].clamp(Vec3::ZERO, Vec3::ONE);
                let dc = (a - Vec3::splat(0.5)) / SH_C0;
                cloud.push(
                    positions[i],
                    [scales[i].ln(); 3],
                    [1.0, 0.0, 0.0, 0.0],
                    &dc.to_array(),
                    opacity,
                );
            }
            Ok(cloud)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbours_on_a_lattice() {
        // A cubic lattice of spacing 0.5: every interior point has 6 neighbours at 0.5.
        let mut pts = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..6 {
                    pts.push([i as f32 * 0.5, j as f32 * 0.5, k as f32 * 0.5]);
                }
            }
        }
        let d = mean_neighbour_distances(&pts).unwrap();
        assert!(d.iter().all(|&x| (x - 0.5).abs() < 1e-6), "{d:?}");
    }

    #[test]
    fn eq2_caps_outliers_and_halves() {
        // 99 points at spacing 1, one isolated at distance 100.
        let mut d = vec![1.0f32; 99];
        d.push(100.0);
        let s = initial_scales(&d, true);
        let mean = (99.0 + 100.0) / 100.0;
        let sd = ((99.0 * (1.0f64 - mean).powi(2) + (100.0f64 - mean).powi(2)) / 100.0).sqrt();
        assert!((s[0] - 0.5).abs() < 1e-6);
        assert!((s[99] as f64 - (mean + 2.0 * sd) / 2.0).abs() < 1e-3);
        let plain = initial_scales(&d, false);
        assert_eq!(plain[99], 100.0);
    }

    #[test]
    fn duplicates_get_a_finite_scale() {
        let pts = vec![[1.0f32, 2.0, 3.0]; 10];
        let d = mean_neighbour_distances(&pts).unwrap();
        let s = initial_scales(&d, true);
        assert!(s.iter().all(|v| v.ln().is_finite()));
    }
}
