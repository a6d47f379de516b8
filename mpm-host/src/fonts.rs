//! The font of every figure: DejaVu Sans compiled into the program (crate `dejavu`) and
//! registered with plotters' `ab_glyph` backend, so that no figure of `mpm` or the harness
//! depends on the fonts a machine has installed.

use plotters::style::FontStyle;
use std::sync::Once;

/// Register the embedded DejaVu Sans as `sans-serif` (normal and bold). Idempotent.
pub fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The embedded fonts are valid TrueType files: registration cannot fail.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}
