//! The driven path: a closed route of waypoints with corners rounded into circular arcs,
//! parameterised by arc length, and a speed profile that respects acceleration limits.

use super::SimError;
use std::f64::consts::PI;

#[derive(Debug, Clone, Copy)]
enum Piece {
    Line {
        start: [f64; 2],
        heading: f64,
    },
    Arc {
        center: [f64; 2],
        radius: f64,
        /// Heading at the start of the arc (unwrapped).
        heading0: f64,
        /// +1 left turn, -1 right turn.
        sign: f64,
    },
}

#[derive(Debug, Clone, Copy)]
struct Element {
    piece: Piece,
    /// Arc length where this element starts (m).
    s0: f64,
    len: f64,
    /// Unwrapped heading at the start (rad).
    yaw0: f64,
}

/// A point of the path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathPoint {
    /// x (m).
    pub x_m: f64,
    /// y (m).
    pub y_m: f64,
    /// Unwrapped heading (rad): continuous along the path and across laps.
    pub yaw_rad: f64,
    /// Signed curvature (1/m, positive left).
    pub curvature_per_m: f64,
}

/// A closed path of lines and arcs.
#[derive(Debug, Clone)]
pub struct Path {
    elements: Vec<Element>,
    lap_m: f64,
    /// Heading gained over one lap (a multiple of 2 pi).
    lap_yaw_rad: f64,
}

fn angle_of(v: [f64; 2]) -> f64 {
    v[1].atan2(v[0])
}

/// Leg `i` of a closed route (waypoint `i` to `i + 1`): unit direction and length (m).
type Leg = ([f64; 2], f64);

/// The legs of the closed route; `Err` when two consecutive waypoints coincide.
fn route_legs(route: &[[f64; 2]]) -> Result<Vec<Leg>, SimError> {
    let n = route.len();
    let mut legs = Vec::with_capacity(n);
    for i in 0..n {
        let a = route[i];
        let b = route[(i + 1) % n];
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        if len < 1e-6 {
            return Err(SimError::BadRoute(format!(
                "waypoints {i} and {} coincide",
                (i + 1) % n
            )));
        }
        legs.push(([(b[0] - a[0]) / len, (b[1] - a[1]) / len], len));
    }
    Ok(legs)
}

/// Turn angle (rad) of the corner at waypoint `i + 1`, between leg `i` and leg `i + 1`;
/// `Err` on a U-turn, which no arc can drive.
fn corner_turns_rad(legs: &[Leg]) -> Result<Vec<f64>, SimError> {
    let n = legs.len();
    let mut turn = vec![0.0; n];
    for i in 0..n {
        let (u, _) = legs[i];
        let (v, _) = legs[(i + 1) % n];
        let phi = pfslam::geometry::wrap_angle(angle_of(v) - angle_of(u));
        if phi.abs() > PI - 1e-3 {
            return Err(SimError::BadRoute(format!(
                "U-turn at waypoint {} (not drivable)",
                (i + 1) % n
            )));
        }
        turn[i] = phi;
    }
    Ok(turn)
}

/// Tangent length and arc radius (m) of each corner: `corner_radius_m`, smaller where the
/// adjacent legs are short; both 0 at a straight corner.
fn corner_fillets_m(legs: &[Leg], turn: &[f64], corner_radius_m: f64) -> (Vec<f64>, Vec<f64>) {
    let n = legs.len();
    let mut tangent = vec![0.0; n];
    let mut radius = vec![0.0; n];
    for i in 0..n {
        let phi = turn[i].abs();
        if phi < 1e-9 {
            continue;
        }
        // each corner may use at most half of each adjacent leg
        let room = 0.5 * legs[i].1.min(legs[(i + 1) % n].1);
        let half_tan = (0.5 * phi).tan();
        let r = corner_radius_m.min(room / half_tan);
        radius[i] = r;
        tangent[i] = r * half_tan;
    }
    (tangent, radius)
}

/// The rounded corners, indexed like the legs (corner `i` at waypoint `i + 1`).
struct Corners<'a> {
    turn_rad: &'a [f64],
    tangent_m: &'a [f64],
    radius_m: &'a [f64],
}

