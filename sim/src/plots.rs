//! PNG line charts for flight and Monte Carlo reports (like the paper's figures), drawn with
//! `plotters` and a bundled font, so no system font library is needed.
//!
//! Legends sit in a strip between the title and the plot, so they never hide data.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::FontStyle;
use plotters::style::text_anchor::{HPos, Pos, VPos};

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

/// A vertical line marking an event at `x` (e.g. the GNSS loss), labelled above the plot.
#[derive(Debug, Clone)]
pub struct XMarker {
    /// Abscissa of the event.
    pub x: f64,
    /// Text written above the plot area at the line.
    pub label: String,
}

/// A labelled point drawn as a filled disc (e.g. where GNSS was lost on a ground track); the
/// label goes to the legend.
#[derive(Debug, Clone)]
pub struct PointMarker {
    /// Legend entry.
    pub label: String,
    /// Position `(x, y)`.
    pub at: (f64, f64),
    /// Fill colour as RGB.
    pub rgb: (u8, u8, u8),
}

/// A chart: title, axis labels and lines.
#[derive(Debug, Clone, Default)]
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
    /// Event lines; those outside the data's x range are not drawn.
    pub x_markers: Vec<XMarker>,
    /// Labelled points, drawn over the lines.
    pub points: Vec<PointMarker>,
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

/// Colour of event markers: dark grey, distinct from every palette line.
const MARKER_RGB: (u8, u8, u8) = (60, 60, 60);
// Layout, pixels.
const MARGIN: i32 = 12;
const X_LABEL_AREA: i32 = 40;
const Y_LABEL_AREA: i32 = 60;
/// Room above the plot area for event labels.
const MARKER_LABEL_ROOM: i32 = 18;
const LEGEND_FONT: i32 = 13;
const LEGEND_ROW_H: i32 = 20;
/// Legend key (line sample or disc) width, and gaps after the key and after each entry.
const KEY_W: i32 = 24;
const KEY_GAP: i32 = 6;
const ENTRY_GAP: i32 = 22;
const POINT_RADIUS: i32 = 5;

fn rgb((r, g, b): (u8, u8, u8)) -> RGBColor {
    RGBColor(r, g, b)
}

