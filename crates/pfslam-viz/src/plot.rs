//! Trajectory plots: several paths on metric axes with equal aspect, a legend, and start
//! (circle) / end (triangle) markers, rendered with plotters into an in-memory RGB buffer and
//! written as PNG atomically.

use super::{FONT_FAMILY, ensure_font};
use pfslam::files::{IoError, write_bytes_atomic};
use pfslam::geometry::{Pose2, StampedPose2, Trajectory};
use plotters::prelude::*;
use std::path::Path;

/// Errors of plotting.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// Writing the file failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// Nothing to draw.
    #[error("nothing to plot: every series is empty")]
    Empty,
    /// The drawing backend or the PNG encoder failed.
    #[error("drawing failed: {0}")]
    Draw(String),
}

/// A path to draw, borrowed in any of the shapes the library keeps poses in.
#[derive(Debug, Clone, Copy)]
pub enum PathRef<'a> {
    /// A trajectory.
    Trajectory(&'a Trajectory),
    /// Stamped poses.
    Stamped(&'a [StampedPose2]),
    /// Plain poses.
    Poses(&'a [Pose2]),
}

impl<'a> From<&'a Trajectory> for PathRef<'a> {
    fn from(t: &'a Trajectory) -> Self {
        PathRef::Trajectory(t)
    }
}

impl<'a> From<&'a [StampedPose2]> for PathRef<'a> {
    fn from(p: &'a [StampedPose2]) -> Self {
        PathRef::Stamped(p)
    }
}

impl<'a> From<&'a [Pose2]> for PathRef<'a> {
    fn from(p: &'a [Pose2]) -> Self {
        PathRef::Poses(p)
    }
}

impl PathRef<'_> {
    fn points(&self) -> Vec<(f64, f64)> {
        match self {
            PathRef::Trajectory(t) => t.poses.iter().map(|p| (p.pose.x_m, p.pose.y_m)).collect(),
            PathRef::Stamped(s) => s.iter().map(|p| (p.pose.x_m, p.pose.y_m)).collect(),
            PathRef::Poses(s) => s.iter().map(|p| (p.x_m, p.y_m)).collect(),
        }
    }
}

/// One series: legend label, path, colour (RGB).
pub type Series<'a> = (&'a str, PathRef<'a>, [u8; 3]);

/// Distinct colours for series (blue, red, green, orange, purple, grey).
pub const PALETTE: [[u8; 3]; 6] = [
    [31, 119, 180],
    [214, 39, 40],
    [44, 160, 44],
    [255, 127, 14],
    [148, 103, 189],
    [127, 127, 127],
];

/// Plot size (px).
const WIDTH: u32 = 1000;
const HEIGHT: u32 = 900;

fn draw_err<E: std::fmt::Display>(e: E) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// Draws the series into a PNG at `path` (atomic write). Axes in metres with equal aspect;
/// every series' start is a circle and its end a triangle in the series' colour.
pub fn plot_trajectories(path: &Path, series: &[Series<'_>], title: &str) -> Result<(), PlotError> {
    let png = render_trajectories_png(series, title)?;
    write_bytes_atomic(path, &png)?;
    Ok(())
}

/// A series as drawn: label, points (m) and colour.
type Drawn<'s> = (&'s str, Vec<(f64, f64)>, RGBColor);

