//! A verification as a campaign: a campaign file with `[campaign] verify = ID` (and no `[axes]`)
//! measures stored characterisation ID again without and with its compensation, as
//! `csmetro verify ID` does, but queued, stored, streamed and reported like any campaign (CLI
//! `run`, the service's `POST /campaigns`). Its hardware and acquisition settings are the file's;
//! its axes, grids and compensation are the characterisation's, which must be in the same store,
//! finished, of the same stage and have compensation tables: all checked at load.
use std::collections::BTreeMap;
use std::sync::Arc;

use serde_json::{json, Value};
use tokio::sync::watch;

use super::attempt::{Attempt, Finished};
use super::compensate::stored;
use super::engine::{Control, EndState, Outcome};
use super::error::CampaignError;
use super::spec::{Campaign, HardwareKind, SpecError};
use super::verify::{self, prior_from_summary, Prior, Sink, VerifyError, VerifyOptions};
use crate::store::{Store, StoreError};
use crate::tomlpos::{line_of, span_of};
use crate::types::{AxisId, CampaignState, Origin, SampleRecord};

/// What a verification campaign measures: targets and cycles as `csmetro verify` chooses them;
/// cycles from `[acquisition] cycles` when the file sets it, else ISO 230-2's 5.
pub fn options(c: &Campaign) -> VerifyOptions {
    let cycles = if span_of(c.text(), "acquisition.cycles").is_some() {
        c.spec().acquisition.cycles
    } else {
        super::spec::DEFAULT_VERIFY_CYCLES
    };
    VerifyOptions {
        cycles,
        ..VerifyOptions::default()
    }
}

/// Resolves a verification campaign against `store`: a new validated campaign measuring the
/// characterisation's axes (any other campaign is returned as it is). Refused, at `campaign.verify`'s line: an id not in this
/// store, of another stage, not finished, itself a verification, without compensation tables,
/// or a characterisation this file's hardware or directions cannot measure.
pub fn resolve(c: Campaign, store: &Store) -> Result<Campaign, SpecError> {
    let Some(id) = c.spec().campaign.verify else {
        return Ok(c);
    };
    let key = "campaign.verify";
    let err = |message: String| SpecError {
        origin: c.origin().to_string(),
        line: span_of(c.text(), key)
            .map(|s| line_of(c.text(), s.start))
            .unwrap_or(0),
        key: key.into(),
        message,
    };
    let row = store
        .campaign(id)
        .map_err(|e| err(format!("store: {e}")))?
        .ok_or_else(|| err(format!("no campaign {id} in this store")))?;
    let stage = &c.spec().campaign.stage;
    if &row.stage != stage {
        return Err(err(format!(
            "campaign {id} ran on stage {:?}, not on {stage:?}",
            row.stage
        )));
    }
    let base = std::path::Path::new(&row.spec_path)
        .parent()
        .map(std::path::Path::to_path_buf)
        .unwrap_or_default();
    let snapshot = store
        .model_snapshot(id)
        .map_err(|e| err(format!("store: {e}")))?;
    let ch =
        Campaign::parse_stored(&row.spec_toml, &row.spec_path, &base, snapshot).map_err(|_| {
            err(format!(
                "campaign {id}: its stored file no longer validates"
            ))
        })?;
    if ch.spec().campaign.verify.is_some() || ch.axes().is_empty() {
        return Err(err(format!(
            "campaign {id} is a verification, not a characterisation"
        )));
    }
    if row.state != CampaignState::Done {
        return Err(err(format!(
            "campaign {id} is {}: only a finished characterisation can be verified",
            row.state.as_str()
        )));
    }
    let comp = stored(store, id, &row.stage).map_err(|e| err(e.to_string()))?;
    let h = &c.spec().hardware;
    let pre = c.spec().acquisition.approach_um;
    for ax in ch.axes() {
        let a = ax.axis;
        comp.check_covers(a, ax.grid.start_um, ax.grid.end_um())
            .map_err(|e| err(e.to_string()))?;
        let t = comp.table(a).expect("checked by check_covers");
        for &d in &c.spec().acquisition.directions {
            if t.served_direction(d) != d {
                return Err(err(format!(
                    "campaign {id} has no {} correction of axis {a}: measure the directions it has",
                    d.as_str()
                )));
            }
        }
        let limits = |axis: AxisId| -> Result<(f64, f64), SpecError> {
            match h.kind {
                HardwareKind::Sim => {
                    let l = match axis {
                        AxisId::X => h.sim.soft_limits_x_um,
                        AxisId::Y => h.sim.soft_limits_y_um,
                    };
                    Ok((l[0], l[1]))
                }
                HardwareKind::Real => h
                    .controllers
                    .get(axis.as_str())
                    .map(|c| c.soft_limits_um)
                    .ok_or_else(|| {
                        err(format!(
                            "campaign {id} measured axis {axis}: this file has no [hardware.controllers.{axis}]"
                        ))
                    }),
            }
        };
        let (lo, hi) = limits(a)?;
        let (s, e) = (ax.grid.start_um, ax.grid.end_um());
        if s - pre < lo - 1e-9 || e + pre > hi + 1e-9 {
            return Err(err(format!(
                "axis {a} of campaign {id}, [{s}, {e}] µm with {pre} µm approach travel, leaves this file's soft limits [{lo}, {hi}] µm"
            )));
        }
        let (olo, ohi) = limits(a.other())?;
        if ax.other_at_um < olo || ax.other_at_um > ohi {
            return Err(err(format!(
                "axis {a} of campaign {id} waits with {} at {} µm, outside this file's soft limits [{olo}, {ohi}] µm",
                a.other(),
                ax.other_at_um
            )));
        }
    }
    Ok(c.measuring_axes_of(ch))
}

