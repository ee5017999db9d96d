//! The integration tests against simulated hardware, as one test binary: cargo runs test
//! binaries one after another, while one binary's tests share the cores (a campaign test that
//! keeps one core busy for a minute no longer leaves the other idle), and the crate is linked
//! once instead of once per file. Each file is a module named as its old binary; run one with
//! `cargo test --test system MODULE::` (e.g. `cargo test --test system web_page::`).
//! Kept as binaries of their own: the tests built with optional features (`camera_aravis`,
//! `camera_cli`, `check_cli`, `sim_rig`, `nexus_export`: CI runs them with `--features`), the
//! stop-latency bound (timed: it runs alone), PI's Python client (`gcs_pipython`), and the two
//! that set the process's lock directory (`queue_stranded`, `trust_api`: `set_var` while other
//! threads read the environment is a data race).

#[path = "../common/mod.rs"]
mod common;
// The second gap generator, shared by gap_independent and gap_iso230.
#[path = "../common/gapgen.rs"]
mod gapgen;

mod api_service;
mod campaign_abort;
mod campaign_adaptive;
mod campaign_failures;
mod campaign_faults;
mod campaign_pause_restart;
mod campaign_run;
mod campaign_soak;
mod client_cli;
mod compensation_api;
mod compensation_sim;
mod compensation_xy;
mod config_examples;
mod events_audit;
mod export_controllers;
mod gap_campaign;
mod gap_cli;
mod gap_fuzz;
mod gap_independent;
mod gap_input;
mod gap_iso230;
mod gap_iso_real;
mod gap_othergen;
mod gcs_cli;
mod gcs_driver;
mod gcs_soak;
mod iso_uncertainty;
mod map_campaign;
mod map_loop;
mod map_service;
mod ppp_cli;
mod recon_band;
mod recon_bpdn;
mod recon_periods;
mod recon_real;
mod reconstruct2d_band_variants;
mod reconstruct2d_input;
mod reconstruct2d_maps;
mod reconstruct2d_rough;
mod reconstruct_cli;
mod report_html;
mod samples_layout;
mod security;
mod systemd_unit;
mod trust_cli;
mod trust_fuzz;
mod web_page;