/// The chart on the in-memory bitmap, in metres.
type MetricChart<'a, 'b> = ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// Renders the plot of [`plot_trajectories`] into PNG bytes.
pub fn render_trajectories_png(series: &[Series<'_>], title: &str) -> Result<Vec<u8>, PlotError> {
    ensure_font();
    let paths: Vec<Drawn<'_>> = series
        .iter()
        .map(|(l, p, c)| (*l, p.points(), RGBColor(c[0], c[1], c[2])))
        .collect();
    let (x0, x1, y0, y1) = padded_bounds_m(&paths)?;
    let mut buf = vec![255u8; (WIDTH * HEIGHT * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let build = |xr: (f64, f64), yr: (f64, f64)| {
            ChartBuilder::on(&root)
                .caption(title, (FONT_FAMILY, 24))
                .margin(20)
                .x_label_area_size(50)
                .y_label_area_size(70)
                .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        };
        // Equal aspect: widen the range of the axis with more metres per pixel's room.
        let (pw, ph) = {
            let chart = build((x0, x1), (y0, y1)).map_err(draw_err)?;
            chart.plotting_area().dim_in_pixel()
        };
        root.fill(&WHITE).map_err(draw_err)?;
        let (xr, yr) = equal_aspect_ranges_m((x0, x1, y0, y1), (pw, ph));
        let mut chart = build(xr, yr).map_err(draw_err)?;
        draw_chart(&mut chart, &paths)?;
        // Marker key under the title.
        root.draw(&Text::new(
            "start: circle, end: triangle",
            (20, HEIGHT as i32 - 25),
            (FONT_FAMILY, 14).into_font().color(&BLACK),
        ))
        .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    encode_png(buf)
}

/// The bounds `(x0, x1, y0, y1)` (m) of the finite points with a margin of 5 % (at least
/// 1 m); `Err` when no point is finite.
fn padded_bounds_m(paths: &[Drawn<'_>]) -> Result<(f64, f64, f64, f64), PlotError> {
    let all = paths.iter().flat_map(|(_, p, _)| p.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let mut any = false;
    for &(x, y) in all {
        if x.is_finite() && y.is_finite() {
            any = true;
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
    }
    if !any {
        return Err(PlotError::Empty);
    }
    let pad = (0.05 * (x1 - x0).max(y1 - y0)).max(1.0);
    Ok((x0 - pad, x1 + pad, y0 - pad, y1 + pad))
}

/// The x and y ranges (m) around the centre of `bounds_m` that give equal metres per pixel
/// on a plotting area of `(pw, ph)` pixels.
fn equal_aspect_ranges_m(
    bounds_m: (f64, f64, f64, f64),
    (pw, ph): (u32, u32),
) -> ((f64, f64), (f64, f64)) {
    let (x0, x1, y0, y1) = bounds_m;
    let m_per_px = ((x1 - x0) / f64::from(pw.max(1))).max((y1 - y0) / f64::from(ph.max(1)));
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let hw = 0.5 * m_per_px * f64::from(pw);
    let hh = 0.5 * m_per_px * f64::from(ph);
    ((cx - hw, cx + hw), (cy - hh, cy + hh))
}

/// The mesh, each path with its start and end markers, and the legend.
fn draw_chart<'a, 'b: 'a>(
    chart: &mut MetricChart<'a, 'b>,
    paths: &[Drawn<'_>],
) -> Result<(), PlotError> {
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .label_style((FONT_FAMILY, 16))
        .axis_desc_style((FONT_FAMILY, 18))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(draw_err)?;
    for (label, pts, color) in paths {
        if pts.is_empty() {
            continue;
        }
        let c = *color;
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))
            .map_err(draw_err)?
            .label(*label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3)));
        let start = pts[0];
        let end = pts[pts.len() - 1];
        chart
            .draw_series(std::iter::once(Circle::new(start, 7, c.filled())))
            .map_err(draw_err)?;
        chart
            .draw_series(std::iter::once(TriangleMarker::new(end, 9, c.filled())))
            .map_err(draw_err)?;
    }
    chart
        .configure_series_labels()
        .label_font((FONT_FAMILY, 16))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_err)?;
    Ok(())
}

/// The RGB pixel buffer as PNG bytes.
fn encode_png(buf: Vec<u8>) -> Result<Vec<u8>, PlotError> {
    let img = image::RgbImage::from_raw(WIDTH, HEIGHT, buf)
        .ok_or_else(|| PlotError::Draw("pixel buffer has the wrong size".to_string()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(draw_err)?;
    Ok(png)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_draws_paths_in_their_colours() {
        let circle: Vec<Pose2> = (0..200)
            .map(|i| {
                let t = i as f64 * 0.03;
                Pose2::new(10.0 * t.sin(), 10.0 * (1.0 - t.cos()), t)
            })
            .collect();
        let line: Vec<Pose2> = (0..50).map(|i| Pose2::new(i as f64, -5.0, 0.0)).collect();
        let png = render_trajectories_png(
            &[
                ("circle", PathRef::Poses(&circle), PALETTE[0]),
                ("line", PathRef::Poses(&line), PALETTE[1]),
            ],
            "test",
        )
        .unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (WIDTH, HEIGHT));
        let count = |c: [u8; 3]| img.pixels().filter(|p| p.0 == c).count();
        assert!(count(PALETTE[0]) > 200, "blue pixels {}", count(PALETTE[0]));
        assert!(count(PALETTE[1]) > 100, "red pixels {}", count(PALETTE[1]));
        // Text was drawn (the font is registered): dark pixels outside the series colours.
        assert!(img.pixels().filter(|p| p.0 == [0, 0, 0]).count() > 100);
        assert!(matches!(
            render_trajectories_png(&[("e", PathRef::Poses(&[]), PALETTE[0])], "t"),
            Err(PlotError::Empty)
        ));
    }
}
