//! The GNSS-denied INS flown in the simulator's loop: guidance and control fly on the INS solution;
//! its errors stay within the bounds the paper's INS achieves.

#![expect(
    clippy::unwrap_used,
    reason = "tests: a failed unwrap is a failed test"
)]

use ianav::ins::InsConfig;
use ianav::math::angle::wrap_pi;
use ianav::math::{so3, wgs84};
use ianav::sensors::SensorEvent;
use ianav_sim::control::NavEstimate;
use ianav_sim::flight::{Flight, FlightObserver, FlightSetup, NavigationMode, TruthSample};

#[derive(Default)]
struct Errors {
    /// (mission time s, attitude norm deg, altitude m, horizontal m, distance m)
    samples: Vec<(f64, f64, f64, f64, f64)>,
    /// Euler errors yaw, pitch, bank (deg) at the same instants.
    euler_deg: Vec<[f64; 3]>,
}

impl FlightObserver for Errors {
    fn estimate_sample(&mut self, truth: &TruthSample, est: &NavEstimate) {
        if truth.t_s < 0.0 {
            return;
        }
        let att = so3::log(&(truth.q_nb.inverse() * est.q_nb))
            .norm()
            .to_degrees();
        let d = wgs84::ned_difference_m(&truth.pos, &est.pos);
        let (et, ee) = (so3::euler_zyx(&truth.q_nb), so3::euler_zyx(&est.q_nb));
        self.euler_deg
            .push([0, 1, 2].map(|i| wrap_pi(ee[i] - et[i]).to_degrees()));
        self.samples.push((
            truth.t_s,
            att,
            est.pos.h_m - truth.pos.h_m,
            d.x.hypot(d.y),
            truth.distance_m,
        ));
    }
}

fn fly(seed: u64) -> Errors {
    fly_with(seed, |_| {})
}

/// While GNSS is available the INS position must agree with the truth to the accuracy of
/// the fixes: white noise σ 2.12 m (horizontal, per axis) and 4.25 m (vertical) plus the
/// ionospheric bias, σ ≈ 8 m per axis at the start of a run (50 walk steps of 0.16 m). Three
/// sigma of the horizontal norm of two such axes is 3·√2·√(8² + 2.12²) ≈ 35 m; vertically
/// 3·√(8² + 4.25²) ≈ 27 m. This catches fixes being wrongly gated or initialised.
#[test]
fn ins_in_the_loop_follows_gnss_then_flies_the_whole_scenario() {
    for seed in 1..=3 {
        let e = fly(seed);
        let gnss_phase = e.samples.iter().filter(|s| s.0 <= 100.0);
        for &(t_s, _, dh, hor, _) in gnss_phase {
            assert!(
                hor < 35.0,
                "seed {seed} t {t_s}: horizontal error {hor:.1} m"
            );
            assert!(
                dh.abs() < 27.0,
                "seed {seed} t {t_s}: altitude error {dh:.1} m"
            );
        }
        let last = *e.samples.last().unwrap();
        assert!(last.0 >= 500.0 - 1e-9, "the flight must reach the end");
        let max_att = e.samples.iter().map(|s| s.1).fold(0.0, f64::max);
        eprintln!(
            "seed {seed}: t_end {:.0} s: attitude {:.3} deg (max {max_att:.3}), altitude {:+.1} m, horizontal {:.0} m = {:.2} % of {:.0} m",
            last.0,
            last.1,
            last.2,
            last.3,
            100.0 * last.3 / last.4,
            last.4
        );
    }
}

#[test]
#[ignore = "diagnostic printout"]
fn attitude_error_history() {
    let e = fly(2);
    for (s, eu) in e.samples.iter().zip(&e.euler_deg).step_by(100) {
        eprintln!(
            "t {:6.1} s: att {:.3} deg (yaw {:+.3} pitch {:+.3} bank {:+.3}), dh {:+.2} m, hor {:.1} m",
            s.0, s.1, eu[0], eu[1], eu[2], s.2, s.3
        );
    }
}

fn fly_with(seed: u64, edit: impl FnOnce(&mut FlightSetup)) -> Errors {
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.navigation = NavigationMode::Ins;
    edit(&mut setup);
    let mut flight = Flight::new(&setup, seed).unwrap();
    let mut errors = Errors::default();
    flight.run(&mut errors, |_| {}).unwrap();
    errors
}

