//! Ray tracing into the scratch mask: the sensor's cell, the planar rays and the rays with
//! height bins, and the places a scan's tracing may be cut.

use super::*;
use crate::kernels::mask::walk_mask;

/// The rays of one scan (or one piece of it) to trace, and where the scratch mask lies.
#[derive(Clone, Copy)]
struct ScanRays<'a> {
    /// The scan in the world frame (sensor position and height).
    world_scan: &'a PlanarScan,
    /// The rays traced: all of `world_scan`'s points or a run of them.
    points: &'a [ScanPoint],
    /// The sensor's cell.
    origin: Cell,
    /// The cell `(i, j)` at the mask's first corner (a multiple of the tile size).
    mask_first_cell: (i32, i32),
}

impl OccupancyGrid {
    /// Traces a scan's rays into the scratch mask (`mask`, or `hmask` for a scan with heights
    /// on a grid with height bins) and lists the touched cells; the grid is not changed.
    pub(super) fn trace_scan(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        scratch: &mut InsertScratch,
    ) -> Result<Traced, MapError> {
        let origin = self.scan_origin(world_scan, points, scratch)?;
        let sh = scratch.half;
        // Tile coordinates of the mask's first tile, and its first cell.
        let (t0i, t0j) = ((origin.i - sh) >> TILE_SHIFT, (origin.j - sh) >> TILE_SHIFT);
        let (mi0, mj0) = (t0i << TILE_SHIFT, t0j << TILE_SHIFT);
        let rays = ScanRays {
            world_scan,
            points,
            origin,
            mask_first_cell: (mi0, mj0),
        };
        let len = match (world_scan.sensor_z_m, self.height.as_ref()) {
            (Some(z), Some(layer)) => self.trace_heights(&rays, z, layer, scratch),
            _ => self.trace_planar(&rays, scratch),
        };
        Ok(Traced {
            t0i,
            t0j,
            len,
            heights: world_scan.sensor_z_m.is_some() && self.height.is_some(),
        })
    }

    /// [`Self::trace_scan`] for a scan without heights: one mark per cell.
    fn trace_planar(&self, rays: &ScanRays<'_>, scratch: &mut InsertScratch) -> usize {
        let (mi0, mj0) = rays.mask_first_cell;
        let InsertScratch {
            mask,
            touched,
            xoff,
            yoff,
            walk,
            ..
        } = scratch;
        let layout = MaskLayout {
            xoff,
            yoff,
            mi0,
            mj0,
        };
        let mut marks = TouchMarks {
            mask,
            touched,
            len: 0,
        };
        self.trace_planar_marks(
            rays.world_scan,
            rays.points,
            rays.origin,
            &layout,
            walk,
            &mut marks,
        );
        marks.len
    }

    /// [`Self::trace_planar`]'s rays into `marks`, one after the other (ray by ray, see
    /// `docs/decisions/0016-joining-returns-in-maps.md`).
    #[inline(always)]
    pub(super) fn trace_planar_marks<M: Marks>(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        origin: Cell,
        layout: &MaskLayout<'_>,
        walk: &mut RayCells,
        marks: &mut M,
    ) {
        // Another scan, or another piece of one: no ray of it marked yet.
        walk.forget();
        let rays = PlanarRays {
            limits: &self.limits,
            world_scan,
            free_margin_cells: self.free_margin_cells,
            origin,
            layout,
        };
        for p in points {
            trace_planar_ray(&rays, p, walk, marks);
        }
    }

    /// Where the tracing of `world_scan` may be cut into pieces
    /// ([`Self::trace_updates_part`]) that insert as the whole scan, with the work before
    /// each place, into `out` (cleared first): `(ray, work)` in ray order, from `(0, 0)` to
    /// `(points, total)`. Every ray is such a place. Work: cells walked per ray (Chebyshev
    /// length plus its end cell).
    pub fn trace_cuts(&self, world_scan: &PlanarScan, out: &mut Vec<(usize, u64)>) {
        out.clear();
        let points = &world_scan.points;
        let o = self.cell_of(world_scan.sensor_x_m, world_scan.sensor_y_m);
        let mut work = 0u64;
        for (i, p) in points.iter().enumerate() {
            out.push((i, work));
            let c = self.cell_of(p.x_m, p.y_m);
            work += u64::from((c.i - o.i).unsigned_abs().max((c.j - o.j).unsigned_abs())) + 1;
        }
        out.push((points.len(), work));
    }

    /// Checks a scan's cells and sizes the scratch mask for its longest ray; returns the
    /// sensor's cell.
    fn scan_origin(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        scratch: &mut InsertScratch,
    ) -> Result<Cell, MapError> {
        let origin = self.cell_of(world_scan.sensor_x_m, world_scan.sensor_y_m);
        Self::check_cell(origin)?;
        // Mask half-size: the farthest end cell (Chebyshev), so every ray fits.
        let mut half = 0i32;
        for p in points {
            let c = self.cell_of(p.x_m, p.y_m);
            Self::check_cell(c)?;
            half = half.max((c.i - origin.i).abs()).max((c.j - origin.j).abs());
        }
        if half > MAX_RAY_CELLS {
            return Err(MapError::RayTooLong {
                cells: half,
                max: MAX_RAY_CELLS,
            });
        }
        scratch.ensure_half(half);
        Ok(origin)
    }

