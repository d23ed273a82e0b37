//! The GNSS-denied INS flown in the simulator's loop (issue 3, point 3): guidance and control
//! fly on the INS solution; its errors stay within the bounds the paper's INS achieves.

#![allow(clippy::unwrap_used)] // tests: a failed unwrap is a failed test

use ianav::math::angle::wrap_pi;
use ianav::math::{so3, wgs84};
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
    let mut setup = FlightSetup::builtin(2).unwrap();
    setup.navigation = NavigationMode::Ins;
    let mut flight = Flight::new(&setup, seed).unwrap();
    let mut errors = Errors::default();
    flight.run(&mut errors, |_| {}).unwrap();
    errors
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