fn bounds<'s>(points: impl Iterator<Item = &'s (f64, f64)>) -> Option<((f64, f64), (f64, f64))> {
    let mut it = points.filter(|(x, y)| x.is_finite() && y.is_finite());
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

/// What a legend entry's key looks like.
#[derive(Debug, Clone, Copy)]
enum Key {
    Line { rgb: (u8, u8, u8), dashed: bool },
    Disc { rgb: (u8, u8, u8) },
}

#[derive(Debug, Clone)]
struct LegendEntry {
    label: String,
    key: Key,
}

/// A row of the legend: its entries with their x offset from the row start, and its width.
#[derive(Debug)]
struct LegendRow<'e> {
    entries: Vec<(i32, &'e LegendEntry)>,
    width: i32,
}

/// Lay `entries` out in rows that fit `width` pixels, in order.
fn layout_legend(
    entries: &[LegendEntry],
    text_w: impl Fn(&str) -> i32,
    width: i32,
) -> Vec<LegendRow<'_>> {
    let mut rows = Vec::new();
    let mut row = Vec::new();
    let mut x = 0;
    for e in entries {
        let w = KEY_W + KEY_GAP + text_w(&e.label);
        if x > 0 && x + w > width {
            let entries = std::mem::take(&mut row);
            rows.push(LegendRow {
                entries,
                width: x - ENTRY_GAP,
            });
            x = 0;
        }
        row.push((x, e));
        x += w + ENTRY_GAP;
    }
    if !row.is_empty() {
        rows.push(LegendRow {
            entries: row,
            width: x - ENTRY_GAP,
        });
    }
    rows
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
    let data = chart.series.iter().flat_map(|s| s.points.iter());
    let Some((xr, yr)) = bounds(data.chain(chart.points.iter().map(|p| &p.at))) else {
        return Err(err("no finite points".into()));
    };
    let (mut xr, mut yr) = (pad(xr), pad(yr));
    let markers: Vec<&XMarker> = chart
        .x_markers
        .iter()
        .filter(|m| m.x >= xr.0 && m.x <= xr.1)
        .collect();

    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let body = root
        .titled(chart.title, ("sans-serif", 20))
        .map_err(|e| err(e.to_string()))?;
    let legend_font = TextStyle::from(("sans-serif", LEGEND_FONT).into_font());
    let lines = chart.series.iter().map(|s| LegendEntry {
        label: s.label.clone(),
        key: Key::Line {
            rgb: s.rgb,
            dashed: s.dashed,
        },
    });
    let discs = chart.points.iter().map(|p| LegendEntry {
        label: p.label.clone(),
        key: Key::Disc { rgb: p.rgb },
    });
    let entries: Vec<LegendEntry> = lines.chain(discs).filter(|e| !e.label.is_empty()).collect();
    let text_w = |t: &str| {
        body.estimate_text_size(t, &legend_font)
            .map_or(0, |(w, _)| i32::try_from(w).unwrap_or(i32::MAX))
    };
    let image_w = i32::try_from(width).unwrap_or(i32::MAX);
    let rows = layout_legend(&entries, text_w, image_w - 2 * MARGIN);
    let legend_h = i32::try_from(rows.len()).unwrap_or(0) * LEGEND_ROW_H;
    let (legend_area, plot_area) = body.split_vertically(legend_h);
    draw_legend(&legend_area, &rows, &legend_font).map_err(|e| err(e.to_string()))?;

    let mut builder = ChartBuilder::on(&plot_area);
    builder
        .margin(MARGIN)
        .margin_top(if markers.is_empty() {
            MARGIN
        } else {
            MARGIN + MARKER_LABEL_ROOM
        })
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA);
    let mut ctx = builder
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|e| err(e.to_string()))?;
    if chart.equal_axes {
        // Same units per pixel on both axes: widen one range to the plot area's aspect.
        let (pw, ph) = ctx.plotting_area().dim_in_pixel();
        let (pw, ph) = (f64::from(pw.max(1)), f64::from(ph.max(1)));
        let scale = ((xr.1 - xr.0) / pw).max((yr.1 - yr.0) / ph);
        let (cx, cy) = ((xr.0 + xr.1) / 2.0, (yr.0 + yr.1) / 2.0);
        xr = (cx - scale * pw / 2.0, cx + scale * pw / 2.0);
        yr = (cy - scale * ph / 2.0, cy + scale * ph / 2.0);
        ctx = builder
            .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
            .map_err(|e| err(e.to_string()))?;
    }
    ctx.configure_mesh()
        .x_desc(chart.x_label)
        .y_desc(chart.y_label)
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    // Event lines first, so the data is drawn over them.
    let marker_color = rgb(MARKER_RGB);
    let marker_style = marker_color.stroke_width(2);
    for m in &markers {
        ctx.draw_series(DashedLineSeries::new(
            [(m.x, yr.0), (m.x, yr.1)],
            8,
            4,
            marker_style,
        ))
        .map_err(|e| err(e.to_string()))?;
    }
    for s in &chart.series {
        let points = s
            .points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite());
        let style = rgb(s.rgb).stroke_width(if s.dashed { 1 } else { 2 });
        if s.dashed {
            ctx.draw_series(DashedLineSeries::new(points, 6, 4, style))
        } else {
            ctx.draw_series(LineSeries::new(points, style))
        }
        .map_err(|e| err(e.to_string()))?;
    }
    for p in &chart.points {
        // A white ring keeps the disc visible on top of a line of any colour.
        let discs = [
            Circle::new(p.at, POINT_RADIUS + 2, WHITE.filled()),
            Circle::new(p.at, POINT_RADIUS, rgb(p.rgb).filled()),
        ];
        ctx.draw_series(discs).map_err(|e| err(e.to_string()))?;
    }
    // Event labels above the plot area (not over the data), kept inside the image.
    let label_font = legend_font.color(&marker_color);
    for m in &markers {
        let (px, top) = ctx.backend_coord(&(m.x, yr.1));
        let half_w = text_w(&m.label) / 2 + 2;
        let px = px.clamp(half_w, image_w - half_w);
        let style = label_font.pos(Pos::new(HPos::Center, VPos::Bottom));
        root.draw_text(&m.label, &style, (px, top - 3))
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))
}

