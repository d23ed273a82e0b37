//! Files written by `ianav-sim run`: the decimated truth trajectory (CSV), every sensor sample
//! (the binary log of `ianav::io::sensor_log`), with the INS in the loop its solution against
//! the truth (CSV), a summary (TOML), PNG plots (ground track, altitude, airspeed, bank) and a
//! Markdown report tying them together.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use ianav::io::sensor_log::SensorLogWriter;
use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav::nav::NavSolution;
use ianav::sensors::SensorEvent;

use crate::control::Operation;
use crate::flight::{FlightObserver, FlightSummary, TruthSample, estimate_from_nav};
use crate::metrics;
use crate::plots::{self, Chart, PALETTE, Series};

/// Errors writing run outputs.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// File system failure, with the file concerned.
    #[error("{path}: {source}")]
    Io {
        /// File or directory.
        path: String,
        /// Cause.
        source: io::Error,
    },
    /// A plot could not be drawn.
    #[error(transparent)]
    Plot(#[from] plots::PlotError),
    /// The summary could not be serialised.
    #[error("summary: {0}")]
    Summary(#[from] toml::ser::Error),
}

/// Names of the files of a run directory.
pub mod files {
    /// Truth trajectory at the output rate.
    pub const TRUTH: &str = "truth.csv";
    /// Sensor samples.
    pub const SENSORS: &str = "sensors.bin";
    /// INS solution, its errors against the truth and its σ (INS navigation only).
    pub const NAVIGATION: &str = "navigation.csv";
    /// Machine-readable summary.
    pub const SUMMARY: &str = "summary.toml";
    /// Human-readable report.
    pub const REPORT: &str = "report.md";
}

const TRUTH_HEADER: &str = "t_us,t_s,lat_deg,lon_deg,h_m,hp_m,v_n_mps,v_e_mps,v_d_mps,yaw_deg,pitch_deg,\
bank_deg,tas_mps,aoa_deg,aos_deg,wind_n_mps,wind_e_mps,wind_d_mps,turb_x_mps,turb_y_mps,\
turb_z_mps,delta_t_k,delta_p_pa,throttle,elevator_deg,aileron_deg,rudder_deg,mass_kg,\
distance_m,operation";

/// Columns of `navigation.csv`: the INS estimate, its error (estimate − truth; attitude errors
/// as in the paper's metrics), the 1σ the filter reports, and the filter's internal estimates
/// next to the truth they estimate where the truth is known to the simulator.
const NAVIGATION_HEADER: &str = "t_s,gnss_denied,lat_deg,lon_deg,h_m,v_n_mps,v_e_mps,v_d_mps,\
yaw_deg,pitch_deg,bank_deg,err_yaw_deg,err_pitch_deg,err_bank_deg,err_att_deg,err_h_m,err_hor_m,\
err_v_n_mps,err_v_e_mps,err_v_d_mps,sigma_att_x_deg,sigma_att_y_deg,sigma_att_z_deg,\
sigma_v_n_mps,sigma_v_e_mps,sigma_v_d_mps,sigma_n_m,sigma_e_m,sigma_d_m,wind_n_mps,wind_e_mps,\
true_wind_n_mps,true_wind_e_mps,tas_mps,true_tas_mps,delta_t_k,true_delta_t_k,delta_p_pa,\
true_delta_p_pa,e_gyr_x_dps,e_gyr_y_dps,e_gyr_z_dps,p_dps,q_dps,r_dps,true_p_dps,true_q_dps,\
true_r_dps,aoa_deg,true_aoa_deg,aos_deg,true_aos_deg,nees_att,nees_vel,gnss_nis";

/// Plot points kept per second of flight (the CSV keeps every output sample).
const PLOT_EVERY_N_SAMPLES: usize = 10;

/// One decimated point of the plots.
#[derive(Debug, Clone, Copy)]
struct PlotPoint {
    t_s: f64,
    pos: Geodetic,
    h_m: f64,
    hp_m: f64,
    tas_mps: f64,
    bank_deg: f64,
    pitch_deg: f64,
}

/// One navigation-error point per second of flight (INS navigation only).
#[derive(Debug, Clone, Copy)]
struct NavPoint {
    nse: metrics::NseSample,
    /// Horizontal 1σ the INS reports, m.
    sigma_hor_m: f64,
    gnss_denied: bool,
}

/// Observer that writes a run directory as the flight goes (memory stays flat: the trajectory
/// and samples stream to disk; only one plot point per second stays in memory).
pub struct RunWriter {
    dir: PathBuf,
    truth: BufWriter<File>,
    sensors: Option<SensorLogWriter<BufWriter<File>>>,
    /// Created at the first INS solution.
    navigation: Option<BufWriter<File>>,
    nav_points: Vec<NavPoint>,
    nav_samples_seen: usize,
    /// The last point with GNSS and the last point of all.
    nav_before_loss: Option<NavPoint>,
    nav_last: Option<NavPoint>,
    plot: Vec<PlotPoint>,
    samples_seen: usize,
    operations: Vec<(f64, usize, Operation)>,
    line: String,
    first_error: Option<OutputError>,
}

fn create(path: &Path) -> Result<BufWriter<File>, OutputError> {
    File::create(path)
        .map(|f| BufWriter::with_capacity(1 << 16, f))
        .map_err(|source| OutputError::Io {
            path: path.display().to_string(),
            source,
        })
}

impl RunWriter {
    /// Record the navigator's settings at the head of the sensor log, so that `ianav replay`
    /// runs it as flown. Call before the first event.
    pub fn record_nav_config(&mut self, cfg: &ianav::nav::NavConfig) -> Result<(), OutputError> {
        let Some(w) = self.sensors.as_mut() else {
            return Ok(());
        };
        w.write_nav_config(&ianav::nav::replay::config_to_toml(cfg))
            .map_err(|source| OutputError::Io {
                path: self.dir.join(files::SENSORS).display().to_string(),
                source,
            })
    }

    /// Create `dir` and open the streaming files. `record_sensors` = false skips the sensor
    /// log (it is the largest file).
    pub fn new(dir: &Path, record_sensors: bool) -> Result<Self, OutputError> {
        std::fs::create_dir_all(dir).map_err(|source| OutputError::Io {
            path: dir.display().to_string(),
            source,
        })?;
        // The CSV files are written with `write!` rather than the `csv` crate: every field is
        // a number at a fixed number of decimals or a fixed identifier (nothing to quote or
        // escape), and the crate would still need each field formatted by hand.
        let mut truth = create(&dir.join(files::TRUTH))?;
        writeln!(truth, "{TRUTH_HEADER}").map_err(|source| OutputError::Io {
            path: dir.join(files::TRUTH).display().to_string(),
            source,
        })?;
        let sensors = if record_sensors {
            let path = dir.join(files::SENSORS);
            Some(
                SensorLogWriter::new(create(&path)?).map_err(|source| OutputError::Io {
                    path: path.display().to_string(),
                    source,
                })?,
            )
        } else {
            None
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            truth,
            sensors,
            navigation: None,
            nav_points: Vec::new(),
            nav_samples_seen: 0,
            nav_before_loss: None,
            nav_last: None,
            plot: Vec::new(),
            samples_seen: 0,
            operations: Vec::new(),
            line: String::with_capacity(512),
            first_error: None,
        })
    }

    fn keep_error(&mut self, file: &str, result: io::Result<()>) {
        if let Err(source) = result
            && self.first_error.is_none()
        {
            let path = self.dir.join(file).display().to_string();
            self.first_error = Some(OutputError::Io { path, source });
        }
    }

    /// Flush the streams, write the summary, plots and report. Returns the report's path.
    pub fn finish(mut self, summary: &FlightSummary) -> Result<PathBuf, OutputError> {
        let flushed = self.truth.flush();
        self.keep_error(files::TRUTH, flushed);
        if let Some(mut nav) = self.navigation.take() {
            let flushed = nav.flush();
            self.keep_error(files::NAVIGATION, flushed);
        }
        if let Some(writer) = self.sensors.take() {
            let finished = writer.finish().map(|_| ());
            self.keep_error(files::SENSORS, finished);
        }
        if let Some(e) = self.first_error.take() {
            return Err(e);
        }
        let write = |name: &str, text: &str| {
            std::fs::write(self.dir.join(name), text).map_err(|source| OutputError::Io {
                path: self.dir.join(name).display().to_string(),
                source,
            })
        };
        write(files::SUMMARY, &toml::to_string_pretty(summary)?)?;
        let plots = self.draw_plots()?;
        write(files::REPORT, &self.report(summary, &plots))?;
        Ok(self.dir.join(files::REPORT))
    }

    fn draw_plots(&self) -> Result<Vec<(&'static str, &'static str)>, OutputError> {
        let mut drawn = Vec::new();
        let Some(origin) = self.plot.first().map(|p| p.pos) else {
            return Ok(drawn);
        };
        let t = |f: fn(&PlotPoint) -> f64| -> Vec<(f64, f64)> {
            self.plot.iter().map(|p| (p.t_s, f(p))).collect()
        };
        let line = |label: &str, points, k: usize| Series {
            label: label.to_owned(),
            points,
            rgb: PALETTE[k],
            dashed: false,
        };
        let track: Vec<(f64, f64)> = self
            .plot
            .iter()
            .map(|p| {
                let d = wgs84::ned_difference_m(&origin, &p.pos);
                (d.y / 1000.0, d.x / 1000.0)
            })
            .collect();
        let charts = [
            (
                "ground_track.png",
                "Ground track",
                Chart {
                    title: "Ground track (truth)",
                    x_label: "east [km]",
                    y_label: "north [km]",
                    series: vec![line("", track, 0)],
                    equal_axes: true,
                },
            ),
            (
                "altitude.png",
                "Altitude",
                Chart {
                    title: "Altitude (truth)",
                    x_label: "mission time [s]",
                    y_label: "altitude [m]",
                    series: vec![
                        line("geometric h", t(|p| p.h_m), 0),
                        line("pressure Hp", t(|p| p.hp_m), 1),
                    ],
                    equal_axes: false,
                },
            ),
            (
                "airspeed.png",
                "Airspeed",
                Chart {
                    title: "True airspeed (truth)",
                    x_label: "mission time [s]",
                    y_label: "airspeed [m/s]",
                    series: vec![line("", t(|p| p.tas_mps), 0)],
                    equal_axes: false,
                },
            ),
            (
                "attitude.png",
                "Bank and pitch",
                Chart {
                    title: "Bank and pitch (truth)",
                    x_label: "mission time [s]",
                    y_label: "angle [deg]",
                    series: vec![
                        line("bank", t(|p| p.bank_deg), 0),
                        line("pitch", t(|p| p.pitch_deg), 1),
                    ],
                    equal_axes: false,
                },
            ),
        ];
        for (file, caption, chart) in charts {
            plots::draw(&self.dir.join(file), &chart, 900, 560)?;
            drawn.push((file, caption));
        }
        if !self.nav_points.is_empty() {
            let n = |f: fn(&NavPoint) -> f64| -> Vec<(f64, f64)> {
                self.nav_points.iter().map(|p| (p.nse.t_s, f(p))).collect()
            };
            let nav_charts = [
                (
                    "nav_attitude_error.png",
                    "INS attitude error",
                    Chart {
                        title: "INS attitude error (estimate − truth)",
                        x_label: "mission time [s]",
                        y_label: "error [deg]",
                        series: vec![
                            line("yaw", n(|p| p.nse.yaw_deg), 0),
                            line("pitch", n(|p| p.nse.pitch_deg), 1),
                            line("bank", n(|p| p.nse.bank_deg), 2),
                        ],
                        equal_axes: false,
                    },
                ),
                (
                    "nav_position_error.png",
                    "INS position error",
                    Chart {
                        title: "INS position error (estimate − truth)",
                        x_label: "mission time [s]",
                        y_label: "error [m]",
                        series: vec![
                            line("horizontal", n(|p| p.nse.hor_m), 0),
                            Series {
                                dashed: true,
                                ..line("horizontal 1σ reported", n(|p| p.sigma_hor_m), 0)
                            },
                            line("altitude", n(|p| p.nse.alt_m), 1),
                        ],
                        equal_axes: false,
                    },
                ),
            ];
            for (file, caption, chart) in nav_charts {
                plots::draw(&self.dir.join(file), &chart, 900, 560)?;
                drawn.push((file, caption));
            }
        }
        Ok(drawn)
    }

    fn report(&self, s: &FlightSummary, plots: &[(&str, &str)]) -> String {
        let mut r = String::new();
        let _ = writeln!(r, "# {}\n", s.scenario);
        let _ = writeln!(r, "Seed {}. Produced by `ianav-sim run`.\n", s.seed);
        let _ = writeln!(r, "| quantity | value |\n|---|---|");
        let _ = writeln!(r, "| mission time flown | {:.1} s |", s.duration_s);
        let _ = writeln!(r, "| ground distance flown | {:.0} m |", s.distance_m);
        let _ = writeln!(
            r,
            "| geometric altitude range | {:.0} to {:.0} m |",
            s.h_range_m[0], s.h_range_m[1]
        );
        let _ = writeln!(r, "| fuel burnt | {:.3} kg |", s.fuel_burnt_kg);
        let _ = writeln!(r, "| final position | {} |", format_position(&s.final_pos));
        let _ = writeln!(
            r,
            "| time bases | sensor `t_us` from the warm-up start; mission time = t_us·1e-6 − {:.0} s; last GNSS fix at {:.0} s |",
            s.warmup_s, s.gnss_loss_s
        );
        let _ = writeln!(r, "| sensor samples | {} |", s.sensor_events);
        let _ = writeln!(r, "| integration steps | {} |\n", s.truth_steps);
        let _ = writeln!(
            r,
            "## Manoeuvres executed\n\n| # | start [s] | airspeed [m/s] | elevator channel | aileron channel | ends on |\n|---|---|---|---|---|---|"
        );
        for (t_s, index, op) in &self.operations {
            let _ = writeln!(
                r,
                "| {index} | {t_s:.1} | {:.2} | {} | {} | {} |",
                op.tas_mps,
                describe_elevator(op),
                describe_aileron(op),
                describe_trigger(op)
            );
        }
        if let Some(last) = self.nav_last {
            let _ = writeln!(
                r,
                "\n## Navigation error (INS in the loop)\n\nEstimate − truth; attitude errors as the paper's (Euler-angle differences and the norm of `Log(q_truth⁻¹ q_est)`); horizontal 1σ as the INS reports it.\n\n| | yaw [deg] | pitch [deg] | bank [deg] | attitude norm [deg] | altitude [m] | horizontal [m] | horizontal [% of distance] | horizontal 1σ reported [m] |\n|---|---|---|---|---|---|---|---|---|"
            );
            let rows = [
                ("last step with GNSS", self.nav_before_loss),
                ("end of flight", Some(last)),
            ];
            for (name, p) in rows {
                let Some(p) = p else { continue };
                let e = &p.nse;
                let _ = writeln!(
                    r,
                    "| {name} (t = {:.1} s{}) | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} | {:.1} | {} | {:.1} |",
                    e.t_s,
                    if p.gnss_denied { ", GNSS denied" } else { "" },
                    e.yaw_deg,
                    e.pitch_deg,
                    e.bank_deg,
                    e.att_norm_deg,
                    e.alt_m,
                    e.hor_m,
                    metrics::format_fixed(e.hor_pct, 2),
                    p.sigma_hor_m
                );
            }
        }
        let _ = writeln!(r, "\n## Plots\n");
        for (file, caption) in plots {
            let _ = writeln!(r, "![{caption}]({file})\n");
        }
        let _ = writeln!(
            r,
            "Files: `{}` (truth every output period), `{}` (sensor samples, format in \
             `ianav::io::sensor_log`), `{}`{}.",
            files::TRUTH,
            files::SENSORS,
            files::SUMMARY,
            if self.nav_last.is_some() {
                format!(
                    ", `{}` (INS solution, errors, reported σ and NEES every output period)",
                    files::NAVIGATION
                )
            } else {
                String::new()
            }
        );
        r
    }
}

