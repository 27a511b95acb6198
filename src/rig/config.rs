//! `rig.toml`: where a real rig's devices are. Unknown keys are errors so a
//! typo never silently falls back to a default; every error names the key.
//!
//! ```toml
//! script = "my-script.toml"         # optional, relative to this file
//! [stage]
//! driver = "apt"                    # "apt" (KDC101 + Z8) or "grbl"
//! port = "/dev/easycalib-stage"
//! actuator = "z825b"                # apt: "z825b" (25 mm) or "z812b" (12 mm)
//! [rotation]
//! driver = "apt"                    # K10CR1
//! port = "/dev/easycalib-rotation"
//! [sensor]
//! kind = "tac3d"                    # "tac3d", "link-serial" or "link-udp"
//! udp_port = 9988
//! # bind = "0.0.0.0"                # tac3d: listen beyond this computer (default 127.0.0.1)
//! # source = "192.168.1.20"         # tac3d: only hear the sensor's computer
//! ```

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use devices::apt::AptConfig;
use devices::grbl::GrblConfig;
use serde::Deserialize;

use super::connect::{RigSpec, RotationSpec, SensorSpec, StageSpec};

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    /// Calibration script for this rig (relative paths are from the rig file).
    pub script: Option<PathBuf>,
    pub stage: StageConfig,
    pub rotation: RotationConfig,
    pub sensor: SensorConfig,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    /// `apt` or `grbl`.
    pub driver: String,
    pub port: PathBuf,
    /// APT actuator preset: `z825b` (default) or `z812b`.
    pub actuator: Option<String>,
    /// GRBL: axis letter (default `Z`).
    pub axis: Option<char>,
    /// GRBL: feed rate of moves, mm/min (default 60).
    pub feed_mm_per_min: Option<f64>,
    /// GRBL: soft travel `[min, max]`, mm (default `[0, 25]`).
    pub travel_mm: Option<[f64; 2]>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RotationConfig {
    /// Only `apt` (Thorlabs K10CR1) is supported.
    pub driver: String,
    pub port: PathBuf,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorConfig {
    /// `tac3d`, `link-serial` or `link-udp`.
    pub kind: String,
    /// Name for the recording and the output folder.
    pub name: Option<String>,
    /// tac3d: local UDP port the main program sends to (default 9988).
    pub udp_port: Option<u16>,
    /// link-serial: the serial device.
    pub path: Option<PathBuf>,
    /// link-serial: baud rate (default 115200).
    pub baud: Option<u32>,
    /// link-udp: local address to bind (default `0.0.0.0:0`, or loopback for a
    /// loopback device); tac3d: the local IP address to listen on (default
    /// 127.0.0.1), given as `ADDR` or `ADDR:PORT`.
    pub bind: Option<String>,
    /// tac3d: only accept datagrams from this IP address (the sensor's computer).
    pub source: Option<std::net::IpAddr>,
    /// link-udp: the device's address.
    pub device: Option<SocketAddr>,
}

/// Why a rig file was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read rig file {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("rig file{}: {message}", at.as_ref().map(|p| format!(" {}", p.display())).unwrap_or_default())]
    Parse { at: Option<PathBuf>, message: String },
    #[error("rig file `{key}`: {message}")]
    Invalid { key: &'static str, message: String },
}

fn invalid(key: &'static str, message: impl Into<String>) -> ConfigError {
    ConfigError::Invalid { key, message: message.into() }
}

impl RigConfig {
    pub fn from_toml(text: &str) -> Result<RigConfig, ConfigError> {
        let cfg: RigConfig =
            toml::from_str(text).map_err(|e| ConfigError::Parse { at: None, message: e.to_string() })?;
        cfg.to_spec()?;
        Ok(cfg)
    }

    /// Read a rig file; a relative `script` path becomes relative to the file.
    pub fn read_path(path: &Path) -> Result<RigConfig, ConfigError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        let mut cfg = Self::from_toml(&text).map_err(|e| match e {
            ConfigError::Parse { message, .. } => ConfigError::Parse { at: Some(path.to_path_buf()), message },
            other => other,
        })?;
        if let Some(s) = &cfg.script
            && s.is_relative()
        {
            cfg.script = Some(path.parent().unwrap_or(Path::new(".")).join(s));
        }
        Ok(cfg)
    }

    /// The devices to open.
    pub fn to_spec(&self) -> Result<RigSpec, ConfigError> {
        let stage = match self.stage.driver.as_str() {
            "apt" => {
                if self.stage.axis.is_some() || self.stage.feed_mm_per_min.is_some() || self.stage.travel_mm.is_some() {
                    return Err(invalid("stage", "axis, feed_mm_per_min and travel_mm are GRBL settings"));
                }
                let cfg = match self.stage.actuator.as_deref().unwrap_or("z825b") {
                    "z825b" => AptConfig::kdc101_z825b(),
                    "z812b" => AptConfig::kdc101_z812b(),
                    other => {
                        return Err(invalid("stage.actuator", format!("`{other}` is not one of \"z825b\", \"z812b\"")));
                    }
                };
                StageSpec::Apt { path: self.stage.port.clone(), cfg }
            }
            "grbl" => {
                if self.stage.actuator.is_some() {
                    return Err(invalid("stage.actuator", "an actuator preset applies to the APT driver only"));
                }
                let mut cfg = GrblConfig::default();
                if let Some(a) = self.stage.axis {
                    if !"XYZABC".contains(a.to_ascii_uppercase()) {
                        return Err(invalid("stage.axis", format!("`{a}` is not one of X, Y, Z, A, B, C")));
                    }
                    cfg.axis = a.to_ascii_uppercase();
                }
                if let Some(f) = self.stage.feed_mm_per_min {
                    if !(f.is_finite() && f > 0.0) {
                        return Err(invalid("stage.feed_mm_per_min", format!("must be a positive number, got {f}")));
                    }
                    cfg.feed_mm_per_min = f;
                }
                if let Some([lo, hi]) = self.stage.travel_mm {
                    if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                        return Err(invalid("stage.travel_mm", format!("needs min < max, got [{lo}, {hi}]")));
                    }
                    cfg.travel_mm = (lo, hi);
                }
                StageSpec::Grbl { path: self.stage.port.clone(), cfg }
            }
            other => return Err(invalid("stage.driver", format!("`{other}` is not one of \"apt\", \"grbl\""))),
        };
        if self.rotation.driver != "apt" {
            return Err(invalid(
                "rotation.driver",
                format!("`{}` is not supported (only \"apt\", a Thorlabs K10CR1)", self.rotation.driver),
            ));
        }
        let rotation = RotationSpec { path: self.rotation.port.clone(), cfg: AptConfig::k10cr1() };
        let s = &self.sensor;
        let unused = |key: &'static str, present: bool| {
            if present { Err(invalid(key, format!("does not apply to a `{}` sensor", s.kind))) } else { Ok(()) }
        };
        let sensor = match s.kind.as_str() {
            "tac3d" => {
                unused("sensor.path", s.path.is_some())?;
                unused("sensor.baud", s.baud.is_some())?;
                unused("sensor.device", s.device.is_some())?;
                let port = s.udp_port.unwrap_or(devices::sensor::tac3d::DEFAULT_PORT);
                let ip = match s.bind.as_deref() {
                    None => std::net::IpAddr::from([127, 0, 0, 1]),
                    Some(b) => b
                        .parse::<std::net::IpAddr>()
                        .or_else(|_| b.parse::<SocketAddr>().map(|a| a.ip()))
                        .map_err(|_| invalid("sensor.bind", format!("`{b}` is not an IP address")))?,
                };
                SensorSpec::Tac3d { bind: SocketAddr::new(ip, port), source: s.source }
            }
            "link-serial" => {
                unused("sensor.udp_port", s.udp_port.is_some())?;
                unused("sensor.device", s.device.is_some())?;
                unused("sensor.bind", s.bind.is_some())?;
                unused("sensor.source", s.source.is_some())?;
                let path = s
                    .path
                    .clone()
                    .ok_or_else(|| invalid("sensor.path", "a link-serial sensor needs its serial device"))?;
                SensorSpec::LinkSerial { path, baud: s.baud.unwrap_or(115_200) }
            }
            "link-udp" => {
                unused("sensor.udp_port", s.udp_port.is_some())?;
                unused("sensor.path", s.path.is_some())?;
                unused("sensor.baud", s.baud.is_some())?;
                unused("sensor.source", s.source.is_some())?;
                let device =
                    s.device.ok_or_else(|| invalid("sensor.device", "a link-udp sensor needs the device's address"))?;
                let bind = match s.bind.as_deref() {
                    Some(b) => b
                        .parse::<SocketAddr>()
                        .map_err(|_| invalid("sensor.bind", format!("`{b}` is not an ADDR:PORT socket address")))?,
                    None if device.ip().is_loopback() => SocketAddr::from(([127, 0, 0, 1], 0)),
                    None => SocketAddr::from(([0, 0, 0, 0], 0)),
                };
                SensorSpec::LinkUdp { bind, device }
            }
            other => {
                return Err(invalid(
                    "sensor.kind",
                    format!("`{other}` is not one of \"tac3d\", \"link-serial\", \"link-udp\""),
                ));
            }
        };
        let sensor_name = s.name.clone().unwrap_or_else(|| s.kind.clone());
        Ok(RigSpec { stage, rotation, sensor, sensor_name })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ROOT: &str = env!("CARGO_MANIFEST_DIR");

    #[test]
    fn shipped_examples_parse() {
        let thor = RigConfig::read_path(&Path::new(ROOT).join("examples/rig-thorlabs.toml")).unwrap();
        let spec = thor.to_spec().unwrap();
        assert!(
            matches!(&spec.stage, StageSpec::Apt { path, cfg } if path == Path::new("/dev/easycalib-stage") && cfg.travel == (0.0, 25.0))
        );
        assert_eq!(spec.rotation.path, Path::new("/dev/easycalib-rotation"));
        assert_eq!(spec.sensor, SensorSpec::Tac3d { bind: "127.0.0.1:9988".parse().unwrap(), source: None });
        let grbl = RigConfig::read_path(&Path::new(ROOT).join("examples/rig-grbl.toml")).unwrap();
        let spec = grbl.to_spec().unwrap();
        assert!(
            matches!(&spec.stage, StageSpec::Grbl { path, cfg } if path == Path::new("/dev/easycalib-grbl") && cfg.axis == 'Z')
        );
        assert!(matches!(&spec.sensor, SensorSpec::LinkSerial { baud: 115_200, .. }));
    }

    fn base() -> String {
        "[stage]\ndriver = \"apt\"\nport = \"/dev/a\"\n[rotation]\ndriver = \"apt\"\nport = \"/dev/b\"\n[sensor]\nkind = \"tac3d\"\n"
            .into()
    }

    #[test]
    fn mistakes_name_the_key() {
        assert!(RigConfig::from_toml(&base()).is_ok());
        let e = RigConfig::from_toml(
            &base().replace("driver = \"apt\"\nport = \"/dev/a\"", "driver = \"zaber\"\nport = \"/dev/a\""),
        )
        .unwrap_err();
        assert!(e.to_string().contains("stage.driver") && e.to_string().contains("zaber"), "{e}");
        let e = RigConfig::from_toml(&base().replace("kind = \"tac3d\"", "kind = \"link-serial\"")).unwrap_err();
        assert!(e.to_string().contains("sensor.path"), "{e}");
        let e = RigConfig::from_toml(&(base() + "baud = 9600\n")).unwrap_err();
        assert!(e.to_string().contains("sensor.baud"), "{e}");
        let e = RigConfig::from_toml(&base().replace("port = \"/dev/b\"", "port = \"/dev/b\"\nspeed = 3")).unwrap_err();
        assert!(e.to_string().contains("speed"), "{e}");
        let e = RigConfig::from_toml(&base().replace("[rotation]", "actuator = \"z999\"\n[rotation]")).unwrap_err();
        assert!(e.to_string().contains("stage.actuator"), "{e}");
    }

    #[test]
    fn tac3d_listens_on_loopback_unless_opened_wider() {
        let spec = RigConfig::from_toml(&base()).unwrap().to_spec().unwrap();
        assert_eq!(spec.sensor, SensorSpec::Tac3d { bind: "127.0.0.1:9988".parse().unwrap(), source: None });
        let wide = base() + "bind = \"0.0.0.0\"\nsource = \"192.168.1.20\"\nudp_port = 9000\n";
        let spec = RigConfig::from_toml(&wide).unwrap().to_spec().unwrap();
        assert_eq!(
            spec.sensor,
            SensorSpec::Tac3d { bind: "0.0.0.0:9000".parse().unwrap(), source: Some("192.168.1.20".parse().unwrap()) }
        );
        let e = RigConfig::from_toml(&(base() + "bind = \"nowhere\"\n")).unwrap_err();
        assert!(e.to_string().contains("sensor.bind"), "{e}");
    }
}
