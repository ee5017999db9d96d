//! The candidate library: which effect groups the diagnosis may add (each kind on each axis,
//! with the structure fixed from the model), and how a fitted group joins the model.
use csmetro_effects::{AxisId, Effect, EffectKind, StageModel};

use super::Options;

/// The fitted structure of a candidate group: everything but its linear coefficients.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Spec {
    Scale {
        ref_um: f64,
    },
    Cyclic {
        motor: bool,
        period_um: f64,
        h: usize,
    },
    Backlash,
    Hysteresis,
    Straightness {
        k: usize,
    },
    Yaw {
        offset_um: f64,
        /// The Abbe arm's zero (the other axis' position where the yaw moves nothing) is not
        /// known: a third coefficient shifts it (`Some(travel)` of the moving axis, over which
        /// `s` runs). The model's own yaw fixes it (`None`).
        free: Option<[f64; 2]>,
    },
    Squareness,
    CamRot,
    CamScale,
    Thermal {
        component: AxisId,
        tau_s: f64,
    },
}

impl Spec {
    pub(super) fn kind_name(&self) -> &'static str {
        match self {
            Spec::Scale { .. } => "scale",
            Spec::Cyclic { motor: false, .. } => "leadscrew_cyclic",
            Spec::Cyclic { motor: true, .. } => "motor_cyclic",
            Spec::Backlash => "backlash",
            Spec::Hysteresis => "hysteresis",
            Spec::Straightness { .. } => "straightness",
            Spec::Yaw { .. } => "yaw_abbe",
            Spec::Squareness => "squareness",
            Spec::CamRot => "camera_rotation",
            Spec::CamScale => "camera_scale",
            Spec::Thermal { .. } => "thermal_drift",
        }
    }
    pub(super) fn n_params(&self) -> usize {
        match self {
            Spec::Cyclic { h, .. } => 2 * h,
            Spec::Yaw { free: Some(_), .. } => 3,
            Spec::Hysteresis | Spec::Yaw { .. } | Spec::Thermal { .. } => 2,
            Spec::Straightness { k } => *k,
            _ => 1,
        }
    }
    /// The effect kind with these linear coefficients.
    pub(super) fn kind(&self, c: &[f64]) -> EffectKind {
        match self {
            Spec::Scale { ref_um } => EffectKind::Scale {
                ppm: c[0],
                ref_um: *ref_um,
            },
            Spec::Cyclic {
                motor,
                period_um,
                h,
            } => {
                let cos_um = (0..*h).map(|i| c[2 * i]).collect();
                let sin_um = (0..*h).map(|i| c[2 * i + 1]).collect();
                if *motor {
                    EffectKind::MotorCyclic {
                        period_um: *period_um,
                        cos_um,
                        sin_um,
                    }
                } else {
                    EffectKind::LeadscrewCyclic {
                        period_um: *period_um,
                        cos_um,
                        sin_um,
                    }
                }
            }
            Spec::Backlash => EffectKind::Backlash { reversal_um: c[0] },
            Spec::Hysteresis => EffectKind::Hysteresis {
                b0_um: c[0],
                b1_um: c[1],
            },
            Spec::Straightness { .. } => EffectKind::Straightness {
                legendre_um: c.to_vec(),
            },
            Spec::Yaw {
                offset_um,
                free: Some([lo, hi]),
            } if c[2] != 0.0 => {
                // c[2] is the deviation (µm) the arm's shift adds at the travel end: a shift of
                // the zero by Δ moves the axis by e1·1e-6·Δ·s. Alone (a design column), that
                // term is a scale about mid-travel.
                if c[1] == 0.0 {
                    EffectKind::Scale {
                        ppm: c[2] * 2e6 / (hi - lo),
                        ref_um: 0.5 * (lo + hi),
                    }
                } else {
                    EffectKind::YawAbbe {
                        yaw_urad: [c[0], c[1]],
                        offset_um: offset_um + c[2] / (c[1] * 1e-6),
                    }
                }
            }
            Spec::Yaw { offset_um, .. } => EffectKind::YawAbbe {
                yaw_urad: [c[0], c[1]],
                offset_um: *offset_um,
            },
            Spec::Squareness => EffectKind::Squareness { angle_urad: c[0] },
            Spec::CamRot => EffectKind::CameraRotation { angle_urad: c[0] },
            Spec::CamScale => EffectKind::CameraScale { ppm: c[0] },
            Spec::Thermal { component, tau_s } => EffectKind::ThermalDrift {
                component: *component,
                amp_um: c[0],
                tau_s: *tau_s,
                rate_um_per_h: c[1],
            },
        }
    }
}

