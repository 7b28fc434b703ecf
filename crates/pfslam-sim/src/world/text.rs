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
            let content = raw.split('#').next().unwrap_or("").trim();
            if content.is_empty() {
                continue;
            }
            let line = Line {
                toks: content.split_whitespace().collect(),
                path,
                line_no: idx + 1,
            };
            world.add_item(&line)?;
        }
        Ok(world)
    }

    /// Adds the item of one non-empty line to the world.
    fn add_item(&mut self, line: &Line) -> Result<(), SimError> {
        let toks = &line.toks;
        match toks[0] {
            "name" => {
                if toks.len() != 2 {
                    return Err(line.err("name: expected exactly one word".to_string()));
                }
                self.name = toks[1].to_string();
            }
            "prism" => self.prisms.push(line.prism()?),
            "box" => self.prisms.push(line.box_prism()?),
            "ground" => {
                if toks.len() != 4 {
                    return Err(line.err("ground: expected R G B".to_string()));
                }
                self.ground.default_rgb = line.colour(1)?;
            }
            "region" => {
                let rgb = line.colour(1)?;
                let polygon = line.points(4, 3)?;
                self.ground.regions.push(GroundRegion { rgb, polygon });
            }
            "marking" => self.ground.markings.push(line.marking()?),
            "route" => {
                let pts = line.points(1, 1)?;
                self.route.extend(pts);
            }
            other => {
                return Err(line.err(format!(
                    "unknown item {other:?} (expected name, prism, box, ground, region, marking or route)"
                )));
            }
        }
        Ok(())
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

/// One non-empty line of a world file, split into whitespace-separated tokens.
struct Line<'a> {
    toks: Vec<&'a str>,
    path: &'a Path,
    line_no: usize,
}

impl Line<'_> {
    /// A parse error at this line.
    fn err(&self, msg: String) -> SimError {
        SimError::Io(pfslam::files::IoError::parse(self.path, self.line_no, msg))
    }

    /// Token `i` as a finite number; `what` names it in errors.
    fn num(&self, i: usize, what: &str) -> Result<f64, SimError> {
        let t = self
            .toks
            .get(i)
            .ok_or_else(|| self.err(format!("{}: missing {what}", self.toks[0])))?;
        pfslam::files::parse_finite_f64(self.path, self.line_no, what, t).map_err(SimError::Io)
    }

    /// Tokens `i..i + 3` as an RGB colour.
    fn colour(&self, i: usize) -> Result<[u8; 3], SimError> {
        let toks = &self.toks;
        let mut c = [0u8; 3];
        for (k, ck) in c.iter_mut().enumerate() {
            let t = toks
                .get(i + k)
                .ok_or_else(|| self.err(format!("{}: missing colour component", toks[0])))?;
            *ck = t.parse().map_err(|_| {
                self.err(format!(
                    "{}: colour component not in 0..=255: {t:?}",
                    toks[0]
                ))
            })?;
        }
        Ok(c)
    }

    /// The tokens from `from` on as x y pairs (m), at least `min` of them.
    fn points(&self, from: usize, min: usize) -> Result<Vec<[f64; 2]>, SimError> {
        let toks = &self.toks;
        let rest = toks.len().saturating_sub(from);
        if !rest.is_multiple_of(2) {
            return Err(self.err(format!("{}: odd number of coordinates", toks[0])));
        }
        if rest / 2 < min {
            return Err(self.err(format!(
                "{}: needs at least {min} points, found {}",
                toks[0],
                rest / 2
            )));
        }
        (0..rest / 2)
            .map(|k| {
                Ok([
                    self.num(from + 2 * k, "x")?,
                    self.num(from + 2 * k + 1, "y")?,
                ])
            })
            .collect()
    }

    /// `prism KIND Z_MIN Z_MAX X Y X Y X Y ...`.
    fn prism(&self) -> Result<Prism, SimError> {
        let kind = self
            .toks
            .get(1)
            .ok_or_else(|| self.err("prism: missing kind".to_string()))?;
        let (z0, z1) = (self.num(2, "z_min")?, self.num(3, "z_max")?);
        let pts = self.points(4, 3)?;
        Prism::new(kind, pts, z0, z1).ok_or_else(|| {
            self.err("prism: degenerate (zero area, z_min < 0 or z_max <= z_min)".into())
        })
    }

    /// `box KIND CX CY LENGTH WIDTH YAW_DEG Z_MIN Z_MAX`.
    fn box_prism(&self) -> Result<Prism, SimError> {
        let toks = &self.toks;
        if toks.len() != 9 {
            return Err(self.err(format!(
                "box: expected KIND CX CY LENGTH WIDTH YAW_DEG Z_MIN Z_MAX, found {} fields",
                toks.len() - 1
            )));
        }
        Prism::rect(
            toks[1],
            [self.num(2, "cx")?, self.num(3, "cy")?],
            self.num(4, "length")?,
            self.num(5, "width")?,
            self.num(6, "yaw_deg")?.to_radians(),
            self.num(7, "z_min")?,
            self.num(8, "z_max")?,
        )
        .ok_or_else(|| self.err("box: degenerate (zero size or z_max <= z_min)".into()))
    }

    /// `marking R G B WIDTH X Y X Y ...` (width positive, at least two points).
    fn marking(&self) -> Result<GroundMarking, SimError> {
        let rgb = self.colour(1)?;
        let width_m = self.num(4, "width")?;
        if width_m <= 0.0 {
            return Err(self.err("marking: width must be positive".to_string()));
        }
        let pts = self.points(5, 2)?;
        Ok(GroundMarking {
            rgb,
            width_m,
            points: pts,
        })
    }
}
