//! Plots for reports, with plotters: line and point charts (linear or log axes) written as SVG
//! and PNG, and labelled image grids written as PNG. PNGs are drawn into memory by plotters'
//! bitmap backend and encoded by `image`; text uses a bundled font through the pure-Rust
//! ab_glyph, so no system font or C library is needed.

use crate::error::{Error, Result};
use glam::Vec3;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// DejaVu Sans Mono (see `data/SOURCES.md`), registered as plotters' "sans-serif".
const FONT: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../data/fonts/DejaVuSansMono.ttf"
));

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The bundled file is a valid TrueType font; a failure would only lose the labels.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// One line (or set of points) of a chart.
#[derive(Debug, Clone, Default)]
pub struct Series {
    pub name: String,
    /// (x, y); points that cannot be drawn (non-finite, or <= 0 on a log axis) are skipped.
    pub points: Vec<(f64, f64)>,
    /// Optional error bars: (x, low, high).
    pub bars: Vec<(f64, f64, f64)>,
    /// Draw markers at the points as well as the line.
    pub markers: bool,
}

/// A chart of series against one x and one y axis.
#[derive(Debug, Clone, Default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
    /// Vertical marks (x, label), e.g. scene edits on a frame axis.
    pub marks: Vec<(f64, String)>,
}

const CHART_SIZE: (u32, u32) = (800, 520);

/// Writes `chart` to `stem.svg` and `stem.png`; returns the two paths.
pub fn write_chart(stem: &Path, chart: &Chart) -> Result<(PathBuf, PathBuf)> {
    register_font();
    let svg = stem.with_extension("svg");
    let png = stem.with_extension("png");
    let mut svg_text = String::new();
    {
        let root = SVGBackend::with_string(&mut svg_text, CHART_SIZE).into_drawing_area();
        draw_chart(&root, chart)?;
        root.present()
            .map_err(|e| Error::file(&svg, e.to_string()))?;
    }
    crate::write_text(&svg, &svg_text)?;
    let (w, h) = CHART_SIZE;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, CHART_SIZE).into_drawing_area();
        draw_chart(&root, chart)?;
        root.present()
            .map_err(|e| Error::file(&png, e.to_string()))?;
    }
    save_png(&png, w, h, &buf)?;
    Ok((svg, png))
}

fn save_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    render_base::write_atomically(path, |file| {
        image::write_buffer_with_format(
            file,
            rgb,
            w,
            h,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| e.to_string())
    })?;
    Ok(())
}

/// JPEG quality of image grids: renders and error maps, where PNG took 1-14 MB a grid and the
/// repository carries every re-run.
const GRID_JPEG_QUALITY: u8 = 85;

/// Writes an RGB image as JPEG (`.jpg`/`.jpeg`) or PNG (anything else), atomically.
fn save_image(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    let jpeg = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("jpg") || e.eq_ignore_ascii_case("jpeg"));
    if !jpeg {
        return save_png(path, w, h, rgb);
    }
    render_base::write_atomically(path, |file| {
        image::codecs::jpeg::JpegEncoder::new_with_quality(file, GRID_JPEG_QUALITY)
            .encode(rgb, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| e.to_string())
    })?;
    Ok(())
}

/// An axis value as drawn: log10 on a log axis; `None` when it cannot be drawn.
fn axis(v: f64, log: bool) -> Option<f64> {
    let t = if log {
        if v > 0.0 { v.log10() } else { return None }
    } else {
        v
    };
    t.is_finite().then_some(t)
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo <= hi) {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.06).max(1e-3);
    (lo - pad, hi + pad)
}

/// Which ticks of an axis get labels.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Labels {
    /// Every tick (a linear axis, or a log axis under half a decade).
    All,
    /// The 1-2-5 values: 0.02, 0.05, 0.1, ... (a log axis of half a decade or more).
    OneTwoFive,
    /// The powers of ten (a log axis holding three or more of them).
    Decades,
}

impl Labels {
    /// The labels for an axis drawing `lo..hi` (exponents when `log`).
    fn for_axis(log: bool, (lo, hi): (f64, f64)) -> Self {
        let powers_of_ten = (hi.floor() - lo.ceil() + 1.0).max(0.0);
        if !log || hi - lo < 0.5 {
            Labels::All
        } else if powers_of_ten >= 3.0 {
            Labels::Decades
        } else {
            Labels::OneTwoFive
        }
    }
}

