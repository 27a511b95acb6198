//! `easycalib devices`: list serial ports (USB ids, serial number, product,
//! udev symlinks) and, with `--probe`, ask each what it is without moving it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::Args;
use devices::discovery::{self, PortInfo, ProbeAttempt};
use serde::Serialize;

use super::CliError;

#[derive(Debug, Args)]
pub struct DevicesArgs {
    /// Ask each port what it is (APT identify, GRBL `?`/`$I`); never moves anything.
    #[arg(long)]
    pub probe: bool,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Time allowed per port and protocol when probing, ms (an Arduino that
    /// reboots on open needs about 2 s before GRBL answers).
    #[arg(long, default_value_t = 2500)]
    pub timeout_ms: u64,
    /// Also list serial ports that are not USB (on-board ttyS*).
    #[arg(long)]
    pub all: bool,
    /// Extra ports to list and probe, e.g. an emulator's /dev/pts/N from `easycalib sim serve`.
    pub paths: Vec<PathBuf>,
    /// sysfs root to read (for tests).
    #[arg(long, hide = true, default_value = "/sys")]
    pub sysfs_root: PathBuf,
    /// Directory holding device nodes and udev symlinks (for tests).
    #[arg(long, hide = true, default_value = "/dev")]
    pub dev_root: PathBuf,
}

/// One listed port and, if probed, what each protocol's probe said.
#[derive(Debug, Serialize)]
pub struct DeviceEntry {
    #[serde(flatten)]
    pub port: PortInfo,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub probe: Option<Vec<ProbeAttempt>>,
}

/// The listing (and probe results) for `args`.
pub fn collect(args: &DevicesArgs) -> Result<Vec<DeviceEntry>, CliError> {
    let mut ports = match discovery::list_ports_in(&args.sysfs_root, &args.dev_root, args.all) {
        Ok(p) => p,
        // No sysfs (a container): explicit paths still work.
        Err(e) if args.paths.is_empty() => {
            return Err(CliError::other(format!("cannot list serial ports under {}: {e}", args.sysfs_root.display())));
        }
        Err(_) => Vec::new(),
    };
    for path in &args.paths {
        if !path.exists() {
            return Err(CliError::bad_input(format!("{}: no such device", path.display())));
        }
        let p = discovery::port_for_path(path, &ports, &args.dev_root);
        if !ports.iter().any(|q| q.path == p.path) {
            ports.push(p);
        }
    }
    let probes = if args.probe {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| CliError::other(format!("cannot start the async runtime: {e}")))?;
        let timeout = Duration::from_millis(args.timeout_ms);
        let probers = discovery::default_probers();
        rt.block_on(discovery::probe_all(&ports, &probers, timeout)).into_iter().map(Some).collect()
    } else {
        vec![None; ports.len()]
    };
    Ok(ports.into_iter().zip(probes).map(|(port, probe)| DeviceEntry { port, probe }).collect())
}

fn show(p: &Path) -> String {
    p.display().to_string()
}

/// Human-readable listing.
pub fn render_text(entries: &[DeviceEntry]) -> String {
    let mut s = String::new();
    if entries.is_empty() {
        s.push_str("no serial ports found\n");
    }
    for e in entries {
        let p = &e.port;
        let _ = write!(s, "{}", show(&p.path));
        match &p.usb {
            Some(u) => {
                let _ = write!(s, "  {}", u.id());
                let _ = write!(s, "  serial {}", u.serial.as_deref().unwrap_or("-"));
                if let Some(prod) = &u.product {
                    let _ = write!(s, "  \"{prod}\"");
                }
                if let Some(m) = &u.manufacturer {
                    let _ = write!(s, " ({m})");
                }
            }
            None => s.push_str("  (not USB)"),
        }
        s.push('\n');
        if !p.symlinks.is_empty() {
            let links: Vec<_> = p.symlinks.iter().map(|l| show(l)).collect();
            let _ = writeln!(s, "    links: {}", links.join(", "));
        }
        if let Some(h) = &p.hint {
            let _ = writeln!(s, "    looks like: {h}");
        }
        for a in e.probe.iter().flatten() {
            match (&a.info, &a.error) {
                (Some(i), _) => {
                    let serial = if i.serial.is_empty() { String::new() } else { format!(", serial {}", i.serial) };
                    let _ = writeln!(s, "    probe {}: {} (firmware {}{serial})", a.kind, i.model, i.firmware);
                }
                (None, Some(err)) => {
                    let _ = writeln!(s, "    probe {}: no ({err})", a.kind);
                }
                (None, None) => {}
            }
        }
    }
    s
}

pub fn run(args: &DevicesArgs) -> Result<(), CliError> {
    let entries = collect(args)?;
    if args.json {
        let doc = serde_json::json!({ "ports": entries });
        let text =
            serde_json::to_string_pretty(&doc).map_err(|e| CliError::other(format!("cannot encode JSON: {e}")))?;
        println!("{text}");
    } else {
        print!("{}", render_text(&entries));
    }
    Ok(())
}
