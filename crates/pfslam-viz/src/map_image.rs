//! Map pictures: the occupancy map (occupied black, free white, unknown grey, the ESE650
//! convention) with optional trajectories (distinct colours, legend), the last scan and a scale
//! bar in metres; and the binary map (occupied black, everything else white).
//!
//! One pixel is one cell, north (world +y) up. Large maps are reduced by an integer factor
//! (a pixel is occupied if any of its cells is, else free if any is, else unknown); small maps
//! are enlarged by an integer factor so that legend and scale bar stay legible.

use super::{FONT_FAMILY, ensure_font};
use pfslam::files::{IoError, write_bytes_atomic};
use pfslam::geometry::Pose2;
use pfslam::map::{Cell, CellRect, CellState, OccupancyGrid, PlanarScan};
use plotters::prelude::*;
use rayon::prelude::*;
use std::path::Path;

/// Errors of drawing map pictures.
#[derive(Debug, thiserror::Error)]
pub enum MapImageError {
    /// Nothing to draw.
    #[error("the map is empty: nothing observed and no trajectory")]
    Empty,
    /// Plotters failed.
    #[error("drawing failed: {0}")]
    Draw(String),
    /// PNG encoding failed.
    #[error("PNG encoding failed: {0}")]
    Encode(String),
    /// Writing the file failed.
    #[error(transparent)]
    Io(#[from] IoError),
}

/// Grey of unknown cells.
pub const UNKNOWN_GREY: u8 = 128;

/// Colours given to trajectories in order (no green: the scan is green).
pub const TRAJECTORY_COLOURS: [RGBColor; 6] = [
    RGBColor(0, 90, 255),
    RGBColor(230, 20, 20),
    RGBColor(255, 140, 0),
    RGBColor(150, 40, 200),
    RGBColor(0, 190, 210),
    RGBColor(140, 80, 20),
];

/// Colour of the last scan's end points.
pub const SCAN_COLOUR: RGBColor = RGBColor(0, 170, 0);

/// A trajectory to draw over the map.
#[derive(Debug, Clone, Copy)]
pub struct TrajectoryOverlay<'a> {
    /// Legend text.
    pub label: &'a str,
    /// Poses in the map's world frame.
    pub poses: &'a [Pose2],
}

/// Options of [`render_map`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapImageOptions {
    /// Longest image side (px) before reduction.
    pub max_side_px: usize,
    /// Smaller maps are enlarged by an integer factor until their longest side reaches this (px).
    pub min_side_px: usize,
    /// Cells of margin around what is drawn.
    pub margin_cells: i32,
    /// Draw the scale bar.
    pub scale_bar: bool,
}

impl Default for MapImageOptions {
    fn default() -> Self {
        MapImageOptions {
            max_side_px: 4000,
            min_side_px: 600,
            margin_cells: 10,
            scale_bar: true,
        }
    }
}

/// An RGB picture and where it lies.
#[derive(Debug, Clone)]
pub struct MapPicture {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
    /// RGB bytes, top row first.
    pub rgb: Vec<u8>,
    /// The cells drawn.
    pub rect: CellRect,
    /// Pixels per cell (> 1 when enlarged, < 1 when reduced).
    pub px_per_cell: f64,
}

impl MapPicture {
    /// PNG bytes of the picture.
    pub fn to_png(&self) -> Result<Vec<u8>, MapImageError> {
        encode_png(
            self.width,
            self.height,
            &self.rgb,
            image::ExtendedColorType::Rgb8,
        )
    }
}

fn encode_png(
    w: u32,
    h: u32,
    bytes: &[u8],
    colour: image::ExtendedColorType,
) -> Result<Vec<u8>, MapImageError> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(bytes, w, h, colour)
        .map_err(|e| MapImageError::Encode(e.to_string()))?;
    Ok(out)
}

/// The cell rectangle to draw: observed cells and trajectory poses, plus a margin.
fn drawing_rect(
    grid: &OccupancyGrid,
    trajectories: &[TrajectoryOverlay],
    last_scan: Option<&PlanarScan>,
    margin: i32,
) -> Option<CellRect> {
    let mut r = grid.observed_bounds();
    let mut add = |x: f64, y: f64| {
        let c = CellRect::around(grid.cell_of(x, y));
        r = Some(r.map_or(c, |r| r.union(&c)));
    };
    for t in trajectories {
        for p in t.poses {
            add(p.x_m, p.y_m);
        }
    }
    if let Some(s) = last_scan {
        for p in &s.points {
            add(p.x_m, p.y_m);
        }
    }
    r.map(|r| r.expanded(margin))
}

