//! The stereo component's options (`[stereo]` in the configuration): the camera's Bayer
//! layout, the demosaicing and block-matching choices and the texture grid. The stereo
//! pipeline itself (demosaicing, rectification, disparity, texture maps) is the
//! `pfslam-stereo` crate's; the options live here so [`crate::Config`] holds them.

use serde::{Deserialize, Serialize};

/// A stereo option out of range.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StereoOptionError {
    /// An option is out of range.
    #[error("stereo options: {0}")]
    Options(String),
    /// The image is too small for the options.
    #[error("image size: {0}")]
    Size(String),
}

/// Options of the stereo component (`[stereo]` in the configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StereoOptions {
    /// Colour filter layout of the raw frames (the car: `bggr`).
    pub bayer_pattern: BayerPattern,
    /// Demosaicing algorithm. Bilinear by default: Malvar-He-Cutler gains 3.8 dB PSNR on a
    /// natural test image, but on the real pair it gives 17 % fewer matched road pixels (its
    /// sharpening also sharpens noise, which the census transform sees) and no better cell
    /// colours on the rendered ground (5.68 vs 5.62 mean error).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub demosaic: Demosaic,
    /// Block matcher.
    pub matcher: MatcherOptions,
    /// Texture grid cell size (m); 0 takes the occupancy map's resolution (the grid's origin
    /// is always the map's).
    pub cell_size_m: f64,
    /// Points below this world z (m) are not ground.
    pub ground_z_min_m: f64,
    /// Points above this world z (m) are not ground.
    pub ground_z_max_m: f64,
    /// Points farther than this along the optical axis (m) are dropped (depth error grows
    /// with the square of the distance).
    pub max_depth_m: f64,
    /// Use every n-th pixel in both directions when projecting (1 = all).
    pub pixel_stride: usize,
}

impl Default for StereoOptions {
    fn default() -> Self {
        StereoOptions {
            bayer_pattern: BayerPattern::UCSD,
            demosaic: Demosaic::Bilinear,
            matcher: MatcherOptions::default(),
            cell_size_m: 0.0,
            ground_z_min_m: -0.3,
            ground_z_max_m: 0.3,
            max_depth_m: 20.0,
            pixel_stride: 1,
        }
    }
}

impl StereoOptions {
    /// Checks the options (image width for the matcher's window).
    pub fn validate(&self, width: usize) -> Result<(), StereoOptionError> {
        self.matcher.validate(width)?;
        if !(self.cell_size_m.is_finite() && self.cell_size_m >= 0.0) {
            return Err(StereoOptionError::Options(format!(
                "cell_size_m must be >= 0 (0 = the map's), got {}",
                self.cell_size_m
            )));
        }
        if !(self.ground_z_min_m.is_finite()
            && self.ground_z_max_m.is_finite()
            && self.ground_z_min_m < self.ground_z_max_m)
        {
            return Err(StereoOptionError::Options(format!(
                "ground z window [{}, {}] m is empty",
                self.ground_z_min_m, self.ground_z_max_m
            )));
        }
        if !(self.max_depth_m.is_finite() && self.max_depth_m > 0.0) {
            return Err(StereoOptionError::Options(format!(
                "max_depth_m must be positive, got {}",
                self.max_depth_m
            )));
        }
        if self.pixel_stride == 0 {
            return Err(StereoOptionError::Options(
                "pixel_stride must be >= 1".into(),
            ));
        }
        Ok(())
    }
}

impl StereoOptions {
    /// The texture grid: the map's origin, and `cell_size_m` or else the map's resolution.
    pub fn texture_limits(&self, map: &crate::map::MapOptions) -> crate::map::MapLimits {
        let res = if self.cell_size_m > 0.0 {
            self.cell_size_m
        } else {
            map.resolution_m
        };
        crate::map::MapLimits::new(res, map.origin_x_m, map.origin_y_m)
    }
}

/// Options of the block matcher (`[stereo.matcher]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatcherOptions {
    /// Number of disparities searched: `0 ..= num_disparities - 1` px.
    pub num_disparities: usize,
    /// Half-size of the square aggregation window (px): the window is `2 r + 1` wide.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_radius: usize,
    /// Reject a match whose best cost is not at least this fraction below the best cost at a
    /// disparity more than 1 px away (0 disables).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub uniqueness_ratio: f32,
    /// Largest allowed difference (px) between the left and the right disparity of a match.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub lr_max_diff_px: u16,
    /// Cost aggregation: the window alone, or semi-global matching over the window's costs.
    pub aggregation: Aggregation,
    /// SGM penalty for a 1 px disparity change between neighbours, in cost units of the
    /// window (the defaults were tuned with `window_radius = 2`).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub sgm_p1: u16,
    /// SGM penalty for a larger disparity change.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub sgm_p2: u16,
}

