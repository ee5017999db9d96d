use super::*;
use crate::pattern::PatternConfig;

#[test]
fn code_match_finds_the_window_and_reports_errors_and_margin() {
    let code = Pattern::new(PatternConfig::default()).unwrap().code;
    let mut bits: Vec<Option<u8>> = code[500..529].iter().map(|&b| Some(b)).collect();
    let m = match_code(&code, &bits);
    assert_eq!((m.offset, m.errors, m.reliable), (500, 0, 29));
    // Nominal frames show ≥ 28 code lines along y: every such window is ≥ 4 bits from any
    // other, so an error-free read always clears the margin of 3.
    for off in 0..=code.len() - 28 {
        let w: Vec<Option<u8>> = code[off..off + 28].iter().map(|&b| Some(b)).collect();
        let m = match_code(&code, &w);
        assert_eq!((m.offset, m.errors), (off as i64, 0));
        assert!(m.margin >= 4, "window at {off}: margin {}", m.margin);
    }
    bits[7] = Some(1 - bits[7].unwrap());
    bits[20] = None;
    let m = match_code(&code, &bits);
    assert_eq!((m.offset, m.errors, m.reliable), (500, 1, 28));
    // A code-free line pattern (all ones) matches nowhere: the run of ones is at most n.
    let m = match_code(&code, &[Some(1); 20]);
    assert!(m.errors >= 5, "{}", m.errors);
}

#[test]
fn wrap_is_into_minus_pi_pi() {
    for a in [-7.0, -3.2, -0.1, 0.0, 3.1, 3.2, 10.0] {
        let w = wrap(a);
        assert!((-std::f64::consts::PI..std::f64::consts::PI).contains(&w));
        assert!(((a - w) / std::f64::consts::TAU).fract().abs() < 1e-12);
    }
}