/// Pixel layout: `down` cells per pixel side or `up` pixels per cell side.
#[derive(Clone, Copy)]
struct Layout {
    rect: CellRect,
    down: usize,
    up: usize,
    w: usize,
    h: usize,
}

impl Layout {
    fn new(rect: CellRect, opts: &MapImageOptions) -> Layout {
        let side = rect.width().max(rect.height());
        let down = side.div_ceil(opts.max_side_px.max(1)).max(1);
        let up = if down == 1 && side < opts.min_side_px {
            opts.min_side_px.div_ceil(side.max(1)).max(1)
        } else {
            1
        };
        let (w, h) = if down > 1 {
            (rect.width().div_ceil(down), rect.height().div_ceil(down))
        } else {
            (rect.width() * up, rect.height() * up)
        };
        Layout {
            rect,
            down,
            up,
            w,
            h,
        }
    }

    fn px_per_cell(&self) -> f64 {
        self.up as f64 / self.down as f64
    }

    /// Continuous pixel coordinates of a world point.
    fn pixel_of(&self, grid: &OccupancyGrid, x_m: f64, y_m: f64) -> (i32, i32) {
        let (ci, cj) = grid.limits().cell_coords(x_m, y_m);
        let s = self.px_per_cell();
        let px = (ci - self.rect.min_i as f64) * s;
        let py = (self.rect.max_j as f64 + 1.0 - cj) * s;
        (px.round() as i32, py.round() as i32)
    }

    /// The state of pixel row `py` (top = 0), column `px`.
    fn state(&self, grid: &OccupancyGrid, px: usize, py: usize) -> CellState {
        if self.down == 1 {
            let i = self.rect.min_i + (px / self.up) as i32;
            let j = self.rect.max_j - (py / self.up) as i32;
            return grid.state(Cell::new(i, j));
        }
        let mut any_free = false;
        for dj in 0..self.down as i32 {
            let j = self.rect.max_j - py as i32 * self.down as i32 - dj;
            if j < self.rect.min_j {
                break;
            }
            for di in 0..self.down as i32 {
                let i = self.rect.min_i + px as i32 * self.down as i32 + di;
                if i > self.rect.max_i {
                    break;
                }
                match grid.state(Cell::new(i, j)) {
                    CellState::Occupied => return CellState::Occupied,
                    CellState::Free => any_free = true,
                    CellState::Unknown => {}
                }
            }
        }
        if any_free {
            CellState::Free
        } else {
            CellState::Unknown
        }
    }
}

/// A "nice" scale-bar length (1, 2 or 5 times a power of ten metres) near `target_m`.
pub fn nice_length_m(target_m: f64) -> f64 {
    if !(target_m.is_finite() && target_m > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(target_m.log10().floor());
    let m = target_m / p;
    let k = if m < 2.0 {
        1.0
    } else if m < 5.0 {
        2.0
    } else {
        5.0
    };
    k * p
}

fn draw_err<E: std::fmt::Debug>(e: E) -> MapImageError {
    MapImageError::Draw(format!("{e:?}"))
}

/// Renders the map with overlays.
pub fn render_map(
    grid: &OccupancyGrid,
    trajectories: &[TrajectoryOverlay],
    last_scan: Option<&PlanarScan>,
    opts: &MapImageOptions,
) -> Result<MapPicture, MapImageError> {
    let rect = drawing_rect(grid, trajectories, last_scan, opts.margin_cells)
        .ok_or(MapImageError::Empty)?;
    let lay = Layout::new(rect, opts);
    let (w, h) = (lay.w, lay.h);
    let mut rgb = map_pixels(grid, &lay);
    ensure_font();
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w as u32, h as u32)).into_drawing_area();
        let thick = ((w.max(h) as f64 / 800.0).ceil() as u32).max(2);
        let pen = Pen {
            root: &root,
            grid,
            lay: &lay,
            thick,
            font_px: ((w.max(h) as f64 / 60.0).round() as u32).clamp(12, 48),
        };
        pen.trajectories(trajectories)?;
        if let Some(s) = last_scan {
            pen.scan(s)?;
        }
        let mut legend: Vec<(String, RGBColor)> = trajectories
            .iter()
            .enumerate()
            .map(|(k, t)| {
                (
                    t.label.to_string(),
                    TRAJECTORY_COLOURS[k % TRAJECTORY_COLOURS.len()],
                )
            })
            .collect();
        if last_scan.is_some() {
            legend.push(("last scan".to_string(), SCAN_COLOUR));
        }
        if !legend.is_empty() {
            pen.legend(&legend)?;
        }
        if opts.scale_bar {
            pen.scale_bar()?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(MapPicture {
        width: w as u32,
        height: h as u32,
        rgb,
        rect,
        px_per_cell: lay.px_per_cell(),
    })
}

