//! The Gaussian cloud, structure of arrays: each parameter group is one flat array, which is
//! what the rasteriser reads and what the optimiser updates in place.
//!
//! Parameters are stored as trained (3DGS conventions): means in world units, natural-log
//! standard deviations, quaternions (w, x, y, z) not necessarily unit (normalised where used),
//! colours, and opacity logits (opacity = sigmoid(logit)).

use crate::real::Real;
use crate::sh::coeffs_for_degree;

/// How colour is stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorModel {
    /// Three values per Gaussian: linear RGB radiance, unclamped above (HDR), clamped at 0.
    Rgb,
    /// Spherical harmonics of this degree (0..=3), 3DGS convention:
    /// colour = max(0, 0.5 + sum_k coef_k Y_k(view direction)).
    Sh(u32),
}

impl ColorModel {
    /// Values per Gaussian per channel.
    pub fn coeffs(self) -> usize {
        match self {
            ColorModel::Rgb => 1,
            ColorModel::Sh(d) => coeffs_for_degree(d),
        }
    }
}

/// A cloud of 3D Gaussians (f32 for rendering and training; f64 for reference computations).
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianCloud<F: Real = f32> {
    /// 3 per Gaussian.
    pub means: Vec<F>,
    /// 3 per Gaussian: ln(sigma) along the local axes.
    pub log_scales: Vec<F>,
    /// 4 per Gaussian: (w, x, y, z).
    pub rotations: Vec<F>,
    /// `3 * color_model.coeffs()` per Gaussian, laid out `[coefficient][channel]`.
    pub colors: Vec<F>,
    /// 1 per Gaussian.
    pub opacity_logits: Vec<F>,
    pub color_model: ColorModel,
}

impl<F: Real> GaussianCloud<F> {
    pub fn new(color_model: ColorModel) -> Self {
        Self {
            means: Vec::new(),
            log_scales: Vec::new(),
            rotations: Vec::new(),
            colors: Vec::new(),
            opacity_logits: Vec::new(),
            color_model,
        }
    }

    pub fn len(&self) -> usize {
        self.opacity_logits.len()
    }

    pub fn is_empty(&self) -> bool {
        self.opacity_logits.is_empty()
    }

    /// Colour values per Gaussian (3 times the coefficients per channel).
    pub fn color_stride(&self) -> usize {
        3 * self.color_model.coeffs()
    }

    /// Appends one Gaussian. `color` holds `color_stride()` values.
    pub fn push(
        &mut self,
        mean: [F; 3],
        log_scale: [F; 3],
        rotation: [F; 4],
        color: &[F],
        opacity_logit: F,
    ) {
        assert_eq!(color.len(), self.color_stride());
        self.means.extend_from_slice(&mean);
        self.log_scales.extend_from_slice(&log_scale);
        self.rotations.extend_from_slice(&rotation);
        self.colors.extend_from_slice(color);
        self.opacity_logits.push(opacity_logit);
    }

    /// How many Gaussians no renderer can use: a non-finite parameter, or a zero quaternion
    /// (no orientation). Renderers skip them; a program that loads a file says how many.
    pub fn count_unusable(&self) -> usize {
        (0..self.len()).filter(|&g| !self.is_usable(g)).count()
    }

    /// Whether Gaussian `g` can be rendered: every parameter finite and a non-zero quaternion.
    pub fn is_usable(&self, g: usize) -> bool {
        let stride = self.color_stride();
        let q = &self.rotations[4 * g..4 * g + 4];
        let q_norm2 = q.iter().fold(F::zero(), |a, &v| a + v * v);
        let finite = self.means[3 * g..3 * g + 3]
            .iter()
            .chain(&self.log_scales[3 * g..3 * g + 3])
            .chain(q)
            .chain(&self.colors[g * stride..(g + 1) * stride])
            .chain(std::iter::once(&self.opacity_logits[g]))
            .all(|v| v.is_finite());
        // Written so that NaN counts as unusable.
        finite && q_norm2 > F::zero() && q_norm2.is_finite()
    }

    /// The cloud without its unusable Gaussians (see [`GaussianCloud::count_unusable`]): what a
    /// program that trains a cloud and writes it back starts from, so no NaN row is written.
    pub fn without_unusable(&self) -> Self {
        let stride = self.color_stride();
        let mut out = Self {
            color_model: self.color_model,
            means: Vec::new(),
            log_scales: Vec::new(),
            rotations: Vec::new(),
            colors: Vec::new(),
            opacity_logits: Vec::new(),
        };
        for g in (0..self.len()).filter(|&g| self.is_usable(g)) {
            out.means.extend_from_slice(&self.means[3 * g..3 * g + 3]);
            out.log_scales
                .extend_from_slice(&self.log_scales[3 * g..3 * g + 3]);
            out.rotations
                .extend_from_slice(&self.rotations[4 * g..4 * g + 4]);
            out.colors
                .extend_from_slice(&self.colors[g * stride..(g + 1) * stride]);
            out.opacity_logits.push(self.opacity_logits[g]);
        }
        out
    }

