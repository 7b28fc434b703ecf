//! Block matching on census-transformed rectified images: Hamming cost aggregated over a square
//! window, winner-take-all with a uniqueness test, left-right consistency and parabolic
//! sub-pixel refinement.
//!
//! Costs are exact integers and every row is computed from the same sums whatever the split,
//! so the result does not depend on the number of threads. Rows are split into a fixed number
//! of chunks processed in parallel; each chunk slides a column-sum of the costs down its rows.

use super::StereoError;
use super::image::GrayImage;
use rayon::prelude::*;

pub use pfslam::config::stereo::{Aggregation, MatcherOptions};

/// The value of a pixel without a valid disparity.
pub const INVALID_DISPARITY: f32 = -1.0;

/// Census window half-size (7x7 window, 48 comparison bits).
const CENSUS_RADIUS: isize = 3;

/// Number of row chunks processed in parallel (fixed so the result never depends on threads).
const CHUNKS: usize = 16;

/// A disparity image (px), row-major; [`INVALID_DISPARITY`] where no match was accepted.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DisparityMap {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// Left-image disparities (px).
    pub data: Vec<f32>,
}

impl DisparityMap {
    /// The disparity at `(x, y)`, `None` when invalid.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> Option<f32> {
        let d = self.data[y * self.width + x];
        (d >= 0.0).then_some(d)
    }

    /// Fraction of valid pixels.
    pub fn valid_fraction(&self) -> f64 {
        if self.data.is_empty() {
            return 0.0;
        }
        self.data.iter().filter(|d| **d >= 0.0).count() as f64 / self.data.len() as f64
    }
}

#[derive(Debug, Clone, Default)]
struct ChunkScratch {
    /// Costs of the `2 r + 1` rows in the window, a ring indexed by row modulo its length.
    ring: Vec<u8>,
    colsum: Vec<u16>,
    agg: Vec<u16>,
    right_best: Vec<u16>,
    right_cost: Vec<u16>,
    sgm: SgmScratch,
}

/// Path costs of SGM: the previous and current rows of the three downward paths, the
/// horizontal paths of the current row, and the sum.
#[derive(Debug, Clone, Default)]
struct SgmScratch {
    prev: [Vec<u16>; 3],
    prev_min: [Vec<u16>; 3],
    cur: [Vec<u16>; 3],
    cur_min: [Vec<u16>; 3],
    horiz: Vec<u16>,
    sum: Vec<u16>,
}

/// Caller-owned buffers of the matcher; reuse across pairs of the same size.
#[derive(Debug, Clone, Default)]
pub struct DisparityWorkspace {
    census_left: Vec<u64>,
    census_right: Vec<u64>,
    chunks: Vec<ChunkScratch>,
}

impl DisparityWorkspace {
    /// An empty workspace; buffers grow on first use.
    pub fn new() -> Self {
        DisparityWorkspace::default()
    }
}

/// 7x7 census transform (bit set where the neighbour is darker than the centre); borders use
/// clamped coordinates.
pub fn census_into(img: &GrayImage, out: &mut Vec<u64>) {
    let (w, h) = (img.width, img.height);
    out.clear();
    out.resize(w * h, 0);
    if w == 0 {
        return;
    }
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let c = img.data[y * w + x];
            let mut bits = 0u64;
            let interior = x as isize >= CENSUS_RADIUS
                && y as isize >= CENSUS_RADIUS
                && x + (CENSUS_RADIUS as usize) < w
                && y + (CENSUS_RADIUS as usize) < h;
            for dy in -CENSUS_RADIUS..=CENSUS_RADIUS {
                for dx in -CENSUS_RADIUS..=CENSUS_RADIUS {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    let (xx, yy) = if interior {
                        ((x as isize + dx) as usize, (y as isize + dy) as usize)
                    } else {
                        (
                            (x as isize + dx).clamp(0, w as isize - 1) as usize,
                            (y as isize + dy).clamp(0, h as isize - 1) as usize,
                        )
                    };
                    bits = (bits << 1) | u64::from(img.data[yy * w + xx] < c);
                }
            }
            *o = bits;
        }
    });
}

