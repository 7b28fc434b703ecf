//! # pfslam-viz — what a pfslam run looks like
//!
//! Pictures and records of the SLAM core's results, kept out of the core so it builds
//! without a plotting or image-encoding stack:
//! - [`map_image`]: occupancy maps as PNG (with trajectories, scans, the binary map);
//! - [`plot`]: trajectories plotted against each other (dead reckoning, SLAM, truth);
//! - [`record`]: a run as MCAP with Foxglove schemas (the map over time, scans, poses,
//!   particles), for Foxglove Studio or any MCAP reader.
//!
//! Text is drawn with the DejaVu Sans font committed under `assets/`, registered once with
//! plotters' `ab_glyph` backend by [`ensure_font`], so pictures look the same everywhere.
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod map_image;

/// The committed DejaVu Sans font.
pub static FONT_TTF: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// The family name under which [`FONT_TTF`] is registered with plotters.
pub const FONT_FAMILY: &str = "sans-serif";

/// Registers the committed font with plotters (idempotent, thread-safe). Call before drawing
/// any text with plotters.
pub fn ensure_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // A font that fails to parse would be a build-time asset bug; plotters then draws no
        // text, which the picture tests would show.
        let _ = plotters::style::register_font(
            FONT_FAMILY,
            plotters::style::FontStyle::Normal,
            FONT_TTF,
        );
    });
}

pub mod plot;
pub mod record;

/// Standard base64 with padding (RFC 4648).
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(ALPHABET[(n >> (18 - 6 * k)) as usize & 63]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_the_rfc_vectors() {
        for (plain, encoded) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(plain.as_bytes()), encoded);
        }
    }
}
