//! Log-odds parameters, their fixed-point form and the logistic sigmoid.
//!
//! Cells store log-odds in fixed point: `i16` units of `1 / LOGODDS_SCALE` (1/256), so
//! `|log-odds| <= 127.99` and the resolution is 0.0039 — far finer than any increment in use
//! (the smallest seed increment is 0.42). Increments, clamp bounds and thresholds are rounded
//! to the same grid once, so an update is one saturating integer add and a classification one
//! integer compare.

use serde::{Deserialize, Serialize};

/// Fixed-point units per log-odds unit.
pub const LOGODDS_SCALE: f64 = 256.0;

/// The largest log-odds magnitude representable (`i16::MAX / LOGODDS_SCALE`).
pub const LOGODDS_MAX: f64 = i16::MAX as f64 / LOGODDS_SCALE;

/// Logistic sigmoid `1 / (1 + exp(-l))`: probability from log-odds (UCSD eq. 7).
#[inline]
pub fn sigmoid(logodds: f64) -> f64 {
    1.0 / (1.0 + (-logodds).exp())
}

/// Logit `ln(p / (1 - p))`: log-odds from probability.
#[inline]
pub fn logit(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// Log-odds to fixed point (rounded, saturated to the `i16` range).
#[inline]
pub fn to_fixed(logodds: f64) -> i16 {
    (logodds * LOGODDS_SCALE)
        .round()
        .clamp(i16::MIN as f64, i16::MAX as f64) as i16
}

/// Fixed point to log-odds.
#[inline]
pub fn from_fixed(v: i16) -> f64 {
    v as f64 / LOGODDS_SCALE
}

/// Probability of a fixed-point log-odds value through a 65,536-entry lookup table (built
/// once, 256 KiB), used when rendering or exporting whole maps.
#[inline]
pub fn probability_fixed(v: i16) -> f32 {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    let t = TABLE.get_or_init(|| {
        (0..=u16::MAX)
            .map(|u| sigmoid(from_fixed(u as i16)) as f32)
            .collect()
    });
    t[v as u16 as usize]
}

/// The log-odds update model: increments, clamp bounds and classification thresholds
/// (`[map.log_odds]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LogOddsParams {
    /// Added to the cell a beam ends in (> 0).
    pub hit: f64,
    /// Added to the cells a beam passes through (< 0).
    pub miss: f64,
    /// Lower clamp bound (< 0, >= -127.99).
    pub clamp_min: f64,
    /// Upper clamp bound (> 0, <= 127.99).
    pub clamp_max: f64,
    /// A cell is occupied when its probability is at least this.
    pub occupied_prob: f64,
    /// A cell is free when its probability is at most this.
    pub free_prob: f64,
}

impl Default for LogOddsParams {
    fn default() -> Self {
        LogOddsParams::ucsd()
    }
}

/// Named presets of [`LogOddsParams`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LogOddsPreset {
    /// UCSD seed: +-ln 4 (80 % / 20 % sensor model), clamped at +-10 ln 4.
    Ucsd,
    /// ESE650 seed: confidence 0.7 -> +0.85 / -0.42, bound 100, thresholds logit(0.9) and
    /// logit(0.2).
    Ese650,
}

impl LogOddsParams {
    /// UCSD seed (eq. 6): `+-ln 4`, clamped at `+-10 ln 4`. The report states no thresholds;
    /// ours are `p >= 0.8` occupied and `p <= 0.2` free, i.e. one net hit / one net miss (the
    /// sign rule of its binary map, leaving never-observed cells unknown).
    pub fn ucsd() -> Self {
        let l4 = 4f64.ln();
        LogOddsParams {
            hit: l4,
            miss: -l4,
            clamp_min: -10.0 * l4,
            clamp_max: 10.0 * l4,
            occupied_prob: 0.8,
            free_prob: 0.2,
        }
    }

    /// ESE650 seed: `ln(0.7/0.3) = 0.85` per hit, half of `-0.85` per miss, bound 100,
    /// occupied above `p = 0.9`, free below `p = 0.2`.
    pub fn ese650() -> Self {
        LogOddsParams {
            hit: 0.85,
            miss: -0.42,
            clamp_min: -100.0,
            clamp_max: 100.0,
            occupied_prob: 0.9,
            free_prob: 0.2,
        }
    }

    /// The parameters of a named preset.
    pub fn preset(p: LogOddsPreset) -> Self {
        match p {
            LogOddsPreset::Ucsd => LogOddsParams::ucsd(),
            LogOddsPreset::Ese650 => LogOddsParams::ese650(),
        }
    }

    /// Checks signs, ranges and the fixed-point limits; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        let all = [
            self.hit,
            self.miss,
            self.clamp_min,
            self.clamp_max,
            self.occupied_prob,
            self.free_prob,
        ];
        if all.iter().any(|v| !v.is_finite()) {
            return Err("map.log_odds: values must be finite".into());
        }
        if self.hit <= 0.0 || self.miss >= 0.0 {
            return Err("map.log_odds: need hit > 0 and miss < 0".into());
        }
        if self.clamp_min >= 0.0 || self.clamp_max <= 0.0 {
            return Err("map.log_odds: need clamp_min < 0 < clamp_max".into());
        }
        if self.clamp_min < -LOGODDS_MAX || self.clamp_max > LOGODDS_MAX {
            return Err(format!(
                "map.log_odds: clamp bounds must lie within +-{LOGODDS_MAX:.2} (fixed point)"
            ));
        }
        if !(0.0 < self.free_prob
            && self.free_prob < self.occupied_prob
            && self.occupied_prob < 1.0)
        {
            return Err("map.log_odds: need 0 < free_prob < occupied_prob < 1".into());
        }
        if self.occupied_prob < 0.5 || self.free_prob > 0.5 {
            return Err("map.log_odds: need free_prob <= 0.5 <= occupied_prob".into());
        }
        if to_fixed(self.hit) == 0 || to_fixed(self.miss) == 0 {
            return Err("map.log_odds: increments below the fixed-point resolution".into());
        }
        Ok(())
    }

    /// The fixed-point form used by the grid.
    pub fn to_fixed(&self) -> FixedLogOdds {
        FixedLogOdds {
            hit: to_fixed(self.hit),
            miss: to_fixed(self.miss),
            min: to_fixed(self.clamp_min),
            max: to_fixed(self.clamp_max),
            occupied: to_fixed(logit(self.occupied_prob)),
            free: to_fixed(logit(self.free_prob)),
        }
    }
}

