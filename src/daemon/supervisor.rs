//! Supervision of the daemon's workers (docs/DAEMON.md "Worker failures"): the tasks under
//! their names and restart policies ([`Supervisor`]), the navigation thread's end and join
//! ([`NavThread`]), how supervision ended ([`Ending`]) and the `IANAV_FAULT` test hook
//! ([`Fault`]).

use std::collections::HashMap;
use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

use tokio::sync::{oneshot, watch};

use super::DaemonError;
use super::shared::Context;
use mavlink::dialects::ardupilotmega as apm;

/// The camera task is restarted after a panic at most this many times, then the daemon stops:
/// the camera is an optional input with its own reconnection, so a failure there should not
/// cost the navigation state (a restarted daemon needs a GNSS fix to start its INS again), but
/// a camera that keeps failing is a fault, not a transient.
pub const MAX_CAMERA_RESTARTS: u64 = 3;

/// Time left to the writer to send the STATUSTEXT announcing a fatal error.
pub(super) const LAST_WORDS: Duration = Duration::from_millis(300);

/// A supervised worker: its `IANAV_FAULT` name, its name in messages, whether it may end on
/// its own (the camera with no source or at the end of its directory, TIMESYNC requests at
/// rate 0), and how many panics it is restarted after.
#[derive(Debug, Clone, Copy)]
pub(super) struct Worker {
    id: &'static str,
    name: &'static str,
    may_end: bool,
    restarts: u64,
}

pub(super) const READER: Worker = Worker {
    id: "reader",
    name: "link reader",
    may_end: false,
    restarts: 0,
};
pub(super) const WRITER: Worker = Worker {
    id: "writer",
    name: "link writer",
    may_end: false,
    restarts: 0,
};
pub(super) const TIMESYNC: Worker = Worker {
    id: "timesync",
    name: "TIMESYNC requests",
    may_end: true,
    restarts: 0,
};
pub(super) const INTERVALS: Worker = Worker {
    id: "intervals",
    name: "interval requests",
    may_end: false,
    restarts: 0,
};
pub(super) const MONITOR: Worker = Worker {
    id: "monitor",
    name: "monitor",
    may_end: false,
    restarts: 0,
};
pub(super) const CAMERA: Worker = Worker {
    id: "camera",
    name: "camera",
    may_end: true,
    restarts: MAX_CAMERA_RESTARTS,
};
/// The navigation thread's name in messages (supervised through [`NavThread`]).
const NAV: &str = "navigation thread";
/// The navigation thread's `IANAV_FAULT` name.
pub(super) const NAV_ID: &str = "nav";

/// Test hook (docs/DAEMON.md "Worker failures"): `IANAV_FAULT=WORKER[:stop]` makes a worker
/// (`reader`, `writer`, `timesync`, `intervals`, `monitor`, `camera`, `nav`) panic, or with
/// `:stop` end, [`Fault::AFTER`] after the start. Only builds with debug assertions read it
/// (the `ci` test profile): a release build ignores the variable.
#[derive(Debug, Clone, Default)]
pub(crate) struct Fault {
    worker: Option<String>,
    stop: bool,
}

/// What an injected fault does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum FaultKind {
    /// Panic.
    Panic,
    /// Return as if done.
    Stop,
}

impl Fault {
    /// Delay before an injected fault strikes (the daemon is running by then).
    pub(crate) const AFTER: Duration = Duration::from_secs(1);

    pub(super) fn from_env() -> Self {
        if !cfg!(debug_assertions) {
            return Self::default();
        }
        let Ok(v) = std::env::var("IANAV_FAULT") else {
            return Self::default();
        };
        let (worker, stop) = match v.split_once(':') {
            Some((w, "stop")) => (w.to_owned(), true),
            _ => (v, false),
        };
        tracing::warn!(worker, stop, "IANAV_FAULT: test fault armed");
        Self {
            worker: Some(worker),
            stop,
        }
    }

    /// The fault armed for `worker`, if any.
    pub(crate) fn on(&self, worker: &str) -> Option<FaultKind> {
        (self.worker.as_deref() == Some(worker)).then_some(if self.stop {
            FaultKind::Stop
        } else {
            FaultKind::Panic
        })
    }

    /// Run `fut` as worker `id`, with its fault if one is armed.
    fn wrap(
        &self,
        id: &str,
        fut: impl Future<Output = ()> + Send + 'static,
    ) -> impl Future<Output = ()> + Send + 'static {
        let fault = self.on(id);
        let id = id.to_owned();
        async move {
            let Some(kind) = fault else {
                return fut.await;
            };
            tokio::select! {
                () = fut => {}
                () = tokio::time::sleep(Fault::AFTER) => {
                    if kind == FaultKind::Panic {
                        panic!("IANAV_FAULT: injected panic in {id}");
                    }
                }
            }
        }
    }
}

/// The message of a panic payload.
pub(super) fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".to_owned())
}

