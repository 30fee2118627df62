//! Charts for the reports (plotters): a grid of line / scatter charts written as PNG and SVG,
//! atomically. Text is drawn with the embedded DejaVu Sans (`assets/` of this crate), so plotting needs no
//! system fonts.

use std::path::{Path, PathBuf};
use std::sync::Once;

use plotters::coord::Shift;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::error::{Context, ensure};
use crate::{Error, Result};

/// One series of a chart.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// `(x, y)` points, drawn in order.
    pub points: Vec<(f64, f64)>,
    /// Draw these markers only (a scatter); `None`: a line.
    pub marker: Option<Marker>,
    /// Its colour, an index into the palette (`None`: the series' own index). A series with
    /// an empty name has no legend entry, and one without points only a legend entry: charts
    /// whose colour and marker say two things give each its own entries.
    pub color: Option<usize>,
}

/// The shape of a scatter series' markers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    /// A filled disc.
    Circle,
    /// A filled triangle.
    Triangle,
    /// A diagonal cross.
    Cross,
    /// A filled square.
    Square,
    /// An open circle, larger than the others: drawn over them, it rings points.
    Ring,
}

/// One chart of a grid.
#[derive(Clone, Debug)]
pub struct Chart {
    /// Caption.
    pub title: String,
    /// X axis label.
    pub x_label: String,
    /// Y axis label.
    pub y_label: String,
    /// The series; colours follow their order.
    pub series: Vec<Series>,
    /// A logarithmic x axis (the values must be positive).
    pub log_x: bool,
    /// The legend in the lower right corner (default: upper right).
    pub legend_at_bottom: bool,
    /// Fixed axis ranges `(x, y)` (default: fitted to the points), e.g. to compare the charts
    /// of a grid.
    pub ranges: Option<(std::ops::Range<f64>, std::ops::Range<f64>)>,
}

/// Colours by series index (colour-blind safe, Okabe–Ito); rings are always black.
const PALETTE: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(240, 228, 66),
    RGBColor(0, 0, 0),
];

fn register_font() {
    static FONT: Once = Once::new();
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        for style in [FontStyle::Normal, FontStyle::Bold] {
            // The font is embedded and known to parse; a failure would show as missing text.
            let _ = plotters::style::register_font("sans-serif", style, bytes);
        }
    });
}

/// Draw `charts` in a grid of `columns` columns, each chart `cell` pixels, into `<stem>.png` and
/// `<stem>.svg` (each written to a temporary name and renamed). Returns the two paths.
pub fn write_charts(
    stem: &Path,
    charts: &[Chart],
    columns: usize,
    cell: (u32, u32),
) -> Result<Vec<PathBuf>> {
    ensure!(
        !charts.is_empty(),
        "no charts to draw into {}",
        stem.display()
    );
    register_font();
    let columns = columns.clamp(1, charts.len());
    let rows = charts.len().div_ceil(columns);
    let size = (cell.0 * columns as u32, cell.1 * rows as u32);
    let mut written = Vec::new();
    for ext in ["png", "svg"] {
        let path = stem.with_extension(ext);
        let tmp = stem.with_extension(format!("tmp.{ext}"));
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        let result = if ext == "png" {
            let root = BitMapBackend::new(&tmp, size).into_drawing_area();
            draw_grid(&root, charts, rows, columns)
        } else {
            let root = SVGBackend::new(&tmp, size).into_drawing_area();
            draw_grid(&root, charts, rows, columns)
        };
        if let Err(message) = result {
            let _ = std::fs::remove_file(&tmp);
            return Err(Error::Write { path, message });
        }
        std::fs::rename(&tmp, &path)
            .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
        written.push(path);
    }
    Ok(written)
}

fn draw_grid<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    charts: &[Chart],
    rows: usize,
    columns: usize,
) -> std::result::Result<(), String>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| format!("{e:?}");
    root.fill(&WHITE).map_err(err)?;
    let cells = root.split_evenly((rows, columns));
    for (chart, area) in charts.iter().zip(&cells) {
        draw_chart(area, chart).map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// The range of `values` with 5 % of room (a unit range around a single value).
fn padded(values: impl Iterator<Item = f64>, from_zero: bool) -> std::ops::Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    if from_zero {
        lo = lo.min(0.0);
    }
    let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 };
    (lo - if from_zero && lo == 0.0 { 0.0 } else { pad })..(hi + pad)
}

