//! Files written by `ianav-sim run`: the decimated truth trajectory (CSV), every sensor sample
//! (the binary log of `ianav::io::sensor_log`), with the INS in the loop its solution against
//! the truth (CSV), a summary (TOML), PNG plots (ground track with the INS track, altitude,
//! airspeed, attitude, INS errors; the GNSS loss marked on each) and a Markdown report tying
//! them together.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use ianav::io::sensor_log::SensorLogWriter;
use ianav::math::so3;
use ianav::math::wgs84::{self, Geodetic};
use ianav::nav::{NavSolution, VisionState};
use ianav::sensors::SensorEvent;

use crate::control::Operation;
use crate::flight::{FlightObserver, FlightSummary, TruthSample, VisionOutput, estimate_from_nav};
use crate::metrics;
use crate::plots::{self, Chart, PALETTE, PointMarker, Series, XMarker};

mod vision;
use vision::VisionTraces;

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
    /// Visual navigation: every system's state, tracking quality, pose and its errors (with a
    /// camera).
    pub const VISION: &str = "vision.csv";
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

/// One plot point kept every this many output samples (the CSV keeps every one), counted
/// from mission time 0 so that the truth and INS points fall at the same instants.
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
    /// INS position (the ground track's navigation line).
    pos: Geodetic,
    /// Horizontal 1σ the INS reports, m.
    sigma_hor_m: f64,
    gnss_denied: bool,
}

/// Name of a vision state in `vision.csv` and the report.
pub fn vision_state_name(state: VisionState) -> &'static str {
    match state {
        VisionState::Inactive => "inactive",
        VisionState::WaitingForStart => "waiting",
        VisionState::Initialising => "initialising",
        VisionState::Tracking => "tracking",
        VisionState::Relocalising => "relocalising",
    }
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
    /// INS outputs from mission time 0.
    nav_samples_seen: usize,
    /// The point at the first output after the last GNSS fix (the GNSS loss, if GNSS is lost)
    /// and the last point of all.
    nav_at_last_fix: Option<NavPoint>,
    nav_last: Option<NavPoint>,
    /// A GNSS fix came since the last INS output.
    fix_since_nav: bool,
    /// Mission time of the first output the INS flagged GNSS-denied: the INS decides this
    /// itself (its timeout without a fix), later than the scenario's GNSS loss.
    ins_denied_s: Option<f64>,
    plot: Vec<PlotPoint>,
    /// Truth outputs from mission time 0.
    samples_seen: usize,
    /// The visual systems (with a camera).
    vision: VisionTraces,
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

