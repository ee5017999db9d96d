//! csmetro-ppp: the pseudo-periodic encoded pattern (PPP) that the camera sees on the stage.
//!
//! - [`pattern`]: the LFSR-coded dot lattice ([`PatternConfig`], [`Pattern`]).
//! - [`render`]: simulated camera frames ([`Optics`], [`Pose`], [`render::render`]).
//! - [`decode`]: absolute (x, y, θ) from a frame, with quality figures and rejection
//!   ([`Decoder`], [`DecodeConfig`], [`DecodeResult`]).
//! - [`io`]: 8/16-bit grayscale PNG frames.
//!
//! Sign convention (shared by renderer and decoder): the stage position (x_um, y_um) is the
//! pattern point imaged at the image centre, relative to `PatternConfig::origin_um`; pattern X
//! runs along image columns (+u, right), Y along image rows (+v, down) at θ = 0, and a pixel
//! offset d from the centre sees the pattern point `origin + (x, y) + s·R(θ)·d`.
pub mod decode;
pub mod io;
pub mod pattern;
pub mod render;
pub mod selftest;

pub use decode::{DecodeConfig, DecodeResult, Decoder, Quality};
pub use pattern::{Pattern, PatternConfig};
pub use render::{Optics, Pose};

use serde::{Deserialize, Serialize};

/// Everything a PPP setup needs, as one TOML document with `[pattern]`, `[optics]` and an
/// optional `[decode]` table (without it the decoder takes its scale from the optics).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PppConfig {
    pub pattern: PatternConfig,
    pub optics: Optics,
    pub decode: Option<DecodeConfig>,
}

impl PppConfig {
    /// The pattern, checked.
    pub fn pattern(&self) -> Result<Pattern, pattern::PatternError> {
        Pattern::new(self.pattern.clone())
    }
    /// A decoder for this pattern and optics.
    pub fn decoder(&self) -> Result<Decoder, pattern::PatternError> {
        let pattern = self.pattern()?;
        let cfg = self
            .decode
            .clone()
            .unwrap_or_else(|| DecodeConfig::for_optics(&pattern, &self.optics));
        Ok(Decoder::new(pattern, cfg))
    }
}
