//! The transfer function: what a scalar value looks like to light.
//!
//! A value `v` is first windowed, `t = clamp((v - lo) / (hi - lo), 0, 1)`, then classified by two
//! piecewise-linear functions of `t`: RGB albedo (the single-scattering albedo, in [0, 1]) and
//! opacity (in [0, 1]). Extinction per world unit is `sigma_t = density_scale * opacity`: one grey
//! channel, so free-flight sampling needs one majorant; albedo gives the RGB scattering
//! `sigma_s = albedo * sigma_t`. Classification happens after the scalar is interpolated
//! (post-classification).

use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

/// A piecewise-linear function of the normalised value, constant beyond its end points.
///
/// Evaluation finds the segment in O(1): `buckets` splits `[xs[0], xs[last]]` evenly and holds,
/// for each bucket, the first control point right of the bucket's start, so only the few points
/// inside one bucket are scanned. The result is exactly the binary-search result.
#[derive(Debug, Clone, PartialEq)]
pub struct PiecewiseLinear<T> {
    xs: Vec<f32>,
    ys: Vec<T>,
    bucket_scale: f32,
    buckets: Vec<u32>,
}

/// Buckets of the segment lookup.
const SEGMENT_BUCKETS: usize = 64;

/// Values a piecewise-linear function can hold.
pub trait Lerp: Copy {
    fn lerp(a: Self, b: Self, t: f32) -> Self;
}

impl Lerp for f32 {
    #[inline]
    fn lerp(a: f32, b: f32, t: f32) -> f32 {
        a + t * (b - a)
    }
}

impl Lerp for Vec3 {
    #[inline]
    fn lerp(a: Vec3, b: Vec3, t: f32) -> Vec3 {
        a + t * (b - a)
    }
}

impl<T: Lerp> PiecewiseLinear<T> {
    /// Control points must be non-empty, finite and sorted by `x` (equal `x` make a step).
    pub fn new(points: Vec<(f32, T)>, what: &str) -> Result<Self> {
        if points.is_empty() {
            return Err(Error::TransferFunction(format!(
                "{what} has no control points: expected at least one"
            )));
        }
        for (i, w) in points.windows(2).enumerate() {
            // Written so that NaN fails.
            if !(w[0].0 <= w[1].0) {
                return Err(Error::TransferFunction(format!(
                    "{what} control points are not sorted: point {} at {} comes after point {} at {}",
                    i + 1,
                    w[1].0,
                    i,
                    w[0].0
                )));
            }
        }
        if let Some((i, p)) = points.iter().enumerate().find(|(_, p)| !p.0.is_finite()) {
            return Err(Error::TransferFunction(format!(
                "{what} control point {i} is at {}: expected a finite value",
                p.0
            )));
        }
        let (xs, ys): (Vec<f32>, Vec<T>) = points.into_iter().unzip();
        let (lo, hi) = (xs[0], xs[xs.len() - 1]);
        let bucket_scale = if hi > lo {
            SEGMENT_BUCKETS as f32 / (hi - lo)
        } else {
            0.0
        };
        let buckets = (0..SEGMENT_BUCKETS)
            .map(|b| {
                // The bucket index of t is floor((t - lo) * scale); every t in bucket b is at
                // least this start, up to rounding, so start one point early to be safe.
                let start = lo + b as f32 / bucket_scale.max(f32::MIN_POSITIVE);
                xs.partition_point(|&x| x <= start).saturating_sub(1) as u32
            })
            .collect();
        Ok(Self {
            xs,
            ys,
            bucket_scale,
            buckets,
        })
    }

    /// Index of the first control point right of `t` (`partition_point(x <= t)`).
    #[inline]
    fn segment(&self, t: f32) -> usize {
        let lo = self.xs[0];
        // Written so that NaN goes to the first point.
        if !(t >= lo) {
            return 0;
        }
        let b = (((t - lo) * self.bucket_scale) as usize).min(SEGMENT_BUCKETS - 1);
        let mut i = self.buckets[b] as usize;
        while i < self.xs.len() && self.xs[i] <= t {
            i += 1;
        }
        i
    }

    #[inline]
    pub fn eval(&self, t: f32) -> T {
        let i = self.segment(t);
        if i == 0 {
            return self.ys[0];
        }
        if i == self.xs.len() {
            return self.ys[i - 1];
        }
        let (x0, x1) = (self.xs[i - 1], self.xs[i]);
        let w = if x1 > x0 { (t - x0) / (x1 - x0) } else { 1.0 };
        T::lerp(self.ys[i - 1], self.ys[i], w)
    }

    pub fn points(&self) -> impl Iterator<Item = (f32, T)> + '_ {
        self.xs.iter().copied().zip(self.ys.iter().copied())
    }
}

