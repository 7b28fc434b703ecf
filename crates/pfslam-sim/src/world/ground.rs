//! The ground's appearance: a default colour, coloured regions and painted markings.

use super::*;

/// A coloured ground polygon.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundRegion {
    /// RGB colour.
    pub rgb: [u8; 3],
    /// Polygon vertices (m).
    pub polygon: Vec<[f64; 2]>,
}

/// A painted polyline on the ground (road marking).
#[derive(Debug, Clone, PartialEq)]
pub struct GroundMarking {
    /// RGB colour.
    pub rgb: [u8; 3],
    /// Line width (m).
    pub width_m: f64,
    /// Polyline vertices (m).
    pub points: Vec<[f64; 2]>,
}

/// The ground's appearance, for the stereo work: a default colour painted over by regions,
/// then markings, in file order.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTexture {
    /// Colour where nothing else is painted.
    pub default_rgb: [u8; 3],
    /// Coloured regions.
    pub regions: Vec<GroundRegion>,
    /// Road markings.
    pub markings: Vec<GroundMarking>,
}

impl Default for GroundTexture {
    fn default() -> Self {
        GroundTexture {
            default_rgb: [90, 90, 90],
            regions: Vec::new(),
            markings: Vec::new(),
        }
    }
}

impl GroundTexture {
    /// The ground colour at a point.
    pub fn rgb_at(&self, x_m: f64, y_m: f64) -> [u8; 3] {
        for m in self.markings.iter().rev() {
            let hw = 0.5 * m.width_m;
            for w in m.points.windows(2) {
                if dist_point_segment(x_m, y_m, w[0], w[1]) <= hw {
                    return m.rgb;
                }
            }
        }
        for r in self.regions.iter().rev() {
            if point_in_polygon(&r.polygon, x_m, y_m) {
                return r.rgb;
            }
        }
        self.default_rgb
    }
}

pub(super) fn dist_point_segment(x: f64, y: f64, a: [f64; 2], b: [f64; 2]) -> f64 {
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let l2 = ex * ex + ey * ey;
    let t = if l2 > 0.0 {
        (((x - a[0]) * ex + (y - a[1]) * ey) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (x - a[0] - t * ex).hypot(y - a[1] - t * ey)
}
