//! Images and plots: occupancy maps, trajectories, reports.
//!
//! Text is drawn with the DejaVu Sans font committed under `assets/`, registered once with
//! plotters' `ab_glyph` backend by [`ensure_font`], so pictures look the same everywhere.

pub mod map_image;

/// The committed DejaVu Sans font.
pub static FONT_TTF: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

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