/// How matching costs are aggregated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Aggregation {
    /// Sum over the square window (block matching); rows in parallel.
    Block,
    /// Semi-global matching (Hirschmüller 2008) on the window's costs along the five paths
    /// that come from above or the sides (left, right, top, top-left, top-right), in one
    /// top-to-bottom pass; sequential over rows.
    Sgm,
}

impl Default for MatcherOptions {
    fn default() -> Self {
        MatcherOptions {
            num_disparities: 128,
            window_radius: 5,
            uniqueness_ratio: 0.05,
            lr_max_diff_px: 1,
            aggregation: Aggregation::Block,
            sgm_p1: 30,
            sgm_p2: 400,
        }
    }
}

impl MatcherOptions {
    /// Checks the options for an image of `width` px.
    pub fn validate(&self, width: usize) -> Result<(), StereoOptionError> {
        if self.num_disparities < 2 || self.num_disparities > 1024 {
            return Err(StereoOptionError::Options(format!(
                "num_disparities must be in 2..=1024, got {}",
                self.num_disparities
            )));
        }
        if self.window_radius == 0 || self.window_radius > 15 {
            return Err(StereoOptionError::Options(format!(
                "window_radius must be in 1..=15, got {}",
                self.window_radius
            )));
        }
        if !(self.uniqueness_ratio.is_finite() && (0.0..1.0).contains(&self.uniqueness_ratio)) {
            return Err(StereoOptionError::Options(format!(
                "uniqueness_ratio must be in [0, 1), got {}",
                self.uniqueness_ratio
            )));
        }
        let max_cost = 48 * (2 * self.window_radius + 1).pow(2);
        if self.aggregation == Aggregation::Sgm
            && (self.sgm_p1 == 0
                || self.sgm_p2 < self.sgm_p1
                || 5 * (max_cost + self.sgm_p2 as usize) > u16::MAX as usize)
        {
            return Err(StereoOptionError::Options(format!(
                "SGM needs 0 < sgm_p1 <= sgm_p2 and 5 (window cost {max_cost} + sgm_p2) < 65536"
            )));
        }
        if width < 2 * self.window_radius + 2 {
            return Err(StereoOptionError::Size(format!(
                "image width {width} is too small for window radius {}",
                self.window_radius
            )));
        }
        Ok(())
    }
}

/// The colour filter layout, named by the top-left 2x2 block read row by row.
///
/// The car's cameras are "Bayer BG": their frames start with a blue pixel, B G / G R, i.e.
/// [`BayerPattern::Bggr`] (checked on the real pair: with it the traffic cones come out orange
/// and the tail lights red; with R G / G B they are blue).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BayerPattern {
    /// R G / G B.
    Rggb,
    /// B G / G R.
    Bggr,
    /// G R / B G.
    Grbg,
    /// G B / R G.
    Gbrg,
}

impl BayerPattern {
    /// The channel (0 R, 1 G, 2 B) sampled at `(x, y)`.
    #[inline]
    pub fn channel(self, x: usize, y: usize) -> usize {
        let k = ((y & 1) << 1) | (x & 1);
        let table: [usize; 4] = match self {
            BayerPattern::Rggb => [0, 1, 1, 2],
            BayerPattern::Bggr => [2, 1, 1, 0],
            BayerPattern::Grbg => [1, 0, 2, 1],
            BayerPattern::Gbrg => [1, 2, 0, 1],
        };
        table[k]
    }

    /// The pattern of the seed car's cameras ("BG": B G / G R).
    pub const UCSD: BayerPattern = BayerPattern::Bggr;
}

/// Demosaicing algorithm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Demosaic {
    /// Bilinear interpolation of each channel from its own samples.
    Bilinear,
    /// Malvar, He & Cutler (2004): bilinear plus a gradient correction from the other channels
    /// (5x5 linear filters), edge-aware at the same cost.
    MalvarHeCutler,
}