/// A worker's future.
type WorkerFuture = Pin<Box<dyn Future<Output = ()> + Send>>;

/// How to start a restartable worker again, and how often it was.
struct Respawn {
    make: Box<dyn FnMut() -> WorkerFuture + Send>,
    done: u64,
}

/// The worker tasks and their names.
pub(super) struct Supervisor {
    tasks: tokio::task::JoinSet<()>,
    workers: HashMap<tokio::task::Id, Worker>,
    respawn: HashMap<&'static str, Respawn>,
    fault: Fault,
}

impl Supervisor {
    /// No workers yet; `fault`: the test fault armed, if any.
    pub(super) fn new(fault: Fault) -> Self {
        Self {
            tasks: tokio::task::JoinSet::new(),
            workers: HashMap::new(),
            respawn: HashMap::new(),
            fault,
        }
    }

    /// Start `fut` as worker `w` (with its test fault, if armed).
    pub(super) fn spawn(&mut self, w: Worker, fut: impl Future<Output = ()> + Send + 'static) {
        let h = self.tasks.spawn(self.fault.wrap(w.id, fut));
        self.workers.insert(h.id(), w);
    }

    /// Start worker `w` from `make`, which starts it again after each of its first
    /// `w.restarts` panics.
    pub(super) fn spawn_restartable<F>(
        &mut self,
        w: Worker,
        mut make: impl FnMut() -> F + Send + 'static,
    ) where
        F: Future<Output = ()> + Send + 'static,
    {
        let mut make: Box<dyn FnMut() -> WorkerFuture + Send> = Box::new(move || Box::pin(make()));
        let fut = make();
        self.respawn.insert(w.id, Respawn { make, done: 0 });
        self.spawn(w, fut);
    }

    /// Supervise until the stop signal, the end of the navigation thread (`nav_exit`) or a
    /// failure; a worker with restarts left is restarted, counted and announced.
    pub(super) async fn supervise(
        &mut self,
        ctx: &Context,
        nav_exit: &mut oneshot::Receiver<()>,
    ) -> Ending {
        let mut stop = ctx.stop.clone();
        loop {
            tokio::select! {
                _ = stop.wait_for(|s| *s) => return Ending::Stopped,
                _ = &mut *nav_exit => return Ending::NavEnded,
                Some(joined) = self.tasks.join_next_with_id() => {
                    let (id, panic) = match joined {
                        Ok((id, ())) => (id, None),
                        Err(e) => {
                            let id = e.id();
                            let msg = match e.try_into_panic() {
                                Ok(p) => panic_message(p.as_ref()),
                                Err(e) => e.to_string(),
                            };
                            (id, Some(msg))
                        }
                    };
                    let Some(w) = self.workers.remove(&id) else { continue };
                    match panic {
                        // Workers end by themselves on the stop signal.
                        None if w.may_end || *ctx.stop.borrow() => {}
                        None => {
                            return Ending::Failed(DaemonError::WorkerStopped { worker: w.name });
                        }
                        Some(msg) => {
                            if !self.restart(w, &msg, ctx) {
                                return Ending::Failed(DaemonError::WorkerPanicked {
                                    worker: w.name,
                                    message: msg,
                                });
                            }
                        }
                    }
                }
            }
        }
    }

    /// Start `w` again after its panic `msg` if it has restarts left (`false` otherwise).
    fn restart(&mut self, w: Worker, msg: &str, ctx: &Context) -> bool {
        let Some(r) = self.respawn.get_mut(w.id).filter(|r| r.done < w.restarts) else {
            return false;
        };
        r.done += 1;
        let n = r.done;
        ctx.shared.count(|c| c.worker_restarts += 1);
        tracing::error!("{} task panicked ({msg}): restarting", w.name);
        ctx.outbox.status(
            apm::MavSeverity::MAV_SEVERITY_WARNING,
            &format!("ianav: {} failed, restart {n}/{}", w.name, w.restarts),
        );
        let fut = (r.make)();
        self.spawn(w, fut);
        true
    }

    /// Wait up to 2 s for the workers to end (the stop signal is raised), abort the rest, and
    /// drop every restart closure (the camera's holds an event sender).
    pub(super) async fn stop(mut self) {
        let _ = tokio::time::timeout(Duration::from_secs(2), async {
            while self.tasks.join_next().await.is_some() {}
        })
        .await;
        self.tasks.abort_all();
    }
}

/// A stop signal of a worker's own, for one run of it: raised by the daemon's stop signal and
/// when this run ends or is dropped (its panic, an injected fault, the final abort). A thread the
/// worker started (the OpenCV capture of `camera_cv`, which a dropped task no longer joins)
/// then ends with it instead of capturing on beside the worker's restarted successor.
pub(super) struct OwnStop {
    raise: watch::Sender<bool>,
    daemon: watch::Receiver<bool>,
}