/// The map's cells as RGB pixels (walls black, free white, unknown grey), rows in parallel.
fn map_pixels(grid: &OccupancyGrid, lay: &Layout) -> Vec<u8> {
    let w = lay.w;
    let mut rgb = vec![0u8; w * lay.h * 3];
    rgb.par_chunks_mut(w * 3).enumerate().for_each(|(py, row)| {
        for px in 0..w {
            let v = match lay.state(grid, px, py) {
                CellState::Occupied => 0,
                CellState::Free => 255,
                CellState::Unknown => UNKNOWN_GREY,
            };
            row[px * 3..px * 3 + 3].fill(v);
        }
    });
    rgb
}

/// What draws on a map picture: its drawing area, where cells land, the line width and
/// the font size (pixels).
struct Pen<'a, 'b> {
    root: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    grid: &'a OccupancyGrid,
    lay: &'a Layout,
    thick: u32,
    font_px: u32,
}

impl Pen<'_, '_> {
    fn font(&self) -> TextStyle<'static> {
        (FONT_FAMILY, self.font_px).into_font().color(&BLACK)
    }

    /// Each trajectory as a line in its colour.
    fn trajectories(&self, trajectories: &[TrajectoryOverlay]) -> Result<(), MapImageError> {
        for (k, t) in trajectories.iter().enumerate() {
            let colour = TRAJECTORY_COLOURS[k % TRAJECTORY_COLOURS.len()];
            let pts: Vec<(i32, i32)> = t
                .poses
                .iter()
                .map(|p| self.lay.pixel_of(self.grid, p.x_m, p.y_m))
                .collect();
            self.root
                .draw(&PathElement::new(pts, colour.stroke_width(self.thick)))
                .map_err(draw_err)?;
        }
        Ok(())
    }

    /// A scan's returns as squares and its sensor as a dot.
    fn scan(&self, s: &PlanarScan) -> Result<(), MapImageError> {
        let r = self.thick as i32;
        for p in s.points.iter().filter(|p| p.hit) {
            let (x, y) = self.lay.pixel_of(self.grid, p.x_m, p.y_m);
            self.root
                .draw(&Rectangle::new(
                    [(x - r / 2, y - r / 2), (x + r - r / 2, y + r - r / 2)],
                    SCAN_COLOUR.filled(),
                ))
                .map_err(draw_err)?;
        }
        let (x, y) = self.lay.pixel_of(self.grid, s.sensor_x_m, s.sensor_y_m);
        self.root
            .draw(&Circle::new((x, y), 2 * r, SCAN_COLOUR.filled()))
            .map_err(draw_err)?;
        Ok(())
    }

    /// A boxed legend in the top left corner: a line of each colour with its label.
    fn legend(&self, legend: &[(String, RGBColor)]) -> Result<(), MapImageError> {
        let fp = self.font_px as i32;
        let longest = legend
            .iter()
            .map(|l| l.0.chars().count())
            .max()
            .unwrap_or(0) as i32;
        let (x0, y0) = (fp / 2, fp / 2);
        let bw = 3 * fp + longest * fp * 6 / 10 + fp / 2;
        let bh = legend.len() as i32 * fp * 14 / 10 + fp / 2;
        let root = self.root;
        root.draw(&Rectangle::new(
            [(x0, y0), (x0 + bw, y0 + bh)],
            WHITE.mix(0.85).filled(),
        ))
        .map_err(draw_err)?;
        root.draw(&Rectangle::new([(x0, y0), (x0 + bw, y0 + bh)], BLACK))
            .map_err(draw_err)?;
        for (k, (label, colour)) in legend.iter().enumerate() {
            let y = y0 + fp / 2 + k as i32 * fp * 14 / 10 + fp / 2;
            root.draw(&PathElement::new(
                vec![(x0 + fp / 3, y), (x0 + 2 * fp, y)],
                colour.stroke_width(self.thick.max(3)),
            ))
            .map_err(draw_err)?;
            root.draw(&Text::new(
                label.clone(),
                (x0 + 2 * fp + fp / 3, y - fp / 2),
                self.font(),
            ))
            .map_err(draw_err)?;
        }
        Ok(())
    }

    /// A scale bar of a round length near a fifth of the width, bottom left.
    fn scale_bar(&self) -> Result<(), MapImageError> {
        let (w, h) = (self.lay.w, self.lay.h);
        let fp = self.font_px as i32;
        let m_per_px = self.grid.limits().resolution_m() / self.lay.px_per_cell();
        let len_m = nice_length_m(w as f64 * m_per_px / 5.0);
        let len_px = (len_m / m_per_px).round() as i32;
        let (x0, y1) = (fp, h as i32 - fp);
        let label = if len_m >= 1.0 {
            format!("{len_m} m")
        } else {
            format!("{} cm", (len_m * 100.0).round())
        };
        let root = self.root;
        root.draw(&Rectangle::new(
            [
                (x0 - fp / 3, y1 - 2 * fp),
                (x0 + len_px + fp / 3, y1 + fp / 3),
            ],
            WHITE.mix(0.85).filled(),
        ))
        .map_err(draw_err)?;
        root.draw(&Rectangle::new(
            [(x0, y1 - fp / 3), (x0 + len_px, y1)],
            BLACK.filled(),
        ))
        .map_err(draw_err)?;
        root.draw(&Text::new(
            label,
            (x0, y1 - fp / 3 - fp * 12 / 10),
            self.font(),
        ))
        .map_err(draw_err)?;
        Ok(())
    }
}