/// `45.06352° N, 89.95502° W, 2794 m`.
fn format_position(pos: &Geodetic) -> String {
    let (lat, lon) = (pos.lat_rad.to_degrees(), pos.lon_rad.to_degrees());
    let lon = ianav::math::angle::wrap_180_deg(lon);
    let ns = if lat >= 0.0 { 'N' } else { 'S' };
    let ew = if lon >= 0.0 { 'E' } else { 'W' };
    format!(
        "{:.5}° {ns}, {:.5}° {ew}, {:.0} m",
        lat.abs(),
        lon.abs(),
        pos.h_m
    )
}

fn describe_elevator(op: &Operation) -> String {
    use crate::control::ElevatorTarget as E;
    match op.elevator {
        E::PressureAltitude { hp_m } => format!("Hp {hp_m:.0} m"),
        E::PathAngle { gamma_rad } => format!("γ {:+.1}°", gamma_rad.to_degrees()),
        E::Pitch { theta_rad } => format!("θ {:+.1}°", theta_rad.to_degrees()),
    }
}

fn describe_aileron(op: &Operation) -> String {
    use crate::control::AileronTarget as A;
    match op.aileron {
        A::Bearing { chi_rad } => format!("χ {:.0}°", chi_rad.to_degrees()),
        A::Bank { xi_rad } => format!("bank {:+.0}°", xi_rad.to_degrees()),
    }
}

