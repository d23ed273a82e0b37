//! Starting and stopping the daemon in-process for the integration tests (its counters and
//! state stay readable through the [`Handle`]).

#![allow(
    dead_code,
    reason = "compiled into every test binary with `mod common`, each using a part of it; `expect` \
              would be unfulfilled in those that use all of it, such as daemon_loopback"
)]
#![expect(
    clippy::unwrap_used,
    reason = "test helper: a daemon that fails to start or stop should fail the test loudly"
)]

use std::time::Duration;

use ianav::daemon::config::DaemonConfig;
use ianav::daemon::{self, Counters, DaemonError, Handle};

/// The running daemon's task.
pub type Task = tokio::task::JoinHandle<Result<(), DaemonError>>;

/// Start the daemon with `cfg`; returns once its handle exists.
pub async fn start(cfg: DaemonConfig) -> (Handle, Task) {
    let (tx, rx) = tokio::sync::oneshot::channel();
    let task = tokio::spawn(daemon::run(cfg, Some(tx)));
    (rx.await.unwrap(), task)
}

/// Stop it; it must end within 5 s, without panic or error. Returns the counters at the stop.
pub async fn stop(h: Handle, task: Task) -> Counters {
    let c = h.shared.counters();
    h.stop();
    tokio::time::timeout(Duration::from_secs(5), task)
        .await
        .expect("daemon stops within 5 s")
        .expect("daemon task did not panic")
        .expect("daemon ran without error");
    c
}
