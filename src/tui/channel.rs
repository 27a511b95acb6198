//! The display works with the sequencer's channels whether they are bounded
//! or unbounded tokio channels: these two small traits are all it needs.

use std::future::Future;

use tokio::sync::mpsc;

use crate::run::events::{RunControl, RunEvent};

/// Where run events come from.
pub trait EventSource: Send {
    /// The next event; `None` once every sender is gone.
    fn next_event(&mut self) -> impl Future<Output = Option<RunEvent>> + Send;
}

impl EventSource for mpsc::Receiver<RunEvent> {
    fn next_event(&mut self) -> impl Future<Output = Option<RunEvent>> + Send {
        self.recv()
    }
}

impl EventSource for mpsc::UnboundedReceiver<RunEvent> {
    fn next_event(&mut self) -> impl Future<Output = Option<RunEvent>> + Send {
        self.recv()
    }
}

/// Where the operator's controls go.
pub trait ControlSink: Send + Sync {
    /// Deliver `c`; a sequencer that has already stopped (closed channel) is
    /// not an error: there is nothing left to control.
    fn send_control(&self, c: RunControl) -> impl Future<Output = ()> + Send;
}

impl ControlSink for mpsc::Sender<RunControl> {
    async fn send_control(&self, c: RunControl) {
        let _ = self.send(c).await;
    }
}

impl ControlSink for mpsc::UnboundedSender<RunControl> {
    fn send_control(&self, c: RunControl) -> impl Future<Output = ()> + Send {
        let _ = self.send(c);
        std::future::ready(())
    }
}