/// The lines and arcs of one lap, with the lap length (m) and the unwrapped heading at its
/// end (rad).
fn lay_out_elements(
    route: &[[f64; 2]],
    legs: &[Leg],
    corners: &Corners,
) -> (Vec<Element>, f64, f64) {
    let n = legs.len();
    let (turn, tangent, radius) = (corners.turn_rad, corners.tangent_m, corners.radius_m);
    let mut elements = Vec::new();
    let mut s = 0.0;
    let mut yaw = angle_of(legs[0].0);
    for i in 0..n {
        let (u, len) = legs[i];
        let start_cut = tangent[(i + n - 1) % n];
        let end_cut = tangent[i];
        let a = route[i];
        let start = [a[0] + u[0] * start_cut, a[1] + u[1] * start_cut];
        let line_len = len - start_cut - end_cut;
        if line_len > 1e-9 {
            elements.push(Element {
                piece: Piece::Line {
                    start,
                    heading: yaw,
                },
                s0: s,
                len: line_len,
                yaw0: yaw,
            });
            s += line_len;
        }
        if radius[i] > 0.0 {
            let arc = corner_arc(route[(i + 1) % n], u, end_cut, turn[i], radius[i], s, yaw);
            s += arc.len;
            elements.push(arc);
        }
        yaw += turn[i];
    }
    (elements, s, yaw)
}

/// The arc of a corner at waypoint `b`, entered along `u` at `end_cut` (m) before `b`,
/// starting at arc length `s0` (m) and heading `yaw0` (rad).
fn corner_arc(
    b: [f64; 2],
    u: [f64; 2],
    end_cut: f64,
    turn_rad: f64,
    radius: f64,
    s0: f64,
    yaw0: f64,
) -> Element {
    let sign = turn_rad.signum();
    let p = [b[0] - u[0] * end_cut, b[1] - u[1] * end_cut];
    let center = [p[0] - sign * u[1] * radius, p[1] + sign * u[0] * radius];
    let len = radius * turn_rad.abs();
    Element {
        piece: Piece::Arc {
            center,
            radius,
            heading0: yaw0,
            sign,
        },
        s0,
        len,
        yaw0,
    }
}

impl Path {
    /// Rounds the corners of the closed route with arcs of radius `corner_radius_m` (smaller
    /// where the legs are short). Starts on the first leg, heading to the second waypoint.
    pub fn from_route(route: &[[f64; 2]], corner_radius_m: f64) -> Result<Path, SimError> {
        if route.len() < 2 {
            return Err(SimError::BadRoute(
                "a route needs at least 2 waypoints".into(),
            ));
        }
        let legs = route_legs(route)?;
        let turn = corner_turns_rad(&legs)?;
        let (tangent, radius) = corner_fillets_m(&legs, &turn, corner_radius_m);
        let corners = Corners {
            turn_rad: &turn,
            tangent_m: &tangent,
            radius_m: &radius,
        };
        let (elements, lap_m, yaw) = lay_out_elements(route, &legs, &corners);
        let lap_yaw_rad = yaw - angle_of(legs[0].0);
        Ok(Path {
            elements,
            lap_m,
            lap_yaw_rad,
        })
    }

    /// Length of one lap (m).
    pub fn lap_m(&self) -> f64 {
        self.lap_m
    }

    /// The point at arc length `s_m >= 0` (laps repeat).
    pub fn at(&self, s_m: f64) -> PathPoint {
        let lap = (s_m / self.lap_m).floor();
        let r = (s_m - lap * self.lap_m).clamp(0.0, self.lap_m);
        let k = self
            .elements
            .partition_point(|e| e.s0 <= r)
            .saturating_sub(1);
        let e = &self.elements[k];
        let ds = (r - e.s0).clamp(0.0, e.len);
        let yaw_offset = lap * self.lap_yaw_rad;
        match e.piece {
            Piece::Line { start, heading } => {
                let (sn, cs) = heading.sin_cos();
                PathPoint {
                    x_m: start[0] + cs * ds,
                    y_m: start[1] + sn * ds,
                    yaw_rad: e.yaw0 + yaw_offset,
                    curvature_per_m: 0.0,
                }
            }
            Piece::Arc {
                center,
                radius,
                heading0,
                sign,
            } => {
                let h = heading0 + sign * ds / radius;
                // position = center + r * (sin h, -cos h) * sign
                PathPoint {
                    x_m: center[0] + sign * radius * h.sin(),
                    y_m: center[1] - sign * radius * h.cos(),
                    yaw_rad: h + yaw_offset,
                    curvature_per_m: sign / radius,
                }
            }
        }
    }

