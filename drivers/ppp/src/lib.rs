#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]
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