fn describe_trigger(op: &Operation) -> String {
    use crate::control::Trigger as T;
    match op.trigger {
        T::Time { t_s } => format!("t = {t_s:.1} s"),
        T::Elapsed { dt_s } => format!("after {dt_s:.1} s"),
        T::PressureAltitude { hp_m } => format!("Hp crosses {hp_m:.0} m"),
        T::Bearing { chi_rad } => format!("χ crosses {:.0}°", chi_rad.to_degrees()),
    }
}

impl FlightObserver for RunWriter {
    fn sensor_event(&mut self, event: &SensorEvent) {
        if let Some(writer) = self.sensors.as_mut() {
            let result = writer.write(event);
            self.keep_error(files::SENSORS, result);
        }
    }

    fn truth_sample(&mut self, s: &TruthSample) {
        let e = s.euler_rad.map(f64::to_degrees);
        let v = s.v_ned_mps;
        let c = s.controls;
        self.line.clear();
        let _ = write!(
            self.line,
            "{},{:.3},{:.9},{:.9},{:.3},{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},\
             {:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.2},{:.4},{:.4},{:.4},{:.4},{:.5},{:.2},{}",
            s.t_us,
            s.t_s,
            s.pos.lat_rad.to_degrees(),
            s.pos.lon_rad.to_degrees(),
            s.pos.h_m,
            s.hp_m,
            v.x,
            v.y,
            v.z,
            e.x,
            e.y,
            e.z,
            s.air.tas_mps,
            s.air.aoa_rad.to_degrees(),
            s.air.aos_rad.to_degrees(),
            s.wind_ned_mps.x,
            s.wind_ned_mps.y,
            s.wind_ned_mps.z,
            s.turb_b_mps.x,
            s.turb_b_mps.y,
            s.turb_b_mps.z,
            s.offsets.delta_t_k,
            s.offsets.delta_p_pa,
            c.throttle,
            c.elevator_rad.to_degrees(),
            c.aileron_rad.to_degrees(),
            c.rudder_rad.to_degrees(),
            s.mass_kg,
            s.distance_m,
            s.operation
        );
        let result = writeln!(self.truth, "{}", self.line);
        self.keep_error(files::TRUTH, result);
        if s.t_s >= 0.0 && self.samples_seen.is_multiple_of(PLOT_EVERY_N_SAMPLES) {
            self.plot.push(PlotPoint {
                t_s: s.t_s,
                pos: s.pos,
                h_m: s.pos.h_m,
                hp_m: s.hp_m,
                tas_mps: s.air.tas_mps,
                bank_deg: e.z,
                pitch_deg: e.y,
            });
        }
        self.samples_seen += 1;
    }

