//! What the end-to-end tests of the daemon beside the SITL vehicle share: accepting the two
//! connections, the relay between them that keeps the daemon's bytes, and the check that the
//! daemon's recording replays to what it published.
#![allow(
    dead_code,
    reason = "each test crate that includes this module uses a part of it"
)]

use std::time::Duration;

use ianav::daemon::{Counters, DaemonError, Handle};
use ianav_sim::flight::{CameraSetup, FlightSetup};
use ianav_sim::sitl::{
    self, Autopilot, FramesListen, SitlError, SitlOptions, SitlSummary, VehicleConfig,
};
use ianav_sim::terrain::{Terrain, Zone};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;

/// Scenario #2 over MX with the camera, cut to `mission_s` of mission with GNSS lost at
/// `loss_s`, starting at the zone's start.
pub fn mx_camera_setup(mission_s: f64, loss_s: f64) -> FlightSetup {
    camera_setup(Zone::Mix, mission_s, loss_s)
}

/// Scenario #2 over `zone` with the camera (terrain seed 0, as `ianav-sim --terrain`), cut to
/// `mission_s` of mission with GNSS lost at `loss_s`, starting at the zone's start.
pub fn camera_setup(zone: Zone, mission_s: f64, loss_s: f64) -> FlightSetup {
    let mut s = FlightSetup::builtin(2).expect("scenario #2");
    s.scenario.duration_s = mission_s;
    s.scenario.gnss_loss_s = loss_s;
    let start = zone.start();
    s.scenario.start.lat_deg = start.lat_deg;
    s.scenario.start.lon_deg = start.lon_deg;
    s.camera = Some(CameraSetup::new(std::sync::Arc::new(Terrain::new(zone, 0))));
    s
}

/// The ideal SITL vehicle flying on the companion's estimates, connecting to `vehicle` (an
/// address), streaming its frames to whoever connects to `frames`, at `speed`.
pub fn camera_vehicle(
    vehicle: std::net::SocketAddr,
    frames: std::net::TcpListener,
    speed: f64,
    out_dir: Option<std::path::PathBuf>,
) -> SitlOptions {
    SitlOptions {
        connect: format!("tcpout:{vehicle}"),
        vehicle: VehicleConfig {
            fly_on_estimates: true,
            ..VehicleConfig::for_autopilot(Autopilot::Ideal)
        },
        speed,
        frames: Some(FramesListen::Listener(frames)),
        out_dir,
    }
}

/// The one connection `who` makes to `l`, within 15 s.
pub async fn accept(l: &TcpListener, who: &str) -> TcpStream {
    let (s, _) = tokio::time::timeout(Duration::from_secs(15), l.accept())
        .await
        .unwrap_or_else(|_| panic!("{who} did not connect within 15 s"))
        .expect("accept");
    s.set_nodelay(true).expect("nodelay");
    s
}

/// The SITL vehicle flying `setup` with `seed`, its notices printed.
pub fn spawn_sitl(
    setup: &FlightSetup,
    seed: u64,
    options: SitlOptions,
) -> JoinHandle<Result<SitlSummary, SitlError>> {
    let setup = setup.clone();
    tokio::spawn(async move {
        sitl::run(&setup, seed, options, |_, notices| {
            for n in notices {
                eprintln!("sitl: {n}");
            }
        })
        .await
    })
}

/// The in-process daemon started with `cfg`, recording its flight into `recording`
/// (`ianav run --record`), and the connection it makes to `daemon_side`.
pub async fn start_recording_daemon(
    mut cfg: ianav::daemon::config::DaemonConfig,
    recording: &std::path::Path,
    daemon_side: &TcpListener,
) -> (Handle, JoinHandle<Result<(), DaemonError>>, TcpStream) {
    cfg.record = Some(recording.to_path_buf());
    let (htx, hrx) = tokio::sync::oneshot::channel();
    let task = tokio::spawn(ianav::daemon::run(cfg, Some(htx)));
    let handle = hrx.await.expect("the daemon starts");
    let stream = accept(daemon_side, "the daemon").await;
    (handle, task, stream)
}

/// Stop the daemon and wait (10 s at most) for it to end without error.
pub async fn stop_daemon(handle: &Handle, task: JoinHandle<Result<(), DaemonError>>) {
    handle.stop();
    tokio::time::timeout(Duration::from_secs(10), task)
        .await
        .expect("daemon stops within 10 s")
        .expect("daemon task")
        .expect("daemon ends without error");
}

/// Vehicle → daemon unchanged; daemon → vehicle unchanged and kept.
pub struct Relay {
    up: JoinHandle<()>,
    down: JoinHandle<Vec<u8>>,
}

impl Relay {
    /// Start relaying between the two connections.
    pub fn start(to_vehicle: TcpStream, to_daemon: TcpStream) -> Self {
        let (mut vr, mut vw) = to_vehicle.into_split();
        let (mut dr, mut dw) = to_daemon.into_split();
        let up = tokio::spawn(async move {
            let _ = tokio::io::copy(&mut vr, &mut dw).await;
        });
        let down = tokio::spawn(async move {
            let (mut log, mut buf) = (Vec::with_capacity(8 << 20), vec![0_u8; 65_536]);
            // Keep every byte the daemon sends until it closes, also after the vehicle has
            // gone (its last messages still count as published).
            let mut vehicle_open = true;
            loop {
                let n = match dr.read(&mut buf).await {
                    Ok(0) | Err(_) => break,
                    Ok(n) => n,
                };
                log.extend_from_slice(&buf[..n]);
                if vehicle_open && vw.write_all(&buf[..n]).await.is_err() {
                    vehicle_open = false;
                }
            }
            log
        });
        Self { up, down }
    }

    /// Everything the daemon sent, once it has closed its side (within 10 s).
    pub async fn finish(self) -> Vec<u8> {
        let bytes = tokio::time::timeout(Duration::from_secs(10), self.down)
            .await
            .expect("relay ends when the daemon closes")
            .expect("relay task");
        self.up.abort();
        bytes
    }
}

/// The daemon's recording of a flight, replayed through the navigation core with the settings
/// recorded in it, gives every solution the daemon's navigator handed its publisher, bit for
/// bit (the same CSV text: numbers in their shortest exact form). Returns the replay's
/// summary.
pub fn assert_replay_gives_the_daemons_solutions(
    recording: &std::path::Path,
    counters: &Counters,
) -> ianav::nav::replay::ReplaySummary {
    assert!(!counters.record_failed, "recording failed");
    let published = std::fs::read_to_string(ianav::daemon::nav_thread::Recorder::solutions_path(
        recording,
    ))
    .expect("the daemon's solutions");
    let log = std::io::BufReader::new(std::fs::File::open(recording).expect("the recording"));
    let mut replayed = Vec::new();
    let summary = ianav::nav::replay::replay_to_csv(
        ianav::io::sensor_log::SensorLogReader::new(log).expect("a sensor log"),
        1,
        &mut replayed,
    )
    .expect("the replay");
    let replayed = String::from_utf8(replayed).expect("UTF-8");
    assert_eq!(summary.events, counters.events_recorded);
    assert!(summary.solutions > 1_000, "{} solutions", summary.solutions);
    if replayed != published {
        let first = replayed
            .lines()
            .zip(published.lines())
            .position(|(a, b)| a != b);
        panic!(
            "replay ({} lines) differs from the daemon's solutions ({} lines) at line {first:?}",
            replayed.lines().count(),
            published.lines().count()
        );
    }
    summary
}