/// Open the CSV stream `slot` as `dir/name` with its `header` line unless it is open already;
/// `false` (the first error kept in `first_error`) if it cannot be opened. Streams that only
/// some flights produce are opened at their first row.
fn open_csv_once(
    slot: &mut Option<BufWriter<File>>,
    first_error: &mut Option<OutputError>,
    dir: &Path,
    name: &str,
    header: &str,
) -> bool {
    if slot.is_some() {
        return true;
    }
    let path = &dir.join(name);
    let opened = create(path).and_then(|mut w| {
        writeln!(w, "{header}").map_err(|source| OutputError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Ok(w)
    });
    match opened {
        Ok(w) => {
            *slot = Some(w);
            true
        }
        Err(e) => {
            first_error.get_or_insert(e);
            false
        }
    }
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
            nav_at_last_fix: None,
            nav_last: None,
            fix_since_nav: false,
            ins_denied_s: None,
            plot: Vec::new(),
            samples_seen: 0,
            vision: VisionTraces::default(),
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
        let flushed = self.vision.flush();
        self.keep_error(files::VISION, flushed);
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
        let plots = self.draw_plots(summary)?;
        write(files::REPORT, &self.report(summary, &plots))?;
        Ok(self.dir.join(files::REPORT))
    }

    fn draw_plots(
        &self,
        summary: &FlightSummary,
    ) -> Result<Vec<(&'static str, &'static str)>, OutputError> {
        let mut drawn = Vec::new();
        let Some(origin) = self.plot.first().map(|p| p.pos) else {
            return Ok(drawn);
        };
        let loss_s = gnss_loss_in_flight(summary);
        // To 0.1 s without a trailing ".0": plotters draws the point raised, like "·".
        let loss_label = |t: f64| format!("GNSS lost at {} s", (t * 10.0).round() / 10.0);
        let markers: Vec<XMarker> = loss_s
            .map(|t| XMarker {
                x: t,
                label: loss_label(t),
            })
            .into_iter()
            .collect();
        let t = |f: fn(&PlotPoint) -> f64| -> Vec<(f64, f64)> {
            self.plot.iter().map(|p| (p.t_s, f(p))).collect()
        };
        let line = |label: &str, points, k: usize| Series {
            label: label.to_owned(),
            points,
            rgb: PALETTE[k],
            dashed: false,
        };
        let time_chart = |title: &'static str, y_label: &'static str, series: Vec<Series>| Chart {
            title,
            x_label: "mission time [s]",
            y_label,
            series,
            x_markers: markers.clone(),
            ..Chart::default()
        };
        // East and north of the first point, km.
        let to_km = |pos: &Geodetic| {
            let d = wgs84::ned_difference_m(&origin, pos);
            (d.y / 1000.0, d.x / 1000.0)
        };
        let track: Vec<(f64, f64)> = self.plot.iter().map(|p| to_km(&p.pos)).collect();
        let nav_track: Vec<(f64, f64)> = self.nav_points.iter().map(|p| to_km(&p.pos)).collect();
        let timed: Vec<(f64, (f64, f64))> = self
            .plot
            .iter()
            .map(|p| p.t_s)
            .zip(track.iter().copied())
            .collect();
        let mut places = vec![PointMarker {
            label: "start".into(),
            at: track[0],
            rgb: PALETTE[2],
        }];
        if let Some(t) = loss_s
            && let Some(at) = track_at(&timed, t)
        {
            places.push(PointMarker {
                label: loss_label(t),
                at,
                rgb: PALETTE[5],
            });
        }
        let mut track_series = vec![line("truth", track, 0)];
        if !nav_track.is_empty() {
            // Dashed over the solid truth, so both show where they coincide (with GNSS).
            track_series.push(Series {
                dashed: true,
                ..line("INS estimate", nav_track, 1)
            });
        }
        track_series.extend(self.vision.tracks(&to_km));
        let charts = [
            (
                "ground_track.png",
                "Ground track",
                Chart {
                    title: if self.nav_points.is_empty() {
                        "Ground track (truth)"
                    } else {
                        "Ground track: truth and INS estimate"
                    },
                    x_label: "east [km]",
                    y_label: "north [km]",
                    series: track_series,
                    equal_axes: true,
                    points: places,
                    ..Chart::default()
                },
            ),
            (
                "altitude.png",
                "Altitude",
                time_chart(
                    "Altitude (truth)",
                    "altitude [m]",
                    vec![
                        line("geometric h", t(|p| p.h_m), 0),
                        line("pressure Hp", t(|p| p.hp_m), 1),
                    ],
                ),
            ),
            (
                "airspeed.png",
                "Airspeed",
                time_chart(
                    "True airspeed (truth)",
                    "airspeed [m/s]",
                    vec![line("", t(|p| p.tas_mps), 0)],
                ),
            ),
            (
                "attitude.png",
                "Bank and pitch",
                time_chart(
                    "Bank and pitch (truth)",
                    "angle [deg]",
                    vec![
                        line("bank", t(|p| p.bank_deg), 0),
                        line("pitch", t(|p| p.pitch_deg), 1),
                    ],
                ),
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
                    time_chart(
                        "INS attitude error (estimate − truth)",
                        "error [deg]",
                        vec![
                            line("yaw", n(|p| p.nse.yaw_deg), 0),
                            line("pitch", n(|p| p.nse.pitch_deg), 1),
                            line("bank", n(|p| p.nse.bank_deg), 2),
                        ],
                    ),
                ),
                (
                    "nav_position_error.png",
                    "INS position error",
                    time_chart(
                        "INS position error (estimate − truth)",
                        "error [m]",
                        vec![
                            line("horizontal", n(|p| p.nse.hor_m), 0),
                            Series {
                                dashed: true,
                                ..line("horizontal 1σ reported", n(|p| p.sigma_hor_m), 0)
                            },
                            line("altitude", n(|p| p.nse.alt_m), 1),
                        ],
                    ),
                ),
            ];
            for (file, caption, chart) in nav_charts {
                plots::draw(&self.dir.join(file), &chart, 900, 560)?;
                drawn.push((file, caption));
            }
        }
        if !self.vision.is_empty() && !self.nav_points.is_empty() {
            let ins = |f: fn(&metrics::NseSample) -> f64| -> Vec<(f64, f64)> {
                self.nav_points
                    .iter()
                    .map(|p| (p.nse.t_s, f(&p.nse)))
                    .collect()
            };
            let error_chart = |title, y_label, f: fn(&metrics::NseSample) -> f64| {
                time_chart(title, y_label, self.vision.error_series(ins(f), f))
            };
            let vision_charts = [
                (
                    "vision_horizontal_error.png",
                    "Horizontal error of the INS and the visual systems",
                    error_chart("Horizontal position error", "error [m]", |e| e.hor_m),
                ),
                (
                    "vision_altitude_error.png",
                    "Altitude error of the INS and the visual systems",
                    error_chart("Altitude error (estimate − truth)", "error [m]", |e| {
                        e.alt_m
                    }),
                ),
                (
                    "vision_attitude_error.png",
                    "Attitude error norm of the INS and the visual systems",
                    error_chart(
                        "Attitude error norm ‖Log(q_truth⁻¹ q_est)‖",
                        "error [deg]",
                        |e| e.att_norm_deg,
                    ),
                ),
            ];
            for (file, caption, chart) in vision_charts {
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
            "| time bases | sensor `t_us` from the warm-up start; mission time = t_us·1e-6 − {:.0} s |",
            s.warmup_s
        );
        let loss_s = gnss_loss_in_flight(s);
        match loss_s {
            Some(t) => {
                let _ = writeln!(
                    r,
                    "| GNSS lost (scenario) | {t:.1} s: last fix, none after |"
                );
            }
            None => {
                let _ = writeln!(
                    r,
                    "| GNSS lost (scenario) | not during the flight (scheduled at {:.1} s) |",
                    s.gnss_loss_s
                );
            }
        }
        if let Some(t) = self.ins_denied_s {
            let _ = writeln!(
                r,
                "| INS declared itself GNSS-denied | {t:.1} s: first output so flagged (the INS's own decision, once its timeout without a fix has run out) |"
            );
        }
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
            // The GNSS-loss row only if GNSS was lost: otherwise the last fix is just the end.
            let rows = [
                (
                    "GNSS lost",
                    self.nav_at_last_fix.filter(|_| loss_s.is_some()),
                ),
                ("end of flight", Some(last)),
            ];
            for (name, p) in rows {
                let Some(p) = p else { continue };
                let e = &p.nse;
                let _ = writeln!(
                    r,
                    "| {name} (t = {:.1} s{}) | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} | {:.1} | {} | {:.1} |",
                    e.t_s,
                    if p.gnss_denied {
                        ", INS GNSS-denied"
                    } else {
                        ""
                    },
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
        self.vision
            .report(&mut r, self.nav_last.as_ref().map(|p| &p.nse));
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

/// Mission time of the GNSS loss if it happened during the flight (the scenario may schedule
/// it after the end).
fn gnss_loss_in_flight(s: &FlightSummary) -> Option<f64> {
    (s.gnss_loss_s < s.duration_s).then_some(s.gnss_loss_s)
}

/// Position at time `t` on a time-ordered track of `(t, (x, y))`, interpolated linearly
/// (the plot points are a second apart); `None` outside the track.
fn track_at(track: &[(f64, (f64, f64))], t: f64) -> Option<(f64, f64)> {
    let i = track.partition_point(|p| p.0 < t);
    let (tb, b) = *track.get(i)?;
    if tb == t {
        return Some(b);
    }
    let (ta, a) = *track.get(i.checked_sub(1)?)?;
    let f = (t - ta) / (tb - ta);
    Some((a.0 + f * (b.0 - a.0), a.1 + f * (b.1 - a.1)))
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
        if matches!(event, SensorEvent::Gnss(_)) {
            self.fix_since_nav = true;
        }
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
        if s.t_s >= 0.0 {
            if self.samples_seen.is_multiple_of(PLOT_EVERY_N_SAMPLES) {
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
    }

    fn nav_solution(&mut self, truth: &TruthSample, sol: &NavSolution) {
        if !open_csv_once(
            &mut self.navigation,
            &mut self.first_error,
            &self.dir,
            files::NAVIGATION,
            NAVIGATION_HEADER,
        ) {
            return;
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
            pos: sol.pos,
            sigma_hor_m: (sd(&c.position_m2, 0).powi(2) + sd(&c.position_m2, 1).powi(2)).sqrt(),
            gnss_denied: sol.ins_status.gnss_denied,
        };
        if std::mem::take(&mut self.fix_since_nav) {
            self.nav_at_last_fix = Some(point);
        }
        if sol.ins_status.gnss_denied && self.ins_denied_s.is_none() {
            self.ins_denied_s = Some(truth.t_s);
        }
        self.nav_last = Some(point);
        if truth.t_s >= 0.0 {
            if self.nav_samples_seen.is_multiple_of(PLOT_EVERY_N_SAMPLES) {
                self.nav_points.push(point);
            }
            self.nav_samples_seen += 1;
        }
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

    fn vision_outputs(&mut self, truth: &TruthSample, t_us: u64, systems: &[VisionOutput]) {
        // The same instants as the INS points (decimated from mission time 0).
        let plot_point = self
            .nav_samples_seen
            .saturating_sub(1)
            .is_multiple_of(PLOT_EVERY_N_SAMPLES);
        self.vision.rows(
            &self.dir,
            &mut self.first_error,
            truth,
            t_us,
            systems,
            plot_point,
        );
    }

    fn operation_started(&mut self, t_s: f64, index: usize, operation: &Operation) {
        self.operations.push((t_s, index, *operation));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flight::{Flight, FlightSetup, NavigationMode};

    /// A short camera flight over the urban zone: the VNS and the IA-VNS start from the INS at
    /// their first images, `vision.csv` holds each one's state every output and its pose with
    /// errors once it tracks, and the report has their section.
    #[test]
    fn a_camera_flight_writes_the_vision_file_and_section() {
        let dir = std::env::temp_dir().join(format!("ianav-output-vns-{}", std::process::id()));
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.navigation = NavigationMode::Ins;
        setup.scenario.duration_s = 5.0;
        let zone = crate::terrain::Zone::Urban;
        let start = zone.start();
        setup.scenario.start.lat_deg = start.lat_deg;
        setup.scenario.start.lon_deg = start.lon_deg;
        setup.camera = Some(crate::flight::CameraSetup::new(std::sync::Arc::new(
            crate::terrain::Terrain::new(zone, 0),
        )));
        let mut writer = RunWriter::new(&dir, false).unwrap();
        let summary = Flight::new(&setup, 1)
            .unwrap()
            .run(&mut writer, |_| {})
            .unwrap();
        let report = std::fs::read_to_string(writer.finish(&summary).unwrap()).unwrap();
        assert!(report.contains("## Visual navigation"), "{report}");
        assert!(report.contains("| VNS | tracking |"), "{report}");
        assert!(report.contains("| IA-VNS | tracking |"), "{report}");
        let csv = std::fs::read_to_string(dir.join(files::VISION)).unwrap();
        let rows: Vec<Vec<&str>> = csv
            .lines()
            .skip(1)
            .map(|l| l.split(',').collect())
            .collect();
        assert!(rows.iter().all(|r| r.len() == 21), "{csv}");
        // Every output has one row per system, in the flight's order.
        let systems: Vec<&str> = rows.iter().map(|r| r[1]).collect();
        assert!(
            systems.chunks(2).all(|pair| pair == ["vns", "ia-vns"]),
            "{systems:?}"
        );
        for system in ["vns", "ia-vns"] {
            let tracked: Vec<&Vec<&str>> = rows
                .iter()
                .filter(|r| r[1] == system && r[2] == "tracking")
                .collect();
            assert!(!tracked.is_empty(), "{system} never tracked");
            for r in &tracked {
                // Started from the INS with GNSS: metres, not kilometres, from the truth.
                let hor_m: f64 = r[19].parse().unwrap();
                assert!(hor_m < 100.0, "{r:?}");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn track_at_interpolates_inside_the_track_only() {
        let track = [(0.0, (0.0, 0.0)), (1.0, (2.0, -4.0)), (2.0, (3.0, 0.0))];
        assert_eq!(track_at(&track, 0.5), Some((1.0, -2.0)));
        assert_eq!(track_at(&track, 1.0), Some((2.0, -4.0)));
        assert_eq!(track_at(&track, 0.0), Some((0.0, 0.0)));
        assert_eq!(track_at(&track, -0.1), None);
        assert_eq!(track_at(&track, 2.1), None);
        assert_eq!(track_at(&[], 0.0), None);
    }

    /// A short INS flight losing GNSS at 10 s: the INS track is kept for the ground track, and
    /// the report gives the scenario's loss time wherever it speaks of the loss, with the
    /// INS's later switch to GNSS-denied mode labelled as such.
    #[test]
    fn the_report_states_the_scenario_gnss_loss_and_the_ins_track_is_kept() {
        let dir = std::env::temp_dir().join(format!("ianav-output-{}", std::process::id()));
        let mut setup = FlightSetup::builtin(2).unwrap();
        setup.navigation = NavigationMode::Ins;
        setup.scenario.duration_s = 30.0;
        setup.scenario.gnss_loss_s = 10.0;
        let mut writer = RunWriter::new(&dir, false).unwrap();
        let summary = Flight::new(&setup, 1)
            .unwrap()
            .run(&mut writer, |_| {})
            .unwrap();

        // One INS point per second from mission time 0, at the truth's instants, close to it.
        let (truth, nav) = (&writer.plot, &writer.nav_points);
        assert_eq!(nav.len(), truth.len());
        assert!(nav.len() >= 30 && truth[0].t_s == 0.0, "{}", nav.len());
        for (p, t) in nav.iter().zip(truth) {
            assert_eq!(p.nse.t_s, t.t_s);
            let d = wgs84::ned_difference_m(&t.pos, &p.pos);
            assert!(d.x.hypot(d.y) < 100.0, "{d:?} at {} s", t.t_s);
        }
        let switch_s = writer.ins_denied_s.expect("the INS notices the loss");
        assert!(switch_s > 10.0 && switch_s < 13.0, "{switch_s}");

        let report = std::fs::read_to_string(writer.finish(&summary).unwrap()).unwrap();
        let loss_lines: Vec<&str> = report.lines().filter(|l| l.contains("GNSS lost")).collect();
        assert_eq!(loss_lines.len(), 2, "{report}");
        assert!(loss_lines[0].starts_with("| GNSS lost (scenario) | 10.0 s"));
        assert!(loss_lines[1].starts_with("| GNSS lost (t = 10.0 s) |"));
        let switch = format!("| INS declared itself GNSS-denied | {switch_s:.1} s");
        assert!(report.contains(&switch), "{report}");
        assert!(dir.join("ground_track.png").is_file());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
