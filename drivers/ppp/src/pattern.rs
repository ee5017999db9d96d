//! The pseudo-periodic encoded pattern (PPP): a square lattice of square dots at `period_um`,
//! with a maximum-length LFSR code written by removing whole dot lines.
//!
//! Layout (the published "Megarena"-style design): the n-bit m-sequence (length 2^n - 1) is
//! extended by its first n - 1 bits so that every n-bit window occurs exactly once, then
//! expanded to 3 lattice lines per code bit: line index `3k + 1` carries code bit `k`, lines
//! `3k` and `3k + 2` are always on. The same sequence codes columns (along X) and rows
//! (along Y). Dot `(c, r)` is present iff `line(c) && line(r)` and not `(c ≡ 0 and r ≡ 0 mod 3)`:
//! that always-missing corner dot of each 3x3 cell fixes the orientation and the mod-3 phase.
//!
//! Coordinates: pattern coordinates (X, Y) in µm, dot `(c, r)` centred at `(c·p, r·p)`.
//! The stage position (x, y) is the pattern point at the image centre minus `origin_um`.
use serde::{Deserialize, Serialize};

/// Pattern parameters (serde, e.g. a `[pattern]` TOML table). Defaults: the paper's 4 µm
/// pattern with a 10-bit code (3096 periods = 12.384 mm per axis).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PatternConfig {
    /// Lattice period, µm.
    pub period_um: f64,
    /// LFSR length n (code of 2^n - 1 + n - 1 bits, 3 lattice lines per bit).
    pub code_bits: u32,
    /// Dot side as a fraction of the period.
    pub dot_fraction: f64,
    /// Pattern coordinates (X, Y) of stage position (0, 0), µm. The default centres the
    /// 9.5 mm x 4.2 mm stage range on the coded area with ≥ 1.4 mm of margin.
    pub origin_um: [f64; 2],
}

impl Default for PatternConfig {
    fn default() -> Self {
        Self {
            period_um: 4.0,
            code_bits: 10,
            dot_fraction: 0.5,
            origin_um: [1440.0, 1440.0],
        }
    }
}

/// Errors in a pattern definition.
#[derive(Debug, thiserror::Error)]
pub enum PatternError {
    #[error("code_bits must be in 4..=16, got {0}")]
    /// Code length out of range.
    CodeBits(u32),
    #[error("period_um must be positive and finite, got {0}")]
    /// Period not positive and finite.
    Period(f64),
    #[error("dot_fraction must be in [0.2, 0.8], got {0}")]
    /// Dot fraction out of range.
    DotFraction(f64),
}

/// Feedback taps (1-based, Fibonacci form, the highest is n) of a primitive polynomial per n.
fn taps(n: u32) -> &'static [u32] {
    match n {
        4 => &[4, 3],
        5 => &[5, 3],
        6 => &[6, 5],
        7 => &[7, 6],
        8 => &[8, 6, 5, 4],
        9 => &[9, 5],
        10 => &[10, 7],
        11 => &[11, 9],
        12 => &[12, 11, 10, 4],
        13 => &[13, 12, 11, 8],
        14 => &[14, 13, 12, 2],
        15 => &[15, 14],
        16 => &[16, 15, 13, 4],
        _ => &[],
    }
}

/// The maximum-length sequence of an n-bit Fibonacci LFSR (length 2^n - 1), bits 0/1.
pub fn m_sequence(n: u32) -> Vec<u8> {
    let t = taps(n);
    let len = (1usize << n) - 1;
    let mut state: u32 = 1;
    let mut out = Vec::with_capacity(len);
    for _ in 0..len {
        out.push((state & 1) as u8);
        let fb = t.iter().fold(0u32, |acc, &k| acc ^ (state >> (n - k)));
        state = (state >> 1) | ((fb & 1) << (n - 1));
    }
    out
}

/// A pattern instance: config plus the expanded code.
#[derive(Debug, Clone)]
pub struct Pattern {
    /// The definition it was built from.
    pub config: PatternConfig,
    /// Code bits (m-sequence extended by n - 1 bits): every n-bit window is unique.
    pub code: Vec<u8>,
    /// Line flags per lattice index (3 per code bit): 1 = the line carries dots.
    lines: Vec<u8>,
    /// Whether the corner dot of each 3x3 cell is removed (false only for the control grid).
    corners: bool,
}