    /// Checks the array lengths agree (a cloud built field by field can be inconsistent).
    pub fn check(&self) -> Result<(), String> {
        let n = self.len();
        let want = [
            ("means", self.means.len(), 3 * n),
            ("log_scales", self.log_scales.len(), 3 * n),
            ("rotations", self.rotations.len(), 4 * n),
            ("colors", self.colors.len(), self.color_stride() * n),
        ];
        for (name, got, expected) in want {
            if got != expected {
                return Err(format!(
                    "{name} has {got} values, expected {expected} for {n} Gaussians"
                ));
            }
        }
        if let ColorModel::Sh(d) = self.color_model
            && d > 3
        {
            return Err(format!("SH degree {d} is not supported: expected 0..=3"));
        }
        Ok(())
    }

    /// The same cloud in another float type.
    pub fn cast<G: Real>(&self) -> GaussianCloud<G> {
        let f = |v: &Vec<F>| v.iter().map(|x| G::c(x.as_f64())).collect();
        GaussianCloud {
            means: f(&self.means),
            log_scales: f(&self.log_scales),
            rotations: f(&self.rotations),
            colors: f(&self.colors),
            opacity_logits: f(&self.opacity_logits),
            color_model: self.color_model,
        }
    }

    /// Bytes per Gaussian held by the parameters.
    pub fn bytes_per_gaussian(&self) -> usize {
        (3 + 3 + 4 + self.color_stride() + 1) * std::mem::size_of::<F>()
    }
}

/// Gradients of a loss with respect to every parameter of a cloud, in the same layout.
pub type CloudGradients<F = f32> = GaussianCloud<F>;

impl<F: Real> GaussianCloud<F> {
    /// A cloud of zeros shaped like `self` (for gradients and optimiser moments).
    pub fn zeros_like(&self) -> Self {
        Self {
            means: vec![F::zero(); self.means.len()],
            log_scales: vec![F::zero(); self.log_scales.len()],
            rotations: vec![F::zero(); self.rotations.len()],
            colors: vec![F::zero(); self.colors.len()],
            opacity_logits: vec![F::zero(); self.opacity_logits.len()],
            color_model: self.color_model,
        }
    }

    /// A cloud whose Gaussian `i` is `self`'s Gaussian `rows[i]` (rows may repeat or be left
    /// out): how a trainer grows and prunes a cloud, one row list for every parameter group.
    /// Panics if a row is out of range.
    pub fn gather(&self, rows: &[usize]) -> Self {
        let rows: Vec<Option<usize>> = rows.iter().copied().map(Some).collect();
        self.gather_or_zero(&rows)
    }

    /// [`GaussianCloud::gather`], with every parameter of Gaussian `i` zero where `rows[i]` is
    /// `None`: what an optimiser's moments (or gradients) of a reshaped cloud start from. (A
    /// zero Gaussian is not renderable: its quaternion is zero.) Panics if a row is out of range.
    pub fn gather_or_zero(&self, rows: &[Option<usize>]) -> Self {
        let pick = |values: &[F], width: usize| {
            let mut out = Vec::with_capacity(rows.len() * width);
            for row in rows {
                match row {
                    Some(r) => out.extend_from_slice(&values[r * width..(r + 1) * width]),
                    None => out.resize(out.len() + width, F::zero()),
                }
            }
            out
        };
        Self {
            means: pick(&self.means, 3),
            log_scales: pick(&self.log_scales, 3),
            rotations: pick(&self.rotations, 4),
            colors: pick(&self.colors, self.color_stride()),
            opacity_logits: pick(&self.opacity_logits, 1),
            color_model: self.color_model,
        }
    }

    /// The parameter groups as (name, slice), in a fixed order.
    pub fn groups(&self) -> [(&'static str, &[F]); 5] {
        [
            ("means", &self.means),
            ("log_scales", &self.log_scales),
            ("rotations", &self.rotations),
            ("colors", &self.colors),
            ("opacity_logits", &self.opacity_logits),
        ]
    }

    /// The parameter groups, mutable, in the order of [`GaussianCloud::groups`].
    pub fn groups_mut(&mut self) -> [&mut [F]; 5] {
        [
            &mut self.means,
            &mut self.log_scales,
            &mut self.rotations,
            &mut self.colors,
            &mut self.opacity_logits,
        ]
    }
}

impl GaussianCloud<f32> {
    /// The cloud with its SH truncated to `degree` (colours of a lower degree, same means,
    /// scales, rotations and opacities). An RGB cloud is returned unchanged.
    pub fn sh_truncated(&self, degree: u32) -> Self {
        let ColorModel::Sh(d) = self.color_model else {
            return self.clone();
        };
        if degree >= d {
            return self.clone();
        }
        let (from, to) = (3 * coeffs_for_degree(d), 3 * coeffs_for_degree(degree));
        let mut out = self.clone();
        out.colors = self
            .colors
            .chunks(from)
            .flat_map(|c| c[..to].to_vec())
            .collect();
        out.color_model = ColorModel::Sh(degree);
        out
    }
}
