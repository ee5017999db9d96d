//! Decode-time probe for profiling: decodes one nominal frame many times.
use csmetro_ppp::{render, DecodeConfig, Decoder, Optics, Pattern, PatternConfig, Pose};
fn main() {
    let pat = Pattern::new(PatternConfig::default()).unwrap();
    let optics = Optics::default();
    let dec = Decoder::new(pat.clone(), DecodeConfig::for_optics(&pat, &optics));
    let f = render(&pat, &optics, Pose::new(1000.0, 2000.0, 3.0), 9);
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(50);
    let mut ts: Vec<f64> = (0..n).map(|_| dec.decode(&f).decode_ms).collect();
    ts.sort_by(f64::total_cmp);
    println!("decode median {:.3} ms min {:.3} ms", ts[n / 2], ts[0]);
}
