//! A second, independent generator of gap-diagnosis data, written from the prediction contract
//! (target + Σ deviations of the effects acting on the sample + a constant offset per line and
//! component) and the effect catalogue's formulas — not from `csmetro_sim`'s model code or
//! `csmetro::gap::data::simulate_campaign`. Its own random numbers (SplitMix64, Box–Muller), its
//! own layouts (the contract's 3 x lines + 1 y line with random targets, ISO 230-2 fixed targets,
//! single lines) and its own notion of an effect's visible peak.
#![allow(dead_code, unreachable_pub)]

use csmetro::gap::data::Sample;
use csmetro_sim::AxisId;

pub const TRAVEL_X: [f64; 2] = [0.0, 9500.0];
pub const TRAVEL_Y: [f64; 2] = [0.0, 4200.0];

/// SplitMix64 with Box–Muller normals.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed ^ 0x9e37_79b9_7f4a_7c15)
    }
    pub fn u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    pub fn normal(&mut self) -> f64 {
        let u1 = self.unit().max(1e-300);
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
    pub fn sign(&mut self) -> f64 {
        if self.u64() & 1 == 0 {
            1.0
        } else {
            -1.0
        }
    }
    pub fn pick(&mut self, n: usize) -> usize {
        (self.u64() % n as u64) as usize
    }
}

/// An effect as the catalogue writes it (`amp` multiplies the whole deviation).
#[derive(Debug, Clone)]
pub enum Eff {
    Scale {
        axis: AxisId,
        ppm: f64,
    },
    Cyclic {
        axis: AxisId,
        period_um: f64,
        cos_um: Vec<f64>,
        sin_um: Vec<f64>,
    },
    Backlash {
        axis: AxisId,
        reversal_um: f64,
    },
    Hysteresis {
        axis: AxisId,
        b0_um: f64,
        b1_um: f64,
    },
    /// Legendre P2, P3, ... of the moving axis' position, in the other component.
    Straightness {
        axis: AxisId,
        coef_um: Vec<f64>,
    },
    /// e_axis = -(y0 + y1 s)·1e-6·(other position).
    Yaw {
        axis: AxisId,
        urad: [f64; 2],
    },
    /// e_x = α·y while y moves.
    Squareness {
        urad: f64,
    },
    CamRotation {
        urad: f64,
    },
    CamScale {
        ppm: f64,
    },
    Thermal {
        comp: AxisId,
        amp_um: f64,
        tau_s: f64,
        rate_um_per_h: f64,
    },
    // Outside the library:
    /// A Gaussian bump over the moving axis' position.
    Defect {
        axis: AxisId,
        on_other: bool,
        center_um: f64,
        height_um: f64,
        width_um: f64,
    },
    /// A sinusoid in time on one component (a drift of another shape).
    TimeSine {
        comp: AxisId,
        amp_um: f64,
        period_s: f64,
        phase: f64,
    },
    /// A periodic error of a period the library does not have.
    Periodic {
        axis: AxisId,
        period_um: f64,
        amp_um: f64,
        phase: f64,
    },
    /// A smooth sensor nonlinearity over the moving axis' travel, no linear part.
    Nonlin {
        axis: AxisId,
        amp_um: f64,
    },
}

fn legendre(k: usize, s: f64) -> f64 {
    let (mut p0, mut p1) = (1.0, s);
    if k == 0 {
        return 1.0;
    }
    for n in 1..k {
        let n = n as f64;
        let p2 = ((2.0 * n + 1.0) * s * p1 - n * p0) / (n + 1.0);
        p0 = p1;
        p1 = p2;
    }
    p1
}

pub struct Ctx {
    pub moving: AxisId,
    pub dir: f64,
    pub x: f64,
    pub y: f64,
    pub t: f64,
    pub travel: [[f64; 2]; 2],
}

impl Ctx {
    fn pos(&self, a: AxisId) -> f64 {
        match a {
            AxisId::X => self.x,
            AxisId::Y => self.y,
        }
    }
    fn s(&self, a: AxisId) -> f64 {
        let tr = self.travel[a as usize];
        2.0 * (self.pos(a) - tr[0]) / (tr[1] - tr[0]) - 1.0
    }
}