/// A tick label; on a log axis `v` is an exponent, and only the ticks `labels` names are
/// labelled (the others stay as unlabelled marks).
fn tick(v: f64, log: bool, labels: Labels) -> String {
    if log && labels != Labels::All {
        let x = 10f64.powf(v);
        let e = (x.log10() + 1e-9).floor();
        let mantissa = x / 10f64.powf(e);
        let allowed: &[f64] = match labels {
            Labels::Decades => &[1.0, 10.0],
            _ => &[1.0, 2.0, 5.0, 10.0],
        };
        return match allowed.iter().find(|&&m| (mantissa / m - 1.0).abs() < 0.01) {
            Some(&m) => short_number(m * 10f64.powf(e)),
            None => String::new(),
        };
    }
    let x = if log { 10f64.powf(v) } else { v };
    let a = x.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{x:.0e}")
    } else if a >= 100.0 {
        format!("{x:.0}")
    } else if a >= 1.0 {
        format!("{x:.2}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .into()
    } else {
        format!("{x:.4}").trim_end_matches('0').into()
    }
}

/// A round value (one significant digit) as written on an axis: `0.02`, `500`, `1e5`.
fn short_number(x: f64) -> String {
    let e = (x.abs().log10() + 1e-9).floor() as i32;
    if (-3..4).contains(&e) {
        format!("{x:.*}", (-e).max(0) as usize)
    } else {
        format!("{x:.0e}")
    }
}

fn draw_chart<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, c: &Chart) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| {
        Error::Invalid(format!("drawing `{}`: {e:?}", c.title))
    };
    root.fill(&WHITE).map_err(err)?;
    let pts = |s: &Series| -> Vec<(f64, f64)> {
        s.points
            .iter()
            .filter_map(|&(x, y)| Some((axis(x, c.log_x)?, axis(y, c.log_y)?)))
            .collect()
    };
    let bars = |s: &Series| -> Vec<(f64, f64, f64)> {
        s.bars
            .iter()
            .filter_map(|&(x, lo, hi)| {
                Some((axis(x, c.log_x)?, axis(lo, c.log_y)?, axis(hi, c.log_y)?))
            })
            .collect()
    };
    let all: Vec<(f64, f64)> = c.series.iter().flat_map(pts).collect();
    let bar_ys = c.series.iter().flat_map(bars).flat_map(|(_, a, b)| [a, b]);
    let xr = range(
        all.iter()
            .map(|p| p.0)
            .chain(c.marks.iter().filter_map(|m| axis(m.0, c.log_x))),
    );
    let yr = range(all.iter().map(|p| p.1).chain(bar_ys));
    let mut chart = ChartBuilder::on(root)
        .caption(&c.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(err)?;
    let (lx, ly) = (c.log_x, c.log_y);
    let (label_x, label_y) = (Labels::for_axis(lx, xr), Labels::for_axis(ly, yr));
    chart
        .configure_mesh()
        .x_desc(&c.x_label)
        .y_desc(&c.y_label)
        // Many candidate ticks on a log axis of half a decade or more (only round values get
        // labels), few otherwise; no minor grid (it dominated the PNGs' size and said nothing).
        .x_labels(if label_x == Labels::All { 8 } else { 40 })
        .y_labels(if label_y == Labels::All { 8 } else { 40 })
        .light_line_style(TRANSPARENT)
        .x_label_formatter(&|v| tick(*v, lx, label_x))
        .y_label_formatter(&|v| tick(*v, ly, label_y))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(err)?;
    for (x, label) in &c.marks {
        if let Some(x) = axis(*x, c.log_x) {
            chart
                .draw_series(LineSeries::new([(x, yr.0), (x, yr.1)], BLACK.mix(0.4)))
                .map_err(err)?;
            chart
                .draw_series([Text::new(label.clone(), (x, yr.1), ("sans-serif", 12))])
                .map_err(err)?;
        }
    }
    for (i, s) in c.series.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let p = pts(s);
        chart
            .draw_series(LineSeries::new(p.clone(), colour.stroke_width(2)))
            .map_err(err)?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour.stroke_width(2)));
        if s.markers {
            chart
                .draw_series(p.iter().map(|&q| Circle::new(q, 3, colour.filled())))
                .map_err(err)?;
        }
        for (x, lo, hi) in bars(s) {
            chart
                .draw_series(LineSeries::new([(x, lo), (x, hi)], colour))
                .map_err(err)?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 13))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(err)?;
    Ok(())
}