/// Targets a verification campaign plans (both passes); `None` for other campaigns.
pub fn planned(c: &Campaign) -> Option<u64> {
    c.spec().campaign.verify?;
    let (b, a) = verify::planned(c, &options(c));
    Some(b + a)
}

/// Commits the samples and events of a verification campaign to its store and streams them.
struct StoreSink {
    run: Attempt,
    on_sample: Box<dyn FnMut(&SampleRecord) + Send>,
}

impl Sink for StoreSink {
    fn sample(&mut self, s: &SampleRecord) -> Result<bool, StoreError> {
        let fresh = self.run.store_sample(s)?;
        (self.on_sample)(s);
        Ok(fresh)
    }
    fn event(&mut self, kind: &str, data: &Value) {
        self.run.emit(kind, data.clone());
    }
}

/// Runs (or resumes: targets stored are not measured again) verification campaign `run.id`,
/// stores its verdict and result files, and records its final state: done when it passed,
/// failed (with the axis that did not) when the compensated residual exceeds the expected one.
pub(super) async fn execute(
    run: &Attempt,
    c: Campaign,
    control: watch::Receiver<Control>,
    on_sample: Box<dyn FnMut(&SampleRecord) + Send>,
    origin: Origin,
) -> Result<Finished, CampaignError> {
    let (store, id) = (&run.store, run.id);
    let char_id = c
        .spec()
        .campaign
        .verify
        .ok_or(CampaignError::NotVerification)?;
    let t0 = std::time::Instant::now();
    let fail = |msg: String| CampaignError::NotStarted {
        id,
        msg: run.fail("verification", msg),
    };
    // Resolved again here: the characterisation may have gone since the file was loaded.
    let resolved = store.with(|s| {
        resolve(c, s).map_err(CampaignError::from).and_then(|c| {
            let comp = stored(s, char_id, &c.spec().campaign.stage)?;
            let summary: Value = s
                .result(char_id, "summary.json")
                .ok()
                .flatten()
                .and_then(|(_, b)| serde_json::from_slice(&b).ok())
                .unwrap_or_default();
            let measured = s.samples(char_id)?;
            let measured = [AxisId::X, AxisId::Y].map(|ax| verify::measured_span(&measured, ax));
            let done: BTreeMap<u64, SampleRecord> = s
                .samples(id)?
                .into_iter()
                .map(|r| (r.target.seq, r))
                .collect();
            Ok((c, comp, summary, measured, done))
        })
    });
    let (c, comp, summary, measured, done) = resolved.map_err(|e| fail(format!("stopped: {e}")))?;
    let opts = VerifyOptions {
        measured_span_um: measured,
        ..options(&c)
    };
    let (nb, na) = verify::planned(&c, &opts);
    run.start(
        nb + na,
        done.len(),
        &c.spec().campaign.name,
        &origin,
        Some(char_id),
    )?;
    let prior = move |axis: AxisId| -> Prior { prior_from_summary(&summary, axis) };
    let mut sink = StoreSink {
        run: run.clone(),
        on_sample,
    };
    let r = verify::run(
        char_id,
        &c,
        Arc::new(comp),
        &prior,
        &opts,
        control,
        &done,
        &mut sink,
    )
    .await;
    let outcome = |end| Outcome {
        end,
        stats: BTreeMap::new(),
        wall_s: t0.elapsed().as_secs_f64(),
    };
    let v = match r {
        Ok(v) => v,
        Err(VerifyError::Halted(end)) => {
            let (state, msg) = if end == EndState::Aborted {
                (CampaignState::Aborted, "aborted by the operator")
            } else {
                (
                    CampaignState::Interrupted,
                    "stopped; resumes from the last stored sample",
                )
            };
            let data = json!({"state": state.as_str(), "reason": msg});
            return run.halted(state, msg, data, outcome(end));
        }
        Err(e) => return Err(fail(format!("stopped: {e}"))),
    };
    let (state, mut errors) = if v.passed {
        (CampaignState::Done, Vec::new())
    } else {
        let why: Vec<String> = v
            .axes
            .iter()
            .filter(|a| !a.passed)
            .map(|a| {
                format!(
                    "axis {}: max |after| {:.3} µm > expected {:.3} µm",
                    a.axis, a.max_abs_after_um, a.expected_um
                )
            })
            .collect();
        (
            CampaignState::Failed,
            vec![format!("verification failed: {}", why.join("; "))],
        )
    };
    let mut summary = verify::json(&v);
    summary["id"] = json!(id);
    summary["name"] = json!(&c.spec().campaign.name);
    summary["verify"] = json!(char_id);
    let table = verify::table(&v);
    let mut files = verify::files(&v);
    files.push((
        "summary.txt".into(),
        "text/plain".into(),
        table.clone().into_bytes(),
    ));
    files.push((
        "report.html".into(),
        "text/html; charset=utf-8".into(),
        verify::report_html(&v, id, &c.spec().campaign.name, c.text(), c.origin()).into_bytes(),
    ));
    let store_id = run.store_id();
    let written = run.put_files(&c, &store_id, &files, &mut errors);
    // The characterisation's report links to this verification (a failure to is logged: the
    // verification's own results are in place).
    let note = format!("(verification campaign {id})");
    let (passed, dir) = (v.passed, written.as_ref().ok());
    let warnings = store.with(|s| {
        let char_dir = finished_out_dir(s, char_id)
            .and_then(|d| super::results::owned_out_dir(&d, &store_id, char_id));
        let file_href = char_dir
            .as_deref()
            .zip(dir)
            .and_then(|(from, to)| relative_href(from, &to.join("report.html")));
        let store_href = format!("../../{id}/results/report.html");
        link_report(
            s,
            char_id,
            char_dir.as_deref().zip(file_href.as_deref()),
            &store_href,
            passed,
            &note,
        )
    });
    for w in warnings {
        tracing::warn!(campaign = char_id, "{w}");
    }
    let mut state = if errors.is_empty() {
        state
    } else {
        CampaignState::Failed
    };
    // summary.json says the campaign's state and errors, its own write's failure included.
    run.write_summary(
        &mut summary,
        &mut state,
        &mut errors,
        written.as_deref().ok(),
        None,
    )
    .map_err(|e| fail(format!("summary.json: {e}")))?;
    run.finish(
        state,
        errors,
        summary,
        table,
        outcome(EndState::Done),
        written.ok(),
    )
}