fn put(a: AxisId, v: f64) -> [f64; 2] {
    match a {
        AxisId::X => [v, 0.0],
        AxisId::Y => [0.0, v],
    }
}

fn other(a: AxisId) -> AxisId {
    match a {
        AxisId::X => AxisId::Y,
        AxisId::Y => AxisId::X,
    }
}

impl Eff {
    /// (kind, axis label) as the diagnosis names the group; None outside the library.
    pub fn label(&self) -> Option<(&'static str, &'static str)> {
        let ax = |a: &AxisId| if *a == AxisId::X { "x" } else { "y" };
        Some(match self {
            Eff::Scale { axis, .. } => ("scale", ax(axis)),
            Eff::Cyclic {
                axis, period_um, ..
            } => {
                if (*period_um - 400.0).abs() < 1e-6 {
                    ("leadscrew_cyclic", ax(axis))
                } else {
                    ("motor_cyclic", ax(axis))
                }
            }
            Eff::Backlash { axis, .. } => ("backlash", ax(axis)),
            Eff::Hysteresis { axis, .. } => ("hysteresis", ax(axis)),
            Eff::Straightness { axis, .. } => ("straightness", ax(axis)),
            Eff::Yaw { axis, .. } => ("yaw_abbe", ax(axis)),
            Eff::Squareness { .. } => ("squareness", "y"),
            Eff::CamRotation { .. } => ("camera_rotation", "-"),
            Eff::CamScale { .. } => ("camera_scale", "-"),
            Eff::Thermal { comp, .. } => ("thermal_drift", ax(comp)),
            _ => return None,
        })
    }

    /// Deviation (x, y) of a sample, zero when the effect does not act on it.
    pub fn dev(&self, c: &Ctx) -> [f64; 2] {
        let z = [0.0, 0.0];
        match self {
            Eff::Scale { axis, ppm } if c.moving == *axis => put(*axis, ppm * 1e-6 * c.pos(*axis)),
            Eff::Cyclic {
                axis,
                period_um,
                cos_um,
                sin_um,
            } if c.moving == *axis => {
                let w = 2.0 * std::f64::consts::PI * c.pos(*axis) / period_um;
                let v: f64 = cos_um
                    .iter()
                    .zip(sin_um)
                    .enumerate()
                    .map(|(h, (a, b))| {
                        let k = (h + 1) as f64;
                        a * (k * w).cos() + b * (k * w).sin()
                    })
                    .sum();
                put(*axis, v)
            }
            Eff::Backlash { axis, reversal_um } if c.moving == *axis => {
                put(*axis, 0.5 * reversal_um * c.dir)
            }
            Eff::Hysteresis { axis, b0_um, b1_um } if c.moving == *axis => {
                put(*axis, 0.5 * (b0_um + b1_um * c.s(*axis)) * c.dir)
            }
            Eff::Straightness { axis, coef_um } if c.moving == *axis => {
                let s = c.s(*axis);
                let v = coef_um
                    .iter()
                    .enumerate()
                    .map(|(i, k)| k * legendre(i + 2, s))
                    .sum();
                put(other(*axis), v)
            }
            Eff::Yaw { axis, urad } if c.moving == *axis => {
                let s = c.s(*axis);
                put(*axis, -(urad[0] + urad[1] * s) * 1e-6 * c.pos(other(*axis)))
            }
            Eff::Squareness { urad } if c.moving == AxisId::Y => [urad * 1e-6 * c.y, 0.0],
            Eff::CamRotation { urad } => [-urad * 1e-6 * c.y, urad * 1e-6 * c.x],
            Eff::CamScale { ppm } => [ppm * 1e-6 * c.x, ppm * 1e-6 * c.y],
            Eff::Thermal {
                comp,
                amp_um,
                tau_s,
                rate_um_per_h,
            } => put(
                *comp,
                amp_um * (1.0 - (-c.t / tau_s).exp()) + rate_um_per_h * c.t / 3600.0,
            ),
            Eff::Defect {
                axis,
                on_other,
                center_um,
                height_um,
                width_um,
            } if c.moving == *axis => {
                let u = (c.pos(*axis) - center_um) / width_um;
                let comp = if *on_other { other(*axis) } else { *axis };
                put(comp, height_um * (-0.5 * u * u).exp())
            }
            Eff::TimeSine {
                comp,
                amp_um,
                period_s,
                phase,
            } => put(
                *comp,
                amp_um * (2.0 * std::f64::consts::PI * c.t / period_s + phase).sin(),
            ),
            Eff::Periodic {
                axis,
                period_um,
                amp_um,
                phase,
            } if c.moving == *axis => put(
                *axis,
                amp_um * (2.0 * std::f64::consts::PI * c.pos(*axis) / period_um + phase).sin(),
            ),
            Eff::Nonlin { axis, amp_um } if c.moving == *axis => {
                // A bow and an S over the travel (what a triangulation sensor's characteristic
                // leaves once its linear part, the scale, is taken out), within ±amp.
                let s = c.s(*axis);
                let p3 = 0.5 * (5.0 * s * s * s - 3.0 * s);
                let v = amp_um * (0.6 * (std::f64::consts::PI * s).cos() + 0.4 * p3);
                put(*axis, v)
            }
            _ => z,
        }
    }

