//! Statistical acceptance tests of the simulated sensors (docs/REFERENCES.md A2.1–A2.5): Allan
//! deviation of the inertial noise and drift, white noise of the magnetometer, air data and
//! GNSS, the per-run/per-aircraft error distributions, exactness with zero errors, lever arm
//! and misalignment geometry, determinism and stream independence.
//!
//! Run with `cargo test -p ianav-sim --profile ci sensors` (the long series are slow
//! unoptimised).
//!
//! Tolerances. A sample standard deviation of `n` independent Gaussian values has relative
//! standard error `1/√(2(n−1))`; tests allow 5–6 of those. The non-overlapping Allan
//! deviation from `n` clusters has relative standard error `κ/√(2(n−1))`, where
//! `κ² = 1 + 2ρ²` corrects for the correlation `ρ` of neighbouring cluster differences:
//! `ρ = −1/2` for white noise (`κ = 1.22`), `ρ = 1/4` for a random walk (`κ = 1.06`).

mod sensors {
    use ianav::math::wgs84::{self, Geodetic};
    use ianav_sim::sensors::allan::allan_deviation;
    use ianav_sim::sensors::{SensorSuite, SensorTruth, SensorsConfig};
    use nalgebra::{UnitQuaternion, Vector3};

    /// Relative standard error of a sample σ from `n` independent Gaussian values.
    fn std_rel_err(n: usize) -> f64 {
        1.0 / (2.0 * (n as f64 - 1.0)).sqrt()
    }