/// Renders and writes the map PNG atomically.
pub fn write_map_png(
    path: &Path,
    grid: &OccupancyGrid,
    trajectories: &[TrajectoryOverlay],
    last_scan: Option<&PlanarScan>,
    opts: &MapImageOptions,
) -> Result<MapPicture, MapImageError> {
    let pic = render_map(grid, trajectories, last_scan, opts)?;
    write_bytes_atomic(path, &pic.to_png()?)?;
    Ok(pic)
}

/// Writes the binary map of `rect` (default: observed cells) as an 8-bit grey PNG, one pixel
/// per cell, north up: occupied 0 (black), free and unknown 255 (white).
pub fn write_binary_png(
    path: &Path,
    grid: &OccupancyGrid,
    rect: Option<CellRect>,
) -> Result<(), MapImageError> {
    let rect = rect
        .or_else(|| grid.observed_bounds())
        .ok_or(MapImageError::Empty)?;
    let (w, h) = (rect.width(), rect.height());
    let mut px = vec![255u8; w * h];
    px.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
        let j = rect.max_j - row as i32;
        for (k, v) in out.iter_mut().enumerate() {
            if grid.is_occupied(Cell::new(rect.min_i + k as i32, j)) {
                *v = 0;
            }
        }
    });
    let png = encode_png(w as u32, h as u32, &px, image::ExtendedColorType::L8)?;
    write_bytes_atomic(path, &png)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pfslam::map::{InsertScratch, LogOddsParams, MapLimits, ScanPoint};

    fn room() -> (OccupancyGrid, PlanarScan) {
        let mut g =
            OccupancyGrid::with_params(MapLimits::new(0.1, 0.0, 0.0), LogOddsParams::ucsd());
        let points = (0..360)
            .map(|k| {
                let a = (k as f64).to_radians();
                ScanPoint {
                    x_m: 5.0 * a.cos(),
                    y_m: 5.0 * a.sin(),
                    hit: true,
                    free_to: 1.0,
                    z_m: 0.0,
                }
            })
            .collect();
        let s = PlanarScan {
            sensor_x_m: 0.0,
            sensor_y_m: 0.0,
            sensor_z_m: None,
            points,
        };
        g.insert_scan(&s, &mut InsertScratch::new()).unwrap();
        (g, s)
    }

    #[test]
    fn nice_lengths() {
        assert_eq!(nice_length_m(1.3), 1.0);
        assert_eq!(nice_length_m(3.0), 2.0);
        assert_eq!(nice_length_m(70.0), 50.0);
        assert!((nice_length_m(0.031) - 0.02).abs() < 1e-12);
    }

    #[test]
    fn colours_and_overlays() {
        let (g, s) = room();
        let traj = [Pose2::new(-2.0, 0.0, 0.0), Pose2::new(2.0, 0.0, 0.0)];
        let overlays = [TrajectoryOverlay {
            label: "ground truth",
            poses: &traj,
        }];
        let opts = MapImageOptions {
            scale_bar: true,
            ..MapImageOptions::default()
        };
        let pic = render_map(&g, &overlays, Some(&s), &opts).unwrap();
        // 101 cells + 2 x 10 margin = 121 cells, enlarged x5 to 605 px
        assert_eq!(pic.px_per_cell, 5.0);
        assert_eq!((pic.width, pic.height), (605, 605));
        let at = |x: u32, y: u32| {
            let k = (y * pic.width + x) as usize * 3;
            [pic.rgb[k], pic.rgb[k + 1], pic.rgb[k + 2]]
        };
        let px = |x_m: f64, y_m: f64| {
            let c = g.cell_of(x_m, y_m);
            (
                ((c.i - pic.rect.min_i) as f64 * 5.0 + 2.0) as u32,
                ((pic.rect.max_j - c.j) as f64 * 5.0 + 2.0) as u32,
            )
        };
        let (x, y) = px(0.0, 3.0); // inside the circle: free
        assert_eq!(at(x, y), [255, 255, 255]);
        let (x, y) = px(7.0, 7.0); // outside: unknown
        assert_eq!(at(x, y), [UNKNOWN_GREY; 3]);
        let (x, y) = px(-1.0, 0.0); // on the trajectory
        assert_eq!(at(x, y + 2), [0, 90, 255]);
        let (x, y) = px(0.0, 0.0);
        let c = at(x, y);
        assert!(c == [0, 90, 255] || c == [0, 170, 0], "{c:?}");
        // the last scan's points are green (drawn centred on their exact position)
        let (ci, cj) = g.limits().cell_coords(-5.0, 0.0);
        let x = ((ci - pic.rect.min_i as f64) * 5.0).round() as u32;
        let y = ((pic.rect.max_j as f64 + 1.0 - cj) * 5.0).round() as u32;
        assert_eq!(at(x, y), [0, 170, 0]);
        // legend box in the top-left corner is light, with some dark text pixels
        let dark = (0..200)
            .flat_map(|x| (0..60).map(move |y| (x, y)))
            .filter(|&(x, y)| at(x, y)[0] < 60 && at(x, y)[2] < 60)
            .count();
        assert!(dark > 20, "legend text drawn: {dark}");
        let png = pic.to_png().unwrap();
        let back = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(back.as_raw(), &pic.rgb);
    }

    #[test]
    fn reduction_keeps_walls_and_binary_png() {
        let (g, _) = room();
        let opts = MapImageOptions {
            max_side_px: 30,
            min_side_px: 1,
            margin_cells: 0,
            scale_bar: false,
        };
        let pic = render_map(&g, &[], None, &opts).unwrap();
        assert_eq!((pic.width, pic.height), (26, 26)); // 101 cells / 4
        let black = pic.rgb.chunks(3).filter(|p| p[0] == 0).count();
        assert!(black > 40, "{black}");
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("binary.png");
        write_binary_png(&p, &g, None).unwrap();
        let img = image::open(&p).unwrap().to_luma8();
        assert_eq!(img.dimensions(), (101, 101));
        // cell (50, 0) at the right of the circle is occupied: column 100, row 50
        assert_eq!(img.get_pixel(100, 50)[0], 0);
        assert_eq!(img.get_pixel(50, 50)[0], 255);
        let empty = OccupancyGrid::with_params(MapLimits::default(), LogOddsParams::ucsd());
        assert!(matches!(
            render_map(&empty, &[], None, &opts),
            Err(MapImageError::Empty)
        ));
    }
}
