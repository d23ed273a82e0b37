//! Criterion benches of the simulated aircraft: one 500 Hz RK4 step (four evaluations of
//! aerodynamics, propeller solve, mass model and the rotating-Earth equations) and one
//! evaluation of the loads. Budget: ≲ 1 µs per step (docs/AIRCRAFT.md).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use ianav::env::atmosphere;
use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav_sim::aircraft::{AirInputs, Aircraft, AircraftParams, TruthState};
use nalgebra::Vector3;

fn bench_aircraft(c: &mut Criterion) {
    let ac = Aircraft::new(AircraftParams::default());
    let hp_m = 2500.0;
    let p_pa = atmosphere::pressure_pa(hp_m);
    let temp_k = atmosphere::temperature_k(hp_m, 0.0);
    let still = AirInputs {
        p_pa,
        temp_k,
        rho_kgpm3: atmosphere::density_kgpm3(p_pa, temp_k),
        wind_ned_mps: Vector3::zeros(),
        turb_b_mps: Vector3::zeros(),
        turb_rate_b_rps: Vector3::zeros(),
    };
    let Ok(trim) = ac.trim(29.0, 0.0, &still, 19.5) else {
        return;
    };
    let air = AirInputs {
        wind_ned_mps: Vector3::new(3.0, -2.0, 0.0),
        turb_b_mps: Vector3::new(0.3, 0.2, -0.1),
        ..still
    };
    let pos = Geodetic {
        lat_rad: 0.7,
        lon_rad: -1.5,
        h_m: 2500.0,
    };
    let q_nb = so3::from_euler_zyx(0.3, trim.pitch_rad, 0.0);
    let v_b_mps = Vector3::new(trim.aoa_rad.cos(), 0.0, trim.aoa_rad.sin()) * 29.0;
    let v_ned = q_nb * v_b_mps;
    let w_in_n = wgs84::omega_ie_n(pos.lat_rad) + wgs84::omega_en_n(&pos, &v_ned);
    let x = TruthState {
        pos,
        v_b_mps,
        q_nb,
        w_ib_b_rps: q_nb.inverse() * w_in_n,
        mass_kg: 19.5,
    };
    let g = wgs84::gravity_ned_mps2(&pos);
    let u = trim.controls();
    c.bench_function("aircraft_step_rk4", |b| {
        b.iter(|| {
            ac.step(
                black_box(&x),
                black_box(&u),
                black_box(&air),
                black_box(&g),
                0.002,
            )
        })
    });
    c.bench_function("aircraft_loads", |b| {
        b.iter(|| ac.loads(black_box(&x), black_box(&u), black_box(&air)))
    });
}

criterion_group!(benches, bench_aircraft);
criterion_main!(benches);