fn draw_chart<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    chart: &Chart,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let points = || chart.series.iter().flat_map(|s| s.points.iter());
    let ys = match &chart.ranges {
        Some((_, y)) => y.clone(),
        None => padded(points().map(|p| p.1), true),
    };
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(&chart.title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(56);
    if let Some((x, _)) = &chart.ranges {
        if chart.log_x {
            draw_series(
                builder.build_cartesian_2d(x.clone().log_scale(), ys)?,
                chart,
            )
        } else {
            draw_series(builder.build_cartesian_2d(x.clone(), ys)?, chart)
        }
    } else if chart.log_x {
        let xs = log_range(points().map(|p| p.0)).unwrap_or(0.1..10.0);
        draw_series(builder.build_cartesian_2d(xs.log_scale(), ys)?, chart)
    } else {
        let xs = padded(points().map(|p| p.0), false);
        draw_series(builder.build_cartesian_2d(xs, ys)?, chart)
    }
}

/// A log axis's range over the finite positive `values`: from the power of ten at or below a
/// fifth of a decade under the smallest (plotters labels a log axis from its first power of
/// ten on, so a range that starts between two leaves the values there without labels) to a
/// fifth of a decade over the largest; `None` when there is none.
pub(crate) fn log_range(values: impl Iterator<Item = f64>) -> Option<std::ops::Range<f64>> {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    // A hair under the power of ten: `10^-2` in floats may lie above 0.01, and plotters would
    // then start its labels at 0.1.
    lo.is_finite()
        .then(|| 10f64.powf((lo / 1.6).log10().floor()) * (1.0 - 1e-9)..hi * 1.6)
}