/// A candidate group: one kind on one axis (global kinds once; thermal once per component and τ).
#[derive(Debug, Clone)]
pub(super) struct Group {
    pub(super) spec: Spec,
    pub(super) axis: AxisId,
    pub(super) travel_um: Option<[f64; 2]>,
    /// Column index per parameter (None = not identifiable from line data, e.g. a constant per line).
    pub(super) cols: Vec<Option<usize>>,
}

impl Group {
    pub(super) fn kind(&self) -> &'static str {
        self.spec.kind_name()
    }
    /// `x`, `y` or `-` (global); thermal drift by component.
    pub(super) fn axis_label(&self) -> String {
        match &self.spec {
            Spec::CamRot | Spec::CamScale => "-".into(),
            Spec::Thermal { component, .. } => component.as_str().into(),
            _ => self.axis.as_str().into(),
        }
    }
    pub(super) fn label(&self) -> String {
        match &self.spec {
            Spec::CamRot | Spec::CamScale => self.kind().into(),
            _ => format!("{} {}", self.kind(), self.axis_label()),
        }
    }
    /// Family key: thermal groups of one component with different τ are alternatives.
    pub(super) fn family(&self) -> String {
        self.label()
    }
    pub(super) fn col_set(&self) -> Vec<usize> {
        self.cols.iter().flatten().copied().collect()
    }
}

pub(super) fn candidate_groups(
    model: &StageModel,
    rows_have: &[AxisId],
    opts: &Options,
) -> Vec<Group> {
    let allowed = |k: &str| {
        opts.kinds
            .as_ref()
            .is_none_or(|ks| ks.iter().any(|x| x == k))
    };
    let existing = |kind: &str, axis: AxisId| -> Option<&Effect> {
        model
            .effects
            .iter()
            .find(|e| e.kind.name() == kind && (e.kind.is_global() || e.axis == axis))
    };
    let mut out = Vec::new();
    let mut push = |spec: Spec, axis: AxisId, travel: Option<[f64; 2]>| {
        if allowed(spec.kind_name()) {
            out.push(Group {
                spec,
                axis,
                travel_um: travel,
                cols: Vec::new(),
            });
        }
    };
    for &a in &[AxisId::X, AxisId::Y] {
        if !rows_have.contains(&a) {
            continue;
        }
        let tr = |k: &str| existing(k, a).and_then(|e| e.travel_um);
        let ref_um = match existing("scale", a).map(|e| &e.kind) {
            Some(EffectKind::Scale { ref_um, .. }) => *ref_um,
            _ => 0.0,
        };
        push(Spec::Scale { ref_um }, a, tr("scale"));
        for motor in [false, true] {
            let name = if motor {
                "motor_cyclic"
            } else {
                "leadscrew_cyclic"
            };
            let (period_um, h0) = match existing(name, a).map(|e| &e.kind) {
                Some(EffectKind::LeadscrewCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                })
                | Some(EffectKind::MotorCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                }) => (*period_um, cos_um.len().max(sin_um.len())),
                _ => (if motor { opts.motor_period_um } else { 400.0 }, 0),
            };
            let h = if motor {
                h0.max(1)
            } else {
                h0.max(opts.leadscrew_harmonics)
            };
            push(
                Spec::Cyclic {
                    motor,
                    period_um,
                    h,
                },
                a,
                tr(name),
            );
        }
        push(Spec::Backlash, a, None);
        push(Spec::Hysteresis, a, tr("hysteresis"));
        let k = match existing("straightness", a).map(|e| &e.kind) {
            Some(EffectKind::Straightness { legendre_um }) => legendre_um.len().max(3),
            _ => 3,
        };
        push(Spec::Straightness { k }, a, tr("straightness"));
        let (offset_um, free) = match existing("yaw_abbe", a).map(|e| &e.kind) {
            Some(EffectKind::YawAbbe { offset_um, .. }) => (*offset_um, None),
            _ => (0.0, Some(tr("yaw_abbe").unwrap_or(model.travel(a)))),
        };
        push(
            Spec::Yaw {
                offset_um,
                free: None,
            },
            a,
            tr("yaw_abbe"),
        );
        // Without the model's own yaw, the arm's zero is also fitted (same family: one of the
        // two is picked, the fixed one when the data cannot tell them apart).
        if free.is_some() {
            push(Spec::Yaw { offset_um, free }, a, tr("yaw_abbe"));
        }
        if a == AxisId::Y {
            push(Spec::Squareness, a, None);
        }
    }
    push(Spec::CamRot, AxisId::X, None);
    push(Spec::CamScale, AxisId::X, None);
    for c in [AxisId::X, AxisId::Y] {
        let mut taus = opts.tau_grid_s.clone();
        for e in &model.effects {
            if let EffectKind::ThermalDrift {
                component, tau_s, ..
            } = e.kind
            {
                if component == c && !taus.contains(&tau_s) {
                    taus.push(tau_s);
                }
            }
        }
        for tau_s in taus {
            push(
                Spec::Thermal {
                    component: c,
                    tau_s,
                },
                AxisId::X,
                None,
            );
        }
    }
    out
}