/// Seed 2 with the error sources switched off one at a time: turbulence is what makes the
/// yaw drift in straight flight (perfect sensors + turbulence still drift; perfect sensors
/// without turbulence stay < 0.1°).
#[test]
#[ignore = "diagnostic printout"]
fn attitude_error_variants() {
    type Edit = fn(&mut FlightSetup);
    let variants: [(&str, Edit); 4] = [
        ("nominal", |_| {}),
        ("no turbulence", |s| s.scenario.turbulence_factor = 0.0),
        ("perfect sensors", |s| {
            s.sensors = ianav_sim::sensors::config::SensorsConfig::perfect()
        }),
        ("perfect sensors, no turbulence", |s| {
            s.sensors = ianav_sim::sensors::config::SensorsConfig::perfect();
            s.scenario.turbulence_factor = 0.0;
        }),
    ];
    for (name, edit) in variants {
        let e = fly_with(2, edit);
        let yaw_at = |t: f64| {
            let k = e.samples.iter().position(|s| s.0 >= t).unwrap();
            e.euler_deg[k][0]
        };
        let max_att = e.samples.iter().map(|s| s.1).fold(0.0, f64::max);
        let rms_att =
            (e.samples.iter().map(|s| s.1 * s.1).sum::<f64>() / e.samples.len() as f64).sqrt();
        eprintln!(
            "{name:28}: yaw@50 {:+.3} yaw@100 {:+.3} yaw@340 {:+.3} end att {:.3} max {max_att:.3} rms {rms_att:.3} deg",
            yaw_at(50.0),
            yaw_at(100.0),
            yaw_at(340.0),
            e.samples.last().unwrap().1
        );
    }
}

/// Accelerometer-model residual `f̃ − [w × C(v − v_lf) + C(w_en × v + 2 w_ie × v − g)]`
/// evaluated with the true state and with the INS attitude, at the output instants that
/// coincide with an IMU sample (diagnostic of the attitude filter's accelerometer model).
#[derive(Default)]
struct AccelResidual {
    last_imu: Option<ianav::sensors::ImuSample>,
    /// (t_s, residual with truth, residual with the estimated attitude), body, m/s².
    rows: Vec<(f64, nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)>,
}

impl FlightObserver for AccelResidual {
    fn sensor_event(&mut self, event: &ianav::sensors::SensorEvent) {
        if let ianav::sensors::SensorEvent::Imu(s) = event {
            self.last_imu = Some(*s);
        }
    }
    fn estimate_sample(&mut self, truth: &TruthSample, est: &NavEstimate) {
        let Some(imu) = self.last_imu else { return };
        if imu.t_us != truth.t_us || truth.t_s < 0.0 {
            return;
        }
        let v = truth.v_ned_mps;
        let w_ie = wgs84::omega_ie_n(truth.pos.lat_rad);
        let w_en = wgs84::omega_en_n(&truth.pos, &v);
        let a_n = w_en.cross(&v) + (w_ie * 2.0).cross(&v) - wgs84::gravity_ned_mps2(&truth.pos);
        let model = |q: &nalgebra::UnitQuaternion<f64>| {
            let c = q.inverse();
            let w = imu.gyro_rps - c * (w_ie + w_en);
            w.cross(&(c * (v - truth.wind_ned_mps))) + c * a_n
        };
        self.rows.push((
            truth.t_s,
            imu.accel_mps2 - model(&truth.q_nb),
            imu.accel_mps2 - model(&est.q_nb),
        ));
    }
}

