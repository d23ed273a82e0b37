//! Error budget of the INS's GNSS-denied dead reckoning against the simulator's truth
//! (docs/INS.md "GNSS-denied covariance"): the velocity error `v̂ − v` after the loss split
//! exactly into the frozen-wind error at the loss, the wind's change since, the attitude
//! term `(Ĉ − C) v̂_air`, the air-data term `C (v̂_air − v_air)` and the turbulence `−C v_turb`;
//! the horizontal position error into the integrals of those terms. Also prints the mean
//! velocity and horizontal-position NEES over the runs.
//!
//! `cargo run -p ianav-sim --profile ci --example ins_denied_budget -- [runs] [q_e_gyr] [novane|vane] [gyro_rw|-] [scenario]`
//! (`q_e_gyr`: the attitude filter's gyro-error Q̃ per step, `-` for the default; `novane`:
//! fly without the AoA/AoS vanes; `gyro_rw`: the simulated gyros' bias random walk σ_u,
//! rad/s^1.5, instead of the paper's; `scenario`: 1 or 2, default 2).

use ianav::math::wgs84;
use ianav::nav::NavSolution;
use ianav_sim::flight::{Flight, FlightObserver, FlightSetup, NavigationMode, TruthSample};
use nalgebra::{Matrix2, Vector2, Vector3};

const TERMS: [&str; 6] = [
    "wind@loss",
    "wind change",
    "attitude",
    "air data",
    "turbulence",
    "total",
];

#[derive(Default)]
struct Budget {
    /// (truth wind at the loss, true C_nb at the loss).
    at_loss: Option<Vector3<f64>>,
    last_t_s: Option<f64>,
    /// Integrated horizontal position error per term, m.
    pos_int: [Vector3<f64>; 6],
    /// Per output sample: t, velocity terms, position terms, actual position error, NEES.
    rows: Vec<Row>,
    /// Attitude NEES sums and counts, GNSS phase (from t = 0) and denied phase.
    att_nees: [(f64, usize); 2],
    /// Attitude-norm error at the last sample, deg.
    att_norm_deg: f64,
}

#[derive(Clone)]
struct Row {
    t_s: f64,
    v: [Vector3<f64>; 6],
    p: [Vector3<f64>; 6],
    p_err: Vector3<f64>,
    nees_v: f64,
    nees_p: f64,
    sigma_v_hor: f64,
    sigma_p_hor: f64,
    att_err_deg: f64,
    sigma_yaw_deg: f64,
    /// Horizontal frozen-wind error², m²/s², and its reported variance (N + E).
    wind_err2: f64,
    wind_var: f64,
}