    /// The same effect with its deviation multiplied by f.
    pub fn times(&self, f: f64) -> Eff {
        let v = |x: &[f64]| x.iter().map(|c| c * f).collect::<Vec<_>>();
        match self.clone() {
            Eff::Scale { axis, ppm } => Eff::Scale { axis, ppm: ppm * f },
            Eff::Cyclic {
                axis,
                period_um,
                cos_um,
                sin_um,
            } => Eff::Cyclic {
                axis,
                period_um,
                cos_um: v(&cos_um),
                sin_um: v(&sin_um),
            },
            Eff::Backlash { axis, reversal_um } => Eff::Backlash {
                axis,
                reversal_um: reversal_um * f,
            },
            Eff::Hysteresis { axis, b0_um, b1_um } => Eff::Hysteresis {
                axis,
                b0_um: b0_um * f,
                b1_um: b1_um * f,
            },
            Eff::Straightness { axis, coef_um } => Eff::Straightness {
                axis,
                coef_um: v(&coef_um),
            },
            Eff::Yaw { axis, urad } => Eff::Yaw {
                axis,
                urad: [urad[0] * f, urad[1] * f],
            },
            Eff::Squareness { urad } => Eff::Squareness { urad: urad * f },
            Eff::CamRotation { urad } => Eff::CamRotation { urad: urad * f },
            Eff::CamScale { ppm } => Eff::CamScale { ppm: ppm * f },
            Eff::Thermal {
                comp,
                amp_um,
                tau_s,
                rate_um_per_h,
            } => Eff::Thermal {
                comp,
                amp_um: amp_um * f,
                tau_s,
                rate_um_per_h: rate_um_per_h * f,
            },
            Eff::Defect {
                axis,
                on_other,
                center_um,
                height_um,
                width_um,
            } => Eff::Defect {
                axis,
                on_other,
                center_um,
                height_um: height_um * f,
                width_um,
            },
            Eff::TimeSine {
                comp,
                amp_um,
                period_s,
                phase,
            } => Eff::TimeSine {
                comp,
                amp_um: amp_um * f,
                period_s,
                phase,
            },
            Eff::Periodic {
                axis,
                period_um,
                amp_um,
                phase,
            } => Eff::Periodic {
                axis,
                period_um,
                amp_um: amp_um * f,
                phase,
            },
            Eff::Nonlin { axis, amp_um } => Eff::Nonlin {
                axis,
                amp_um: amp_um * f,
            },
        }
    }
}

/// One measured line: moving axis, static position and its targets (the same every run).
#[derive(Debug, Clone)]
pub struct Line {
    pub moving: AxisId,
    pub static_um: f64,
    pub targets: Vec<f64>,
}

/// The contract's layout: x lines at y = 600, 2100, 3600 µm with `nx` random targets each, one
/// y line at x = 4750 µm with `ny` random targets.
pub fn contract_layout(nx: usize, ny: usize, rng: &mut Rng) -> Vec<Line> {
    let mut rand_targets = |n: usize, tr: [f64; 2]| {
        let mut v: Vec<f64> = (0..n)
            .map(|_| (rng.range(tr[0] + 50.0, tr[1] - 50.0) * 1000.0).round() / 1000.0)
            .collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    };
    let mut out: Vec<Line> = [600.0, 2100.0, 3600.0]
        .iter()
        .map(|&y| Line {
            moving: AxisId::X,
            static_um: y,
            targets: rand_targets(nx, TRAVEL_X),
        })
        .collect();
    out.push(Line {
        moving: AxisId::Y,
        static_um: 4750.0,
        targets: rand_targets(ny, TRAVEL_Y),
    });
    out
}

