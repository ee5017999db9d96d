//! Validation of a campaign file as written: every section checked, axes, grids, the
//! reconstruction method, the map and the stage model resolved.
#[allow(clippy::wildcard_imports)]
use super::*;

pub(super) type Validated = (
    Vec<AxisPlan>,
    Method,
    Solver,
    Option<MapPlan>,
    Option<LoadedModel>,
);

/// A campaign or stage name: it becomes part of file names, so a short plain word.
fn check_name(v: &str) -> Result<(), NameError> {
    if v.trim().is_empty() {
        return Err(NameError::Empty);
    }
    if v.len() > MAX_NAME_LEN {
        return Err(NameError::TooLong);
    }
    let plain = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    if !v.starts_with(|c: char| c.is_ascii_alphanumeric()) || !v.chars().all(plain) {
        return Err(NameError::NotPlain);
    }
    Ok(())
}

/// Why a campaign or stage name was refused (the key is named by the caller).
#[derive(Debug, thiserror::Error)]
enum NameError {
    #[error("must not be empty")]
    Empty,
    #[error("must be at most {MAX_NAME_LEN} characters")]
    TooLong,
    #[error("may hold only letters, digits, `-`, `_` and `.`, and starts with a letter or digit")]
    NotPlain,
}

pub(super) fn validate(
    spec: &CampaignSpec,
    trust: &Trust,
    fail: &dyn Fn(&str, String) -> SpecError,
) -> Result<Validated, SpecError> {
    let pos = |v: f64| v.is_finite() && v > 0.0;
    let nonneg = |v: f64| v.is_finite() && v >= 0.0;
    check_name(&spec.campaign.name).map_err(|e| fail("campaign.name", e.to_string()))?;
    check_name(&spec.campaign.stage).map_err(|e| fail("campaign.stage", e.to_string()))?;
    if spec.campaign.description.len() > MAX_DESCRIPTION_LEN {
        return Err(fail(
            "campaign.description",
            format!("must be at most {MAX_DESCRIPTION_LEN} bytes"),
        ));
    }
    if let Some(id) = spec.campaign.verify {
        check_verification(spec, id).map_err(|(k, m)| fail(k, m))?;
    } else if spec.axes.is_empty() && spec.map.is_none() {
        return Err(fail(
            "axes",
            "no axis to characterize: add [axes.x] and/or [axes.y] (or a [map])".into(),
        ));
    }
    let h = &spec.hardware;
    let mut model = None;
    if !pos(h.reference_timeout_s) {
        return Err(fail("hardware.reference_timeout_s", "must be > 0 s".into()));
    }
    if !pos(h.move_timeout_s) {
        return Err(fail("hardware.move_timeout_s", "must be > 0 s".into()));
    }
    h.optics
        .validate()
        .map_err(|e| fail("hardware.optics", e))?;
    csmetro_ppp::Pattern::new(h.pattern.clone())
        .map_err(|e| fail("hardware.pattern", e.to_string()))?;
    let limits_of = |a: AxisId| -> Result<(f64, f64), SpecError> {
        match h.kind {
            HardwareKind::Sim => {
                let l = match a {
                    AxisId::X => h.sim.soft_limits_x_um,
                    AxisId::Y => h.sim.soft_limits_y_um,
                };
                Ok((l[0], l[1]))
            }
            HardwareKind::Real => h
                .controllers
                .get(a.as_str())
                .map(|c| c.soft_limits_um)
                .ok_or_else(|| {
                    fail(
                        "hardware.controllers",
                        format!("no controller for axis {a} ([hardware.controllers.{a}])"),
                    )
                }),
        }
    };
    match h.kind {
        HardwareKind::Sim => {
            let s = &h.sim;
            if let Err(m) = csmetro_sim::check_time_scale(s.time_scale) {
                return Err(fail("hardware.sim.time_scale", m));
            }
            if !nonneg(s.frame_time_s) {
                return Err(fail("hardware.sim.frame_time_s", "must be ≥ 0 s".into()));
            }
            if !(pos(s.velocity_mm_s) && s.velocity_mm_s <= 1.5) {
                return Err(fail(
                    "hardware.sim.velocity_mm_s",
                    "must be in (0, 1.5] mm/s (M-111.1DG)".into(),
                ));
            }
            if !(pos(s.acceleration_mm_s2) && s.acceleration_mm_s2 <= 200.0) {
                return Err(fail(
                    "hardware.sim.acceleration_mm_s2",
                    "must be in (0, 200] mm/s²".into(),
                ));
            }
            if let Some(o) = &s.render_optics {
                o.validate()
                    .map_err(|e| fail("hardware.sim.render_optics", e))?;
            }
            if let Some(f) = &s.faults {
                let rate = |v: f64| (0.0..=1.0).contains(&v);
                let rates = [
                    f.delay_rate,
                    f.drop_rate,
                    f.garbage_rate,
                    f.error_rate,
                    f.vanish_rate,
                ];
                if !rates.into_iter().all(rate) {
                    return Err(fail(
                        "hardware.sim.faults",
                        "every *_rate must be in [0, 1]".into(),
                    ));
                }
                let [lo, hi] = f.delay_ms;
                if !(lo <= hi && hi <= 60_000 && f.vanish_ms <= 60_000) {
                    return Err(fail(
                        "hardware.sim.faults",
                        "delay_ms = [lo, hi] with lo <= hi and vanish_ms at most 60000 ms".into(),
                    ));
                }
            }
            if let Some(m) = &s.model {
                model = Some(
                    load_model(m, trust).map_err(|e| fail("hardware.sim.model", e.to_string()))?,
                );
            }
            let [tlo, thi] = s.travel_mm;
            if !(tlo.is_finite() && thi.is_finite() && tlo < thi && thi - tlo <= 15.0) {
                return Err(fail(
                    "hardware.sim.travel_mm",
                    "must be [lo, hi] mm with lo < hi and at most 15 mm (M-111.1DG)".into(),
                ));
            }
            for (k, l) in [
                ("hardware.sim.soft_limits_x_um", s.soft_limits_x_um),
                ("hardware.sim.soft_limits_y_um", s.soft_limits_y_um),
            ] {
                let inside = l[0] >= tlo * 1000.0 && l[1] <= thi * 1000.0;
                if !(l[0].is_finite() && l[1].is_finite() && l[0] < l[1] && inside) {
                    return Err(fail(
                        k,
                        format!(
                            "must be [lo, hi] µm with lo < hi inside the travel [{}, {}] µm",
                            tlo * 1000.0,
                            thi * 1000.0
                        ),
                    ));
                }
            }
        }
        HardwareKind::Real => {
            for name in spec.axes.keys() {
                if AxisId::parse(name).is_some() && !h.controllers.contains_key(name) {
                    return Err(fail(
                        "hardware.controllers",
                        format!("no controller for axis {name} ([hardware.controllers.{name}])"),
                    ));
                }
            }
            for (name, c) in &h.controllers {
                if AxisId::parse(name).is_none() {
                    return Err(fail(
                        &format!("hardware.controllers.{name}"),
                        "axis names are x and y".into(),
                    ));
                }
                let (lo, hi) = c.soft_limits_um;
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    return Err(fail(
                        &format!("hardware.controllers.{name}.soft_limits_um"),
                        "must be [lo, hi] with lo < hi (µm)".into(),
                    ));
                }
                if let Trust::Submitted(policy) = trust {
                    // A submitted file opens only what the service's configuration lists; the
                    // value is not repeated (it may be a probe of the server's devices).
                    let allowed = match &c.transport {
                        csmetro_gcs::Transport::Serial { port, .. } => {
                            use std::os::unix::fs::FileTypeExt;
                            policy.serial_ports.iter().any(|p| p == port)
                                && port.starts_with("/dev/")
                                && std::fs::metadata(port)
                                    .is_ok_and(|m| m.file_type().is_char_device())
                        }
                        csmetro_gcs::Transport::Tcp { address, .. } => {
                            policy.tcp_endpoints.iter().any(|a| a == address)
                        }
                    };
                    if !allowed {
                        return Err(fail(
                            &format!("hardware.controllers.{name}.transport"),
                            "the service does not allow this port: submitted campaigns open \
                             only the serial devices and TCP endpoints listed in the service's \
                             [hardware] serial_ports and tcp_endpoints"
                                .into(),
                        ));
                    }
                }
            }
            match &h.camera {
                None => {
                    return Err(fail(
                        "hardware.camera",
                        "a real campaign needs [hardware.camera]".into(),
                    ))
                }
                Some(c) => c
                    .validate()
                    .map_err(|e| fail("hardware.camera", e.to_string()))?,
            }
        }
    }

    let s = &spec.sampling;
    if s.batch < 2 {
        return Err(fail("sampling.batch", "must be ≥ 2".into()));
    }
    if let Some(f) = s.fraction {
        if !(f > 0.0 && f <= 1.0) {
            return Err(fail("sampling.fraction", "must be in (0, 1]".into()));
        }
    }
    if let Some(t) = s.target_error_um {
        if !pos(t) {
            return Err(fail("sampling.target_error_um", "must be > 0 µm".into()));
        }
    }
    let a = &spec.acquisition;
    if a.directions.is_empty() {
        return Err(fail(
            "acquisition.directions",
            "needs forward and/or backward".into(),
        ));
    }
    let mut dirs = a.directions.clone();
    dirs.dedup();
    if dirs.len() != a.directions.len() {
        return Err(fail(
            "acquisition.directions",
            "a direction is listed twice".into(),
        ));
    }
    if !(1..=1000).contains(&a.cycles) {
        return Err(fail("acquisition.cycles", "must be in 1..=1000".into()));
    }
    if !(nonneg(a.settle_s) && a.settle_s <= 600.0) {
        return Err(fail("acquisition.settle_s", "must be in [0, 600] s".into()));
    }
    if !(nonneg(a.dwell_s) && a.dwell_s <= 3600.0) {
        return Err(fail("acquisition.dwell_s", "must be in [0, 3600] s".into()));
    }
    if !(1..=100).contains(&a.frames_per_point) {
        return Err(fail(
            "acquisition.frames_per_point",
            "must be in 1..=100".into(),
        ));
    }
    if a.max_retries > 100 {
        return Err(fail("acquisition.max_retries", "must be ≤ 100".into()));
    }
    if !(nonneg(a.approach_um) && a.approach_um <= 1000.0) {
        return Err(fail(
            "acquisition.approach_um",
            "must be in [0, 1000] µm".into(),
        ));
    }

    let r = &spec.reconstruction;
    let method: Method = r
        .method
        .parse()
        .map_err(|e: String| fail("reconstruction.method", e))?;
    let solver: Solver = r
        .solver
        .parse()
        .map_err(|e: String| fail("reconstruction.solver", e))?;
    if !nonneg(r.noise_um) {
        return Err(fail("reconstruction.noise_um", "must be ≥ 0 µm".into()));
    }
    if r.pitch_um.is_some_and(|p| !pos(p)) {
        return Err(fail("reconstruction.pitch_um", "must be > 0 µm".into()));
    }
    spec.uncertainty.inputs().map_err(|(k, m)| fail(k, m))?;
    if spec.outputs.nexus && !cfg!(feature = "nexus") {
        return Err(fail(
            "outputs.nexus",
            "writing NeXus files needs a csmetro built with --features nexus (and Debian's \
             libhdf5-dev)"
                .into(),
        ));
    }
    if spec.outputs.dir.trim().is_empty() {
        return Err(fail("outputs.dir", "must not be empty".into()));
    }
    if spec.outputs.dir.len() > MAX_PATH_LEN {
        return Err(fail(
            "outputs.dir",
            format!("must be at most {MAX_PATH_LEN} bytes"),
        ));
    }
    if let Trust::Submitted(_) = trust {
        check_submitted_outputs(&spec.outputs.dir)
            .map_err(|e| fail("outputs.dir", e.to_string()))?;
    }

    let mut plans = Vec::new();
    let mut planned = 0u64;
    for (name, ax) in &spec.axes {
        let key = |k: &str| format!("axes.{name}.{k}");
        let axis = AxisId::parse(name)
            .ok_or_else(|| fail(&format!("axes.{name}"), "axis names are x and y".into()))?;
        let [start, end] = ax.range_um;
        let grid = Grid::new(start, ax.step_um, end).map_err(|e| fail(&key("range_um"), e))?;
        let (lo, hi) = limits_of(axis)?;
        let pre = a.approach_um;
        if start - pre < lo - 1e-9 || end + pre > hi + 1e-9 {
            return Err(fail(
                &key("range_um"),
                format!(
                    "[{start}, {end}] µm with {pre} µm approach travel leaves the soft limits [{lo}, {hi}] µm"
                ),
            ));
        }
        let (olo, ohi) = limits_of(axis.other())?;
        if !(ax.other_at_um.is_finite() && ax.other_at_um >= olo && ax.other_at_um <= ohi) {
            return Err(fail(
                &key("other_at_um"),
                format!(
                    "{} µm is outside the soft limits [{olo}, {ohi}] µm of axis {}",
                    ax.other_at_um,
                    axis.other()
                ),
            ));
        }
        let n = grid.n;
        let (m, mkey) = match (ax.m.or(s.m), ax.fraction.or(s.fraction)) {
            (Some(m), _) => (
                m,
                if ax.m.is_some() {
                    key("m")
                } else {
                    "sampling.m".into()
                },
            ),
            (None, Some(f)) => (
                ((f * n as f64).round() as usize).max(2),
                if ax.fraction.is_some() {
                    key("fraction")
                } else {
                    "sampling.fraction".into()
                },
            ),
            (None, None) if s.design == DesignKind::Full => (n, "sampling.design".into()),
            (None, None) => {
                return Err(fail(
                    "sampling.m",
                    format!("give m or fraction (axis {name} has {n} grid points)"),
                ))
            }
        };
        if let Some(f) = ax.fraction {
            if !(f > 0.0 && f <= 1.0) {
                return Err(fail(&key("fraction"), "must be in (0, 1]".into()));
            }
        }
        if s.design != DesignKind::Full && !(2..=n).contains(&m) {
            return Err(fail(
                &mkey,
                format!("m = {m} must be in 2..={n} (grid points)"),
            ));
        }
        let target_error_um = ax.target_error_um.or(s.target_error_um);
        if let Some(t) = ax.target_error_um {
            if !pos(t) {
                return Err(fail(&key("target_error_um"), "must be > 0 µm".into()));
            }
        }
        if target_error_um.is_some() && s.design == DesignKind::Full {
            return Err(fail(
                "sampling.target_error_um",
                "adaptive sampling needs a random or jittered design".into(),
            ));
        }
        let m = if s.design == DesignKind::Full { n } else { m };
        crate::recon::limits::check_solve_size(method, solver, n, m)
            .map_err(|e| fail(&key("range_um"), e.to_string()))?;
        let per_run = m as u64 + if s.full_scan { n as u64 } else { 0 };
        planned += per_run * a.directions.len() as u64 * u64::from(a.cycles);
        if planned > MAX_PLANNED {
            return Err(fail(
                &mkey,
                format!("the campaign would plan more than {MAX_PLANNED} measurements"),
            ));
        }
        plans.push(AxisPlan {
            axis,
            grid,
            other_at_um: ax.other_at_um,
            m,
            target_error_um,
        });
    }
    let map = match &spec.map {
        Some(m) => {
            if spec.compensation.is_some() {
                return Err(fail("map", "a map campaign runs uncompensated".into()));
            }
            // The simulator's truth of a map is planar (both axes' errors at once), a line's is
            // not: lines and a map are separate campaigns.
            if !spec.axes.is_empty() {
                return Err(fail(
                    "map",
                    "a map campaign has no [axes.*]: characterize lines in a campaign of their own"
                        .into(),
                ));
            }
            let p = map::validate_map(m, a.approach_um, &limits_of, fail)?;
            planned += (p.design.m * p.directions.len()) as u64;
            if planned > MAX_PLANNED {
                return Err(fail(
                    "map",
                    format!("the campaign would plan more than {MAX_PLANNED} measurements"),
                ));
            }
            Some(p)
        }
        None => None,
    };
    Ok((plans, method, solver, map, model))
}