/// An 8-bit RGB image.
#[derive(Debug, Clone)]
pub struct Rgb8 {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl Rgb8 {
    /// The image shrunk by an integer `factor` (each output pixel the mean of a `factor` x
    /// `factor` block; a partial block at the edge is dropped). `factor` 1 is a copy.
    pub fn downscaled(&self, factor: u32) -> Rgb8 {
        let f = factor.max(1);
        let (w, h) = ((self.width / f).max(1), (self.height / f).max(1));
        let mut data = Vec::with_capacity((w * h * 3) as usize);
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    let mut sum = 0u32;
                    let mut n = 0u32;
                    for dy in 0..f.min(self.height) {
                        for dx in 0..f.min(self.width) {
                            let (sx, sy) = (x * f + dx, y * f + dy);
                            if sx < self.width && sy < self.height {
                                sum += self.data[((sy * self.width + sx) * 3 + c) as usize] as u32;
                                n += 1;
                            }
                        }
                    }
                    data.push((sum / n.max(1)) as u8);
                }
            }
        }
        Rgb8 {
            width: w,
            height: h,
            data,
        }
    }
}

/// Per-pixel values (e.g. relative squared error) in false colour (viridis) on a log scale
/// from `10^lo` (dark) to `10^hi` (yellow).
pub fn false_colour(values: &[f64], width: u32, height: u32, lo: f64, hi: f64) -> Rgb8 {
    let data = values
        .iter()
        .flat_map(|&v| {
            let t = if v > 0.0 { v.log10() } else { lo };
            let t = if t.is_finite() { t.clamp(lo, hi) } else { hi };
            let c = ViridisRGB::get_color_normalized(t, lo, hi);
            [c.0, c.1, c.2]
        })
        .collect();
    Rgb8 {
        width,
        height,
        data,
    }
}

/// Tone-mapped 8-bit sRGB of linear radiance.
pub fn tone_mapped(
    pixels: &[Vec3],
    width: u32,
    height: u32,
    exposure: f32,
    tone: hdr_image::ToneMap,
) -> Rgb8 {
    Rgb8 {
        width,
        height,
        data: hdr_image::tone_map(pixels, exposure, tone),
    }
}