impl PiecewiseLinear<f32> {
    /// The largest value on `[a, b]`: the end points and every control point inside.
    pub fn max_on(&self, a: f32, b: f32) -> f32 {
        self.extreme_on(a, b, f32::max)
    }

    /// The smallest value on `[a, b]` (a piecewise-linear function's extremes lie at the end
    /// points or at control points).
    pub fn min_on(&self, a: f32, b: f32) -> f32 {
        self.extreme_on(a, b, f32::min)
    }

    fn extreme_on(&self, a: f32, b: f32, pick: fn(f32, f32) -> f32) -> f32 {
        let mut m = pick(self.eval(a), self.eval(b));
        let lo = self.xs.partition_point(|&x| x < a);
        let hi = self.xs.partition_point(|&x| x <= b);
        for &y in &self.ys[lo..hi.max(lo)] {
            m = pick(m, y);
        }
        m
    }
}

/// Window, colour, opacity and density scale: everything that turns a scalar into a medium.
#[derive(Debug, Clone)]
pub struct TransferFunction {
    window: (f32, f32),
    inv_width: f32,
    albedo: PiecewiseLinear<Vec3>,
    opacity: PiecewiseLinear<f32>,
    density_scale: f32,
}

impl TransferFunction {
    /// `window` maps data values `lo..hi` to `0..1`; `density_scale` is the extinction per world
    /// unit at opacity 1.
    pub fn new(
        window: (f32, f32),
        albedo: PiecewiseLinear<Vec3>,
        opacity: PiecewiseLinear<f32>,
        density_scale: f32,
    ) -> Result<Self> {
        let (lo, hi) = window;
        // The width must be finite too: [-3e38, 3e38] has an infinite width, which would map
        // every value to 0 and leave the volume silently empty.
        if !(lo.is_finite() && hi.is_finite() && hi > lo && (hi - lo).is_finite()) {
            return Err(Error::TransferFunction(format!(
                "window [{lo}, {hi}] is invalid: expected finite values with lo < hi and a \
                 finite width hi - lo"
            )));
        }
        if !(density_scale >= 0.0 && density_scale.is_finite()) {
            return Err(Error::TransferFunction(format!(
                "density_scale {density_scale} is invalid: expected a finite value >= 0"
            )));
        }
        for (x, c) in albedo.points() {
            // Per component, so that NaN fails (glam's min/max skip NaN).
            if !(c.cmpge(Vec3::ZERO).all() && c.cmple(Vec3::ONE).all()) {
                // Named by the fault: above 1 creates energy, below 0 (or NaN) is no fraction.
                let why = if c.cmpgt(Vec3::ONE).any() {
                    "a scattering albedo above 1 creates energy"
                } else {
                    "an albedo is the fraction of extinguished light that scatters, from 0 to 1"
                };
                return Err(Error::TransferFunction(format!(
                    "albedo {c} at {x} is outside [0, 1]: {why}"
                )));
            }
        }
        for (x, o) in opacity.points() {
            if !(0.0..=1.0).contains(&o) {
                return Err(Error::TransferFunction(format!(
                    "opacity {o} at {x} is outside [0, 1]"
                )));
            }
        }
        Ok(Self {
            window,
            inv_width: 1.0 / (hi - lo),
            albedo,
            opacity,
            density_scale,
        })
    }

    /// Combined control points `(t, rgb, opacity)` sharing their positions.
    pub fn from_points(
        window: (f32, f32),
        points: &[(f32, Vec3, f32)],
        density_scale: f32,
    ) -> Result<Self> {
        let albedo = PiecewiseLinear::new(points.iter().map(|p| (p.0, p.1)).collect(), "colour")?;
        let opacity = PiecewiseLinear::new(points.iter().map(|p| (p.0, p.2)).collect(), "opacity")?;
        Self::new(window, albedo, opacity, density_scale)
    }