impl FlightObserver for Budget {
    fn nav_solution(&mut self, truth: &TruthSample, nav: &NavSolution) {
        // The INS detail: the wind and air data behind the fused solution.
        let sol = &nav.ins;
        if truth.t_s >= 0.0 {
            let (att, _) = ianav_sim::metrics::nees(truth, nav).unwrap_or((f64::NAN, f64::NAN));
            let k = usize::from(sol.gnss_denied);
            self.att_nees[k].0 += att;
            self.att_nees[k].1 += 1;
            self.att_norm_deg = ianav::math::so3::log(&(truth.q_nb.inverse() * sol.q_nb))
                .norm()
                .to_degrees();
        }
        if !sol.gnss_denied {
            return;
        }
        let wind0 = *self.at_loss.get_or_insert(truth.wind_ned_mps);
        let c_hat = sol.q_nb.to_rotation_matrix().into_inner();
        let c = truth.q_nb.to_rotation_matrix().into_inner();
        let (sa, ca) = sol.aoa_rad.sin_cos();
        let (sb, cb) = sol.aos_rad.sin_cos();
        let vb_hat = Vector3::new(ca * cb, sb, sa * cb) * sol.tas_mps;
        let vb = truth.air.v_tas_b_mps;
        let terms = [
            sol.wind_ned_mps - wind0,
            wind0 - truth.wind_ned_mps,
            (c_hat - c) * vb_hat,
            c * (vb_hat - vb),
            -(c * truth.turb_b_mps),
            sol.v_ned_mps - truth.v_ned_mps,
        ];
        let dt = self.last_t_s.map_or(0.0, |t| truth.t_s - t);
        self.last_t_s = Some(truth.t_s);
        for (acc, v) in self.pos_int.iter_mut().zip(terms.iter()) {
            *acc += v * dt;
        }
        let p_err = wgs84::ned_difference_m(&truth.pos, &sol.pos);
        let dv = terms[5];
        let nees_v = sol
            .cov
            .velocity_m2ps2
            .try_inverse()
            .map_or(f64::NAN, |i| dv.dot(&(i * dv)));
        let p2: Matrix2<f64> = sol.cov.position_m2.fixed_view::<2, 2>(0, 0).into_owned();
        let e2 = Vector2::new(p_err.x, p_err.y);
        let nees_p = p2.try_inverse().map_or(f64::NAN, |i| e2.dot(&(i * e2)));
        let att = ianav::math::so3::log(&(sol.q_nb.inverse() * truth.q_nb));
        let p_att_n = c_hat * sol.cov.attitude_rad2 * c_hat.transpose();
        self.rows.push(Row {
            t_s: truth.t_s,
            v: terms,
            p: self.pos_int,
            p_err,
            nees_v,
            nees_p,
            sigma_v_hor: (sol.cov.velocity_m2ps2[(0, 0)] + sol.cov.velocity_m2ps2[(1, 1)]).sqrt(),
            sigma_p_hor: (p2[(0, 0)] + p2[(1, 1)]).sqrt(),
            att_err_deg: (c_hat * att).z.to_degrees(),
            sigma_yaw_deg: p_att_n[(2, 2)].sqrt().to_degrees(),
            wind_err2: terms[0].x.powi(2) + terms[0].y.powi(2),
            wind_var: sol.cov.wind_m2ps2[(0, 0)] + sol.cov.wind_m2ps2[(1, 1)],
        });
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let runs: u64 = args.get(1).map_or(Ok(20), |s| s.parse())?;
    let q_e_gyr: Option<f64> = args
        .get(2)
        .filter(|s| s.as_str() != "-")
        .map(|s| s.parse())
        .transpose()?;
    let no_vane = args.get(3).is_some_and(|s| s == "novane");
    let gyro_rw: Option<f64> = args
        .get(4)
        .filter(|s| s.as_str() != "-")
        .map(|s| s.parse())
        .transpose()?;
    let scenario: u8 = args.get(5).map_or(Ok(2), |s| s.parse())?;
    let mut all = Vec::new();
    let (mut hor_end, mut att_end, mut att_nees) = (Vec::new(), Vec::new(), [0.0; 2]);
    for seed in 1..=runs {
        let mut setup = FlightSetup::builtin(scenario)?;
        setup.navigation = NavigationMode::Ins;
        if let Some(q) = q_e_gyr {
            setup.ins.attitude.q_e_gyr_rad2ps2 = q;
        }
        if let Some(rw) = gyro_rw {
            setup.sensors.gyro.bias_rw_sigma = rw;
        }
        if no_vane {
            setup.sensors.air.vanes_enabled = false;
        }
        let mut flight = Flight::new(&setup, seed)?;
        let mut b = Budget::default();
        flight.run(&mut b, |_| {})?;
        let last = b
            .rows
            .last()
            .cloned()
            .ok_or_else(|| anyhow::anyhow!("no denied samples"))?;
        let hor = |v: &Vector3<f64>| v.x.hypot(v.y);
        println!(
            "seed {seed:2}: end t {:.0} s, hor err {:6.1} m (σ {:6.1}), yaw err {:+.3}° (σ {:.3}°); pos terms (m): {}",
            last.t_s,
            hor(&last.p_err),
            last.sigma_p_hor,
            last.att_err_deg,
            last.sigma_yaw_deg,
            TERMS
                .iter()
                .zip(last.p.iter())
                .map(|(n, p)| format!("{n} {:.1}", hor(p)))
                .collect::<Vec<_>>()
                .join(", ")
        );
        hor_end.push(hor(&last.p_err));
        att_end.push(b.att_norm_deg);
        for (acc, (sum, count)) in att_nees.iter_mut().zip(b.att_nees) {
            *acc += sum / count as f64 / runs as f64;
        }
        all.push(b.rows);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let sd = |v: &[f64]| {
        let m = mean(v);
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0)).sqrt()
    };
    println!(
        "at t_end: horizontal error {:.1} ± {:.1} m, attitude norm {:.3} ± {:.3}°; attitude NEES mean GNSS phase {:.2}, denied {:.2}",
        mean(&hor_end),
        sd(&hor_end),
        mean(&att_end),
        sd(&att_end),
        att_nees[0],
        att_nees[1]
    );
    let n = all.iter().map(Vec::len).min().unwrap_or(0);
    let nr = all.len() as f64;
    // RMS per term of the horizontal velocity (over runs and samples) and the vertical.
    println!("velocity error terms, RMS over runs and samples after the loss (N, E, D), m/s:");
    for (k, name) in TERMS.iter().enumerate() {
        let mut s = Vector3::zeros();
        for run in &all {
            for r in &run[..n] {
                s += r.v[k].component_mul(&r.v[k]);
            }
        }
        let rms = (s / (nr * n as f64)).map(f64::sqrt);
        println!("  {name:12} {:.3} {:.3} {:.3}", rms.x, rms.y, rms.z);
    }
    let mut sv = 0.0;
    for run in &all {
        for r in &run[..n] {
            sv += r.sigma_v_hor.powi(2);
        }
    }
    println!(
        "  reported σ_hor (√(σN²+σE²)) RMS {:.3}",
        (sv / (nr * n as f64)).sqrt()
    );
    let we = all.iter().map(|r| r[0].wind_err2).sum::<f64>() / nr;
    let wv = all.iter().map(|r| r[0].wind_var).sum::<f64>() / nr;
    println!(
        "  frozen wind error (horizontal) RMS {:.3} m/s, reported σ RMS {:.3} m/s",
        we.sqrt(),
        wv.sqrt()
    );
    println!("time   NEES_v  NEES_p  rms_hor_p  σ_hor_p  | RMS position terms (hor) m");
    let (mut inv, mut inp) = (0usize, 0usize);
    let (lo3, hi3) = (2.024, 4.165);
    let (lo2, hi2) = (1.222, 2.967);
    for i in 0..n {
        let t = all[0][i].t_s;
        let mv = all.iter().map(|r| r[i].nees_v).sum::<f64>() / nr;
        let mp = all.iter().map(|r| r[i].nees_p).sum::<f64>() / nr;
        if (lo3..=hi3).contains(&mv) {
            inv += 1;
        }
        if (lo2..=hi2).contains(&mp) {
            inp += 1;
        }
        if i % 500 == 0 || i == n - 1 {
            let rp = (all
                .iter()
                .map(|r| r[i].p_err.x.powi(2) + r[i].p_err.y.powi(2))
                .sum::<f64>()
                / nr)
                .sqrt();
            let sp = (all.iter().map(|r| r[i].sigma_p_hor.powi(2)).sum::<f64>() / nr).sqrt();
            let terms: Vec<String> = (0..6)
                .map(|k| {
                    format!(
                        "{:.1}",
                        (all.iter()
                            .map(|r| r[i].p[k].x.powi(2) + r[i].p[k].y.powi(2))
                            .sum::<f64>()
                            / nr)
                            .sqrt()
                    )
                })
                .collect();
            println!(
                "{t:5.0} {mv:7.2} {mp:7.2} {rp:9.1} {sp:8.1}  | {}",
                terms.join(" ")
            );
        }
    }
    println!(
        "in band (20-run band, valid for 20 runs): velocity {:.1}%, horizontal position {:.1}% of {n}",
        100.0 * inv as f64 / n as f64,
        100.0 * inp as f64 / n as f64
    );
    Ok(())
}