    /// [`Self::trace_scan`] for a scan with heights on a grid with height bins: the same
    /// cells, rules and margins, but per (cell, height bin). A ray is the 3-D segment from the
    /// sensor (`sensor_z_m`) to its end point (`z_m`); the cell `k` steps along its digital
    /// line (of `n` to the end cell) is passed at the height `k / n` of the way, the end cell
    /// hit at the return's height. Per scan each bin of a cell gets at most one update,
    /// occupied winning; applying re-projects the cell's 2-D log-odds ([`project_bins`]).
    fn trace_heights(
        &self,
        rays: &ScanRays<'_>,
        sensor_z_m: f64,
        layer: &HeightLayer,
        scratch: &mut InsertScratch,
    ) -> usize {
        let ScanRays {
            world_scan,
            points,
            origin,
            mask_first_cell: (mi0, mj0),
        } = *rays;
        let InsertScratch {
            hmask,
            touched,
            mask,
            bits,
            cells,
            xoff,
            yoff,
            ..
        } = scratch;
        let layout = MaskLayout {
            xoff,
            yoff,
            mi0,
            mj0,
        };
        let flat = |c: Cell| layout.index(c);
        if hmask.len() != mask.len() {
            // Zeroed: a previous insertion left it clear, a new one is clear.
            *hmask = vec![0; mask.len()];
        }
        let mut len = 0usize;
        let mark = |hmask: &mut [u32], touched: &mut [u32], len: &mut usize, k: usize, m: u32| {
            let old = hmask[k];
            hmask[k] = old | m;
            touched[*len] = k as u32;
            *len += usize::from(old == 0);
        };
        let limits = self.limits;
        let z0 = sensor_z_m as f32;
        let margin_cells = self.free_margin_cells;
        for p in points {
            let (end, clear_end, partial) = ray_cells(&limits, world_scan, p);
            let margin = if p.hit { margin_cells } else { 0 };
            let n_full = (end.i - origin.i).abs().max((end.j - origin.j).abs());
            // Height gained per step of the full ray's digital line.
            let dz = if n_full > 0 {
                (p.z_m - z0) / n_full as f32
            } else {
                0.0
            };
            let n = (clear_end.i - origin.i)
                .abs()
                .max((clear_end.j - origin.j).abs());
            if touched.len() < len + n as usize + 2 {
                touched.resize(len + n as usize + 2 + 4096, 0);
            }
            // Steps along the clearing line stand for the same distance as along the full
            // ray's (both are the major-axis distance to the sensor's cell, up to rounding).
            if partial && margin > 0 {
                let mut step = 0i32;
                bresenham(origin, clear_end, |c| {
                    let z = z0 + step as f32 * dz;
                    step += 1;
                    if (c.i - end.i).abs().max((c.j - end.j).abs()) <= margin || c == clear_end {
                        return;
                    }
                    mark(hmask, touched, &mut len, flat(c), layer.bit(z));
                });
            } else {
                let count = if partial { n } else { (n - margin).max(0) } as usize;
                if bits.len() < count {
                    bits.resize(count + 1024, 0);
                }
                if cells.len() < count {
                    cells.resize(count + 1024, 0);
                }
                let (bits, cells) = (&mut bits[..count], &mut cells[..count]);
                layer.fill_bits(z0, dz, bits);
                walk_mask(origin, clear_end, &layout, cells);
                len = mark_cells(hmask, touched, len, cells, bits.iter().copied());
            }
            let bit = layer.bit(p.z_m);
            let want = if p.hit { bit << 16 } else { bit };
            mark(hmask, touched, &mut len, flat(end), want);
        }
        len
    }
}

/// What every ray of one planar scan is traced with: the grid's limits and free margin, the
/// scan, the sensor's cell and the mask the marks go to.
struct PlanarRays<'a, 'm> {
    limits: &'a MapLimits,
    world_scan: &'a PlanarScan,
    free_margin_cells: i32,
    /// The sensor's cell.
    origin: Cell,
    layout: &'a MaskLayout<'m>,
}

/// Traces one ray of a planar scan (its free cells as [`ray_cells`] and the free margin
/// say, then its end cell).
#[inline(always)]
fn trace_planar_ray<M: Marks>(
    rays: &PlanarRays<'_, '_>,
    p: &ScanPoint,
    walk: &mut RayCells,
    marks: &mut M,
) {
    let PlanarRays {
        limits,
        world_scan,
        free_margin_cells,
        origin,
        layout,
    } = *rays;
    let (end, clear_end, partial) = ray_cells(limits, world_scan, p);
    let margin = if p.hit { free_margin_cells } else { 0 };
    let n = (clear_end.i - origin.i)
        .abs()
        .max((clear_end.j - origin.j).abs());
    // Room for every cell of this ray and its end cell.
    marks.reserve(n as usize + 2);
    if partial && margin > 0 {
        // Rare (a free margin and a climbing beam): the per-cell rule as written.
        bresenham(origin, clear_end, |c| {
            if (c.i - end.i).abs().max((c.j - end.j).abs()) <= margin || c == clear_end {
                return;
            }
            marks.mark(layout.index(c), false);
        });
        walk.forget();
    } else {
        // Along a digital line the Chebyshev distance to its last cell drops by one per
        // cell, so the cells the rule skips are the last ones: within `margin` of `end`
        // (full ray), or the last one (partial ray: `clear_end`; `end` lies beyond it,
        // hence not on the line).
        let count = if partial { n } else { (n - margin).max(0) } as usize;
        marks.mark_free(walk.walk_fresh(origin, clear_end, layout, count));
    }
    marks.mark(layout.index(end), p.hit);
}
