//! The world-file format (see the module documentation of [`super`]): reading and writing.

use super::*;

impl World {
    /// Parses world-file text; `path` names the source in errors.
    pub fn parse(text: &str, path: &Path, default_name: &str) -> Result<World, SimError> {
        let mut world = World {
            name: default_name.to_string(),
            prisms: Vec::new(),
            ground: GroundTexture::default(),
            route: Vec::new(),
        };
        for (idx, raw) in text.lines().enumerate() {
            let line_no = idx + 1;
            let content = raw.split('#').next().unwrap_or("").trim();
            if content.is_empty() {
                continue;
            }
            let toks: Vec<&str> = content.split_whitespace().collect();
            let err = |msg: String| SimError::Io(crate::io::IoError::parse(path, line_no, msg));
            let num = |i: usize, what: &str| -> Result<f64, SimError> {
                let t = toks
                    .get(i)
                    .ok_or_else(|| err(format!("{}: missing {what}", toks[0])))?;
                crate::io::parse_finite_f64(path, line_no, what, t).map_err(SimError::Io)
            };
            let colour = |i: usize| -> Result<[u8; 3], SimError> {
                let mut c = [0u8; 3];
                for (k, ck) in c.iter_mut().enumerate() {
                    let t = toks
                        .get(i + k)
                        .ok_or_else(|| err(format!("{}: missing colour component", toks[0])))?;
                    *ck = t.parse().map_err(|_| {
                        err(format!(
                            "{}: colour component not in 0..=255: {t:?}",
                            toks[0]
                        ))
                    })?;
                }
                Ok(c)
            };
            let points = |from: usize, min: usize| -> Result<Vec<[f64; 2]>, SimError> {
                let rest = toks.len().saturating_sub(from);
                if !rest.is_multiple_of(2) {
                    return Err(err(format!("{}: odd number of coordinates", toks[0])));
                }
                if rest / 2 < min {
                    return Err(err(format!(
                        "{}: needs at least {min} points, found {}",
                        toks[0],
                        rest / 2
                    )));
                }
                (0..rest / 2)
                    .map(|k| Ok([num(from + 2 * k, "x")?, num(from + 2 * k + 1, "y")?]))
                    .collect()
            };
            match toks[0] {
                "name" => {
                    if toks.len() != 2 {
                        return Err(err("name: expected exactly one word".to_string()));
                    }
                    world.name = toks[1].to_string();
                }
                "prism" => {
                    let kind = toks
                        .get(1)
                        .ok_or_else(|| err("prism: missing kind".to_string()))?;
                    let (z0, z1) = (num(2, "z_min")?, num(3, "z_max")?);
                    let pts = points(4, 3)?;
                    let p = Prism::new(kind, pts, z0, z1).ok_or_else(|| {
                        err("prism: degenerate (zero area, z_min < 0 or z_max <= z_min)".into())
                    })?;
                    world.prisms.push(p);
                }
                "box" => {
                    if toks.len() != 9 {
                        return Err(err(format!(
                            "box: expected KIND CX CY LENGTH WIDTH YAW_DEG Z_MIN Z_MAX, found {} fields",
                            toks.len() - 1
                        )));
                    }
                    let p = Prism::rect(
                        toks[1],
                        [num(2, "cx")?, num(3, "cy")?],
                        num(4, "length")?,
                        num(5, "width")?,
                        num(6, "yaw_deg")?.to_radians(),
                        num(7, "z_min")?,
                        num(8, "z_max")?,
                    )
                    .ok_or_else(|| err("box: degenerate (zero size or z_max <= z_min)".into()))?;
                    world.prisms.push(p);
                }
                "ground" => {
                    if toks.len() != 4 {
                        return Err(err("ground: expected R G B".to_string()));
                    }
                    world.ground.default_rgb = colour(1)?;
                }
                "region" => {
                    let rgb = colour(1)?;
                    let polygon = points(4, 3)?;
                    world.ground.regions.push(GroundRegion { rgb, polygon });
                }
                "marking" => {
                    let rgb = colour(1)?;
                    let width_m = num(4, "width")?;
                    if width_m <= 0.0 {
                        return Err(err("marking: width must be positive".to_string()));
                    }
                    let pts = points(5, 2)?;
                    world.ground.markings.push(GroundMarking {
                        rgb,
                        width_m,
                        points: pts,
                    });
                }
                "route" => {
                    let pts = points(1, 1)?;
                    world.route.extend(pts);
                }
                other => {
                    return Err(err(format!(
                        "unknown item {other:?} (expected name, prism, box, ground, region, marking or route)"
                    )));
                }
            }
        }
        Ok(world)
    }

    /// The world in the file format (round-trips through [`World::parse`] up to float
    /// formatting, which is Rust's shortest exact representation).
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "name {}", self.name);
        let g = self.ground.default_rgb;
        let _ = writeln!(s, "ground {} {} {}", g[0], g[1], g[2]);
        for r in &self.ground.regions {
            let _ = write!(s, "region {} {} {}", r.rgb[0], r.rgb[1], r.rgb[2]);
            for p in &r.polygon {
                let _ = write!(s, " {} {}", p[0], p[1]);
            }
            s.push('\n');
        }
        for m in &self.ground.markings {
            let _ = write!(
                s,
                "marking {} {} {} {}",
                m.rgb[0], m.rgb[1], m.rgb[2], m.width_m
            );
            for p in &m.points {
                let _ = write!(s, " {} {}", p[0], p[1]);
            }
            s.push('\n');
        }
        for p in &self.prisms {
            let _ = write!(s, "prism {} {} {}", p.kind, p.z_min_m, p.z_max_m);
            for v in &p.footprint {
                let _ = write!(s, " {} {}", v[0], v[1]);
            }
            s.push('\n');
        }
        if !self.route.is_empty() {
            s.push_str("route");
            for p in &self.route {
                let _ = write!(s, " {} {}", p[0], p[1]);
            }
            s.push('\n');
        }
        s
    }
}
