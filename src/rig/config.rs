//! `rig.toml`: where a real rig's devices are. Unknown keys are errors so a
//! typo never silently falls back to a default; every error names the key.
//! The `[stage]` and `[rotation]` sections name a registered driver
//! (`super::drivers`), which reads its own keys there.
//!
//! ```toml
//! script = "my-script.toml"         # optional, relative to this file
//! [stage]
//! driver = "apt"                    # "apt" (KDC101 + Z8) or "grbl"
//! port = "/dev/easycalib-stage"
//! actuator = "z825b"                # apt: "z825b" (25 mm) or "z812b" (12 mm)
//! # grbl: axis = "Z", feed_mm_per_min = 60, travel_mm = [0, 25]
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

use serde::Deserialize;

use super::connect::{RigSpec, SensorSpec};
use super::drivers::Drivers;

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    /// Calibration script for this rig (relative paths are from the rig file).
    pub script: Option<PathBuf>,
    pub stage: AxisConfig,
    pub rotation: AxisConfig,
    pub sensor: SensorConfig,
}

/// A `[stage]` or `[rotation]` section.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct AxisConfig {
    /// A registered driver's name, e.g. `apt` or `grbl`.
    pub driver: String,
    pub port: PathBuf,
    /// The driver's own keys (e.g. `actuator`), read by the driver.
    #[serde(flatten)]
    pub keys: toml::Table,
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
    #[error("rig file{}: {source}", at.as_ref().map(|p| format!(" {}", p.display())).unwrap_or_default())]
    Parse {
        at: Option<PathBuf>,
        #[source]
        source: toml::de::Error,
    },
    #[error("rig file `{key}`: {message}")]
    Invalid { key: String, message: String },
    #[error("rig file `{key}`: {source}")]
    Value {
        key: String,
        #[source]
        source: toml::de::Error,
    },
}

fn invalid(key: &str, message: impl Into<String>) -> ConfigError {
    ConfigError::Invalid { key: key.to_string(), message: message.into() }
}

impl RigConfig {
    /// Parse and check a rig file's text against the built-in drivers.
    pub fn from_toml(text: &str) -> Result<RigConfig, ConfigError> {
        Self::from_toml_with(text, &Drivers::builtin())
    }

    /// Parse and check a rig file's text against `drivers`.
    pub fn from_toml_with(text: &str, drivers: &Drivers) -> Result<RigConfig, ConfigError> {
        let cfg: RigConfig = toml::from_str(text).map_err(|source| ConfigError::Parse { at: None, source })?;
        cfg.to_spec_with(drivers)?;
        Ok(cfg)
    }

    /// Read a rig file; a relative `script` path becomes relative to the file.
    pub fn read_path(path: &Path) -> Result<RigConfig, ConfigError> {
        Self::read_path_with(path, &Drivers::builtin())
    }

    /// [`Self::read_path`] against `drivers`.
    pub fn read_path_with(path: &Path, drivers: &Drivers) -> Result<RigConfig, ConfigError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        let mut cfg = Self::from_toml_with(&text, drivers).map_err(|e| match e {
            ConfigError::Parse { source, .. } => ConfigError::Parse { at: Some(path.to_path_buf()), source },
            other => other,
        })?;
        if let Some(s) = &cfg.script
            && s.is_relative()
        {
            cfg.script = Some(path.parent().unwrap_or(Path::new(".")).join(s));
        }
        Ok(cfg)
    }

    /// The devices to open, with the built-in drivers.
    pub fn to_spec(&self) -> Result<RigSpec, ConfigError> {
        self.to_spec_with(&Drivers::builtin())
    }

    /// The devices to open; the stage and the mount by the `drivers` they name.
    pub fn to_spec_with(&self, drivers: &Drivers) -> Result<RigSpec, ConfigError> {
        let stage = drivers.stage_spec(&self.stage.driver, &self.stage.port, self.stage.keys.clone())?;
        let rotation = drivers.rotation_spec(&self.rotation.driver, &self.rotation.port, self.rotation.keys.clone())?;
        let sensor = self.sensor_spec()?;
        let sensor_name = self.sensor.name.clone().unwrap_or_else(|| self.sensor.kind.clone());
        Ok(RigSpec { stage, rotation, sensor, sensor_name })
    }

    fn sensor_spec(&self) -> Result<SensorSpec, ConfigError> {
        let s = &self.sensor;
        let unused = |key: &str, present: bool| {
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
        Ok(sensor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use devices::apt::AptConfig;
    use devices::grbl::GrblConfig;

    const ROOT: &str = env!("CARGO_MANIFEST_DIR");

    #[test]
    fn shipped_examples_parse() {
        let thor = RigConfig::read_path(&Path::new(ROOT).join("examples/rig-thorlabs.toml")).unwrap();
        let spec = thor.to_spec().unwrap();
        assert!(
            spec.stage.path == Path::new("/dev/easycalib-stage")
                && spec.stage.settings::<AptConfig>().is_some_and(|cfg| cfg.travel == (0.0, 25.0))
        );
        assert_eq!(spec.rotation.path, Path::new("/dev/easycalib-rotation"));
        assert_eq!(spec.sensor, SensorSpec::Tac3d { bind: "127.0.0.1:9988".parse().unwrap(), source: None });
        let grbl = RigConfig::read_path(&Path::new(ROOT).join("examples/rig-grbl.toml")).unwrap();
        let spec = grbl.to_spec().unwrap();
        assert!(
            spec.stage.path == Path::new("/dev/easycalib-grbl")
                && spec.stage.settings::<GrblConfig>().is_some_and(|cfg| cfg.axis == 'Z')
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