    /// The opacity curve's control points, `(position in the window (0..1), opacity)`.
    pub fn opacity_points(&self) -> impl Iterator<Item = (f32, f32)> + '_ {
        self.opacity.points()
    }

    pub fn window(&self) -> (f32, f32) {
        self.window
    }

    pub fn density_scale(&self) -> f32 {
        self.density_scale
    }

    /// The same function with another density scale (an edit that makes the medium denser or
    /// thinner without changing its colours).
    pub fn with_density_scale(&self, density_scale: f32) -> Result<Self> {
        Self::new(
            self.window,
            self.albedo.clone(),
            self.opacity.clone(),
            density_scale,
        )
    }

    #[inline]
    pub fn normalise(&self, v: f32) -> f32 {
        ((v - self.window.0) * self.inv_width).clamp(0.0, 1.0)
    }

    /// Extinction per world unit at data value `v`.
    #[inline]
    pub fn extinction(&self, v: f32) -> f32 {
        self.density_scale * self.opacity.eval(self.normalise(v))
    }

    /// Single-scattering albedo at data value `v`.
    #[inline]
    pub fn albedo(&self, v: f32) -> Vec3 {
        self.albedo.eval(self.normalise(v))
    }

    /// The opacity curve at `t`, a position in the window (0 at its low end, 1 at its high).
    pub fn opacity_at(&self, t: f32) -> f32 {
        self.opacity.eval(t)
    }

    /// The colour (single-scattering albedo) at window position `t`.
    pub fn albedo_at(&self, t: f32) -> Vec3 {
        self.albedo.eval(t)
    }

    /// The largest extinction any value in `[vmin, vmax]` can produce.
    pub fn max_extinction(&self, vmin: f32, vmax: f32) -> f32 {
        self.density_scale
            * self
                .opacity
                .max_on(self.normalise(vmin), self.normalise(vmax))
    }

    /// The smallest extinction any value in `[vmin, vmax]` can produce: the control extinction of
    /// residual ratio tracking.
    pub fn min_extinction(&self, vmin: f32, vmax: f32) -> f32 {
        self.density_scale
            * self
                .opacity
                .min_on(self.normalise(vmin), self.normalise(vmax))
    }

    /// True when no value gives any extinction.
    pub fn is_empty(&self) -> bool {
        self.density_scale == 0.0 || self.opacity.points().all(|(_, o)| o == 0.0)
    }
}