/// Computes the left image's disparity into `out` (reshaped as needed).
pub fn compute_disparity(
    left: &GrayImage,
    right: &GrayImage,
    opts: &MatcherOptions,
    ws: &mut DisparityWorkspace,
    out: &mut DisparityMap,
) -> Result<(), StereoError> {
    if left.width != right.width || left.height != right.height {
        return Err(StereoError::Size(format!(
            "left {}x{} and right {}x{} differ",
            left.width, left.height, right.width, right.height
        )));
    }
    let (w, h) = (left.width, left.height);
    opts.validate(w)?;
    if h == 0 {
        return Err(StereoError::Size("empty image".into()));
    }
    census_into(left, &mut ws.census_left);
    census_into(right, &mut ws.census_right);
    let nd = opts.num_disparities;
    ws.chunks.resize_with(CHUNKS, ChunkScratch::default);
    let ring_len = (2 * opts.window_radius + 1) * w * nd;
    for c in &mut ws.chunks {
        c.ring.clear();
        c.ring.resize(ring_len, 0);
        c.colsum.resize(w * nd, 0);
        c.agg.resize(w * nd, 0);
        c.right_best.resize(w, 0);
        c.right_cost.resize(w, 0);
    }
    out.width = w;
    out.height = h;
    out.data.clear();
    out.data.resize(w * h, INVALID_DISPARITY);
    // SGM's downward paths make rows depend on the rows above: one sequential chunk.
    let rows_per_chunk = match opts.aggregation {
        Aggregation::Block => h.div_ceil(CHUNKS),
        Aggregation::Sgm => h,
    };
    if opts.aggregation == Aggregation::Sgm {
        let g = &mut ws.chunks[0].sgm;
        for k in 0..3 {
            for v in [&mut g.prev[k], &mut g.cur[k]] {
                v.clear();
                v.resize(w * nd, 0);
            }
            for v in [&mut g.prev_min[k], &mut g.cur_min[k]] {
                v.clear();
                v.resize(w, 0);
            }
        }
        g.horiz.clear();
        g.horiz.resize(w * nd, 0);
        g.sum.clear();
        g.sum.resize(w * nd, 0);
    }
    let census = CensusPair {
        left: &ws.census_left,
        right: &ws.census_right,
        width_px: w,
        height_px: h,
    };
    out.data
        .par_chunks_mut(rows_per_chunk * w)
        .zip(ws.chunks.par_iter_mut())
        .enumerate()
        .for_each(|(k, (rows, scratch))| {
            let y0 = k * rows_per_chunk;
            let y1 = (y0 + rows_per_chunk).min(h);
            match_rows(&census, y0, y1, opts, scratch, rows);
        });
    Ok(())
}

/// Replaces the costs stored in `slot` by those of the row `(cl, cr)` and updates the column
/// sums by the difference. Entries with `d > x` stay zero in every slot.
#[inline]
fn replace_row(colsum: &mut [u16], slot: &mut [u8], cl: &[u64], cr: &[u64], nd: usize) {
    for (x, &l) in cl.iter().enumerate() {
        let dmax = x.min(nd - 1);
        let cs = &mut colsum[x * nd..x * nd + dmax + 1];
        let sl = &mut slot[x * nd..x * nd + dmax + 1];
        let rs = &cr[x - dmax..=x];
        // Element d pairs with cr[x - d] = rs[dmax - d].
        for ((c, s), r) in cs.iter_mut().zip(sl.iter_mut()).zip(rs.iter().rev()) {
            let new = (l ^ r).count_ones() as u8;
            *c = c.wrapping_add(new as u16).wrapping_sub(*s as u16);
            *s = new;
        }
    }
}

/// The census transforms of a rectified pair, row-major.
#[derive(Clone, Copy)]
struct CensusPair<'a> {
    left: &'a [u64],
    right: &'a [u64],
    width_px: usize,
    height_px: usize,
}

