//! `sim-host`: render camera frames, run the vision, fly the paper's experiment in simulation.
//!
//! Exit codes: 0 success; 1 bad input or option (message on stderr); 2 the frame has no target (or the frame
//! pair no flow); 3 the simulated vehicle crashed.
mod cli;

use clap::{Parser, Subcommand};
use cli::export::{ExportArgs, run_export};
use cli::fly::{FlyArgs, fly};
use cli::import::{ImportCommand, import_euroc, import_ulog};
use cli::render::{RenderArgs, render};
use cli::replay::{ReplayArgs, replay};
use cli::sweep::{SweepArgs, sweep};
use cli::vision::{VisionCommand, vision_flow, vision_pose};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "sim-host",
    version,
    about = "Simulator, ground-station vision and tools for the wall-line quadrotor",
    long_about = "Simulator, ground-station vision and tools for the wall-line quadrotor.\n\n\
        World frame: x along the wall and the line, y from the wall to the vehicle (the distance to the wall), \
        z up from the floor. Angles are in degrees; roll, pitch and yaw are all zero when the vehicle is level \
        and faces the wall. Body frame: x forward, y left, z up.\n\nExit codes: 0 success, 1 bad input or \
        option, 2 no target in the frame (or no flow between two frames), 3 the simulated vehicle crashed."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args, Debug)]
struct KeygenArgs {
    /// The key file to write (refused if it exists).
    #[arg(long, value_name = "FILE")]
    out: std::path::PathBuf,
}

#[derive(clap::Args, Debug)]
struct KeyImageArgs {
    /// The key file (`sim-host keygen --out FILE`).
    #[arg(long, value_name = "FILE")]
    key: std::path::PathBuf,
    /// The 48-byte flash block to write (refused if it exists; mode 0600).
    #[arg(long, value_name = "FILE")]
    out: std::path::PathBuf,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render the frame a camera sees from a vehicle pose.
    Render(RenderArgs),
    /// Run the vision on recorded frames.
    #[command(subcommand)]
    Vision(VisionCommand),
    /// Fly a scenario in simulation with the flight code (software in the loop).
    Fly(FlyArgs),
    /// Re-run the flight stack on a flight log's inputs and compare every output with the log, bit for bit.
    Replay(ReplayArgs),
    /// Export a flight log to MCAP (Foxglove, Lichtblick, PlotJuggler, Rerun) and/or CSV files.
    Export(ExportArgs),
    /// Import a recorded dataset into a flight log (then `replay --out` runs the flight code on it).
    #[command(subcommand)]
    Import(ImportCommand),
    /// Fly many seeded runs of a mission with the scenario drawn from distributions (model error, wind,
    /// faults), in parallel and shardable; `sweep merge` joins the shards.
    Sweep(SweepArgs),
    /// The ground station for a real vehicle, or the virtual one (`fly --serve-link ...`): the cameras'
    /// streams measured, the measurements stamped on the vehicle's clock and sent up the radio with the
    /// operator's commands.
    Station(cli::station::StationArgs),
    /// Upload a scenario's flight configuration (parameters, forward camera, line) to a vehicle on the ground
    /// over its radio: applied at once and stored in its flash, loaded at each boot (docs/firmware.md,
    /// "Parameters in flash").
    Configure(cli::configure::ConfigureArgs),
    /// Make a new radio key (32 random bytes, mode 0600) for `station --key` and the vehicle
    /// (docs/security.md); an existing file is never overwritten.
    Keygen(KeygenArgs),
    /// Turn a radio key file into the flash block a debug probe writes into the board (never sent over the
    /// radio): `probe-rs download --chip STM32F405RGTx --binary-format bin --base-address 0x080E0000 FILE`
    /// (docs/security.md, "Provisioning a board").
    KeyImage(KeyImageArgs),
    /// Print the flight parameters' reference as Markdown (docs/parameters.md): each parameter's dotted name,
    /// type, default, range, unit and description, from their one declaration.
    Params,
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            use clap::error::ErrorKind;
            let code = match e.kind() {
                ErrorKind::DisplayHelp
                | ErrorKind::DisplayVersion
                | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => 0,
                _ => 1,
            };
            let _ = e.print();
            return ExitCode::from(code);
        }
    };
    let result = match &cli.command {
        Command::Render(a) => render(a),
        Command::Vision(VisionCommand::Pose(a)) => vision_pose(a),
        Command::Vision(VisionCommand::Flow(a)) => vision_flow(a),
        Command::Fly(a) => fly(a),
        Command::Station(a) => cli::station::station(a),
        Command::Configure(a) => cli::configure::configure(a),
        Command::Keygen(a) => sim_host::link_key::keygen(&a.out).map(|()| {
            eprintln!(
                "wrote the radio key {} (mode 0600): give it to the station and the vehicle",
                a.out.display()
            );
            ExitCode::SUCCESS
        }),
        Command::KeyImage(a) => sim_host::link_key::key_image(&a.key, &a.out).map(|()| {
            eprintln!(
                "wrote the key image {} (48 bytes, mode 0600): write it with `probe-rs download --chip \
                 STM32F405RGTx --binary-format bin --base-address 0x080E0000 {}`, then delete it",
                a.out.display(),
                a.out.display()
            );
            ExitCode::SUCCESS
        }),
        Command::Replay(a) => replay(a),
        Command::Export(a) => run_export(a),
        Command::Import(ImportCommand::Euroc(a)) => import_euroc(a),
        Command::Import(ImportCommand::Ulog(a)) => import_ulog(a),
        Command::Sweep(a) => sweep(a),
        Command::Params => sim_host::params_doc::markdown().map(|page| {
            print!("{page}");
            ExitCode::SUCCESS
        }),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