/// The colour and opacity functions of a ParaView colour-map preset (JSON), with their positions
/// rescaled to `0..1` over each function's own range, as ParaView rescales presets to the data.
///
/// Reads `RGBPoints` (x, r, g, b) and, if present, `Points` (x, opacity, midpoint, sharpness);
/// midpoint and sharpness are ignored (the segments are linear). The file may hold one preset or
/// an array of them; `name` picks one by its `Name`.
pub fn read_paraview_preset(
    path: &Path,
    name: Option<&str>,
) -> Result<(PiecewiseLinear<Vec3>, Option<PiecewiseLinear<f32>>)> {
    let bad = |m: String| Error::format(path, m);
    let text = crate::io::read_text_file(path, "a colour-map preset")?;
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not valid JSON: {e}")))?;
    let presets: Vec<&serde_json::Value> = match &json {
        serde_json::Value::Array(a) => a.iter().collect(),
        v => vec![v],
    };
    let preset = match name {
        Some(n) => presets
            .iter()
            .find(|p| p.get("Name").and_then(|v| v.as_str()) == Some(n))
            .ok_or_else(|| bad(format!("no preset named `{n}`")))?,
        None if presets.len() == 1 => presets[0],
        None => {
            return Err(bad(format!(
                "file holds {} presets: give `preset_name` to choose one",
                presets.len()
            )));
        }
    };
    let numbers = |key: &str, stride: usize| -> Result<Option<Vec<f32>>> {
        let Some(v) = preset.get(key) else {
            return Ok(None);
        };
        let arr = v
            .as_array()
            .ok_or_else(|| bad(format!("`{key}` is not an array")))?;
        let nums: Vec<f32> = arr
            .iter()
            .map(|x| x.as_f64().map(|f| f as f32))
            .collect::<Option<_>>()
            .ok_or_else(|| bad(format!("`{key}` holds a non-number")))?;
        if nums.is_empty() || !nums.len().is_multiple_of(stride) {
            return Err(bad(format!(
                "`{key}` has {} numbers: expected a non-empty multiple of {stride}",
                nums.len()
            )));
        }
        Ok(Some(nums))
    };
    let rescale = |xs: Vec<f32>| -> Vec<f32> {
        let lo = xs.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = xs.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        xs.into_iter()
            .map(|x| if hi > lo { (x - lo) / (hi - lo) } else { 0.0 })
            .collect()
    };
    let rgb = numbers("RGBPoints", 4)?.ok_or_else(|| bad("preset has no `RGBPoints`".into()))?;
    let xs = rescale(rgb.chunks(4).map(|c| c[0]).collect());
    let colour = PiecewiseLinear::new(
        xs.into_iter()
            .zip(rgb.chunks(4).map(|c| Vec3::new(c[1], c[2], c[3])))
            .collect(),
        "preset colour",
    )
    .map_err(|e| bad(e.to_string()))?;
    let opacity = match numbers("Points", 4)? {
        None => None,
        Some(p) => {
            let xs = rescale(p.chunks(4).map(|c| c[0]).collect());
            Some(
                PiecewiseLinear::new(
                    xs.into_iter().zip(p.chunks(4).map(|c| c[1])).collect(),
                    "preset opacity",
                )
                .map_err(|e| bad(e.to_string()))?,
            )
        }
    };
    Ok((colour, opacity))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> PiecewiseLinear<f32> {
        PiecewiseLinear::new(vec![(0.2, 0.0), (0.5, 1.0), (0.5, 0.3), (0.8, 0.6)], "o").unwrap()
    }

    #[test]
    fn bucketed_segment_lookup_equals_binary_search() {
        let xs = [0.0f32, 0.001, 0.3, 0.3, 0.31, 0.9999, 1.0];
        let f = PiecewiseLinear::new(xs.iter().map(|&x| (x, x)).collect(), "o").unwrap();
        for i in 0..=100_000 {
            let t = -0.01 + 1.02 * i as f32 / 100_000.0;
            assert_eq!(f.segment(t), xs.partition_point(|&x| x <= t), "t = {t}");
        }
        for t in xs {
            assert_eq!(f.segment(t), xs.partition_point(|&x| x <= t), "t = {t}");
        }
    }

    #[test]
    fn eval_is_linear_and_clamped() {
        let f = ramp();
        assert_eq!(f.eval(0.0), 0.0);
        assert!((f.eval(0.35) - 0.5).abs() < 1e-6);
        assert!((f.eval(0.65) - 0.45).abs() < 1e-6);
        assert_eq!(f.eval(1.0), 0.6);
    }

    #[test]
    fn max_on_sees_interior_control_points_and_steps() {
        let f = ramp();
        assert_eq!(f.max_on(0.3, 0.7), 1.0);
        assert!((f.max_on(0.6, 0.7) - 0.5).abs() < 1e-6);
        assert_eq!(f.max_on(0.0, 0.1), 0.0);
        // Brute force agrees on random intervals.
        for k in 0..200 {
            let a = (k as f32 * 0.618).fract();
            let b = (a + (k as f32 * 0.377).fract() * 0.5).min(1.0);
            let brute = (0..=1000)
                .map(|i| f.eval(a + (b - a) * i as f32 / 1000.0))
                .fold(0.0f32, f32::max);
            assert!(f.max_on(a, b) >= brute - 1e-6, "[{a}, {b}]");
        }
    }

    #[test]
    fn bad_control_points_are_rejected() {
        assert!(PiecewiseLinear::<f32>::new(vec![], "o").is_err());
        let e = PiecewiseLinear::new(vec![(0.5, 0.0), (0.2, 1.0)], "opacity").unwrap_err();
        assert!(e.to_string().contains("not sorted"), "{e}");
        assert!(PiecewiseLinear::new(vec![(f32::NAN, 0.0)], "o").is_err());
        let op = PiecewiseLinear::new(vec![(0.0, 1.5)], "o").unwrap();
        let c = PiecewiseLinear::new(vec![(0.0, Vec3::ONE)], "c").unwrap();
        assert!(TransferFunction::new((0.0, 1.0), c.clone(), op, 1.0).is_err());
        let op = PiecewiseLinear::new(vec![(0.0, 0.5)], "o").unwrap();
        assert!(TransferFunction::new((1.0, 1.0), c.clone(), op.clone(), 1.0).is_err());
        assert!(TransferFunction::new((0.0, 1.0), c, op, f32::NAN).is_err());
    }

    #[test]
    fn paraview_preset_is_read_and_rescaled() {
        let dir = std::env::temp_dir().join(format!("volume-pt-preset-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("presets.json");
        std::fs::write(
            &p,
            r#"[{"Name": "A", "ColorSpace": "RGB", "RGBPoints": [-1, 0, 0, 1, 0, 1, 1, 1, 3, 1, 0, 0],
                 "Points": [-1, 0, 0.5, 0, 3, 1, 0.5, 0]},
                {"Name": "B", "RGBPoints": [0, 1, 1, 1]}]"#,
        )
        .unwrap();
        let (c, o) = read_paraview_preset(&p, Some("A")).unwrap();
        // x in [-1, 3] rescaled to [0, 1]: the middle point sits at 0.25.
        assert_eq!(c.eval(0.25), Vec3::ONE);
        assert_eq!(c.eval(0.0), Vec3::new(0.0, 0.0, 1.0));
        assert!((o.unwrap().eval(0.5) - 0.5).abs() < 1e-6);
        let (_, o) = read_paraview_preset(&p, Some("B")).unwrap();
        assert!(o.is_none());
        let e = read_paraview_preset(&p, None).unwrap_err().to_string();
        assert!(
            e.contains("presets.json") && e.contains("preset_name"),
            "{e}"
        );
        let e = read_paraview_preset(&p, Some("C")).unwrap_err().to_string();
        assert!(e.contains("no preset named `C`"), "{e}");
        std::fs::write(&p, r#"{"RGBPoints": [0, 1, 1]}"#).unwrap();
        let e = read_paraview_preset(&p, None).unwrap_err().to_string();
        assert!(e.contains("multiple of 4"), "{e}");
    }
}