/// Writes a grid of images as one PNG: a title, a label per column and per row. Rows may have
/// fewer images than there are columns.
pub fn write_image_grid(
    path: &Path,
    title: &str,
    columns: &[String],
    rows: &[(String, Vec<Rgb8>)],
) -> Result<()> {
    register_font();
    let (cw, ch) = rows
        .iter()
        .flat_map(|r| &r.1)
        .fold((1, 1), |(w, h), i| (w.max(i.width), h.max(i.height)));
    let (label_w, head_h, pad) = (200u32, 56u32, 4u32);
    // Room for a four-line row label and a column title.
    let (cw, ch) = (cw.max(200), ch.max(72));
    let ncols = columns
        .len()
        .max(rows.iter().map(|r| r.1.len()).max().unwrap_or(0))
        .max(1) as u32;
    let w = label_w + ncols * (cw + pad);
    let h = head_h + rows.len() as u32 * (ch + pad);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    for (r, (_, images)) in rows.iter().enumerate() {
        for (c, img) in images.iter().enumerate() {
            let (x0, y0) = (
                label_w + c as u32 * (cw + pad),
                head_h + r as u32 * (ch + pad),
            );
            for y in 0..img.height {
                let src = (y * img.width * 3) as usize;
                let dst = (((y0 + y) * w + x0) * 3) as usize;
                let n = (img.width * 3) as usize;
                buf[dst..dst + n].copy_from_slice(&img.data[src..src + n]);
            }
        }
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let err = |e: DrawingAreaErrorKind<_>| Error::file(path, format!("{e:?}"));
        let style = ("sans-serif", 15).into_font().color(&BLACK);
        root.draw(&Text::new(title.to_string(), (8, 6), ("sans-serif", 18)))
            .map_err(err)?;
        for (c, label) in columns.iter().enumerate() {
            let x = (label_w + c as u32 * (cw + pad)) as i32;
            root.draw(&Text::new(label.clone(), (x + 2, 32), style.clone()))
                .map_err(err)?;
        }
        for (r, (label, _)) in rows.iter().enumerate() {
            let y = (head_h + r as u32 * (ch + pad) + ch / 2) as i32 - 8;
            for (i, line) in label.split('\n').enumerate() {
                root.draw(&Text::new(
                    line.to_string(),
                    (6, y + 17 * i as i32),
                    style.clone(),
                ))
                .map_err(err)?;
            }
        }
        root.present().map_err(err)?;
    }
    save_image(path, w, h, &buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_read_as_numbers() {
        use Labels::*;
        assert_eq!(tick(-2.0, true, OneTwoFive), "0.01");
        assert_eq!(tick(0.0, true, OneTwoFive), "1");
        assert_eq!(tick(2.0, true, Decades), "100");
        assert_eq!(tick(1.5, false, All), "1.5");
        assert_eq!(tick(5.0, true, Decades), "1e5");
        assert_eq!(tick(0.02f64.log10(), true, OneTwoFive), "0.02");
        assert_eq!(tick(0.05f64.log10(), true, OneTwoFive), "0.05");
        assert_eq!(tick(500f64.log10(), true, OneTwoFive), "500");
        assert_eq!(tick(0.03f64.log10(), true, OneTwoFive), "");
        assert_eq!(tick(0.02f64.log10(), true, Decades), "");
        assert_eq!(tick(0.03f64.log10(), true, All), "0.03");
        // Three powers of ten or more: decades; half a decade to that: 1-2-5; less: all.
        assert_eq!(Labels::for_axis(true, (-3.1, -0.9)), Decades);
        assert_eq!(Labels::for_axis(true, (-1.8, -0.3)), OneTwoFive);
        assert_eq!(Labels::for_axis(true, (-1.4, -1.1)), All);
        assert_eq!(Labels::for_axis(false, (0.0, 100.0)), All);
        assert_eq!(axis(0.0, true), None);
        assert_eq!(axis(f64::NAN, false), None);
    }

    #[test]
    fn charts_and_grids_are_written_with_their_labels() {
        let dir = std::env::temp_dir().join(format!("gscache-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let chart = Chart {
            title: "relMSE against time".into(),
            x_label: "seconds".into(),
            y_label: "relMSE".into(),
            log_x: true,
            log_y: true,
            series: vec![Series {
                name: "nee".into(),
                points: vec![(0.1, 0.5), (0.2, 0.25), (0.0, 1.0)],
                bars: vec![(0.1, 0.4, 0.6)],
                markers: true,
            }],
            marks: vec![],
        };
        let (svg, png) = write_chart(&dir.join("c"), &chart).unwrap();
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("relMSE against time") && text.contains("nee"));
        let img = image::open(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), CHART_SIZE);
        // Text and lines were drawn: not every pixel is white.
        assert!(img.pixels().filter(|p| p.0 != [255, 255, 255]).count() > 1000);
        let tile = false_colour(&[1e-4, 1.0], 2, 1, -4.0, 0.0);
        assert_ne!(tile.data[..3], tile.data[3..]);
        let grid = dir.join("g.png");
        write_image_grid(
            &grid,
            "t",
            &["a".into()],
            &[("row".into(), vec![tile.clone()])],
        )
        .unwrap();
        assert!(image::open(&grid).is_ok());
        let jpg = dir.join("g.jpg");
        write_image_grid(&jpg, "t", &["a".into()], &[("row".into(), vec![tile])]).unwrap();
        assert_eq!(
            image::ImageFormat::from_path(&jpg).unwrap(),
            image::ImageFormat::Jpeg
        );
        assert!(image::open(&jpg).is_ok());
        // A 4x2 image of two flat halves shrinks by 2 to their two colours.
        let halves = Rgb8 {
            width: 4,
            height: 2,
            data: (0..8)
                .flat_map(|i| [if i % 4 < 2 { 10 } else { 200 }; 3])
                .collect(),
        };
        let small = halves.downscaled(2);
        assert_eq!((small.width, small.height), (2, 1));
        assert_eq!(small.data, vec![10, 10, 10, 200, 200, 200]);
        std::fs::remove_dir_all(&dir).ok();
    }
}