    /// Distance travelled by a wheel at lateral offset `offset_m` (left positive) from the
    /// path, from `s = 0` to `s_m`: `integral (1 - kappa * offset) ds`.
    pub fn offset_distance_m(&self, s_m: f64, offset_m: f64) -> f64 {
        let lap = (s_m / self.lap_m).floor();
        let r = (s_m - lap * self.lap_m).clamp(0.0, self.lap_m);
        // per lap: lap length minus offset * total turning
        let mut d = lap * (self.lap_m - offset_m * self.lap_yaw_rad);
        for e in &self.elements {
            if e.s0 >= r {
                break;
            }
            let ds = (r - e.s0).min(e.len);
            let kappa = match e.piece {
                Piece::Line { .. } => 0.0,
                Piece::Arc { radius, sign, .. } => sign / radius,
            };
            d += ds * (1.0 - kappa * offset_m);
        }
        d
    }

    /// Arc length reached by driving at most `cruise_mps` with the given acceleration limits,
    /// sampled every `dt_s` from standstill at `s = 0`, for `steps + 1` samples. The speed
    /// limit on arcs is `sqrt(lateral / kappa)`; the cruise speed varies slowly (+-10 %)
    /// along the lap so the speed is not constant.
    pub fn drive(
        &self,
        cruise_mps: f64,
        accel_mps2: f64,
        decel_mps2: f64,
        lateral_mps2: f64,
        dt_s: f64,
        steps: usize,
    ) -> Vec<f64> {
        // speed limit on a 0.5 m grid of one lap, then backward (braking) passes over two laps
        let ds = 0.5;
        let m = (self.lap_m / ds).ceil() as usize + 1;
        let mut lim: Vec<f64> = (0..m)
            .map(|k| {
                let s = k as f64 * ds;
                let p = self.at(s);
                let wave = 1.0 + 0.1 * (2.0 * PI * s / 310.0).sin();
                let v = cruise_mps * wave;
                if p.curvature_per_m.abs() > 1e-9 {
                    v.min((lateral_mps2 / p.curvature_per_m.abs()).sqrt())
                } else {
                    v
                }
            })
            .collect();
        for _ in 0..2 {
            for k in (0..m).rev() {
                let next = if k + 1 < m { lim[k + 1] } else { lim[0] };
                let cap = (next * next + 2.0 * decel_mps2 * ds).sqrt();
                if lim[k] > cap {
                    lim[k] = cap;
                }
            }
        }
        let limit_at = |s: f64| {
            let r = s.rem_euclid(self.lap_m) / ds;
            let k = r.floor() as usize;
            let f = r - k as f64;
            let a = lim[k.min(m - 1)];
            let b = lim[(k + 1).min(m - 1)];
            a + f * (b - a)
        };
        let mut out = Vec::with_capacity(steps + 1);
        let (mut s, mut v) = (0.0f64, 0.0f64);
        out.push(s);
        for _ in 0..steps {
            let target = limit_at(s);
            let dv = (target - v).clamp(-decel_mps2 * dt_s, accel_mps2 * dt_s);
            let v_new = (v + dv).max(0.0);
            s += 0.5 * (v + v_new) * dt_s;
            v = v_new;
            out.push(s);
        }
        out
    }
}

/// Time step of the motion integration (s).
pub(crate) const DRIVE_DT_S: f64 = 1e-3;

/// The true motion along a path: arc length sampled every [`DRIVE_DT_S`] after a standstill.
pub(crate) struct Motion {
    pub(crate) path: Path,
    pub(crate) s: Vec<f64>,
    pub(crate) standstill_s: f64,
}