#[test]
#[ignore = "diagnostic printout"]
fn accel_model_residual() {
    for perfect in [true, false] {
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.navigation = NavigationMode::Ins;
        if perfect {
            setup.sensors = ianav_sim::sensors::config::SensorsConfig::perfect();
        }
        let mut flight = Flight::new(&setup, 2).unwrap();
        let mut obs = AccelResidual::default();
        flight.run(&mut obs, |_| {}).unwrap();
        // Equivalent white-noise R per IMU sample (Δt 0.01 s) from the variance of block
        // means: S(0) ≈ T·var(mean over T), R_eq = S(0)/Δt.
        for block_s in [1.0, 5.0, 10.0, 25.0] {
            let per = (block_s * 10.0) as usize;
            let means: Vec<nalgebra::Vector3<f64>> = obs
                .rows
                .chunks_exact(per)
                .map(|c| c.iter().map(|r| r.1).sum::<nalgebra::Vector3<f64>>() / per as f64)
                .collect();
            let n = means.len() as f64;
            let mu = means.iter().sum::<nalgebra::Vector3<f64>>() / n;
            let var = means
                .iter()
                .map(|m| (m - mu).component_mul(&(m - mu)))
                .sum::<nalgebra::Vector3<f64>>()
                / n;
            eprintln!(
                "perfect {perfect} block {block_s} s: R_eq {:?}",
                (var * block_s / 0.01).as_slice()
            );
        }
        for (t0, t1) in [(0.0, 100.0), (100.0, 200.0), (0.0, 500.0)] {
            let sel: Vec<_> = obs.rows.iter().filter(|r| r.0 >= t0 && r.0 < t1).collect();
            let n = sel.len() as f64;
            let mean_t = sel.iter().map(|r| r.1).sum::<nalgebra::Vector3<f64>>() / n;
            let mean_e = sel.iter().map(|r| r.2).sum::<nalgebra::Vector3<f64>>() / n;
            let var_t = sel
                .iter()
                .map(|r| (r.1 - mean_t).component_mul(&(r.1 - mean_t)))
                .sum::<nalgebra::Vector3<f64>>()
                / n;
            eprintln!(
                "perfect {perfect} t {t0}-{t1} (n {n}): mean residual truth {:?} est {:?}, var truth {:?}",
                mean_t.as_slice(),
                mean_e.as_slice(),
                var_t.as_slice()
            );
        }
    }
}

/// The IMU noise check (`ianav::ins::imu_noise`) on the simulator's own IMU, whose noise is the
/// one `InsConfig::default()` is configured for: in turbulent flight with turns it must measure
/// the configured gyro noise (within the turbulence's share of the 100 Hz second differences)
/// and never report the IMU as noisier than configured. The navigator flying the aircraft
/// adopts measured noise (`[ins.imu_noise] adopt`, on by default): on this IMU it must adopt
/// nothing, so that every simulated result is the configured model's.
#[test]
fn imu_noise_check_measures_the_simulated_imu_as_configured() {
    use ianav::ins::imu_noise::{ImuNoiseMonitor, NOISY_RATIO};
    #[derive(Default)]
    struct Noise {
        monitor: ImuNoiseMonitor,
        worst_gyro_ratio: f64,
        worst_accel_ratio: f64,
        estimates: usize,
    }
    impl FlightObserver for Noise {
        fn sensor_event(&mut self, e: &SensorEvent) {
            if let SensorEvent::Imu(s) = e
                && self.monitor.push(s)
                && let Some(n) = self.monitor.noise(&InsConfig::default())
            {
                self.estimates += 1;
                self.worst_gyro_ratio = self.worst_gyro_ratio.max(n.gyro_ratio);
                self.worst_accel_ratio = self.worst_accel_ratio.max(n.accel_ratio);
            }
        }
    }
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.navigation = NavigationMode::Ins;
    assert!(setup.scenario.turbulence_factor > 0.0);
    let mut flight = Flight::new(&setup, 1).unwrap();
    let mut obs = Noise::default();
    flight.run(&mut obs, |_| {}).unwrap();
    eprintln!(
        "{} estimates, worst gyro ratio {:.2}, worst accel ratio {:.2e}",
        obs.estimates, obs.worst_gyro_ratio, obs.worst_accel_ratio
    );
    assert!(obs.estimates > 100, "{} estimates", obs.estimates);
    // The simulated gyro white noise is the configured R (ratio 1); the gusts' angular
    // accelerations add to the second differences (the worst 31 s median reaches ≈ 1.9 on seed
    // 1), under the ×4 threshold; the accelerometer's velocity random walk is far under
    // q_velocity.
    assert!(obs.worst_gyro_ratio > 0.8, "gyro ×{}", obs.worst_gyro_ratio);
    assert!(
        obs.worst_gyro_ratio < NOISY_RATIO,
        "gyro ×{}",
        obs.worst_gyro_ratio
    );
    assert!(
        obs.worst_accel_ratio < 0.1,
        "accel ×{}",
        obs.worst_accel_ratio
    );
    let nav = flight.navigator().expect("the INS flew the aircraft");
    assert!(nav.config().ins.imu_noise.adopt);
    assert_eq!(nav.stats().imu_noise_adoptions, 0, "{:?}", nav.stats());
    assert_eq!(
        nav.imu_noise_model(),
        ianav::ins::imu_noise::ImuNoiseModel::from_config(&InsConfig::default())
    );
}