/// ISO 230-2 targets: P_i = lo + (i-1)·p + r_i over `travel`, r_i random within ±p/4.
pub fn iso_targets(n: usize, travel: [f64; 2], rng: &mut Rng) -> Vec<f64> {
    let p = (travel[1] - travel[0]) / (n as f64 + 1.0);
    (0..n)
        .map(|i| {
            let v = travel[0] + (i as f64 + 1.0) * p + rng.range(-0.25, 0.25) * p;
            (v * 1000.0).round() / 1000.0
        })
        .collect()
}

/// An ISO 230-2 style layout: x lines at the given static y, fixed targets, and optionally one y
/// line.
pub fn iso_layout(nx: usize, statics_y: &[f64], ny: usize, rng: &mut Rng) -> Vec<Line> {
    let tx = iso_targets(nx, TRAVEL_X, rng);
    let mut out: Vec<Line> = statics_y
        .iter()
        .map(|&y| Line {
            moving: AxisId::X,
            static_um: y,
            targets: tx.clone(),
        })
        .collect();
    if ny > 0 {
        out.push(Line {
            moving: AxisId::Y,
            static_um: 4750.0,
            targets: iso_targets(ny, TRAVEL_Y, rng),
        });
    }
    out
}

pub struct Campaign {
    pub runs: usize,
    pub noise_um: f64,
    pub offset_um: f64,
    /// Components measured (x, y); an unmeasured one is NaN (an empty CSV field).
    pub measure: [bool; 2],
    /// Seconds per sample.
    pub dt_s: f64,
    pub travel: [[f64; 2]; 2],
}

impl Default for Campaign {
    fn default() -> Self {
        Campaign {
            runs: 4,
            noise_um: 0.05,
            offset_um: 1.0,
            measure: [true, true],
            dt_s: 2.0,
            travel: [TRAVEL_X, TRAVEL_Y],
        }
    }
}

/// Forward then backward over each line's targets, line after line, run after run.
pub fn generate(truth: &[Eff], lines: &[Line], c: &Campaign, seed: u64) -> Vec<Sample> {
    let mut rng = Rng::new(seed);
    let mut out = Vec::new();
    let mut t = 0.0;
    for run in 0..c.runs {
        for l in lines {
            let off = [c.offset_um * rng.normal(), c.offset_um * rng.normal()];
            let fwd = l.targets.iter().map(|&p| (p, 1.0));
            let bwd = l.targets.iter().rev().map(|&p| (p, -1.0));
            for (p, d) in fwd.chain(bwd) {
                let (x, y) = match l.moving {
                    AxisId::X => (p, l.static_um),
                    AxisId::Y => (l.static_um, p),
                };
                let ctx = Ctx {
                    moving: l.moving,
                    dir: d,
                    x,
                    y,
                    t,
                    travel: c.travel,
                };
                let mut dev = [0.0, 0.0];
                for e in truth {
                    let v = e.dev(&ctx);
                    dev[0] += v[0];
                    dev[1] += v[1];
                }
                let mx = x + dev[0] + off[0] + c.noise_um * rng.normal();
                let my = y + dev[1] + off[1] + c.noise_um * rng.normal();
                out.push(Sample {
                    run: run as i64 + 1,
                    moving: l.moving,
                    direction: d,
                    target_x_um: x,
                    target_y_um: y,
                    time_s: t,
                    meas_x_um: if c.measure[0] { mx } else { f64::NAN },
                    meas_y_um: if c.measure[1] { my } else { f64::NAN },
                });
                t += c.dt_s;
            }
            t += 20.0 * c.dt_s;
        }
    }
    out
}