/// How a vehicle drives its route.
pub(crate) struct DriveProfile {
    pub(crate) cruise_mps: f64,
    pub(crate) accel_mps2: f64,
    pub(crate) decel_mps2: f64,
    pub(crate) lateral_mps2: f64,
    pub(crate) corner_radius_m: f64,
    pub(crate) standstill_s: f64,
}

impl Motion {
    /// Plans the drive along the world's route for `duration_s` (plus a margin).
    pub(crate) fn plan(
        world: &super::World,
        duration_s: f64,
        p: &DriveProfile,
    ) -> Result<Motion, SimError> {
        if world.route.len() < 2 {
            return Err(SimError::BadRoute(format!(
                "world {:?} has no route",
                world.name
            )));
        }
        let path = Path::from_route(&world.route, p.corner_radius_m)?;
        let steps = ((duration_s + 1.0) / DRIVE_DT_S).ceil() as usize + 2;
        let s = path.drive(
            p.cruise_mps,
            p.accel_mps2,
            p.decel_mps2,
            p.lateral_mps2,
            DRIVE_DT_S,
            steps,
        );
        Ok(Motion {
            path,
            s,
            standstill_s: p.standstill_s,
        })
    }

    /// Arc length at time `t_s` (linear between samples).
    pub(crate) fn s_at(&self, t_s: f64) -> f64 {
        let t = (t_s - self.standstill_s).max(0.0) / DRIVE_DT_S;
        let k = (t.floor() as usize).min(self.s.len().saturating_sub(2));
        let f = (t - k as f64).min(1.0);
        self.s[k] + f * (self.s[k + 1] - self.s[k])
    }

    /// Pose (yaw wrapped) and unwrapped yaw at time `t_s`.
    pub(crate) fn pose_at(&self, t_s: f64) -> (pfslam::geometry::Pose2, f64) {
        let p = self.path.at(self.s_at(t_s));
        (
            pfslam::geometry::Pose2::new(p.x_m, p.y_m, p.yaw_rad),
            p.yaw_rad,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_path_is_continuous() {
        let route = [[0.0, 0.0], [100.0, 0.0], [100.0, 50.0], [0.0, 50.0]];
        let p = Path::from_route(&route, 8.0).unwrap();
        let expected = 300.0 - 4.0 * (2.0 * 8.0 - 8.0 * PI / 2.0);
        assert!((p.lap_m() - expected).abs() < 1e-9);
        let mut prev = p.at(0.0);
        for k in 1..3000 {
            let q = p.at(k as f64 * 0.2);
            let step = (q.x_m - prev.x_m).hypot(q.y_m - prev.y_m);
            assert!(step <= 0.2 + 1e-9 && step > 0.19, "k {k} step {step}");
            assert!((q.yaw_rad - prev.yaw_rad).abs() < 0.2 / 8.0 + 1e-9);
            prev = q;
        }
        // after one lap: same place, yaw + 2 pi
        let a = p.at(1.0);
        let b = p.at(1.0 + p.lap_m());
        assert!((a.x_m - b.x_m).abs() < 1e-9 && (a.y_m - b.y_m).abs() < 1e-9);
        assert!((b.yaw_rad - a.yaw_rad - 2.0 * PI).abs() < 1e-9);
        // wheel distances: left wheel travels less on left turns... offsets integrate
        let d_left = p.offset_distance_m(p.lap_m(), 0.75);
        assert!((d_left - (p.lap_m() - 0.75 * 2.0 * PI)).abs() < 1e-9);
    }

    #[test]
    fn drive_respects_limits() {
        let route = [[0.0, 0.0], [100.0, 0.0], [100.0, 50.0], [0.0, 50.0]];
        let p = Path::from_route(&route, 8.0).unwrap();
        let s = p.drive(10.0, 1.5, 2.0, 2.0, 0.01, 10_000);
        for w in s.windows(3) {
            let v0 = (w[1] - w[0]) / 0.01;
            let v1 = (w[2] - w[1]) / 0.01;
            assert!((0.0..=11.0 + 1e-9).contains(&v1));
            assert!((v1 - v0).abs() <= 2.0 * 0.01 + 1e-9);
        }
        assert!(s[10_000] > 500.0);
        assert!(Path::from_route(&[[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]], 1.0).is_err());
    }
}
