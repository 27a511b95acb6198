//! The one place a motion driver is registered.
//!
//! A driver is known to the controller by one [`Driver`] entry: its name in a
//! rig file (`driver = "apt"` under `[stage]` or `[rotation]`) and, for each
//! axis it can drive, a function that reads its own keys of that section into
//! its settings. The settings know how to open the device ([`OpenAxis`]),
//! which gives a boxed [`devices::Axis`] ([`DynAxis`]): from there the rig
//! file, the emulated rig, the session and the sequencer treat every driver
//! alike. [`BUILTIN`] lists the drivers of this build; a program (or a test)
//! may register more with [`Drivers::with`].
//!
//! Adding a driver (ARCHITECTURE.md, "Adding a driver"): implement
//! [`devices::Axis`] for it, then add its entry to [`BUILTIN`] below with its
//! settings reader and its [`OpenAxis`] impl next to the others here.

use std::any::Any;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use async_trait::async_trait;
use devices::apt::{AptAxis, AptConfig};
use devices::grbl::{GrblConfig, GrblStage};
use devices::motion::{AxisFault, Deg, DeviceFault, DynAxis, Mm, Unit, boxed};
use devices::serial::{open_serial, open_serial_settle};
use serde::de::DeserializeOwned;
use tokio_serial::SerialStream;

use super::config::ConfigError;

/// Why an axis could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error("cannot open the port: {0}")]
    Port(#[source] std::io::Error),
    #[error("{driver} connect: {source}")]
    Connect {
        /// The driver family, e.g. `APT`.
        driver: &'static str,
        #[source]
        source: AxisFault,
    },
}

impl OpenError {
    /// A driver's connect failed.
    pub fn connect<E: DeviceFault>(driver: &'static str) -> impl FnOnce(E) -> OpenError {
        move |e| OpenError::Connect { driver, source: AxisFault::new(e) }
    }
}

/// A driver's settings for one axis, able to open the device they describe.
#[async_trait]
pub trait OpenAxis<U: Unit>: fmt::Debug + Send + Sync + AsAny {
    /// Open and start the device at `path` (identify is the sequencer's first step).
    async fn open(&self, path: &Path) -> Result<DynAxis<U>, OpenError>;
}

/// Gives settings back as their own type ([`AxisSpec::settings`]).
pub trait AsAny: Any {
    fn as_any(&self) -> &dyn Any;
}

impl<T: Any> AsAny for T {
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// Where one axis is and which driver, with which settings, opens it.
#[derive(Debug, Clone)]
pub struct AxisSpec<U> {
    pub path: PathBuf,
    settings: Arc<dyn OpenAxis<U>>,
}

/// The linear stage of a rig.
pub type StageSpec = AxisSpec<Mm>;
/// The rotation mount of a rig.
pub type RotationSpec = AxisSpec<Deg>;

impl<U: Unit> AxisSpec<U> {
    pub fn new(path: impl Into<PathBuf>, settings: impl OpenAxis<U>) -> Self {
        Self { path: path.into(), settings: Arc::new(settings) }
    }

    /// The driver's settings, when they are an `S` (e.g. [`AptConfig`]).
    pub fn settings<S: Any>(&self) -> Option<&S> {
        self.settings.as_ref().as_any().downcast_ref()
    }

    pub async fn open(&self) -> Result<DynAxis<U>, OpenError> {
        self.settings.open(&self.path).await
    }
}

/// Reads a driver's own keys of a rig-file section into its settings.
pub type ReadSettings<U> = fn(&mut Keys) -> Result<Arc<dyn OpenAxis<U>>, ConfigError>;

/// One driver as rig files name it.
#[derive(Clone, Copy)]
pub struct Driver {
    /// `driver = "..."` in a rig file.
    pub name: &'static str,
    /// Its `[stage]` keys; `None` when it drives no linear stage.
    pub stage: Option<ReadSettings<Mm>>,
    /// Its `[rotation]` keys; `None` when it drives no rotation mount.
    pub rotation: Option<ReadSettings<Deg>>,
}

/// The drivers of this build: the one list a new driver joins.
pub const BUILTIN: &[Driver] = &[
    // Thorlabs APT: KDC101 + Z8 actuator, K10CR1 rotation mount.
    Driver { name: "apt", stage: Some(apt_stage), rotation: Some(apt_rotation) },
    // A GRBL 1.1 controller driving a stepper micrometer.
    Driver { name: "grbl", stage: Some(grbl_stage), rotation: None },
];

/// The drivers a rig file may name.
#[derive(Clone)]
pub struct Drivers(Vec<Driver>);

impl Default for Drivers {
    fn default() -> Self {
        Self::builtin()
    }
}

impl Drivers {
    pub fn builtin() -> Self {
        Self(BUILTIN.to_vec())
    }

    /// These drivers and `driver` (which replaces one of the same name).
    pub fn with(mut self, driver: Driver) -> Self {
        self.0.retain(|d| d.name != driver.name);
        self.0.push(driver);
        self
    }

    /// The reader of `section` (`stage` or `rotation`) for `driver`; the
    /// error lists the drivers that can drive that axis.
    fn reader<U>(
        &self,
        section: &'static str,
        driver: &str,
        pick: fn(&Driver) -> Option<ReadSettings<U>>,
    ) -> Result<ReadSettings<U>, ConfigError> {
        if let Some(read) = self.0.iter().find(|d| d.name == driver).and_then(pick) {
            return Ok(read);
        }
        let names: Vec<String> =
            self.0.iter().filter(|d| pick(d).is_some()).map(|d| format!("\"{}\"", d.name)).collect();
        Err(ConfigError::Invalid {
            key: format!("{section}.driver"),
            message: format!("`{driver}` is not one of {}", names.join(", ")),
        })
    }