/// Where campaign `id`'s results folder went (its last `finished` event's `out_dir`).
fn finished_out_dir(store: &Store, id: i64) -> Option<std::path::PathBuf> {
    let events = store.events_after(id, 0).ok()?;
    events
        .iter()
        .rev()
        .filter(|e| e.kind == "finished")
        .find_map(|e| e.data["out_dir"].as_str().map(std::path::PathBuf::from))
}

/// `to` relative to the folder `from` (both made absolute), `/`-separated for a link.
fn relative_href(from: &std::path::Path, to: &std::path::Path) -> Option<String> {
    let (from, to) = (
        std::path::absolute(from).ok()?,
        std::path::absolute(to).ok()?,
    );
    let (a, b): (Vec<_>, Vec<_>) = (from.components().collect(), to.components().collect());
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    if common == 0 {
        return None;
    }
    let mut parts: Vec<String> = vec!["..".into(); a.len() - common];
    parts.extend(
        b[common..]
            .iter()
            .map(|c| c.as_os_str().to_string_lossy().into_owned()),
    );
    Some(parts.join("/"))
}

/// Links campaign `id`'s `report.html` to a verification: the stored copy at `store_href`
/// (relative to the API's `/campaigns/{id}/results/report.html`), and the copy in its results
/// folder, when given as (folder, href relative to it). A report that cannot be updated keeps
/// its content; what could not be done comes back as warnings.
pub fn link_report(
    store: &Store,
    id: i64,
    file: Option<(&std::path::Path, &str)>,
    store_href: &str,
    passed: bool,
    note: &str,
) -> Vec<String> {
    use crate::report::verification::with_verification_link;
    let mut warnings = Vec::new();
    if let Ok(Some((ctype, bytes))) = store.result(id, "report.html") {
        if let Some(h) = std::str::from_utf8(&bytes)
            .ok()
            .and_then(|t| with_verification_link(t, store_href, passed, note))
        {
            if let Err(e) = store.put_result(id, "report.html", &ctype, h.as_bytes()) {
                warnings.push(format!("report.html not updated in the store: {e}"));
            }
        }
    }
    if let Some((dir, href)) = file {
        let p = dir.join("report.html");
        if let Some(h) = std::fs::read_to_string(&p)
            .ok()
            .and_then(|t| with_verification_link(&t, href, passed, note))
        {
            if let Err(e) = std::fs::write(&p, h) {
                warnings.push(format!("{}: not updated: {e}", p.display()));
            }
        }
    }
    warnings
}

#[cfg(test)]
mod link_tests {
    use super::relative_href;
    use std::path::Path;

    #[test]
    fn a_sibling_folder_is_one_level_up() {
        assert_eq!(
            relative_href(Path::new("/r/char-1"), Path::new("/r/ver-2/report.html")).as_deref(),
            Some("../ver-2/report.html")
        );
        assert_eq!(
            relative_href(
                Path::new("/r/a/char-1"),
                Path::new("/r/b/ver-2/report.html")
            )
            .as_deref(),
            Some("../../b/ver-2/report.html")
        );
    }
}