    /// Sample mean and standard deviation.
    fn mean_std(x: &[f64]) -> (f64, f64) {
        let n = x.len() as f64;
        let mean = x.iter().sum::<f64>() / n;
        let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, var.sqrt())
    }

    /// Assert `|measured/expected − 1| ≤ tol`.
    fn assert_rel(what: &str, measured: f64, expected: f64, tol: f64) {
        let rel = measured / expected - 1.0;
        assert!(
            rel.abs() <= tol,
            "{what}: measured {measured:.6e}, expected {expected:.6e} ({:+.2} %, tol {:.2} %)",
            100.0 * rel,
            100.0 * tol
        );
    }

    /// Level flight at 3000 m over Wisconsin with a static (non-rotating) body.
    fn static_truth() -> SensorTruth {
        SensorTruth {
            t_us: 0,
            pos: Geodetic {
                lat_rad: 45.0_f64.to_radians(),
                lon_rad: (-90.0_f64).to_radians(),
                h_m: 3000.0,
            },
            v_ned_mps: Vector3::new(28.0, 9.0, -0.5),
            q_nb: UnitQuaternion::from_euler_angles(0.03, 0.05, 1.1),
            w_ib_b_rps: Vector3::zeros(),
            w_dot_ib_b_rps2: Vector3::zeros(),
            f_ib_b_mps2: Vector3::new(0.5, -0.3, -9.78),
            cg_from_ref_b_m: Vector3::new(0.207, 0.0, -0.005),
            mag_ned_nt: Vector3::new(17455.7, -764.6, 52192.7),
            tas_mps: 30.0,
            aoa_rad: 0.04,
            aos_rad: -0.01,
            p_pa: 70_000.0,
            temp_k: 270.0,
        }
    }

    /// A manoeuvring truth at sample `k`: rotation rate growing at a constant rate.
    fn turning_truth(k: u64, dt_s: f64) -> SensorTruth {
        let t = k as f64 * dt_s;
        let w_dot = Vector3::new(0.2, -0.1, 0.05);
        SensorTruth {
            t_us: k * (dt_s * 1e6).round() as u64,
            w_ib_b_rps: Vector3::new(0.1, -0.2, 0.3) + w_dot * t,
            w_dot_ib_b_rps2: w_dot,
            f_ib_b_mps2: Vector3::new(1.0 + t, -2.0, -9.0),
            tas_mps: 30.0 + t,
            ..static_truth()
        }
    }

    /// Cluster means of `m` consecutive samples, updated on line (no long series kept).
    struct Clusters {
        m: usize,
        sum: [f64; 3],
        count: usize,
        means: [Vec<f64>; 3],
    }

    impl Clusters {
        fn new(m: usize) -> Self {
            Self {
                m,
                sum: [0.0; 3],
                count: 0,
                means: Default::default(),
            }
        }

        fn push(&mut self, v: &Vector3<f64>) {
            for i in 0..3 {
                self.sum[i] += v[i];
            }
            self.count += 1;
            if self.count == self.m {
                for i in 0..3 {
                    self.means[i].push(self.sum[i] / self.m as f64);
                }
                self.sum = [0.0; 3];
                self.count = 0;
            }
        }
    }

    /// Expected Allan variance of white noise of density `sv` plus a discrete random walk of
    /// density `su` sampled every `dt`, at `tau`: `sv²/τ + su²(τ/3 + Δt²/(6τ))` (the last
    /// term is the exact discrete-walk correction, negligible for τ ≫ Δt).
    fn expected_avar(sv: f64, su: f64, dt: f64, tau: f64) -> f64 {
        sv * sv / tau + su * su * (tau / 3.0 + dt * dt / (6.0 * tau))
    }

    /// Config for the inertial noise tests: zero lever arm, so the accelerometer output has
    /// no lever-arm compensation term. That term (`ω̇_est × r`, from the differentiated gyro
    /// noise) is blue noise with its own test below; here it would hide the accelerometer's
    /// own noise.
    fn no_lever_arm(mut cfg: SensorsConfig) -> SensorsConfig {
        cfg.platform.t_rp_b_m = [0.0; 3];
        cfg.platform.t_rp_est_sigma_m = 0.0;
        cfg
    }

    fn no_lever_arm_truth() -> SensorTruth {
        SensorTruth {
            cg_from_ref_b_m: Vector3::zeros(),
            ..static_truth()
        }
    }

    #[test]
    fn sensors_inertial_white_noise_allan() {
        // Default 100 Hz sensors, band on (it only acts on the walk at τ ≳ 100 s).
        // τ = 0.1 s and 1 s, 2000 s of data: n = 2000 clusters at 1 s → relative standard
        // error 1.22/√3998 = 1.9 %, so 15 % is ~8σ. The constant truth, offsets and scale
        // errors are constant and drop out of the Allan deviation.
        let cfg = no_lever_arm(SensorsConfig::default());
        let dt = cfg.imu_period_s;
        let mut suite = SensorSuite::new(&cfg, 11);
        let truth = no_lever_arm_truth();
        let m_short = 10; // τ = 0.1 s
        let (mut gyro, mut accel) = (Clusters::new(m_short), Clusters::new(m_short));
        for _ in 0..200_000 {
            let s = suite.sample_imu(&truth);
            gyro.push(&s.gyro_rps);
            accel.push(&s.accel_mps2);
        }
        for (name, clusters, c) in [("gyro", &gyro, &cfg.gyro), ("accel", &accel, &cfg.accel)] {
            for axis in 0..3 {
                for (tau, per) in [(0.1, 1), (1.0, 10)] {
                    let p = allan_deviation(&clusters.means[axis], per).unwrap();
                    let expected = expected_avar(c.noise_density, c.bias_rw_sigma, dt, tau).sqrt();
                    eprintln!(
                        "ADEV {name}[{axis}] τ = {tau} s: {:.4e} (model {expected:.4e}, n = {})",
                        p.adev, p.clusters
                    );
                    assert_rel(&format!("{name}[{axis}] τ={tau}"), p.adev, expected, 0.15);
                }
            }
        }
    }

    #[test]
    fn sensors_inertial_random_walk_allan() {
        // The soft band (L = 100 steps) bounds the walk at ≈ 100 steps, which a free walk
        // reaches after 100² steps = 100 s at 100 Hz, so it bends σ_A below σ_u√(τ/3) for
        // τ ≳ 100 s: it is disabled here (its own test checks the bound). The sample period
        // is 0.1 s instead of 0.01 s to make 1000-s clusters affordable; σ_A(τ ≫ Δt) does not
        // depend on Δt, and this also checks the √Δt scaling of the drift and noise steps.
        // τ = 250 s and 1000 s, 800 000 s of data: n = 800 clusters at 1000 s → relative
        // standard error 1.06/√1598 = 2.7 % (15 % ≈ 5.6σ); at 250 s, 1.3 %. White noise is
        // ≤ 4 % of the Allan variance at 250 s and is included in the model.
        let mut cfg = no_lever_arm(SensorsConfig::default());
        cfg.imu_period_s = 0.1;
        cfg.gyro.band_limit_steps = f64::INFINITY;
        cfg.accel.band_limit_steps = f64::INFINITY;
        let dt = cfg.imu_period_s;
        let mut suite = SensorSuite::new(&cfg, 12);
        let truth = no_lever_arm_truth();
        let m_250 = 2500;
        let (mut gyro, mut accel) = (Clusters::new(m_250), Clusters::new(m_250));
        for _ in 0..8_000_000 {
            let s = suite.sample_imu(&truth);
            gyro.push(&s.gyro_rps);
            accel.push(&s.accel_mps2);
        }
        for (name, clusters, c) in [("gyro", &gyro, &cfg.gyro), ("accel", &accel, &cfg.accel)] {
            for axis in 0..3 {
                for (tau, per) in [(250.0, 1), (1000.0, 4)] {
                    let p = allan_deviation(&clusters.means[axis], per).unwrap();
                    let expected = expected_avar(c.noise_density, c.bias_rw_sigma, dt, tau).sqrt();
                    eprintln!(
                        "ADEV {name}[{axis}] τ = {tau} s: {:.4e} (model {expected:.4e}, n = {})",
                        p.adev, p.clusters
                    );
                    assert_rel(&format!("{name}[{axis}] τ={tau}"), p.adev, expected, 0.15);
                }
            }
        }
    }

    #[test]
    fn sensors_bias_drift_stays_in_the_band() {
        // Default band (L = 100, safety 20): beyond 80 steps the pull is an OU process of
        // spread 10 steps (random_walk module doc), so |S| < 140 is a 6σ bound; a free walk
        // would spread √300 000 ≈ 550 steps over this run. It must also reach the band.
        let mut cfg = no_lever_arm(SensorsConfig::default());
        cfg.gyro.bias_offset_sigma = 0.0;
        cfg.accel.bias_offset_sigma = 0.0;
        let step_g = cfg.gyro.bias_rw_sigma * cfg.imu_period_s.sqrt();
        let step_a = cfg.accel.bias_rw_sigma * cfg.imu_period_s.sqrt();
        let mut suite = SensorSuite::new(&cfg, 13);
        let truth = no_lever_arm_truth();
        let (mut max_g, mut max_a) = (0.0_f64, 0.0_f64);
        for _ in 0..300_000 {
            suite.sample_imu(&truth);
            let e = suite.true_errors();
            max_g = max_g.max(e.gyr_bias_rps.amax() / step_g);
            max_a = max_a.max(e.acc_bias_mps2.amax() / step_a);
        }
        eprintln!("max |drift|: gyro {max_g:.3} steps, accel {max_a:.3} steps");
        for m in [max_g, max_a] {
            assert!(m > 60.0 && m < 140.0, "max |S| = {m}");
        }
    }

    #[test]
    fn sensors_lever_arm_compensation_noise() {
        // With the default lever arm, the accelerometer output carries −ω̇_est × r_est where
        // ω̇_est = Δω̃/Δt is the differenced gyro noise: per axis
        // var = σ_a² + (2σ_g²/Δt²)(|r|² − r_i²) (ω̃×(ω̃×r) is ~1e-7 m/s², negligible).
        // 100 000 samples; neighbouring samples correlate (ρ = −1/2), inflating the standard
        // error of σ by √1.5 to 0.27 %: 2 % is > 7σ.
        let cfg = SensorsConfig::default();
        let dt = cfg.imu_period_s;
        let mut suite = SensorSuite::new(&cfg, 14);
        let truth = static_truth();
        let e0 = suite.true_errors();
        let r = e0.t_rp_b_est_m - truth.cg_from_ref_b_m;
        let sg = cfg.gyro.noise_density / dt.sqrt();
        let sa = cfg.accel.noise_density / dt.sqrt();
        let n = 100_000;
        let mut resid: [Vec<f64>; 3] = Default::default();
        for _ in 0..n {
            let s = suite.sample_imu(&truth);
            let e = suite.true_errors();
            // Output minus truth minus everything systematic except the lever-arm noise.
            let sys =
                e.acc_bias_mps2 + (suite.imu().accel().a() * truth.f_ib_b_mps2 - truth.f_ib_b_mps2);
            let d = s.accel_mps2 - truth.f_ib_b_mps2 - sys;
            for i in 0..3 {
                resid[i].push(d[i]);
            }
        }
        for i in 0..3 {
            let (_, std) = mean_std(&resid[i][1..]);
            let expected =
                (sa * sa + 2.0 * sg * sg / (dt * dt) * (r.norm_squared() - r[i] * r[i])).sqrt();
            eprintln!("accel[{i}] with lever arm: σ {std:.4e} (model {expected:.4e})");
            assert_rel(&format!("accel[{i}] lever noise"), std, expected, 0.02);
        }
    }

    #[test]
    fn sensors_magnetometer_noise_and_rate_scaling() {
        // σ per sample = σ_v/√Δt: 50 nT at 100 Hz, 35.4 nT at 50 Hz. 50 000 samples:
        // standard error 0.32 %, tolerance 2 % (6σ). The mean of the residual after removing
        // E_mag is zero within 5 standard errors (5·σ/√n).
        for period_s in [0.01, 0.02] {
            let mut cfg = SensorsConfig::default();
            cfg.mag.period_s = period_s;
            let mut suite = SensorSuite::new(&cfg, 15);
            let truth = static_truth();
            let b_b = truth.q_nb.inverse_transform_vector(&truth.mag_ned_nt);
            let n = 50_000;
            let mut resid: [Vec<f64>; 3] = Default::default();
            for _ in 0..n {
                let s = suite.sample_mag(&truth);
                let d = s.mag_b_nt - b_b - suite.true_errors().e_mag_nt;
                for i in 0..3 {
                    resid[i].push(d[i]);
                }
            }
            let expected = cfg.mag.noise_density_nt_sqrt_s / period_s.sqrt();
            for (i, r) in resid.iter().enumerate() {
                let (mean, std) = mean_std(r);
                eprintln!("mag[{i}] Δt {period_s}: σ {std:.3} nT (model {expected:.3})");
                assert_rel(&format!("mag[{i}]"), std, expected, 6.0 * std_rel_err(n));
                assert!(
                    mean.abs() < 5.0 * expected / (n as f64).sqrt(),
                    "mean {mean}"
                );
            }
        }
    }

    #[test]
    fn sensors_air_data_noise_is_per_sample() {
        // ỹ − x − bias has σ equal to the configured per-sample σ whatever the period
        // (docs/REFERENCES.md A9.10). 40 000 samples: standard error 0.35 %, tolerance 6σ.
        for period_s in [0.01, 0.1] {
            let mut cfg = SensorsConfig::default();
            cfg.air.period_s = period_s;
            let a = cfg.air;
            let mut suite = SensorSuite::new(&cfg, 16);
            let truth = static_truth();
            let bias = suite.true_errors().air;
            let n = 40_000;
            let mut resid: [Vec<f64>; 5] = Default::default();
            for _ in 0..n {
                let s = suite.sample_air(&truth);
                let d = [
                    s.tas_mps - truth.tas_mps - bias.tas_mps,
                    s.aoa_rad.unwrap() - truth.aoa_rad - bias.aoa_rad.unwrap(),
                    s.aos_rad.unwrap() - truth.aos_rad - bias.aos_rad.unwrap(),
                    s.p_pa - truth.p_pa - bias.p_pa,
                    s.temp_k - truth.temp_k - bias.temp_k,
                ];
                for (r, v) in resid.iter_mut().zip(d) {
                    r.push(v);
                }
            }
            let expected = [
                a.tas_noise_sigma_mps,
                a.aoa_noise_sigma_deg.to_radians(),
                a.aos_noise_sigma_deg.to_radians(),
                a.p_noise_sigma_pa,
                a.temp_noise_sigma_k,
            ];
            for (k, (r, e)) in resid.iter().zip(expected).enumerate() {
                let (mean, std) = mean_std(r);
                eprintln!("air[{k}] Δt {period_s}: σ {std:.4e} (model {e:.4e})");
                assert_rel(&format!("air[{k}]"), std, e, 6.0 * std_rel_err(n));
                assert!(
                    mean.abs() < 5.0 * e / (n as f64).sqrt(),
                    "air[{k}] mean {mean}"
                );
            }
        }
    }

    /// NED error of a fix with the same radii the receiver model uses.
    fn fix_error_ned(truth: &SensorTruth, fix: &Geodetic) -> Vector3<f64> {
        let p = truth.pos;
        let m = wgs84::radius_meridian_m(p.lat_rad);
        let n = wgs84::radius_prime_vertical_m(p.lat_rad);
        Vector3::new(
            (fix.lat_rad - p.lat_rad) * (m + p.h_m),
            (fix.lon_rad - p.lon_rad) * (n + p.h_m) * p.lat_rad.cos(),
            -(fix.h_m - p.h_m),
        )
    }

    #[test]
    fn sensors_gnss_white_noise_and_iono() {
        // 20 000 fixes. Position error minus the ionospheric part (known from true_errors)
        // and the velocity error are white with the configured σ: standard error 0.5 %,
        // tolerance 6σ. The ionospheric part is linear between nodes 60 fixes apart (zero
        // second difference inside an interval) and moves σ_iono per node: 333 nodes × 3
        // axes, standard error 2.2 %, tolerance 12 % (band off so that the pull does not bias
        // the steps).
        let mut cfg = SensorsConfig::default();
        cfg.gnss.iono_band_limit_steps = f64::INFINITY;
        let g = cfg.gnss;
        let mut suite = SensorSuite::new(&cfg, 17);
        let truth = static_truth();
        let n = 20_000;
        let mut pos_white: [Vec<f64>; 3] = Default::default();
        let mut vel: [Vec<f64>; 3] = Default::default();
        let mut iono = Vec::with_capacity(n);
        for _ in 0..n {
            let fix = suite.sample_gnss(&truth);
            assert_eq!(fix.sigma_hor_m, g.sigma_hor_m);
            assert_eq!(fix.sigma_ver_m, g.sigma_ver_m);
            assert_eq!(fix.sigma_vel_mps, g.sigma_vel_mps);
            let i_ned = suite.true_errors().gnss_iono_ned_m;
            let e = fix_error_ned(&truth, &fix.pos) - i_ned;
            let dv = fix.v_ned_mps - truth.v_ned_mps;
            for k in 0..3 {
                pos_white[k].push(e[k]);
                vel[k].push(dv[k]);
            }
            iono.push(i_ned);
        }
        let sig = [g.sigma_hor_m, g.sigma_hor_m, g.sigma_ver_m];
        for k in 0..3 {
            let (_, sp) = mean_std(&pos_white[k]);
            let (_, sv) = mean_std(&vel[k]);
            eprintln!(
                "gnss[{k}]: pos σ {sp:.4} m (model {}), vel σ {sv:.5} m/s",
                sig[k]
            );
            assert_rel(&format!("gnss pos[{k}]"), sp, sig[k], 6.0 * std_rel_err(n));
            assert_rel(
                &format!("gnss vel[{k}]"),
                sv,
                g.sigma_vel_mps,
                6.0 * std_rel_err(n),
            );
        }
        let per = g.iono_fixes_per_step as usize;
        let mut node_steps = Vec::new();
        for (j, w) in iono.windows(3).enumerate() {
            // Second difference is zero unless the window straddles a node.
            if (j + 1) % per != 0 {
                assert!((w[2] - 2.0 * w[1] + w[0]).amax() < 1e-9, "fix {j}");
            }
        }
        for nodes in iono.chunks_exact(per).collect::<Vec<_>>().windows(2) {
            let d = (nodes[1][0] - nodes[0][0]) / g.iono_sigma_m;
            node_steps.extend(d.iter());
        }
        let (_, s) = mean_std(&node_steps);
        eprintln!(
            "iono node step: {s:.3} σ_iono over {} steps",
            node_steps.len()
        );
        assert_rel("iono step", s, 1.0, 0.12);
    }

    #[test]
    fn sensors_gnss_geodetic_mapping_matches_ecef() {
        // With the white noise off, the fix is displaced by the ionospheric error alone;
        // the exact ECEF difference must equal it to the curvature error of the radii
        // approximation, ~|e|²/R ≈ 1e-5 m for errors of ~10 m: 1 mm tolerance.
        let mut cfg = SensorsConfig::default();
        cfg.gnss.sigma_hor_m = 0.0;
        cfg.gnss.sigma_ver_m = 0.0;
        for seed in 0..20 {
            let mut suite = SensorSuite::new(&cfg, seed);
            let truth = static_truth();
            let fix = suite.sample_gnss(&truth);
            let iono = suite.true_errors().gnss_iono_ned_m;
            let d = wgs84::ned_difference_m(&truth.pos, &fix.pos);
            assert!((d - iono).amax() < 1e-3, "seed {seed}: {d} vs {iono}");
        }
    }

    #[test]
    fn sensors_per_run_and_per_aircraft_distributions() {
        // Across 4000 seeds every drawn constant has the configured σ: standard error 1.1 %,
        // tolerance 6σ = 6.7 %. Systematic errors are read from true_errors.
        let n = 4000;
        let cfg = SensorsConfig::default();
        let truth = static_truth();
        let b_b = truth.q_nb.inverse_transform_vector(&truth.mag_ned_nt);
        let mut cols: Vec<(String, f64, Vec<f64>)> = Vec::new();
        let mut push = |name: String, expected: f64, v: f64| {
            if let Some(c) = cols.iter_mut().find(|c| c.0 == name) {
                c.2.push(v);
            } else {
                cols.push((name, expected, vec![v]));
            }
        };
        let m = cfg.mag;
        for seed in 0..n as u64 {
            let mut suite = SensorSuite::new(&cfg, seed);
            let e = suite.true_errors();
            let (yaw_t, pitch_t, bank_t) = {
                let (r, p, y) = e.q_bp_true.euler_angles();
                (y, p, r)
            };
            let (yaw_e, pitch_e, bank_e) = {
                let (r, p, y) = e.q_bp_est.euler_angles();
                (y, p, r)
            };
            let p = cfg.platform;
            let rad = f64::to_radians;
            push("mount yaw".into(), rad(p.euler_bp_sigma_deg[0]), yaw_t);
            push("mount pitch".into(), rad(p.euler_bp_sigma_deg[1]), pitch_t);
            push("mount bank".into(), rad(p.euler_bp_sigma_deg[2]), bank_t);
            let est = rad(p.euler_bp_est_sigma_deg);
            push("mount est yaw".into(), est, yaw_e - yaw_t);
            push("mount est pitch".into(), est, pitch_e - pitch_t);
            push("mount est bank".into(), est, bank_e - bank_t);
            for i in 0..3 {
                let dt_rp = e.t_rp_b_est_m[i] - e.t_rp_b_true_m[i];
                push(format!("lever est {i}"), p.t_rp_est_sigma_m, dt_rp);
                // Before the first sample the biases are the offsets B₀ν₀.
                push(
                    format!("gyro B0 {i}"),
                    cfg.gyro.bias_offset_sigma,
                    e.gyr_bias_rps[i],
                );
                push(
                    format!("accel B0 {i}"),
                    cfg.accel.bias_offset_sigma,
                    e.acc_bias_mps2[i],
                );
                push(format!("iono0 {i}"), g_iono0(&cfg), e.gnss_iono_ned_m[i]);
            }
            push("tas bias".into(), cfg.air.tas_bias_sigma_mps, e.air.tas_mps);
            push(
                "aoa bias".into(),
                rad(cfg.air.aoa_bias_sigma_deg),
                e.air.aoa_rad.unwrap(),
            );
            push(
                "aos bias".into(),
                rad(cfg.air.aos_bias_sigma_deg),
                e.air.aos_rad.unwrap(),
            );
            push("p bias".into(), cfg.air.p_bias_sigma_pa, e.air.p_pa);
            push("temp bias".into(), cfg.air.temp_bias_sigma_k, e.air.temp_k);
            // E_mag = B_hi + B_off + M_si·B^b: per axis
            // σ² = σ_hi² + σ_off² + s²B_i² + m²Σ_{j≠i}B_j².
            suite.sample_mag(&truth);
            let e_mag = suite.true_errors().e_mag_nt;
            for i in 0..3 {
                let cross: f64 = (0..3).filter(|&j| j != i).map(|j| b_b[j] * b_b[j]).sum();
                let var = m.hard_iron_sigma_nt.powi(2)
                    + m.offset_sigma_nt.powi(2)
                    + (m.soft_iron_scale_sigma * b_b[i]).powi(2)
                    + m.soft_iron_cross_sigma.powi(2) * cross;
                push(format!("E_mag {i}"), var.sqrt(), e_mag[i]);
            }
        }
        for (name, expected, v) in &cols {
            let (mean, std) = mean_std(v);
            eprintln!("{name}: σ {std:.4e} (model {expected:.4e})");
            assert_rel(name, std, *expected, 6.0 * std_rel_err(n));
            assert!(
                mean.abs() < 5.0 * expected / (n as f64).sqrt(),
                "{name} mean {mean}"
            );
        }
    }

    fn g_iono0(cfg: &SensorsConfig) -> f64 {
        cfg.gnss.iono_sigma_m * cfg.gnss.iono_initial_sigma_steps
    }

    #[test]
    fn sensors_scale_and_cross_coupling() {
        // Only M on (no bias, noise, mounting): E = M·u. With u = x̂ the error is the first
        // column of M, (s, m, m)·ν for both; with u = ẑ the gyro gives (m, m, s)·ν and the
        // lower-triangular accelerometer (0, 0, s)·ν — exactly zero above the diagonal.
        // 4000 seeds, tolerance 6σ of the sample σ.
        let n = 4000;
        let mut cfg = SensorsConfig::perfect();
        cfg.platform.t_rp_b_m = [0.0; 3];
        let d = SensorsConfig::default();
        for (c, dc) in [(&mut cfg.gyro, d.gyro), (&mut cfg.accel, d.accel)] {
            c.scale_sigma = dc.scale_sigma;
            c.cross_coupling_sigma = dc.cross_coupling_sigma;
        }
        let truth_x = SensorTruth {
            w_ib_b_rps: Vector3::x(),
            f_ib_b_mps2: Vector3::x(),
            ..no_lever_arm_truth()
        };
        let truth_z = SensorTruth {
            w_ib_b_rps: Vector3::z(),
            f_ib_b_mps2: Vector3::z(),
            ..no_lever_arm_truth()
        };
        let mut cols: [[Vec<f64>; 3]; 4] = Default::default();
        for seed in 0..n as u64 {
            let mut suite = SensorSuite::new(&cfg, seed);
            suite.sample_imu(&truth_x);
            let ex = suite.true_errors();
            let mut suite = SensorSuite::new(&cfg, seed);
            suite.sample_imu(&truth_z);
            let ez = suite.true_errors();
            let errors = [ex.e_gyr_rps, ex.e_acc_mps2, ez.e_gyr_rps, ez.e_acc_mps2];
            for (col, e) in cols.iter_mut().zip(errors) {
                for (c, v) in col.iter_mut().zip(e.iter()) {
                    c.push(*v);
                }
            }
            assert_eq!(ez.e_acc_mps2.x, 0.0);
            assert_eq!(ez.e_acc_mps2.y, 0.0);
        }
        let (g, a) = (cfg.gyro, cfg.accel);
        let expected = [
            [
                g.scale_sigma,
                g.cross_coupling_sigma,
                g.cross_coupling_sigma,
            ],
            [
                a.scale_sigma,
                a.cross_coupling_sigma,
                a.cross_coupling_sigma,
            ],
            [
                g.cross_coupling_sigma,
                g.cross_coupling_sigma,
                g.scale_sigma,
            ],
            [0.0, 0.0, a.scale_sigma],
        ];
        for (c, e) in cols.iter().zip(expected) {
            for i in 0..3 {
                if e[i] > 0.0 {
                    let (_, std) = mean_std(&c[i]);
                    assert_rel("M entry", std, e[i], 6.0 * std_rel_err(n));
                }
            }
        }
    }

    #[test]
    fn sensors_zero_errors_return_the_truth_exactly() {
        // Perfect sensors with the default (non-zero) lever arm estimated exactly: a constant
        // rotation rate gives a non-zero centripetal lever term that must cancel exactly
        // (ω̇ = 0 and the finite-difference estimate is exactly 0 too).
        let cfg = SensorsConfig::perfect();
        let mut suite = SensorSuite::new(&cfg, 21);
        for k in 0..50 {
            let truth = SensorTruth {
                t_us: k * 10_000,
                w_ib_b_rps: Vector3::new(0.3, -0.2, 0.5),
                ..static_truth()
            };
            let imu = suite.sample_imu(&truth);
            assert_eq!(imu.t_us, truth.t_us);
            assert_eq!(imu.gyro_rps, truth.w_ib_b_rps);
            assert_eq!(imu.accel_mps2, truth.f_ib_b_mps2);
            let mag = suite.sample_mag(&truth);
            assert_eq!(
                mag.mag_b_nt,
                truth.q_nb.inverse_transform_vector(&truth.mag_ned_nt)
            );
            let air = suite.sample_air(&truth);
            assert_eq!(air.tas_mps, truth.tas_mps);
            assert_eq!(air.aoa_rad, Some(truth.aoa_rad));
            assert_eq!(air.aos_rad, Some(truth.aos_rad));
            assert_eq!(air.p_pa, truth.p_pa);
            assert_eq!(air.temp_k, truth.temp_k);
            let fix = suite.sample_gnss(&truth);
            assert_eq!(fix.pos, truth.pos);
            assert_eq!(fix.v_ned_mps, truth.v_ned_mps);
        }
        let e = suite.true_errors();
        assert_eq!(e.e_gyr_rps, Vector3::zeros());
        assert_eq!(e.e_acc_mps2, Vector3::zeros());
        assert_eq!(e.e_mag_nt, Vector3::zeros());
    }

    #[test]
    fn sensors_lever_arm_and_misalignment_geometry() {
        // Perfect sensors except a mis-estimated lever arm: with ω̇ constant the finite
        // difference of the (noise-free) gyro equals ω̇ to rounding (~1e-14 rad/s²), so
        // f̃ − f = ℓ(r_true) − ℓ(r_est) = ω×(ω×δ) + ω̇×δ, δ = T_rp,true − T_rp,est. The first
        // sample has no previous gyro and uses ω̇_est = 0.
        let mut cfg = SensorsConfig::perfect();
        cfg.platform.t_rp_est_sigma_m = 0.01;
        let dt = cfg.imu_period_s;
        let mut suite = SensorSuite::new(&cfg, 22);
        let e = suite.true_errors();
        let delta = e.t_rp_b_true_m - e.t_rp_b_est_m;
        assert!(delta.norm() > 1e-4);
        for k in 0..100 {
            let t = turning_truth(k, dt);
            let s = suite.sample_imu(&t);
            let (w, wd) = (t.w_ib_b_rps, t.w_dot_ib_b_rps2);
            let r_est = e.t_rp_b_est_m - t.cg_from_ref_b_m;
            let mut expected = w.cross(&w.cross(&delta)) + wd.cross(&delta);
            if k == 0 {
                expected += wd.cross(&r_est);
            }
            assert_eq!(s.gyro_rps, w);
            assert!(
                (s.accel_mps2 - t.f_ib_b_mps2 - expected).amax() < 1e-12,
                "k {k}: {} vs {expected}",
                s.accel_mps2 - t.f_ib_b_mps2
            );
        }

        // Perfect sensors except the mounting: outputs are R_bp,est·R_pb,true·u; when the
        // navigation knows the mounting exactly (estimate error 0) they equal the truth.
        for est_sigma in [0.03, 0.0] {
            let mut cfg = SensorsConfig::perfect();
            cfg.platform.euler_bp_sigma_deg = [0.5, 2.0, 0.1];
            cfg.platform.euler_bp_est_sigma_deg = est_sigma;
            cfg.platform.t_rp_b_m = [0.0; 3];
            let mut suite = SensorSuite::new(&cfg, 23);
            let e = suite.true_errors();
            let t = SensorTruth {
                w_ib_b_rps: Vector3::new(0.3, -0.2, 0.5),
                ..no_lever_arm_truth()
            };
            let s = suite.sample_imu(&t);
            let map = |u: Vector3<f64>| e.q_bp_est * (e.q_bp_true.inverse() * u);
            assert!((s.gyro_rps - map(t.w_ib_b_rps)).amax() < 1e-15);
            assert!((s.accel_mps2 - map(t.f_ib_b_mps2)).amax() < 1e-13);
            let misalignment = (s.accel_mps2 - t.f_ib_b_mps2).amax();
            if est_sigma == 0.0 {
                assert!(misalignment < 1e-13);
            } else {
                // 0.03° errors rotate a 9.8 m/s² vector by ~5e-3 m/s².
                assert!(misalignment > 1e-4, "{misalignment}");
            }
        }
    }

    /// Everything one suite outputs over `n` IMU periods (GNSS every 100).
    fn run_all(cfg: &SensorsConfig, run_seed: u64, aircraft_seed: u64, n: u64) -> Vec<String> {
        let mut suite = SensorSuite::with_seeds(cfg, run_seed, aircraft_seed);
        let mut out = Vec::new();
        for k in 0..n {
            let t = turning_truth(k, cfg.imu_period_s);
            out.push(format!("{:?}", suite.sample_imu(&t)));
            out.push(format!("{:?}", suite.sample_mag(&t)));
            out.push(format!("{:?}", suite.sample_air(&t)));
            if k % 100 == 0 {
                out.push(format!("{:?}", suite.sample_gnss(&t)));
            }
        }
        out
    }

    #[test]
    fn sensors_same_seed_is_bit_identical_and_streams_are_independent() {
        let cfg = SensorsConfig::default();
        // `{:?}` of f64 is the shortest round-trip representation: equal strings are equal
        // bits.
        let a = run_all(&cfg, 5, 5, 300);
        assert_eq!(a, run_all(&cfg, 5, 5, 300));
        let b = run_all(&cfg, 6, 6, 300);
        assert_eq!(a.len(), b.len());
        assert!(a.iter().zip(&b).all(|(x, y)| x != y));

        // Removing the vanes or changing the magnetometer changes no other sensor's draws.
        let mut other = cfg;
        other.air.vanes_enabled = false;
        other.mag = ianav_sim::sensors::MagConfig::worse();
        let mut s1 = SensorSuite::new(&cfg, 5);
        let mut s2 = SensorSuite::new(&other, 5);
        for k in 0..200 {
            let t = turning_truth(k, cfg.imu_period_s);
            assert_eq!(s1.sample_imu(&t), s2.sample_imu(&t));
            let (a1, a2) = (s1.sample_air(&t), s2.sample_air(&t));
            assert_eq!(a2.aoa_rad, None);
            assert_eq!(a2.aos_rad, None);
            assert_eq!(
                (a1.tas_mps, a1.p_pa, a1.temp_k),
                (a2.tas_mps, a2.p_pa, a2.temp_k)
            );
            assert_eq!(s1.sample_gnss(&t), s2.sample_gnss(&t));
        }

        // One aircraft, two runs: same airframe errors, different run errors.
        let r1 = SensorSuite::with_seeds(&cfg, 1, 99);
        let r2 = SensorSuite::with_seeds(&cfg, 2, 99);
        let (e1, e2) = (r1.true_errors(), r2.true_errors());
        assert_eq!(e1.q_bp_true, e2.q_bp_true);
        assert_eq!(e1.t_rp_b_est_m, e2.t_rp_b_est_m);
        assert_eq!(r1.imu().gyro().a(), r2.imu().gyro().a());
        assert_eq!(r1.mag().hard_iron_nt(), r2.mag().hard_iron_nt());
        assert_ne!(e1.gyr_bias_rps, e2.gyr_bias_rps);
        assert_ne!(e1.e_mag_nt, e2.e_mag_nt);
    }

    #[test]
    #[ignore = "timing report, run with --ignored --nocapture in the ci profile"]
    fn sensors_cost_per_call() {
        let cfg = SensorsConfig::default();
        let mut suite = SensorSuite::new(&cfg, 1);
        let truths: Vec<SensorTruth> = (0..1000).map(|k| turning_truth(k, 0.01)).collect();
        let n = 2_000_000;
        let mut acc = 0.0;
        let start = std::time::Instant::now();
        for k in 0..n {
            acc += suite.sample_imu(&truths[k % 1000]).accel_mps2.x;
        }
        let imu_ns = start.elapsed().as_nanos() as f64 / n as f64;
        let start = std::time::Instant::now();
        for k in 0..n {
            acc += suite.sample_mag(&truths[k % 1000]).mag_b_nt.x;
            acc += suite.sample_air(&truths[k % 1000]).tas_mps;
        }
        let mag_air_ns = start.elapsed().as_nanos() as f64 / n as f64;
        let start = std::time::Instant::now();
        for k in 0..n / 10 {
            acc += suite.sample_gnss(&truths[k % 1000]).pos.h_m;
        }
        let gnss_ns = start.elapsed().as_nanos() as f64 / (n / 10) as f64;
        eprintln!(
            "sample_imu {imu_ns:.0} ns, sample_mag + sample_air {mag_air_ns:.0} ns, \
             sample_gnss {gnss_ns:.0} ns ({acc:.1})"
        );
    }
}
