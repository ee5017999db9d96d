#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]
// Modules are private; the curated list below is the crate's API. `selftest` stays a public
// namespace of figures (`selftest::timing`, `selftest::precision`, ...).
mod decode;
mod io;
mod pattern;
mod render;
pub mod selftest;

pub use decode::{DecodeConfig, DecodeResult, Decoder, Quality};
pub use io::{png_from_bytes, read_png, write_png, IoError, MAX_FRAME_PIXELS, MAX_FRAME_SIDE};
pub use pattern::{m_sequence, Pattern, PatternConfig, PatternError};
pub use render::{render, render_coverage, Optics, Pose};

use serde::{Deserialize, Serialize};

/// Everything a PPP setup needs, as one TOML document with `[pattern]`, `[optics]` and an
/// optional `[decode]` table (without it the decoder takes its scale from the optics).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PppConfig {
    /// The pattern on the stage.
    pub pattern: PatternConfig,
    /// The camera optics.
    pub optics: Optics,
    /// Decoder thresholds; `None`: defaults scaled from the optics.
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