    /// A `[stage]` section: `driver`, `port` and the driver's own `keys`.
    pub fn stage_spec(&self, driver: &str, port: &Path, keys: toml::Table) -> Result<StageSpec, ConfigError> {
        let read = self.reader("stage", driver, |d| d.stage)?;
        Ok(AxisSpec { path: port.to_path_buf(), settings: Keys::read("stage", driver, keys, read)? })
    }

    /// A `[rotation]` section.
    pub fn rotation_spec(&self, driver: &str, port: &Path, keys: toml::Table) -> Result<RotationSpec, ConfigError> {
        let read = self.reader("rotation", driver, |d| d.rotation)?;
        Ok(AxisSpec { path: port.to_path_buf(), settings: Keys::read("rotation", driver, keys, read)? })
    }
}

/// A driver's keys of one rig-file section, handed to its reader; a key the
/// reader does not take is refused (a typo never falls back to a default).
pub struct Keys {
    section: &'static str,
    table: toml::Table,
}

impl Keys {
    fn read<T>(
        section: &'static str,
        driver: &str,
        table: toml::Table,
        read: fn(&mut Keys) -> Result<T, ConfigError>,
    ) -> Result<T, ConfigError> {
        let mut keys = Keys { section, table };
        let settings = read(&mut keys)?;
        match keys.table.keys().next() {
            Some(k) => Err(keys.invalid(k, format!("does not apply to the `{driver}` driver"))),
            None => Ok(settings),
        }
    }

    /// Take `key`, if present; a value of the wrong type is refused.
    pub fn take<T: DeserializeOwned>(&mut self, key: &str) -> Result<Option<T>, ConfigError> {
        match self.table.remove(key) {
            None => Ok(None),
            Some(v) => v.try_into().map(Some).map_err(|source| ConfigError::Value { key: self.key(key), source }),
        }
    }

    /// An error naming `section.key`.
    pub fn invalid(&self, key: &str, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid { key: self.key(key), message: message.into() }
    }

    fn key(&self, key: &str) -> String {
        format!("{}.{key}", self.section)
    }
}

// ---- the built-in drivers' settings ----------------------------------------

/// A serial port: an emulator's pty opens without the settle delay a USB
/// adapter needs (the delay is for boards that reset when the port opens).
async fn serial(path: &Path) -> std::io::Result<SerialStream> {
    if path.starts_with("/dev/pts") { open_serial_settle(path, Duration::ZERO).await } else { open_serial(path).await }
}

/// `actuator = "z825b"` (25 mm, the default) or `"z812b"` (12 mm).
fn apt_stage(keys: &mut Keys) -> Result<Arc<dyn OpenAxis<Mm>>, ConfigError> {
    let cfg = match keys.take::<String>("actuator")?.as_deref().unwrap_or("z825b") {
        "z825b" => AptConfig::kdc101_z825b(),
        "z812b" => AptConfig::kdc101_z812b(),
        other => return Err(keys.invalid("actuator", format!("`{other}` is not one of \"z825b\", \"z812b\""))),
    };
    Ok(Arc::new(cfg))
}

/// A K10CR1; no keys.
fn apt_rotation(_keys: &mut Keys) -> Result<Arc<dyn OpenAxis<Deg>>, ConfigError> {
    Ok(Arc::new(AptConfig::k10cr1()))
}

/// `axis` (default `Z`), `feed_mm_per_min` (default 60), `travel_mm = [min, max]` (default `[0, 25]`).
fn grbl_stage(keys: &mut Keys) -> Result<Arc<dyn OpenAxis<Mm>>, ConfigError> {
    let mut cfg = GrblConfig::default();
    if let Some(a) = keys.take::<char>("axis")? {
        if !"XYZABC".contains(a.to_ascii_uppercase()) {
            return Err(keys.invalid("axis", format!("`{a}` is not one of X, Y, Z, A, B, C")));
        }
        cfg.axis = a.to_ascii_uppercase();
    }
    if let Some(f) = keys.take::<f64>("feed_mm_per_min")? {
        if !(f.is_finite() && f > 0.0) {
            return Err(keys.invalid("feed_mm_per_min", format!("must be a positive number, got {f}")));
        }
        cfg.feed_mm_per_min = f;
    }
    if let Some([lo, hi]) = keys.take::<[f64; 2]>("travel_mm")? {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(keys.invalid("travel_mm", format!("needs min < max, got [{lo}, {hi}]")));
        }
        cfg.travel_mm = (lo, hi);
    }
    Ok(Arc::new(cfg))
}

/// An APT unit: the same settings type and driver for the stage and the mount.
#[async_trait]
impl<U: Unit> OpenAxis<U> for AptConfig {
    async fn open(&self, path: &Path) -> Result<DynAxis<U>, OpenError> {
        let io = serial(path).await.map_err(OpenError::Port)?;
        let axis = AptAxis::<_, U>::connect(io, self.clone()).await.map_err(OpenError::connect("APT"))?;
        Ok(boxed(axis))
    }
}

#[async_trait]
impl OpenAxis<Mm> for GrblConfig {
    async fn open(&self, path: &Path) -> Result<DynAxis<Mm>, OpenError> {
        let stage = GrblStage::open(path, self.clone()).await.map_err(OpenError::connect("GRBL"))?;
        Ok(boxed(stage))
    }
}
