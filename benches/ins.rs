//! Criterion benches of the INS (docs/INS.md, "Performance"): one full IMU step of the
//! cascade (air data, attitude, position) at 100 Hz with GNSS fixes at 1 Hz, and one step in
//! GNSS-denied mode. Budget: ≤ 5 µs median per step, since every Monte Carlo run takes 100 of
//! them per simulated second (docs/PERFORMANCE.md, "INS").
//!
//! The input is a precomputed, exactly consistent stream of straight level flight (air data,
//! magnetometer and IMU every 10 ms, GNSS every second); each timed run starts from a clone of
//! an INS that has already processed the first minute, so only steady-state steps are timed.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use ianav::env::atmosphere;
use ianav::env::magnetic::{MagneticGrid, MagneticModel};
use ianav::ins::{Ins, InsConfig, InsInit};
use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav::sensors::{AirSample, GnssFix, ImuSample, MagSample, SensorEvent};
use nalgebra::Vector3;

/// IMU period, µs (100 Hz).
const DT_US: u64 = 10_000;
/// Magnetic-model epoch, decimal year.
const YEAR: f64 = 2026.0;
/// Steps of the warm-up (1 min) and of the timed stream (5 min).
const WARMUP_STEPS: usize = 6_000;
const TIMED_STEPS: usize = 30_000;

/// Events of straight level flight at 30 m/s heading 60° at 1500 m, in the order the INS
/// consumes them without lag: air, mag, GNSS (while `t < gnss_until_s`), IMU.
fn stream(steps: usize, gnss_until_s: f64) -> (InsInit, Vec<Vec<SensorEvent>>) {
    let mut pos = Geodetic {
        lat_rad: 44.5_f64.to_radians(),
        lon_rad: (-89.5_f64).to_radians(),
        h_m: 1500.0,
    };
    let aoa = 0.05_f64;
    let q_nb = so3::from_euler_zyx(60_f64.to_radians(), aoa, 0.0);
    let v_n = q_nb * Vector3::new(aoa.cos(), 0.0, aoa.sin()) * 30.0;
    let mut grid = MagneticGrid::new(MagneticModel::new(YEAR).expect("WMM epoch"));
    let init = InsInit::new(q_nb, pos, v_n, YEAR);
    let mut out = Vec::with_capacity(steps);
    let dt = DT_US as f64 * 1e-6;
    for k in 0..steps {
        let t_us = k as u64 * DT_US;
        let hp = atmosphere::pressure_altitude_from_geometric_m(pos.h_m, &Default::default());
        let c_bn = q_nb.inverse();
        let w_ie = wgs84::omega_ie_n(pos.lat_rad);
        let w_en = wgs84::omega_en_n(&pos, &v_n);
        let mut ev = vec![
            SensorEvent::Air(AirSample {
                t_us,
                tas_mps: 30.0,
                aoa_rad: Some(aoa),
                aos_rad: Some(0.0),
                p_pa: atmosphere::pressure_pa(hp),
                temp_k: atmosphere::temperature_k(hp, 0.0),
            }),
            SensorEvent::Mag(MagSample {
                t_us,
                mag_b_nt: c_bn * grid.field_ned_nt(&pos).expect("WMM"),
            }),
        ];
        if k % 100 == 0 && (t_us as f64) * 1e-6 < gnss_until_s {
            ev.push(SensorEvent::Gnss(GnssFix {
                t_us,
                pos,
                v_ned_mps: v_n,
                sigma_hor_m: 2.12,
                sigma_ver_m: 4.25,
                sigma_vel_mps: 0.0741,
            }));
        }
        ev.push(SensorEvent::Imu(ImuSample {
            t_us,
            gyro_rps: c_bn * (w_ie + w_en),
            accel_mps2: c_bn * ((w_ie * 2.0 + w_en).cross(&v_n) - wgs84::gravity_ned_mps2(&pos)),
        }));
        out.push(ev);
        let r = wgs84::geodetic_rates(&pos, &v_n);
        pos.lat_rad += r.x * dt;
        pos.lon_rad += r.y * dt;
        pos.h_m += r.z * dt;
    }
    (init, out)
}

/// Time `iters` steps of the stream after the warm-up, restarting from the warmed-up INS when
/// the stream is exhausted (the restarts are not timed).
fn time_steps(warm: &Ins, timed: &[Vec<SensorEvent>], iters: u64) -> Duration {
    let mut total = Duration::ZERO;
    let mut done = 0_u64;
    while done < iters {
        let mut ins = warm.clone();
        let n = (iters - done).min(timed.len() as u64) as usize;
        let start = Instant::now();
        for step in &timed[..n] {
            for e in step {
                black_box(ins.push(black_box(e)));
            }
        }
        total += start.elapsed();
        done += n as u64;
    }
    total
}

fn bench_ins(c: &mut Criterion) {
    let cfg = InsConfig::default();
    for (name, gnss_until_s) in [
        ("ins_step_gnss_100hz", f64::INFINITY),
        ("ins_step_denied_100hz", 30.0),
    ] {
        let (init, events) = stream(WARMUP_STEPS + TIMED_STEPS, gnss_until_s);
        let Ok(mut warm) = Ins::new(&cfg, &init) else {
            return;
        };
        for step in &events[..WARMUP_STEPS] {
            for e in step {
                warm.push(e);
            }
        }
        let timed = &events[WARMUP_STEPS..];
        c.bench_function(name, |b| {
            b.iter_custom(|iters| time_steps(&warm, timed, iters))
        });
    }
}

criterion_group!(benches, bench_ins);
criterion_main!(benches);