impl Pattern {
    /// Expands and checks a pattern definition.
    pub fn new(config: PatternConfig) -> Result<Self, PatternError> {
        if !(4..=16).contains(&config.code_bits) {
            return Err(PatternError::CodeBits(config.code_bits));
        }
        if !(config.period_um.is_finite() && config.period_um > 0.0) {
            return Err(PatternError::Period(config.period_um));
        }
        if !(0.2..=0.8).contains(&config.dot_fraction) {
            return Err(PatternError::DotFraction(config.dot_fraction));
        }
        let n = config.code_bits as usize;
        let mut code = m_sequence(config.code_bits);
        let head: Vec<u8> = code[..n - 1].to_vec();
        code.extend_from_slice(&head);
        let lines = (0..3 * code.len())
            .map(|c| if c % 3 == 1 { code[c / 3] } else { 1 })
            .collect();
        Ok(Self {
            config,
            code,
            lines,
            corners: true,
        })
    }

    /// Control pattern: the same lattice with every dot present (no code, no corner marks).
    /// It measures the fine phase without the coded-dot bias and must never decode absolutely.
    pub fn full_grid(config: PatternConfig) -> Result<Self, PatternError> {
        let mut p = Self::new(config)?;
        p.lines.iter_mut().for_each(|l| *l = 1);
        p.corners = false;
        Ok(p)
    }

    /// Whether the corner dot of each 3x3 cell is removed.
    pub fn has_corner_marks(&self) -> bool {
        self.corners
    }

    /// Number of lattice lines per axis.
    pub fn lines(&self) -> usize {
        self.lines.len()
    }

    /// Pattern extent per axis, µm (dot centres at 0 .. (lines - 1)·period).
    pub fn extent_um(&self) -> f64 {
        self.lines.len() as f64 * self.config.period_um
    }

    /// Whether lattice line `c` carries dots (false outside the pattern).
    #[inline]
    pub fn line_on(&self, c: i64) -> bool {
        c >= 0 && (c as usize) < self.lines.len() && self.lines[c as usize] == 1
    }

    /// Whether dot (c, r) is present.
    pub fn dot(&self, c: i64, r: i64) -> bool {
        self.line_on(c)
            && self.line_on(r)
            && !(self.corners && c.rem_euclid(3) == 0 && r.rem_euclid(3) == 0)
    }

    /// Line flags as a slice (index = lattice line).
    pub fn line_flags(&self) -> &[u8] {
        &self.lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn m_sequences_are_maximal_and_windows_unique() {
        for n in 4..=12u32 {
            let p = Pattern::new(PatternConfig {
                code_bits: n,
                ..Default::default()
            })
            .unwrap();
            let len = (1usize << n) - 1;
            let ones = p.code[..len].iter().filter(|&&b| b == 1).count();
            assert_eq!(
                ones,
                1 << (n - 1),
                "n = {n}: an m-sequence has 2^(n-1) ones"
            );
            let mut seen = std::collections::HashSet::new();
            for w in p.code.windows(n as usize) {
                assert!(seen.insert(w.to_vec()), "n = {n}: repeated window");
            }
            assert_eq!(seen.len(), len);
        }
    }

    #[test]
    fn default_pattern_covers_the_stage_range_with_margin() {
        let p = Pattern::new(PatternConfig::default()).unwrap();
        assert_eq!(p.lines(), 3096);
        let [ox, oy] = p.config.origin_um;
        // Half field of view of the nominal camera (1024 x 768 px at 0.465 µm/px) at 20 mrad.
        let (hw, hh) = (
            512.0 * 0.465 + 384.0 * 0.465 * 0.02,
            384.0 * 0.465 + 512.0 * 0.465 * 0.02,
        );
        assert!(ox - hw > 0.0 && ox + 9500.0 + hw < p.extent_um());
        assert!(oy - hh > 0.0 && oy + 4200.0 + hh < p.extent_um());
    }

    #[test]
    fn dot_rule_removes_corner_and_code_lines() {
        let p = Pattern::new(PatternConfig::default()).unwrap();
        assert!(!p.dot(0, 0) && !p.dot(3, 6));
        assert!(p.dot(2, 2) && p.dot(0, 2));
        for k in 0..50i64 {
            assert_eq!(p.dot(3 * k + 1, 2), p.code[k as usize] == 1);
            assert_eq!(p.dot(2, 3 * k + 1), p.code[k as usize] == 1);
        }
        assert!(!p.dot(-1, 5) && !p.dot(5, p.lines() as i64));
    }
}
