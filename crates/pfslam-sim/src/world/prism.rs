//! Obstacles: vertical extrusions of simple polygons, and the polygon tests they use.

/// A vertical extrusion of a simple polygon: an obstacle.
#[derive(Debug, Clone, PartialEq)]
pub struct Prism {
    /// Free-form kind (`building`, `car`, `pole`, ...).
    pub kind: String,
    /// Footprint vertices `(x_m, y_m)`, counter-clockwise (normalised on construction).
    pub footprint: Vec<[f64; 2]>,
    /// Bottom face height (m).
    pub z_min_m: f64,
    /// Top face height (m).
    pub z_max_m: f64,
}

impl Prism {
    /// A prism from a polygon in any orientation; `None` when degenerate (fewer than three
    /// vertices, zero area, non-finite numbers, or `z_max <= z_min`).
    pub fn new(
        kind: &str,
        mut footprint: Vec<[f64; 2]>,
        z_min_m: f64,
        z_max_m: f64,
    ) -> Option<Self> {
        if footprint.len() < 3
            || !z_min_m.is_finite()
            || !z_max_m.is_finite()
            || z_max_m <= z_min_m
            || z_min_m < 0.0
            || footprint
                .iter()
                .any(|p| !p[0].is_finite() || !p[1].is_finite())
        {
            return None;
        }
        let area = signed_area(&footprint);
        if area.abs() < 1e-9 {
            return None;
        }
        if area < 0.0 {
            footprint.reverse();
        }
        Some(Prism {
            kind: kind.to_string(),
            footprint,
            z_min_m,
            z_max_m,
        })
    }

    /// A rotated rectangle centred at `(cx, cy)`.
    pub fn rect(
        kind: &str,
        center_m: [f64; 2],
        length_m: f64,
        width_m: f64,
        yaw_rad: f64,
        z_min_m: f64,
        z_max_m: f64,
    ) -> Option<Self> {
        let (s, c) = yaw_rad.sin_cos();
        let (hl, hw) = (0.5 * length_m, 0.5 * width_m);
        let corners = [(-hl, -hw), (hl, -hw), (hl, hw), (-hl, hw)]
            .iter()
            .map(|&(x, y)| [center_m[0] + c * x - s * y, center_m[1] + s * x + c * y])
            .collect();
        Prism::new(kind, corners, z_min_m, z_max_m)
    }

    /// True when the point lies inside the footprint (even-odd rule).
    pub fn contains_xy(&self, x_m: f64, y_m: f64) -> bool {
        point_in_polygon(&self.footprint, x_m, y_m)
    }
}

/// The signed area of a polygon (positive when counter-clockwise).
pub(crate) fn signed_area(poly: &[[f64; 2]]) -> f64 {
    let n = poly.len();
    let mut a = 0.0;
    for i in 0..n {
        let p = poly[i];
        let q = poly[(i + 1) % n];
        a += p[0] * q[1] - q[0] * p[1];
    }
    0.5 * a
}

/// Even-odd point-in-polygon test.
pub(crate) fn point_in_polygon(poly: &[[f64; 2]], x: f64, y: f64) -> bool {
    let n = poly.len();
    let mut inside = false;
    let mut j = n - 1;
    for i in 0..n {
        let (xi, yi) = (poly[i][0], poly[i][1]);
        let (xj, yj) = (poly[j][0], poly[j][1]);
        if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
            inside = !inside;
        }
        j = i;
    }
    inside
}
