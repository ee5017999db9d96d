//! `csmetro`: one binary, one subcommand per job.
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use csmetro::cli;

#[derive(Parser)]
#[command(
    name = "csmetro",
    version,
    about = "Compressive-sensing metrology for micropositioning stages"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Recover a whole error curve from m samples on a grid.
    Reconstruct(cli::reconstruct::Args),
    /// Recover the XY workspace error map e_x, e_y (θ) from samples at scattered grid points.
    Reconstruct2d(cli::reconstruct2d::Args),
    /// Write a paper-like reference error curve (full and sampled) as CSV.
    Generate(cli::generate::Args),
    /// Reconstruction demo on generated data: every method against the ground truth.
    Demo(cli::demo::Args),
    /// Benchmarks that print JSON (accuracy and speed).
    Bench(cli::bench::Args),
    /// Pseudo-periodic pattern: render a camera frame, decode a frame.
    Ppp(cli::ppp::Args),
    /// Simulated devices (C-863 controller, camera).
    Sim(cli::sim::Args),
    /// Sim-to-real gap diagnosis: where measured data leave the stage model, and which effect explains it.
    Gap(cli::gap::Args),
    /// Pre-flight of a campaign without motion: config, controllers, limits, camera, pattern, store.
    Check(cli::check::Args),
    /// Run a campaign file in the foreground: acquisition, reconstruction, report.
    Run(cli::run::Args),
    /// Continue an interrupted campaign from its last stored sample.
    Resume(cli::run::ResumeArgs),
    /// The HTTP/JSON service: queues and runs campaigns, streams their events, serves results.
    Serve(cli::serve::Args),
    /// Send a campaign file to the service; prints its id.
    Submit(cli::client::SubmitArgs),
    /// State and progress of one campaign, or of all, on the service.
    Status(cli::client::StatusArgs),
    /// Follow a campaign's events until it ends (exit 0 done, 130 aborted, 1 otherwise).
    Watch(cli::client::WatchArgs),
    /// Pause a running campaign on the service (between two points).
    Pause(cli::client::IdArgs),
    /// Continue a paused campaign, or queue an interrupted one again, on the service.
    Unpause(cli::client::IdArgs),
    /// Abort a campaign on the service: motion stops, the campaign ends aborted.
    Abort(cli::client::AbortArgs),
    /// Download every result (curves, plots, tables, summary) of a campaign.
    Report(cli::client::ReportArgs),
    /// Fault soak: simulated campaigns with random faults and kills, checked against the truth (JSON).
    Soak(cli::soak::Args),
    /// Move the stage to wanted positions, with the measured compensation applied.
    Move(cli::move_cmd::Args),
    /// Verification run: measure a characterised stage again without and with its compensation.
    Verify(cli::verify::Args),
    /// Cameras: list those this build reaches, grab and decode one frame.
    Camera(cli::camera::Args),
    /// Write a stored campaign in a facility's format (NeXus/HDF5).
    Export(cli::export::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Reconstruct(a) => cli::reconstruct::run(a),
        Command::Reconstruct2d(a) => cli::reconstruct2d::run(a),
        Command::Generate(a) => cli::generate::run(a),
        Command::Demo(a) => cli::demo::run(a),
        Command::Bench(a) => cli::bench::run(a),
        Command::Ppp(a) => cli::ppp::run(a),
        Command::Sim(a) => cli::sim::run(a),
        Command::Gap(a) => cli::gap::run(a),
        Command::Check(a) => cli::check::run(a),
        Command::Run(a) => cli::run::run(a),
        Command::Resume(a) => cli::run::resume(a),
        Command::Serve(a) => cli::serve::run(a),
        Command::Submit(a) => cli::client::submit(a),
        Command::Status(a) => cli::client::status(a),
        Command::Watch(a) => cli::client::watch(a),
        Command::Pause(a) => cli::client::pause(a),
        Command::Unpause(a) => cli::client::unpause(a),
        Command::Abort(a) => cli::client::abort(a),
        Command::Report(a) => cli::client::report(a),
        Command::Soak(a) => cli::soak::run(a),
        Command::Move(a) => cli::move_cmd::run(a),
        Command::Verify(a) => cli::verify::run(a),
        Command::Camera(a) => cli::camera::run(a),
        Command::Export(a) => cli::export::run(a),
    };
    cli::finish(result)
}