/// [`LogOddsParams`] in fixed point (units of `1 / LOGODDS_SCALE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FixedLogOdds {
    /// Hit increment.
    pub hit: i16,
    /// Miss increment.
    pub miss: i16,
    /// Lower clamp bound.
    pub min: i16,
    /// Upper clamp bound.
    pub max: i16,
    /// Occupied when `value >= occupied`.
    pub occupied: i16,
    /// Free when `value <= free`.
    pub free: i16,
}

/// What a cell is, by the thresholds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CellState {
    /// Probability at or above the occupied threshold.
    Occupied,
    /// Probability at or below the free threshold.
    Free,
    /// In between, or never observed.
    Unknown,
}

impl FixedLogOdds {
    /// `value + delta`, clamped to the bounds.
    #[inline(always)]
    pub fn apply(&self, value: i16, delta: i16) -> i16 {
        (value as i32 + delta as i32).clamp(self.min as i32, self.max as i32) as i16
    }

    /// The state of a cell with this log-odds.
    #[inline(always)]
    pub fn classify(&self, value: i16) -> CellState {
        if value >= self.occupied {
            CellState::Occupied
        } else if value <= self.free {
            CellState::Free
        } else {
            CellState::Unknown
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigmoid_and_logit() {
        assert_eq!(sigmoid(0.0), 0.5);
        assert!((sigmoid(4f64.ln()) - 0.8).abs() < 1e-12);
        assert!((sigmoid(-4f64.ln()) - 0.2).abs() < 1e-12);
        assert!((logit(0.7) - 0.8473).abs() < 1e-4);
        for l in [-20.0, -3.0, -0.1, 0.0, 0.4, 5.0] {
            assert!((logit(sigmoid(l)) - l).abs() < 1e-9);
        }
        // the table agrees with the formula to f32 precision
        for l in [-100.0, -1.3862, 0.0, 0.85, 13.86] {
            let v = to_fixed(l);
            assert!((probability_fixed(v) as f64 - sigmoid(from_fixed(v))).abs() < 1e-6);
        }
        assert_eq!(
            probability_fixed(i16::MIN),
            sigmoid(from_fixed(i16::MIN)) as f32
        );
    }

    #[test]
    fn presets_match_the_seeds() {
        let u = LogOddsParams::ucsd();
        assert!((u.hit - 1.386294).abs() < 1e-6);
        assert!((u.clamp_max - 13.86294).abs() < 1e-5);
        u.validate().unwrap();
        let e = LogOddsParams::ese650();
        assert!((logit(0.7) - e.hit).abs() < 0.01);
        assert!((0.5 * logit(0.3) - e.miss).abs() < 0.01);
        e.validate().unwrap();
        let f = e.to_fixed();
        assert_eq!(f.max, 25600);
        assert_eq!(f.hit, 218);
        assert_eq!(f.occupied, to_fixed(logit(0.9)));
    }

    #[test]
    fn clamping() {
        let f = LogOddsParams::ucsd().to_fixed();
        let mut v = 0i16;
        for _ in 0..100 {
            v = f.apply(v, f.hit);
        }
        assert_eq!(v, f.max);
        assert!((from_fixed(v) - 10.0 * 4f64.ln()).abs() < 0.01);
        for _ in 0..5 {
            v = f.apply(v, f.miss);
        }
        assert_eq!(v, f.max + 5 * f.miss);
        for _ in 0..100 {
            v = f.apply(v, f.miss);
        }
        assert_eq!(v, f.min);
        // the integer path never wraps, even at the i16 edges
        let wide = FixedLogOdds {
            hit: i16::MAX,
            miss: i16::MIN,
            min: i16::MIN,
            max: i16::MAX,
            occupied: 1,
            free: -1,
        };
        assert_eq!(wide.apply(i16::MAX, i16::MAX), i16::MAX);
        assert_eq!(wide.apply(i16::MIN, i16::MIN), i16::MIN);
    }

    #[test]
    fn thresholds() {
        let f = LogOddsParams::ucsd().to_fixed();
        assert_eq!(f.classify(0), CellState::Unknown);
        assert_eq!(f.classify(f.hit), CellState::Occupied);
        assert_eq!(f.classify(f.miss), CellState::Free);
        let e = LogOddsParams::ese650().to_fixed();
        // ESE650: two hits (1.70) are not yet 0.9 (2.197); three are
        assert_eq!(e.classify(2 * e.hit), CellState::Unknown);
        assert_eq!(e.classify(3 * e.hit), CellState::Occupied);
        assert_eq!(e.classify(4 * e.miss), CellState::Free);
    }

    #[test]
    fn validation() {
        let mut p = LogOddsParams::ucsd();
        p.hit = -1.0;
        assert!(p.validate().is_err());
        let mut p = LogOddsParams::ucsd();
        p.clamp_max = 200.0;
        assert!(p.validate().is_err());
        let mut p = LogOddsParams::ucsd();
        p.free_prob = 0.9;
        assert!(p.validate().is_err());
    }
}
