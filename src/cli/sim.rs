//! `easycalib sim serve`: the emulated rig for someone else's client. Prints
//! one `NAME PATH` line per device, then serves until Ctrl-C.

use std::io::Write;
use std::net::SocketAddr;

use clap::{Args, Subcommand};

use super::sim_setup::{SimSetupArgs, sim_setup};
use super::{CliError, ElastomerArgs};
use crate::rig::emulated::{CONTACT_STAGE_MM, EmulatedRig, EmulatedSensor, ServeOptions};

#[derive(Debug, Args)]
pub struct SimArgs {
    #[command(subcommand)]
    pub command: SimCommand,
}

#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Serve the emulated rig (stage, rotation mount, sensor) on pseudo-terminals until Ctrl-C.
    Serve(ServeArgs),
}

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Serve the stage as a GRBL controller instead of a Thorlabs KDC101 (APT).
    #[arg(long)]
    pub grbl: bool,
    /// Rig time runs this many times faster than wall time (1 = real time).
    #[arg(long, value_name = "N", default_value_t = 1.0)]
    pub speedup: f64,
    /// Send the sensor's frames as a Tac3D (UDP) to this address instead of
    /// serving easycalib's link protocol on a pty.
    #[arg(long, value_name = "HOST:PORT")]
    pub tac3d_to: Option<SocketAddr>,
    /// Give the simulated contact the left-out physics of this sim profile.
    #[arg(long, value_name = "PROFILE.toml")]
    pub profile: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub elastomer: ElastomerArgs,
}

pub fn run(args: &SimArgs) -> Result<(), CliError> {
    match &args.command {
        SimCommand::Serve(a) => serve(a),
    }
}

fn serve(a: &ServeArgs) -> Result<(), CliError> {
    let setup = sim_setup(SimSetupArgs {
        elastomer: &a.elastomer,
        script: None,
        profile: a.profile.as_deref(),
        speedup: a.speedup,
    })?;
    let truth = setup.truth();
    let opts = ServeOptions {
        grbl: a.grbl,
        sensor: match a.tac3d_to {
            Some(to) => EmulatedSensor::Tac3d { to },
            None => EmulatedSensor::LinkPty,
        },
        ..ServeOptions::default()
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|err| CliError::other(format!("cannot start the async runtime: {err}")))?;
    rt.block_on(async move {
        let rig = EmulatedRig::start(setup, opts)
            .await
            .map_err(|err| CliError::other(format!("cannot start the emulated rig: {err}")))?;
        let mut out = std::io::stdout().lock();
        for line in rig.device_lines() {
            writeln!(out, "{line}").map_err(|err| CliError::other(err.to_string()))?;
        }
        out.flush().map_err(|err| CliError::other(err.to_string()))?;
        drop(out);
        eprintln!(
            "emulated rig at {}x real time (E1 {} MPa, nu1 {}; first contact at stage {} mm); Ctrl-C to stop",
            rig.speedup(),
            truth.e1_mpa,
            truth.nu1,
            CONTACT_STAGE_MM
        );
        tokio::signal::ctrl_c().await.map_err(|err| CliError::other(format!("cannot wait for Ctrl-C: {err}")))?;
        drop(rig);
        Ok(())
    })
}