/// Draw the legend rows, centred, in `area`.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    rows: &[LegendRow<'_>],
    font: &TextStyle<'_>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let area_w = i32::try_from(area.dim_in_pixel().0).unwrap_or(i32::MAX);
    let text_style = font.pos(Pos::new(HPos::Left, VPos::Center));
    for (r, row) in (0..).zip(rows) {
        let y = r * LEGEND_ROW_H + LEGEND_ROW_H / 2;
        let x0 = (area_w - row.width) / 2;
        for &(dx, LegendEntry { label, key }) in &row.entries {
            let x = x0 + dx;
            match *key {
                Key::Line { rgb: c, dashed } => {
                    let ends = [(x, y), (x + KEY_W, y)];
                    if dashed {
                        let style = rgb(c).stroke_width(1);
                        area.draw(&DashedPathElement::new(ends, 6, 4, style))?;
                    } else {
                        area.draw(&PathElement::new(ends, rgb(c).stroke_width(2)))?;
                    }
                }
                Key::Disc { rgb: c } => {
                    area.draw(&Circle::new(
                        (x + KEY_W / 2, y),
                        POINT_RADIUS,
                        rgb(c).filled(),
                    ))?;
                }
            }
            area.draw_text(label, &text_style, (x + KEY_W + KEY_GAP, y))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sine(label: &str) -> Series {
        Series {
            label: label.into(),
            points: (0..100)
                .map(|i| (f64::from(i), (f64::from(i) * 0.1).sin()))
                .collect(),
            rgb: PALETTE[0],
            dashed: false,
        }
    }

    #[test]
    fn draws_a_png_and_rejects_empty_charts() {
        let dir = std::env::temp_dir().join(format!("ianav-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sine.png");
        let chart = Chart {
            title: "sine",
            x_label: "t [s]",
            y_label: "y",
            series: vec![sine("sin")],
            x_markers: vec![XMarker {
                x: 50.0,
                label: "event".into(),
            }],
            points: vec![PointMarker {
                label: "peak".into(),
                at: (16.0, 1.0),
                rgb: PALETTE[5],
            }],
            ..Chart::default()
        };
        draw(&path, &chart, 640, 400).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        let empty = Chart {
            series: vec![],
            points: vec![],
            ..chart
        };
        assert!(draw(&dir.join("empty.png"), &empty, 640, 400).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn legend_wraps_to_the_width_and_keeps_order() {
        let key = Key::Disc { rgb: PALETTE[0] };
        let entries: Vec<LegendEntry> = ["a", "b", "c"]
            .iter()
            .map(|s| LegendEntry {
                label: (*s).to_owned(),
                key,
            })
            .collect();
        // Each entry is KEY_W + KEY_GAP + 50 = 80 px wide, plus ENTRY_GAP between entries.
        let rows = layout_legend(&entries, |_| 50, 200);
        let labels: Vec<Vec<&str>> = rows
            .iter()
            .map(|r| r.entries.iter().map(|(_, e)| e.label.as_str()).collect())
            .collect();
        assert_eq!(labels, [vec!["a", "b"], vec!["c"]]);
        assert_eq!(rows[0].width, 80 + ENTRY_GAP + 80);
        assert_eq!(rows[1].entries[0].0, 0);
        assert!(layout_legend(&[], |_| 50, 200).is_empty());
    }
}