    fn nav_solution(&mut self, truth: &TruthSample, sol: &NavSolution) {
        if self.navigation.is_none() {
            let opened = create(&self.dir.join(files::NAVIGATION)).and_then(|mut w| {
                writeln!(w, "{NAVIGATION_HEADER}").map_err(|source| OutputError::Io {
                    path: self.dir.join(files::NAVIGATION).display().to_string(),
                    source,
                })?;
                Ok(w)
            });
            match opened {
                Ok(w) => self.navigation = Some(w),
                Err(e) => {
                    if self.first_error.is_none() {
                        self.first_error = Some(e);
                    }
                    return;
                }
            }
        }
        let est = estimate_from_nav(sol);
        let e = metrics::nse(truth, &est);
        let euler_deg = so3::euler_zyx(&sol.q_nb).map(f64::to_degrees);
        let dv = sol.v_ned_mps - truth.v_ned_mps;
        let sd = |m: &nalgebra::Matrix3<f64>, i: usize| m[(i, i)].max(0.0).sqrt();
        let c = &sol.cov;
        let gyr_dps = sol.ins.e_gyr_rps.map(f64::to_degrees);
        let nees = metrics::nees(truth, sol).unwrap_or((f64::NAN, f64::NAN));
        let point = NavPoint {
            nse: e,
            sigma_hor_m: (sd(&c.position_m2, 0).powi(2) + sd(&c.position_m2, 1).powi(2)).sqrt(),
            gnss_denied: sol.ins_status.gnss_denied,
        };
        if !sol.ins_status.gnss_denied {
            self.nav_before_loss = Some(point);
        }
        self.nav_last = Some(point);
        if truth.t_s >= 0.0 && self.nav_samples_seen.is_multiple_of(PLOT_EVERY_N_SAMPLES) {
            self.nav_points.push(point);
        }
        self.nav_samples_seen += 1;
        self.line.clear();
        let _ = write!(
            self.line,
            "{:.3},{},{:.9},{:.9},{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.5},{:.5},{:.5},{:.5},\
             {:.3},{:.3},{:.4},{:.4},{:.4},{:.5},{:.5},{:.5},{:.4},{:.4},{:.4},{:.3},{:.3},{:.3},\
             {:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.2},{:.2},{:.3e},{:.3e},{:.3e},\
             {:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.3},{:.3},{}",
            truth.t_s,
            u8::from(sol.ins_status.gnss_denied),
            sol.pos.lat_rad.to_degrees(),
            sol.pos.lon_rad.to_degrees(),
            sol.pos.h_m,
            sol.v_ned_mps.x,
            sol.v_ned_mps.y,
            sol.v_ned_mps.z,
            euler_deg.x,
            euler_deg.y,
            euler_deg.z,
            e.yaw_deg,
            e.pitch_deg,
            e.bank_deg,
            e.att_norm_deg,
            e.alt_m,
            e.hor_m,
            dv.x,
            dv.y,
            dv.z,
            sd(&c.attitude_rad2, 0).to_degrees(),
            sd(&c.attitude_rad2, 1).to_degrees(),
            sd(&c.attitude_rad2, 2).to_degrees(),
            sd(&c.velocity_m2ps2, 0),
            sd(&c.velocity_m2ps2, 1),
            sd(&c.velocity_m2ps2, 2),
            sd(&c.position_m2, 0),
            sd(&c.position_m2, 1),
            sd(&c.position_m2, 2),
            sol.ins.wind_ned_mps.x,
            sol.ins.wind_ned_mps.y,
            truth.wind_ned_mps.x,
            truth.wind_ned_mps.y,
            sol.ins.tas_mps,
            truth.air.tas_mps,
            sol.ins.delta_t_k,
            truth.offsets.delta_t_k,
            sol.ins.delta_p_pa,
            truth.offsets.delta_p_pa,
            gyr_dps.x,
            gyr_dps.y,
            gyr_dps.z,
            sol.ins.w_nb_b_rps.x.to_degrees(),
            sol.ins.w_nb_b_rps.y.to_degrees(),
            sol.ins.w_nb_b_rps.z.to_degrees(),
            truth.w_nb_b_rps.x.to_degrees(),
            truth.w_nb_b_rps.y.to_degrees(),
            truth.w_nb_b_rps.z.to_degrees(),
            sol.ins.aoa_rad.to_degrees(),
            truth.air.aoa_rad.to_degrees(),
            sol.ins.aos_rad.to_degrees(),
            truth.air.aos_rad.to_degrees(),
            nees.0,
            nees.1,
            sol.ins
                .gnss_nis
                .map_or(String::new(), |v| format!("{v:.3}")),
        );
        if let Some(w) = self.navigation.as_mut() {
            let result = writeln!(w, "{}", self.line);
            self.keep_error(files::NAVIGATION, result);
        }
    }

    fn operation_started(&mut self, t_s: f64, index: usize, operation: &Operation) {
        self.operations.push((t_s, index, *operation));
    }
}
