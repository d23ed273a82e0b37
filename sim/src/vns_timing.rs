//! Time per frame of the visual navigation (the paper's VNS and IA-VNS: SVO on the
//! down-looking camera, with or without the inertial aiding) over a simulated camera flight,
//! for `ianav-sim bench-vns` and the `vns` criterion bench (docs/PERFORMANCE.md).
//!
//! The flight's own navigator runs without the camera; for each visual system, a navigator of
//! the timer's own running that system alone, with the flight's estimated camera mounting,
//! takes every sensor event of the flight and the handling of each frame (pyramid, tracking,
//! mapping, and the IA-VNS's steps) is timed alone. Only the frames are timed: the IMU and
//! air-data events between them are the INS's cost, measured elsewhere.

use std::time::Instant;

use ianav::nav::{NavCamera, NavConfig, NavError, Navigator, VisionState};
use ianav::sensors::SensorEvent;

use crate::flight::systems::VisionSystem;
use crate::flight::{Flight, FlightObserver, FlightSetup};

/// Why a timer could not be built.
#[derive(Debug, thiserror::Error)]
pub enum VnsTimingError {
    /// The flight has no camera (`--terrain` missing) or no navigator (truth navigation).
    #[error("the VNS timing needs a camera flight with INS navigation (--terrain ZONE)")]
    NoCameraFlight,
    /// The navigator refused the configuration.
    #[error(transparent)]
    Nav(#[from] NavError),
}

/// The navigation configuration of `flight` with the camera of `setup`, the flight's estimated
/// mounting and the visual system `system` alone: what the flight's own navigator runs for
/// that system when it navigates on the frames.
pub fn vision_config(
    setup: &FlightSetup,
    flight: &Flight,
    system: VisionSystem,
) -> Result<NavConfig, VnsTimingError> {
    let (Some(camera), Some(mounting), Some(nav)) =
        (&setup.camera, flight.camera_mounting(), flight.navigator())
    else {
        return Err(VnsTimingError::NoCameraFlight);
    };
    let mut cfg = nav.config().clone();
    cfg.camera = Some(NavCamera {
        intrinsics: camera.camera,
        mounting: mounting.estimate,
    });
    cfg.vision = system.config(&setup.vision);
    cfg.compared_vision.clear();
    Ok(cfg)
}

/// One frame's handling.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTime {
    /// Exposure time, µs.
    pub t_us: u64,
    /// Wall time of `Navigator::push` for the frame, ns.
    pub ns: u64,
    /// The visual navigation's state after the frame.
    pub state: VisionState,
    /// The frame became a keyframe (feature detection and new seeds).
    pub keyframe: bool,
    /// Keyframes in the map after the frame.
    pub n_keyframes: u32,
    /// Points in the map after the frame (candidates included).
    pub n_points: u32,
}

/// Feeds a navigator of its own with a flight's sensor events and times each frame.
#[derive(Debug)]
pub struct VnsTimer {
    nav: Navigator,
    frames: Vec<FrameTime>,
}

impl VnsTimer {
    /// A timer running `cfg` (see [`vision_config`]).
    pub fn new(cfg: &NavConfig) -> Result<Self, VnsTimingError> {
        Ok(Self {
            nav: Navigator::new(cfg)?,
            frames: Vec::new(),
        })
    }

    /// Feed one event; a frame is timed.
    pub fn push(&mut self, event: &SensorEvent) {
        let SensorEvent::Frame(frame) = event else {
            self.nav.push(event);
            return;
        };
        let keyframes_before = self.keyframes();
        let started = Instant::now();
        self.nav.push(event);
        let ns = u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX);
        let vision = self.nav.vision();
        self.frames.push(FrameTime {
            t_us: frame.t_us,
            ns,
            state: vision.state,
            keyframe: self.keyframes() > keyframes_before,
            n_keyframes: vision.n_keyframes,
            n_points: vision.n_points,
        });
    }

    fn keyframes(&self) -> u64 {
        self.nav.vns_counters().map_or(0, |c| c.keyframes)
    }

    /// The frames timed so far.
    pub fn frames(&self) -> &[FrameTime] {
        &self.frames
    }

    /// The navigator (its VNS counters).
    pub fn navigator(&self) -> &Navigator {
        &self.nav
    }
}

impl FlightObserver for VnsTimer {
    fn sensor_event(&mut self, event: &SensorEvent) {
        self.push(event);
    }
}

/// One timer per visual system, fed the same events (each system timed alone).
#[derive(Debug)]
pub struct VnsTimers(pub Vec<(VisionSystem, VnsTimer)>);

impl FlightObserver for VnsTimers {
    fn sensor_event(&mut self, event: &SensorEvent) {
        for (_, timer) in &mut self.0 {
            timer.push(event);
        }
    }
}

/// Order statistics of frame times, ms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeSummary {
    /// Frames.
    pub n: usize,
    /// Mean, ms.
    pub mean_ms: f64,
    /// Median, ms.
    pub median_ms: f64,
    /// 90th percentile, ms.
    pub p90_ms: f64,
    /// 99th percentile, ms.
    pub p99_ms: f64,
    /// Largest, ms.
    pub max_ms: f64,
}

impl TimeSummary {
    /// The summary of `ns` (nearest-rank percentiles); `None` when empty.
    pub fn of(ns: impl IntoIterator<Item = u64>) -> Option<Self> {
        let mut sorted: Vec<u64> = ns.into_iter().collect();
        if sorted.is_empty() {
            return None;
        }
        sorted.sort_unstable();
        let n = sorted.len();
        let rank = |p: f64| sorted[((p * n as f64).ceil() as usize).clamp(1, n) - 1] as f64 * 1e-6;
        Some(Self {
            n,
            mean_ms: sorted.iter().map(|&v| v as f64).sum::<f64>() / n as f64 * 1e-6,
            median_ms: rank(0.5),
            p90_ms: rank(0.9),
            p99_ms: rank(0.99),
            max_ms: rank(1.0),
        })
    }
}

/// Collects a flight's sensor events (the criterion bench replays them).
#[derive(Debug, Default)]
pub struct EventRecorder {
    /// The events, in the order the flight produced them.
    pub events: Vec<SensorEvent>,
}

impl FlightObserver for EventRecorder {
    fn sensor_event(&mut self, event: &SensorEvent) {
        self.events.push(event.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        // 1..=100 ms: the p-th percentile by nearest rank is p ms.
        let s = TimeSummary::of((1..=100).map(|ms| ms * 1_000_000)).expect("non-empty");
        assert_eq!(s.n, 100);
        assert!((s.median_ms - 50.0).abs() < 1e-9);
        assert!((s.p90_ms - 90.0).abs() < 1e-9);
        assert!((s.p99_ms - 99.0).abs() < 1e-9);
        assert!((s.max_ms - 100.0).abs() < 1e-9);
        assert!((s.mean_ms - 50.5).abs() < 1e-9);
        let one = TimeSummary::of([3_000_000]).expect("non-empty");
        assert_eq!((one.median_ms, one.p99_ms), (3.0, 3.0));
        assert!(TimeSummary::of([]).is_none());
    }
}
