//! A third generator, of ISO 230-2 tables only, written apart from `gapgen.rs` and from the
//! simulator (`csmetro_sim`): its own random numbers (PCG-XSH-RR 32 and the Marsaglia polar
//! method), its own notion of a test (targets `(i - 1)·p + r_i` with a random r_i per target as
//! ISO 230-2 asks, a linear cycle: forward up, backward down, a dwell per target and at the
//! reversals) and its own effects: a reversal (backlash), a drift between cycles (linear or
//! settling, either continuous in time or stepping once per cycle), a large repeatable
//! position-dependent error (smooth or irregular from target to target), a scale error, noise.
#![allow(dead_code, unreachable_pub)]

/// PCG-XSH-RR with 64-bit state, 32-bit output.
pub struct Pcg {
    state: u64,
    inc: u64,
    spare: Option<f64>,
}

impl Pcg {
    pub fn new(seed: u64) -> Self {
        let mut p = Pcg {
            state: 0,
            inc: (seed << 1) | 1,
            spare: None,
        };
        p.next_u32();
        p.state = p.state.wrapping_add(seed ^ 0x853c_49e6_748f_ea9b);
        p.next_u32();
        p
    }
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xs = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xs.rotate_right(rot)
    }
    /// Uniform in [0, 1) from two outputs.
    pub fn uniform(&mut self) -> f64 {
        let hi = u64::from(self.next_u32() >> 5);
        let lo = u64::from(self.next_u32() >> 6);
        ((hi << 26) | lo) as f64 / (1u64 << 53) as f64
    }
    pub fn between(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    pub fn int(&mut self, lo: usize, hi_inclusive: usize) -> usize {
        lo + (self.next_u32() as usize) % (hi_inclusive - lo + 1)
    }
    pub fn coin(&mut self) -> bool {
        self.next_u32() & 0x8000_0000 != 0
    }
    /// Standard normal, Marsaglia polar.
    pub fn gauss(&mut self) -> f64 {
        if let Some(s) = self.spare.take() {
            return s;
        }
        loop {
            let u = 2.0 * self.uniform() - 1.0;
            let v = 2.0 * self.uniform() - 1.0;
            let s = u * u + v * v;
            if s > 0.0 && s < 1.0 {
                let m = (-2.0 * s.ln() / s).sqrt();
                self.spare = Some(v * m);
                return u * m;
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DriftShape {
    None,
    /// µm per cycle.
    Linear(f64),
    /// Total settling amplitude (µm) and time constant in cycles: a·(1 − e^(−t/τ)).
    Settling(f64, f64),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PositionError {
    None,
    /// A smooth curve (a few sinusoids with periods 0.3–2 spans), RMS µm; it has whatever
    /// linear part its sinusoids give it.
    Smooth(f64),
    /// The same smooth curve with its least-squares line over the targets removed (a test table
    /// whose reference was aligned to the axis, as the real MUTS tables are).
    SmoothNoLine(f64),
    /// Independent from target to target (a period far below the spacing), RMS µm.
    Irregular(f64),
}

#[derive(Debug, Clone, Copy)]
pub struct IsoSpec {
    pub targets: usize,
    pub cycles: usize,
    /// Target range, µm (first target at `start_um`).
    pub start_um: f64,
    pub span_um: f64,
    pub noise_um: f64,
    /// x̄↑ − x̄↓ the stage has, µm.
    pub backlash_um: f64,
    pub drift: DriftShape,
    /// Drift acts at each sample's time (true) or steps once per cycle (false).
    pub drift_continuous: bool,
    pub position: PositionError,
    pub scale_ppm: f64,
    /// A periodic error (period µm, amplitude µm, phase rad), the same in both directions.
    pub periodic: Option<(f64, f64, f64)>,
    /// Seconds at each target (move + dwell + reading) and at each reversal.
    pub dwell_s: f64,
    pub reversal_s: f64,
}

impl Default for IsoSpec {
    fn default() -> Self {
        IsoSpec {
            targets: 9,
            cycles: 5,
            start_um: -20000.0,
            span_um: 40000.0,
            noise_um: 1.0,
            backlash_um: 0.0,
            drift: DriftShape::None,
            drift_continuous: true,
            position: PositionError::None,
            scale_ppm: 0.0,
            periodic: None,
            dwell_s: 12.0,
            reversal_s: 30.0,
        }
    }
}

/// One reading of the table.
#[derive(Debug, Clone, Copy)]
pub struct Reading {
    pub cycle: usize,
    pub up: bool,
    pub target_um: f64,
    pub deviation_um: f64,
    pub time_s: f64,
}

/// A table and the truth it was made from.
pub struct IsoTable {
    pub readings: Vec<Reading>,
    pub targets: Vec<f64>,
    pub spec: IsoSpec,
}

fn drift_at(shape: DriftShape, t_cycles: f64) -> f64 {
    match shape {
        DriftShape::None => 0.0,
        DriftShape::Linear(r) => r * t_cycles,
        DriftShape::Settling(a, tau) => a * (1.0 - (-t_cycles / tau).exp()),
    }
}

pub fn make(spec: IsoSpec, seed: u64) -> IsoTable {
    let mut g = Pcg::new(seed);
    let n = spec.targets;
    let p = spec.span_um / (n - 1) as f64;
    // ISO 230-2: P_i = (i − 1)·p + r_i, r_i random (here within ±p/5), ends kept in the range.
    let targets: Vec<f64> = (0..n)
        .map(|i| {
            let r = if i == 0 || i == n - 1 {
                0.0
            } else {
                g.between(-0.2, 0.2) * p
            };
            ((spec.start_um + i as f64 * p + r) * 1000.0).round() / 1000.0
        })
        .collect();
    // Position-dependent error at each target.
    let smooth = |g: &mut Pcg| -> Vec<f64> {
        let waves: Vec<(f64, f64, f64)> = (0..3)
            .map(|_| {
                (
                    g.between(0.3, 2.0) * spec.span_um,
                    g.between(0.0, std::f64::consts::TAU),
                    g.between(0.3, 1.0),
                )
            })
            .collect();
        targets
            .iter()
            .map(|&x| {
                waves
                    .iter()
                    .map(|(per, ph, a)| a * (std::f64::consts::TAU * x / per + ph).sin())
                    .sum()
            })
            .collect()
    };
    let scaled = |v: Vec<f64>, rms: f64| -> Vec<f64> {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let r = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        v.iter().map(|x| (x - m) / r.max(1e-12) * rms).collect()
    };
    let pos_err: Vec<f64> = match spec.position {
        PositionError::None => vec![0.0; n],
        PositionError::Smooth(rms) => scaled(smooth(&mut g), rms),
        PositionError::SmoothNoLine(rms) => {
            let v = smooth(&mut g);
            let mx = targets.iter().sum::<f64>() / n as f64;
            let my = v.iter().sum::<f64>() / n as f64;
            let sxx: f64 = targets.iter().map(|x| (x - mx).powi(2)).sum();
            let k = targets
                .iter()
                .zip(&v)
                .map(|(x, y)| (x - mx) * (y - my))
                .sum::<f64>()
                / sxx;
            let d: Vec<f64> = targets
                .iter()
                .zip(&v)
                .map(|(x, y)| y - my - k * (x - mx))
                .collect();
            scaled(d, rms)
        }
        PositionError::Irregular(rms) => scaled((0..n).map(|_| g.gauss()).collect(), rms),
    };
    let cycle_s = 2.0 * n as f64 * spec.dwell_s + 2.0 * spec.reversal_s;
    let mut t = 0.0;
    let mut readings = Vec::new();
    for c in 0..spec.cycles {
        let cycle_mid = (c as f64 + 0.5) * cycle_s;
        for up in [true, false] {
            let order: Vec<usize> = if up {
                (0..n).collect()
            } else {
                (0..n).rev().collect()
            };
            for i in order {
                t += spec.dwell_s;
                let x = targets[i];
                let when = if spec.drift_continuous { t } else { cycle_mid };
                let wave = spec.periodic.map_or(0.0, |(per, amp, ph)| {
                    amp * (std::f64::consts::TAU * x / per + ph).sin()
                });
                let dev = pos_err[i]
                    + wave
                    + spec.scale_ppm * 1e-6 * x
                    + if up { 0.5 } else { -0.5 } * spec.backlash_um
                    + drift_at(spec.drift, when / cycle_s)
                    + spec.noise_um * g.gauss();
                readings.push(Reading {
                    cycle: c + 1,
                    up,
                    target_um: x,
                    deviation_um: dev,
                    time_s: t,
                });
            }
            t += spec.reversal_s;
        }
    }
    IsoTable {
        readings,
        targets,
        spec,
    }
}

impl IsoTable {
    /// The ISO 230-2 export csmetro reads.
    pub fn csv(&self, with_time: bool) -> String {
        let mut s = String::from("cycle,direction,target_um,deviation_um");
        s.push_str(if with_time { ",time_s\n" } else { "\n" });
        for r in &self.readings {
            s.push_str(&format!(
                "{},{},{:.3},{:.4}",
                r.cycle,
                if r.up { "up" } else { "down" },
                r.target_um,
                r.deviation_um
            ));
            if with_time {
                s.push_str(&format!(",{:.1}", r.time_s));
            }
            s.push('\n');
        }
        s
    }

    /// The true drift per cycle, µm (linear) or its mean over the test (settling).
    pub fn drift_per_cycle(&self) -> f64 {
        let c = self.spec.cycles as f64;
        (drift_at(self.spec.drift, c) - drift_at(self.spec.drift, 0.0)) / c
    }
}