/// Matches rows `y0..y1` of `census` into `out_rows` (the disparities of those rows).
fn match_rows(
    census: &CensusPair<'_>,
    y0: usize,
    y1: usize,
    opts: &MatcherOptions,
    s: &mut ChunkScratch,
    out_rows: &mut [f32],
) {
    let CensusPair {
        left: cl,
        right: cr,
        width_px: w,
        height_px: h,
    } = *census;
    let nd = opts.num_disparities;
    let r = opts.window_radius;
    let row_at = |y: isize| -> usize { y.clamp(0, h as isize - 1) as usize };
    let slot_len = w * nd;
    let ring_rows = 2 * r + 1;
    s.colsum.fill(0);
    s.ring.fill(0);
    for k in 0..ring_rows {
        let yy = row_at(y0 as isize - r as isize + k as isize);
        replace_row(
            &mut s.colsum,
            &mut s.ring[k * slot_len..(k + 1) * slot_len],
            &cl[yy * w..(yy + 1) * w],
            &cr[yy * w..(yy + 1) * w],
            nd,
        );
    }
    for y in y0..y1 {
        if y > y0 {
            // The oldest row (y - r - 1) sits in slot (y - y0 - 1) mod (2 r + 1).
            let k = (y - y0 - 1) % ring_rows;
            let ya = row_at(y as isize + r as isize);
            replace_row(
                &mut s.colsum,
                &mut s.ring[k * slot_len..(k + 1) * slot_len],
                &cl[ya * w..(ya + 1) * w],
                &cr[ya * w..(ya + 1) * w],
                nd,
            );
        }
        // Horizontal box sums for x in r .. w - r.
        {
            let (colsum, agg) = (&s.colsum, &mut s.agg);
            let first = &mut agg[r * nd..(r + 1) * nd];
            first.fill(0);
            for xx in 0..=2 * r {
                for (a, c) in first.iter_mut().zip(&colsum[xx * nd..(xx + 1) * nd]) {
                    *a = a.wrapping_add(*c);
                }
            }
            for x in r + 1..w - r {
                let (prev, cur) = agg[(x - 1) * nd..(x + 1) * nd].split_at_mut(nd);
                let add = &colsum[(x + r) * nd..(x + r + 1) * nd];
                let sub = &colsum[(x - r - 1) * nd..(x - r) * nd];
                for d in 0..nd {
                    cur[d] = prev[d].wrapping_add(add[d]).wrapping_sub(sub[d]);
                }
            }
        }
        let out = &mut out_rows[(y - y0) * w..(y - y0 + 1) * w];
        match opts.aggregation {
            Aggregation::Block => {
                select_row(&s.agg, &mut s.right_best, &mut s.right_cost, w, opts, out)
            }
            Aggregation::Sgm => {
                sgm_row(&s.agg, &mut s.sgm, w, y == y0, opts);
                select_row(
                    &s.sgm.sum,
                    &mut s.right_best,
                    &mut s.right_cost,
                    w,
                    opts,
                    out,
                );
            }
        }
    }
}

/// Cost of a disparity the window cannot evaluate (the largest census cost of the window).
#[inline]
fn invalid_cost(r: usize) -> u16 {
    (48 * (2 * r + 1) * (2 * r + 1)) as u16
}

/// One SGM step along a path: `out[d] = c[d] + min(prev[d], prev[d +- 1] + p1, prev_min +
/// p2) - prev_min`; returns `min(out)`.
#[inline]
fn path_step(c: &[u16], prev: &[u16], prev_min: u16, p1: u16, p2: u16, out: &mut [u16]) -> u16 {
    let nd = c.len();
    let jump = prev_min + p2;
    let mut m_out = u16::MAX;
    for d in 0..nd {
        let mut m = prev[d].min(jump);
        if d > 0 {
            m = m.min(prev[d - 1] + p1);
        }
        if d + 1 < nd {
            m = m.min(prev[d + 1] + p1);
        }
        let v = c[d] + m - prev_min;
        out[d] = v;
        m_out = m_out.min(v);
    }
    m_out
}

/// Adds the five path costs of one row into `g.sum` from the window costs `agg` (valid for
/// `r <= x < w - r`, `d <= x - r`; the rest counts as [`invalid_cost`]).
fn sgm_row(agg: &[u16], g: &mut SgmScratch, w: usize, first_row: bool, opts: &MatcherOptions) {
    let nd = opts.num_disparities;
    let r = opts.window_radius;
    let (p1, p2) = (opts.sgm_p1, opts.sgm_p2);
    let bad = invalid_cost(r);
    let mut c = vec![bad; nd];
    let cost_at = |x: usize, c: &mut [u16]| {
        c.fill(bad);
        if x >= r && x + r < w {
            let dmax = (nd - 1).min(x - r);
            c[..=dmax].copy_from_slice(&agg[x * nd..x * nd + dmax + 1]);
        }
    };
    // Downward paths: 0 from above, 1 from above-left, 2 from above-right.
    for x in 0..w {
        cost_at(x, &mut c);
        for k in 0..3 {
            let px = match k {
                0 => Some(x),
                1 => x.checked_sub(1),
                _ => (x + 1 < w).then_some(x + 1),
            };
            let out = &mut g.cur[k][x * nd..(x + 1) * nd];
            g.cur_min[k][x] = match px {
                Some(px) if !first_row => path_step(
                    &c,
                    &g.prev[k][px * nd..(px + 1) * nd],
                    g.prev_min[k][px],
                    p1,
                    p2,
                    out,
                ),
                _ => {
                    out.copy_from_slice(&c);
                    c.iter().copied().min().unwrap_or(0)
                }
            };
        }
        let sum = &mut g.sum[x * nd..(x + 1) * nd];
        let (a, b, c2) = (
            &g.cur[0][x * nd..(x + 1) * nd],
            &g.cur[1][x * nd..(x + 1) * nd],
            &g.cur[2][x * nd..(x + 1) * nd],
        );
        for (((s, a), b), c) in sum.iter_mut().zip(a).zip(b).zip(c2) {
            *s = a + b + c;
        }
    }
    for k in 0..3 {
        std::mem::swap(&mut g.prev[k], &mut g.cur[k]);
        std::mem::swap(&mut g.prev_min[k], &mut g.cur_min[k]);
    }
    // Horizontal paths, left to right then right to left.
    let mut prev = vec![0u16; nd];
    for pass in 0..2 {
        let mut prev_min = 0u16;
        for step in 0..w {
            let x = if pass == 0 { step } else { w - 1 - step };
            cost_at(x, &mut c);
            let out = &mut g.horiz[x * nd..(x + 1) * nd];
            prev_min = if step == 0 {
                out.copy_from_slice(&c);
                c.iter().copied().min().unwrap_or(0)
            } else {
                path_step(&c, &prev, prev_min, p1, p2, out)
            };
            prev.copy_from_slice(out);
            let sum = &mut g.sum[x * nd..(x + 1) * nd];
            for (s, h) in sum.iter_mut().zip(out.iter()) {
                *s += *h;
            }
        }
    }
}