/// An axis label with three significant digits and no trailing zeros (a log axis's key points
/// are products of floats: `0.30000000000000004` for 0.3).
fn tick_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (3 - v.abs().log10().ceil() as i32).clamp(0, 12) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn draw_series<'a, DB: DrawingBackend + 'a, X>(
    mut ctx: ChartContext<'a, DB, Cartesian2d<X, RangedCoordf64>>,
    chart: &Chart,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    ctx.configure_mesh()
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .x_labels(if chart.log_x { 20 } else { 10 })
        .x_label_formatter(&|v| {
            // On a log axis, label 1, 2, 3 and 5 of each decade (all nine crowd at its top).
            let leading = (v / 10f64.powf(v.log10().floor())).round();
            if chart.log_x && ![1.0, 2.0, 3.0, 5.0].contains(&leading) {
                String::new()
            } else {
                tick_label(*v)
            }
        })
        .y_label_formatter(&|v| tick_label(*v))
        .label_style(("sans-serif", 13))
        .draw()?;
    for (k, s) in chart.series.iter().enumerate() {
        let color = if s.marker == Some(Marker::Ring) {
            BLACK
        } else {
            PALETTE[s.color.unwrap_or(k) % PALETTE.len()]
        };
        let pts = s
            .points
            .iter()
            .copied()
            .filter(|p| p.0.is_finite() && p.1.is_finite());
        let anno = match s.marker {
            None => ctx.draw_series(LineSeries::new(pts, color.stroke_width(2)))?,
            Some(Marker::Circle) => {
                ctx.draw_series(pts.map(|p| Circle::new(p, 4, color.filled())))?
            }
            Some(Marker::Triangle) => {
                ctx.draw_series(pts.map(|p| TriangleMarker::new(p, 5, color.filled())))?
            }
            Some(Marker::Cross) => {
                ctx.draw_series(pts.map(|p| Cross::new(p, 4, color.stroke_width(2))))?
            }
            Some(Marker::Square) => ctx.draw_series(pts.map(|p| {
                EmptyElement::at(p) + Rectangle::new([(-4, -4), (4, 4)], color.filled())
            }))?,
            Some(Marker::Ring) => {
                ctx.draw_series(pts.map(|p| Circle::new(p, 8, color.stroke_width(2))))?
            }
        };
        if s.name.is_empty() {
            continue;
        }
        let marker = s.marker;
        anno.label(&s.name).legend(move |(x, y)| {
            let at = (x + 8, y);
            match marker {
                None => Rectangle::new([(x, y - 1), (x + 16, y + 1)], color.filled()).into_dyn(),
                Some(Marker::Circle) => Circle::new(at, 4, color.filled()).into_dyn(),
                Some(Marker::Triangle) => TriangleMarker::new(at, 5, color.filled()).into_dyn(),
                Some(Marker::Cross) => Cross::new(at, 4, color.stroke_width(2)).into_dyn(),
                Some(Marker::Square) => {
                    Rectangle::new([(x + 4, y - 4), (x + 12, y + 4)], color.filled()).into_dyn()
                }
                Some(Marker::Ring) => Circle::new(at, 7, color.stroke_width(2)).into_dyn(),
            }
        });
    }
    if chart.series.len() > 1 || chart.series.iter().any(|s| !s.name.is_empty()) {
        ctx.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .position(if chart.legend_at_bottom {
                SeriesLabelPosition::LowerRight
            } else {
                SeriesLabelPosition::UpperRight
            })
            .draw()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charts_are_written_as_png_and_svg_with_text() {
        let dir = tempfile::tempdir().expect("tempdir");
        let chart = Chart {
            title: "error".into(),
            x_label: "frame".into(),
            y_label: "mm".into(),
            series: vec![
                Series {
                    name: "ours".into(),
                    points: (0..10).map(|i| (i as f64, (i * i) as f64)).collect(),
                    marker: None,
                    color: None,
                },
                Series {
                    name: "lbs".into(),
                    points: vec![(1.0, 3.0), (4.0, f64::NAN)],
                    marker: Some(Marker::Circle),
                    color: None,
                },
            ],
            log_x: false,
            legend_at_bottom: false,
            ranges: None,
        };
        let stem = dir.path().join("sub/plot");
        let log = Chart {
            log_x: true,
            series: vec![Series {
                name: "ring".into(),
                points: vec![(0.05, 1.0), (3.0, 2.0)],
                marker: Some(Marker::Ring),
                color: None,
            }],
            ..chart.clone()
        };
        let paths = write_charts(&stem, &[chart, log], 2, (300, 200)).expect("drawn");
        assert_eq!(paths.len(), 2);
        let png = std::fs::read(&paths[0]).expect("png");
        assert_eq!(&png[1..4], b"PNG");
        let svg = std::fs::read_to_string(&paths[1]).expect("svg");
        assert!(
            svg.contains("ours") && svg.contains("frame"),
            "legend and labels"
        );
        let names: Vec<_> = std::fs::read_dir(dir.path().join("sub"))
            .expect("dir")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names.len(), 2, "no temporary files left: {names:?}");
        assert!(write_charts(&stem, &[], 1, (10, 10)).is_err());
    }

    #[test]
    fn tick_labels_keep_three_significant_digits_and_drop_float_noise() {
        assert_eq!(tick_label(0.30000000000000004), "0.3");
        assert_eq!(tick_label(0.7000000000000001), "0.7");
        assert_eq!(tick_label(0.02), "0.02");
        assert_eq!(tick_label(0.0005), "0.0005");
        assert_eq!(tick_label(1500.0), "1500");
        assert_eq!(tick_label(12.5), "12.5");
        assert_eq!(tick_label(-2.25), "-2.25");
        assert_eq!(tick_label(0.0), "0");
    }

    #[test]
    fn log_axes_start_at_a_power_of_ten_and_pad_a_fifth_of_a_decade_over_positive_values() {
        // 0.05 / 1.6 = 0.031: the axis starts at 0.01; 0.2 / 1.6 = 0.125: at 0.1.
        let r = log_range([0.05, f64::NAN, -1.0, 0.0, 3.0].into_iter()).expect("two values");
        assert!((r.start - 0.01).abs() < 1e-10 && r.start < 0.01 && (r.end - 4.8).abs() < 1e-12);
        let r = log_range([0.2, 0.7].into_iter()).expect("two values");
        assert!((r.start - 0.1).abs() < 1e-9 && r.start < 0.1, "{r:?}");
        assert!(log_range([0.0, f64::INFINITY].into_iter()).is_none());
    }
}