/// Peak |deviation| of `e` on the layout once every line's constant is removed (what the data can
/// show of it), over the measured components.
pub fn visible_peak(e: &Eff, lines: &[Line], c: &Campaign) -> f64 {
    let quiet = Campaign {
        noise_um: 0.0,
        offset_um: 0.0,
        ..*c
    };
    let s = generate(std::slice::from_ref(e), lines, &quiet, 1);
    let mut peak = 0.0f64;
    let per_line = 2 * lines.iter().map(|l| l.targets.len()).collect::<Vec<_>>()[0].max(1);
    let _ = per_line;
    // Group by (run, line index) via consecutive runs of the same (run, moving, static).
    let mut start = 0;
    while start < s.len() {
        let key = |x: &Sample| {
            (
                x.run,
                x.moving,
                (x.target_x_um * 1e3) as i64 * (x.moving == AxisId::Y) as i64
                    + (x.target_y_um * 1e3) as i64 * (x.moving == AxisId::X) as i64,
            )
        };
        let k0 = key(&s[start]);
        let mut end = start;
        while end < s.len() && key(&s[end]) == k0 {
            end += 1;
        }
        for comp in 0..2 {
            if !c.measure[comp] {
                continue;
            }
            let dev = |x: &Sample| {
                if comp == 0 {
                    x.meas_x_um - x.target_x_um
                } else {
                    x.meas_y_um - x.target_y_um
                }
            };
            let m = s[start..end].iter().map(dev).sum::<f64>() / (end - start) as f64;
            for x in &s[start..end] {
                peak = peak.max((dev(x) - m).abs());
            }
        }
        start = end;
    }
    peak
}

/// A random shape of a library effect (kind, axis).
pub fn random_library_effect(kind: &str, axis: AxisId, rng: &mut Rng) -> Eff {
    match kind {
        "scale" => Eff::Scale {
            axis,
            ppm: rng.sign(),
        },
        "leadscrew_cyclic" => Eff::Cyclic {
            axis,
            period_um: 400.0,
            cos_um: vec![rng.normal(), 0.3 * rng.normal()],
            sin_um: vec![rng.normal(), 0.3 * rng.normal()],
        },
        "motor_cyclic" => Eff::Cyclic {
            axis,
            period_um: 400.0 / 28.4,
            cos_um: vec![rng.normal()],
            sin_um: vec![rng.normal()],
        },
        "backlash" => Eff::Backlash {
            axis,
            reversal_um: rng.sign(),
        },
        "hysteresis" => Eff::Hysteresis {
            axis,
            b0_um: rng.normal(),
            b1_um: rng.sign() * rng.range(0.7, 1.5),
        },
        "straightness" => Eff::Straightness {
            axis,
            coef_um: vec![rng.normal(), rng.normal()],
        },
        "yaw_abbe" => Eff::Yaw {
            axis,
            urad: [rng.normal(), rng.sign()],
        },
        "squareness" => Eff::Squareness { urad: rng.sign() },
        "camera_rotation" => Eff::CamRotation { urad: rng.sign() },
        "camera_scale" => Eff::CamScale { ppm: rng.sign() },
        "thermal_drift" => Eff::Thermal {
            comp: axis,
            amp_um: rng.sign(),
            tau_s: rng.range(600.0, 4000.0),
            rate_um_per_h: 0.3 * rng.normal(),
        },
        other => panic!("not a library kind: {other}"),
    }
}

/// The library groups a case can withhold.
pub const GROUPS: &[(&str, AxisId)] = &[
    ("scale", AxisId::X),
    ("scale", AxisId::Y),
    ("leadscrew_cyclic", AxisId::X),
    ("leadscrew_cyclic", AxisId::Y),
    ("motor_cyclic", AxisId::X),
    ("motor_cyclic", AxisId::Y),
    ("backlash", AxisId::X),
    ("backlash", AxisId::Y),
    ("hysteresis", AxisId::X),
    ("hysteresis", AxisId::Y),
    ("straightness", AxisId::X),
    ("straightness", AxisId::Y),
    ("yaw_abbe", AxisId::X),
    ("yaw_abbe", AxisId::Y),
    ("squareness", AxisId::Y),
    ("camera_rotation", AxisId::X),
    ("camera_scale", AxisId::X),
    ("thermal_drift", AxisId::X),
    ("thermal_drift", AxisId::Y),
];
