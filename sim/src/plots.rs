//! PNG line charts for flight and Monte Carlo reports (like the paper's figures), drawn with
//! `plotters` and a bundled font, so no system font library is needed.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;
use plotters::style::FontStyle;

/// Font shipped with the program (DejaVu Sans, Bitstream Vera licence: `assets/`).
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

/// Errors drawing a chart.
#[derive(Debug, thiserror::Error)]
#[error("plot {path}: {message}")]
pub struct PlotError {
    /// File being drawn.
    pub path: String,
    /// What went wrong.
    pub message: String,
}

/// One line of a chart.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend entry.
    pub label: String,
    /// Points `(x, y)`; non-finite points are skipped.
    pub points: Vec<(f64, f64)>,
    /// Line colour as RGB.
    pub rgb: (u8, u8, u8),
    /// Dashed (e.g. ± σ bands) rather than solid.
    pub dashed: bool,
}

/// A chart: title, axis labels and lines.
#[derive(Debug, Clone)]
pub struct Chart<'a> {
    /// Title above the plot.
    pub title: &'a str,
    /// Horizontal axis label.
    pub x_label: &'a str,
    /// Vertical axis label.
    pub y_label: &'a str,
    /// Lines.
    pub series: Vec<Series>,
    /// Same scale on both axes (maps, ground tracks).
    pub equal_axes: bool,
}

/// Colours used for successive series.
pub const PALETTE: [(u8, u8, u8); 6] = [
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (148, 103, 189),
    (255, 127, 14),
    (0, 0, 0),
];

fn bounds(series: &[Series]) -> Option<((f64, f64), (f64, f64))> {
    let mut it = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|(x, y)| x.is_finite() && y.is_finite());
    let &(x0, y0) = it.next()?;
    let (mut xr, mut yr) = ((x0, x0), (y0, y0));
    for &(x, y) in it {
        xr = (xr.0.min(x), xr.1.max(x));
        yr = (yr.0.min(y), yr.1.max(y));
    }
    Some((xr, yr))
}

/// Widen a degenerate or tight range so flat lines remain visible.
fn pad((lo, hi): (f64, f64)) -> (f64, f64) {
    let span = hi - lo;
    let margin = if span > 1e-9 {
        0.05 * span
    } else {
        lo.abs().max(1.0) * 0.01
    };
    (lo - margin, hi + margin)
}

/// Draw `chart` to a `width × height` PNG at `path`.
pub fn draw(path: &Path, chart: &Chart<'_>, width: u32, height: u32) -> Result<(), PlotError> {
    let err = |message: String| PlotError {
        path: path.display().to_string(),
        message,
    };
    REGISTER.call_once(|| {
        // The bundled font is valid; if registration failed, text would simply be missing.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
    let Some((mut xr, mut yr)) = bounds(&chart.series) else {
        return Err(err("no finite points".into()));
    };
    xr = pad(xr);
    yr = pad(yr);
    if chart.equal_axes {
        // Same metres per pixel on both axes (plot area is roughly width-90 by height-70).
        let (pw, ph) = (
            f64::from(width.saturating_sub(90)),
            f64::from(height.saturating_sub(70)),
        );
        let scale = ((xr.1 - xr.0) / pw).max((yr.1 - yr.0) / ph);
        let (cx, cy) = ((xr.0 + xr.1) / 2.0, (yr.0 + yr.1) / 2.0);
        xr = (cx - scale * pw / 2.0, cx + scale * pw / 2.0);
        yr = (cy - scale * ph / 2.0, cy + scale * ph / 2.0);
    }
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut ctx = ChartBuilder::on(&root)
        .caption(chart.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|e| err(e.to_string()))?;
    ctx.configure_mesh()
        .x_desc(chart.x_label)
        .y_desc(chart.y_label)
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let labelled = chart.series.iter().filter(|s| !s.label.is_empty()).count();
    for s in &chart.series {
        let color = RGBColor(s.rgb.0, s.rgb.1, s.rgb.2);
        let points = s
            .points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite());
        let style = color.stroke_width(if s.dashed { 1 } else { 2 });
        let drawn = if s.dashed {
            ctx.draw_series(DashedLineSeries::new(points, 6, 4, style))
        } else {
            ctx.draw_series(LineSeries::new(points, style))
        }
        .map_err(|e| err(e.to_string()))?;
        if !s.label.is_empty() {
            drawn.label(s.label.clone()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
        }
    }
    if labelled > 0 {
        ctx.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .draw()
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_a_png_and_rejects_empty_charts() {
        let dir = std::env::temp_dir().join(format!("ianav-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sine.png");
        let chart = Chart {
            title: "sine",
            x_label: "t [s]",
            y_label: "y",
            series: vec![Series {
                label: "sin".into(),
                points: (0..100)
                    .map(|i| (f64::from(i), (f64::from(i) * 0.1).sin()))
                    .collect(),
                rgb: PALETTE[0],
                dashed: false,
            }],
            equal_axes: false,
        };
        draw(&path, &chart, 640, 400).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        let empty = Chart {
            series: vec![],
            ..chart
        };
        assert!(draw(&dir.join("empty.png"), &empty, 640, 400).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
