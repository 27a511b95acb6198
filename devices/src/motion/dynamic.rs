//! Axes chosen at run time: any driver boxed behind one trait object, its
//! typed error carried as an [`AxisFault`].

use std::error::Error;
use std::fmt;
use std::time::Duration;

use async_trait::async_trait;

use super::{Axis, AxisStatus, DeviceFault, DeviceInfo, FaultKind, Identify};
use crate::motion::unit::{Deg, Mm};

/// Any driver's error behind a [`DynAxis`]: its [`FaultKind`], its message,
/// and the driver's own typed error, reachable with [`AxisFault::downcast_ref`].
#[derive(Debug)]
pub struct AxisFault {
    kind: FaultKind,
    inner: Box<dyn Error + Send + Sync + 'static>,
}

impl AxisFault {
    pub fn new<E: DeviceFault>(e: E) -> Self {
        Self { kind: e.kind(), inner: Box::new(e) }
    }

    /// The driver's own error, when it is an `E`.
    pub fn downcast_ref<E: Error + 'static>(&self) -> Option<&E> {
        self.inner.downcast_ref()
    }
}

/// The driver's message, as it is.
impl fmt::Display for AxisFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&self.inner, f)
    }
}

/// Transparent: the cause is the driver error's own cause.
impl Error for AxisFault {
    fn source(&self) -> Option<&(dyn Error + 'static)> {
        self.inner.source()
    }
}

impl DeviceFault for AxisFault {
    fn kind(&self) -> FaultKind {
        self.kind
    }
}

/// An axis whose driver is chosen at run time (the rig's driver registry).
pub type DynAxis<U> = Box<dyn Axis<Unit = U, Error = AxisFault>>;
/// A linear stage chosen at run time.
pub type DynStage = DynAxis<Mm>;
/// A rotation mount chosen at run time.
pub type DynMount = DynAxis<Deg>;

/// Box a driver as a [`DynAxis`].
pub fn boxed<A: Axis + 'static>(axis: A) -> DynAxis<A::Unit> {
    Box::new(Erased(axis))
}

/// A driver with its error type erased into [`AxisFault`].
struct Erased<A>(A);

#[async_trait]
impl<A: Identify> Identify for Erased<A> {
    type Error = AxisFault;
    async fn identify(&mut self) -> Result<DeviceInfo, AxisFault> {
        self.0.identify().await.map_err(AxisFault::new)
    }
}

#[async_trait]
impl<A: Axis> Axis for Erased<A> {
    type Unit = A::Unit;
    fn travel(&self) -> (A::Unit, A::Unit) {
        self.0.travel()
    }
    async fn home(&mut self, timeout: Duration) -> Result<(), AxisFault> {
        self.0.home(timeout).await.map_err(AxisFault::new)
    }
    async fn start_move_to(&mut self, target: A::Unit) -> Result<(), AxisFault> {
        self.0.start_move_to(target).await.map_err(AxisFault::new)
    }
    async fn start_move_by(&mut self, delta: A::Unit) -> Result<(), AxisFault> {
        self.0.start_move_by(delta).await.map_err(AxisFault::new)
    }
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<A::Unit, AxisFault> {
        self.0.wait_until_stopped(timeout).await.map_err(AxisFault::new)
    }
    async fn stop(&mut self) -> Result<(), AxisFault> {
        self.0.stop().await.map_err(AxisFault::new)
    }
    async fn position(&mut self) -> Result<A::Unit, AxisFault> {
        self.0.position().await.map_err(AxisFault::new)
    }
    async fn status(&mut self) -> Result<AxisStatus, AxisFault> {
        self.0.status().await.map_err(AxisFault::new)
    }
    async fn set_max_speed(&mut self, speed: f64) -> Result<Option<f64>, AxisFault> {
        self.0.set_max_speed(speed).await.map_err(AxisFault::new)
    }
}

#[async_trait]
impl<A: Identify + ?Sized> Identify for Box<A> {
    type Error = A::Error;
    async fn identify(&mut self) -> Result<DeviceInfo, A::Error> {
        (**self).identify().await
    }
}

/// A boxed axis (a [`DynAxis`] above all) is an axis.
#[async_trait]
impl<A: Axis + ?Sized> Axis for Box<A> {
    type Unit = A::Unit;
    fn travel(&self) -> (A::Unit, A::Unit) {
        (**self).travel()
    }
    async fn home(&mut self, timeout: Duration) -> Result<(), A::Error> {
        (**self).home(timeout).await
    }
    async fn start_move_to(&mut self, target: A::Unit) -> Result<(), A::Error> {
        (**self).start_move_to(target).await
    }
    async fn start_move_by(&mut self, delta: A::Unit) -> Result<(), A::Error> {
        (**self).start_move_by(delta).await
    }
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<A::Unit, A::Error> {
        (**self).wait_until_stopped(timeout).await
    }
    async fn stop(&mut self) -> Result<(), A::Error> {
        (**self).stop().await
    }
    async fn position(&mut self) -> Result<A::Unit, A::Error> {
        (**self).position().await
    }
    async fn status(&mut self) -> Result<AxisStatus, A::Error> {
        (**self).status().await
    }
    async fn set_max_speed(&mut self, speed: f64) -> Result<Option<f64>, A::Error> {
        (**self).set_max_speed(speed).await
    }
}