/// `big` generalises `small` (same axis): a tie between them is not a confound. A yaw whose
/// Abbe arm has a free zero holds a scale of its axis (the arm's shift).
pub(super) fn generalises(big: &Group, small: &Group) -> bool {
    big.axis == small.axis
        && matches!(
            (&big.spec, &small.spec),
            (Spec::Hysteresis, Spec::Backlash)
                | (Spec::Yaw { free: Some(_), .. }, Spec::Scale { .. })
        )
}

/// One of the two generalises the other and these data tell them apart (a yaw whose arm's zero
/// is free is the same columns as the scale of its axis on a single line: then they tie).
pub(super) fn nested(a: &Group, b: &Group) -> bool {
    let span = |g: &Group| {
        let mut v = g.col_set();
        v.sort_unstable();
        v.dedup();
        v
    };
    (generalises(a, b) || generalises(b, a)) && span(a) != span(b)
}

/// Adds a fitted effect to the model: into the existing effect of the same kind and axis (same
/// structure) when there is one, else as a new effect.
pub(super) fn merge_into(model: &mut StageModel, add: &Effect) {
    use EffectKind as K;
    for e in model.effects.iter_mut() {
        if e.kind.name() != add.kind.name()
            || (!e.kind.is_global() && e.axis != add.axis)
            || e.travel_um != add.travel_um
        {
            continue;
        }
        let sum_vec = |a: &mut Vec<f64>, b: &[f64]| {
            if a.len() < b.len() {
                a.resize(b.len(), 0.0);
            }
            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        };
        match (&mut e.kind, &add.kind) {
            (
                K::Scale { ppm, ref_um },
                K::Scale {
                    ppm: p2,
                    ref_um: r2,
                },
            ) if ref_um == r2 => {
                *ppm += p2;
                return;
            }
            (
                K::LeadscrewCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                },
                K::LeadscrewCyclic {
                    period_um: p2,
                    cos_um: c2,
                    sin_um: s2,
                },
            )
            | (
                K::MotorCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                },
                K::MotorCyclic {
                    period_um: p2,
                    cos_um: c2,
                    sin_um: s2,
                },
            ) if period_um == p2 => {
                sum_vec(cos_um, c2);
                sum_vec(sin_um, s2);
                return;
            }
            (K::Backlash { reversal_um }, K::Backlash { reversal_um: r2 }) => {
                *reversal_um += r2;
                return;
            }
            (K::Hysteresis { b0_um, b1_um }, K::Hysteresis { b0_um: a, b1_um: b }) => {
                *b0_um += a;
                *b1_um += b;
                return;
            }
            (K::Straightness { legendre_um }, K::Straightness { legendre_um: l2 }) => {
                sum_vec(legendre_um, l2);
                return;
            }
            (
                K::YawAbbe {
                    yaw_urad,
                    offset_um,
                },
                K::YawAbbe {
                    yaw_urad: y2,
                    offset_um: o2,
                },
            ) if offset_um == o2 => {
                yaw_urad[0] += y2[0];
                yaw_urad[1] += y2[1];
                return;
            }
            (K::Squareness { angle_urad }, K::Squareness { angle_urad: a })
            | (K::CameraRotation { angle_urad }, K::CameraRotation { angle_urad: a }) => {
                *angle_urad += a;
                return;
            }
            (K::CameraScale { ppm }, K::CameraScale { ppm: p2 }) => {
                *ppm += p2;
                return;
            }
            (
                K::ThermalDrift {
                    component,
                    amp_um,
                    tau_s,
                    rate_um_per_h,
                },
                K::ThermalDrift {
                    component: c2,
                    amp_um: a2,
                    tau_s: t2,
                    rate_um_per_h: r2,
                },
            ) if component == c2 && tau_s == t2 => {
                *amp_um += a2;
                *rate_um_per_h += r2;
                return;
            }
            _ => {}
        }
    }
    model.push(add.clone());
}