/// Winner-take-all with uniqueness, left-right check and sub-pixel refinement on one row of
/// costs (`costs[x * nd + d]`, valid for `r <= x < w - r`, `d <= x - r`).
fn select_row(
    costs_row: &[u16],
    right_best: &mut [u16],
    right_cost: &mut [u16],
    w: usize,
    opts: &MatcherOptions,
    out: &mut [f32],
) {
    let nd = opts.num_disparities;
    let r = opts.window_radius;
    let uniq = 1.0 + opts.uniqueness_ratio;
    // Best disparity of each right pixel (for the left-right check): cost (x, d) belongs to
    // right pixel x - d. Visiting x in increasing order visits each right pixel's disparities
    // in increasing order, so the strict `<` keeps the smallest of equal costs.
    right_best.fill(u16::MAX);
    right_cost.fill(u16::MAX);
    for x in r..w - r {
        let dmax = (nd - 1).min(x - r);
        let costs = &costs_row[x * nd..x * nd + dmax + 1];
        let rc = &mut right_cost[x - dmax..=x];
        let rb = &mut right_best[x - dmax..=x];
        // Element k is right pixel x - dmax + k, i.e. disparity dmax - k; branch-free selects.
        for (k, (bc, bd)) in rc.iter_mut().zip(rb.iter_mut()).enumerate() {
            let d = dmax - k;
            let c = costs[d];
            let better = c < *bc;
            *bc = if better { c } else { *bc };
            *bd = if better { d as u16 } else { *bd };
        }
    }
    for (x, out_x) in out.iter_mut().enumerate().take(w - r).skip(r) {
        let dmax = (nd - 1).min(x - r);
        let costs = &costs_row[x * nd..x * nd + dmax + 1];
        // Two passes (minimum, then its first position) vectorise better than one.
        let best = costs.iter().copied().min().unwrap_or(u16::MAX);
        let d1 = costs.iter().position(|&c| c == best).unwrap_or(0);
        if opts.uniqueness_ratio > 0.0 {
            let below = costs[..d1.saturating_sub(1)].iter().copied().min();
            let above = costs.get(d1 + 2..).and_then(|c| c.iter().copied().min());
            let second = below.into_iter().chain(above).min().unwrap_or(u16::MAX);
            if (second as f32) < best as f32 * uniq {
                continue;
            }
        }
        let rb = right_best[x - d1];
        if rb == u16::MAX || (rb as usize).abs_diff(d1) > opts.lr_max_diff_px as usize {
            continue;
        }
        let mut d = d1 as f32;
        if d1 > 0 && d1 < dmax {
            let cm = costs[d1 - 1] as f32;
            let cp = costs[d1 + 1] as f32;
            let denom = cm + cp - 2.0 * best as f32;
            if denom > 0.0 {
                d += ((cm - cp) / (2.0 * denom)).clamp(-0.5, 0.5);
            }
        }
        *out_x = d;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` xorshift random bytes.
    fn random_bytes(n: usize, seed: u64) -> Vec<u8> {
        let mut state = seed;
        (0..n)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 56) as u8
            })
            .collect()
    }

    /// A random-dot pair: the right image is the left shifted by `shift(y)` px.
    fn shifted_pair(w: usize, h: usize, shift: impl Fn(usize) -> usize) -> (GrayImage, GrayImage) {
        let big_w = w + 200;
        let tex = random_bytes(big_w * h, 0x1234_5678_9abc_def0);
        let mut l = GrayImage::new(w, h);
        let mut r = GrayImage::new(w, h);
        for y in 0..h {
            let s = shift(y);
            for x in 0..w {
                l.data[y * w + x] = tex[y * big_w + x + 100];
                r.data[y * w + x] = tex[y * big_w + x + 100 + s];
            }
        }
        (l, r)
    }

    #[test]
    fn recovers_known_integer_shifts() {
        let (w, h) = (200, 64);
        let shift = |y: usize| 5 + y / 8;
        let (l, r) = shifted_pair(w, h, shift);
        let opts = MatcherOptions {
            num_disparities: 32,
            window_radius: 3,
            ..MatcherOptions::default()
        };
        let mut ws = DisparityWorkspace::new();
        let mut out = DisparityMap::default();
        compute_disparity(&l, &r, &opts, &mut ws, &mut out).unwrap();
        let mut checked = 0;
        for y in 4..h - 4 {
            // Rows whose window straddles two shifts are ambiguous.
            if y % 8 != 4 {
                continue;
            }
            for x in 40..w - 10 {
                let d = out.get(x, y).expect("valid");
                assert!(
                    (d - shift(y) as f32).abs() < 0.5,
                    "({x},{y}): {d} vs {}",
                    shift(y)
                );
                checked += 1;
            }
        }
        assert!(checked > 1000);
    }

    #[test]
    fn result_does_not_depend_on_threads() {
        let (l, r) = shifted_pair(300, 90, |y| 3 + y / 10);
        let opts = MatcherOptions {
            num_disparities: 24,
            ..MatcherOptions::default()
        };
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut ws = DisparityWorkspace::new();
                let mut out = DisparityMap::default();
                compute_disparity(&l, &r, &opts, &mut ws, &mut out).unwrap();
                out
            })
        };
        let one = run(1);
        assert!(one.valid_fraction() > 0.5);
        assert_eq!(one, run(3));
    }

    #[test]
    fn rejects_bad_options_and_sizes() {
        let (l, r) = shifted_pair(64, 16, |_| 2);
        let mut ws = DisparityWorkspace::new();
        let mut out = DisparityMap::default();
        let bad = MatcherOptions {
            window_radius: 0,
            ..MatcherOptions::default()
        };
        assert!(compute_disparity(&l, &r, &bad, &mut ws, &mut out).is_err());
        let small = GrayImage::new(32, 16);
        let opts = MatcherOptions::default();
        assert!(compute_disparity(&l, &small, &opts, &mut ws, &mut out).is_err());
    }

    #[test]
    fn sgm_recovers_a_slanted_surface_and_is_deterministic() {
        // Disparity 6 + x / 40: a surface slanted in depth, smooth for SGM's penalties.
        let (w, h) = (240, 48);
        let big_w = w + 64;
        let tex = random_bytes(big_w * h, 0x9e37_79b9_7f4a_7c15);
        let truth = |x: usize| 6 + x / 40;
        let mut l = GrayImage::new(w, h);
        let mut r = GrayImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                l.data[y * w + x] = tex[y * big_w + x + 32];
            }
        }
        // Right pixel xr shows the left pixel x with x - truth(x) = xr.
        for y in 0..h {
            for x in 0..w {
                let xr = x - truth(x).min(x);
                r.data[y * w + xr] = l.data[y * w + x];
            }
        }
        let opts = MatcherOptions {
            num_disparities: 16,
            window_radius: 2,
            aggregation: Aggregation::Sgm,
            ..MatcherOptions::default()
        };
        let mut ws = DisparityWorkspace::new();
        let mut out = DisparityMap::default();
        compute_disparity(&l, &r, &opts, &mut ws, &mut out).unwrap();
        let (mut good, mut valid) = (0, 0);
        for y in 4..h - 4 {
            for x in 30..w - 10 {
                if let Some(d) = out.get(x, y) {
                    valid += 1;
                    if (d - truth(x) as f32).abs() <= 1.0 {
                        good += 1;
                    }
                }
            }
        }
        let total = (h - 8) * (w - 40);
        assert!(valid as f64 > 0.8 * total as f64, "{valid} of {total}");
        assert!(good as f64 > 0.97 * valid as f64, "{good} of {valid}");
        let mut again = DisparityMap::default();
        compute_disparity(&l, &r, &opts, &mut DisparityWorkspace::new(), &mut again).unwrap();
        assert_eq!(out, again);
    }
}