impl OwnStop {
    /// A signal following the daemon's `stop`, and the receiver to give the worker.
    pub(super) fn new(stop: &watch::Receiver<bool>) -> (Self, watch::Receiver<bool>) {
        let (raise, own) = watch::channel(*stop.borrow());
        let daemon = stop.clone();
        (Self { raise, daemon }, own)
    }

    /// Run `worker` (given this signal's receiver), passing the daemon's stop on to it.
    pub(super) async fn around(mut self, worker: impl Future<Output = ()>) {
        let follow = async {
            // Err: every sender is gone, which also means stop.
            let _ = self.daemon.wait_for(|s| *s).await;
            self.raise.send_replace(true);
            std::future::pending::<()>().await;
        };
        tokio::select! {
            () = worker => {}
            () = follow => {}
        }
    }
}

impl Drop for OwnStop {
    fn drop(&mut self) {
        self.raise.send_replace(true);
    }
}

/// How supervision ended.
pub(super) enum Ending {
    /// `Handle::stop` (SIGINT / SIGTERM).
    Stopped,
    /// The navigation thread ended (its panic, if any, is taken from its join).
    NavEnded,
    /// A worker failed.
    Failed(DaemonError),
}

impl Ending {
    /// The worker to name in the STATUSTEXT announcing the exit (`None` on a requested stop).
    /// `nav_ended`: the navigation thread has ended, maybe seen after the reader's end.
    pub(super) fn failed_worker(&self, nav_ended: bool) -> Option<&'static str> {
        match self {
            Ending::Stopped => None,
            Ending::NavEnded => Some(NAV),
            _ if nav_ended => Some(NAV),
            Ending::Failed(
                DaemonError::WorkerPanicked { worker, .. } | DaemonError::WorkerStopped { worker },
            ) => Some(*worker),
            Ending::Failed(_) => Some("worker"),
        }
    }
}

/// The navigation thread as supervised: its end notice (sent on return and while unwinding
/// alike, `nav_thread::Exit`) and its join handle.
pub(super) struct NavThread {
    pub(super) exit: oneshot::Receiver<()>,
    pub(super) join: std::thread::JoinHandle<()>,
}

impl NavThread {
    /// Wait for the thread to end (within 5 s unless it already has, `nav_ended`) once every
    /// event sender is gone, and say why the daemon stopped: the navigation thread's end first,
    /// since the reader then stops too for that reason.
    pub(super) async fn finish(
        mut self,
        nav_ended: bool,
        ending: Ending,
    ) -> Result<(), DaemonError> {
        if !nav_ended
            && tokio::time::timeout(Duration::from_secs(5), &mut self.exit)
                .await
                .is_err()
        {
            return Err(DaemonError::Thread("did not stop within 5 s".to_owned()));
        }
        let join = self.join;
        let nav_result = tokio::task::spawn_blocking(move || join.join())
            .await
            .map_err(|e| DaemonError::Thread(e.to_string()))?;
        match (nav_result, ending) {
            (Err(p), _) => Err(DaemonError::WorkerPanicked {
                worker: NAV,
                message: panic_message(p.as_ref()),
            }),
            (Ok(()), Ending::NavEnded) => Err(DaemonError::WorkerStopped { worker: NAV }),
            (Ok(()), _) if nav_ended => Err(DaemonError::WorkerStopped { worker: NAV }),
            (Ok(()), Ending::Failed(e)) => Err(e),
            (Ok(()), Ending::Stopped) => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A thread started by a worker, polling its stop signal like the OpenCV capture does.
    fn polling_thread(stop: watch::Receiver<bool>) -> std::sync::mpsc::Receiver<()> {
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            while !*stop.borrow() {
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = done_tx.send(());
        });
        done_rx
    }

    #[tokio::test]
    async fn a_thread_of_a_worker_ends_with_the_worker_or_the_daemon() {
        let wait = Duration::from_secs(2);
        // The worker's task dropped (a panic, an injected fault, the final abort).
        let (_daemon_tx, stop) = watch::channel(false);
        let (own_stop, own) = OwnStop::new(&stop);
        let done = polling_thread(own);
        let task = tokio::spawn(own_stop.around(std::future::pending()));
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert!(done.try_recv().is_err(), "ended before its worker");
        task.abort();
        assert!(task.await.unwrap_err().is_cancelled());
        done.recv_timeout(wait).unwrap();
        // The daemon stopping: the signal is passed on and the worker ends by itself.
        let (daemon_tx, stop) = watch::channel(false);
        let (own_stop, mut own) = OwnStop::new(&stop);
        let done = polling_thread(own.clone());
        let task = tokio::spawn(own_stop.around(async move {
            let _ = own.wait_for(|s| *s).await;
            tokio::task::spawn_blocking(move || done.recv_timeout(Duration::from_secs(2)))
                .await
                .unwrap()
                .unwrap();
        }));
        daemon_tx.send_replace(true);
        tokio::time::timeout(wait, task).await.unwrap().unwrap();
    }
}
