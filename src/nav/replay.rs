//! Replay of a sensor log through the navigator (ARCHITECTURE "The navigation core": a replay
//! is one more driver): every event of an `io::sensor_log` file, in order, into a
//! [`Navigator`] built with the settings the log was recorded with; the solutions come out as
//! CSV whose numbers read back bit for bit (shortest round-trip decimal form). The same log
//! and settings give the same solutions as the flight that recorded them, which makes a
//! committed log and its output a regression test of the whole core.

use std::fmt::Write as _;
use std::io::{Read, Write};

use super::{NavConfig, NavSolution, Navigator, NavigatorStats};
use crate::ins::InsStats;
use crate::io::sensor_log::{SensorLogError, SensorLogReader};

/// Columns of the solutions CSV: time, geodetic position (rad, m), NED velocity, attitude
/// quaternion body → NED, position σ north / east / down, GNSS-denied flag, reset counter.
pub const CSV_HEADER: &str = "t_us,lat_rad,lon_rad,h_m,v_n_mps,v_e_mps,v_d_mps,q_w,q_x,q_y,q_z,\
                              sigma_n_m,sigma_e_m,sigma_d_m,gnss_denied,reset_counter";

/// Columns of the states CSV (`ianav replay --states`): the INS's internal estimates at the
/// same solutions, for looking into a flight: air data (TAS, AoA, AoS), the wind, the
/// specific force, the sensor-error states (gyro, accelerometer, magnetometer), the magnetic
/// model error `ΔB_n`, the reference's attitude error and the last GNSS NIS.
pub const STATES_HEADER: &str = "t_us,tas_mps,aoa_rad,aos_rad,wind_n_mps,wind_e_mps,wind_d_mps,\
                                 f_x_mps2,f_y_mps2,f_z_mps2,e_gyr_x_rps,e_gyr_y_rps,e_gyr_z_rps,\
                                 e_acc_x_mps2,e_acc_y_mps2,e_acc_z_mps2,e_mag_x_nt,e_mag_y_nt,\
                                 e_mag_z_nt,delta_b_n_nt,delta_b_e_nt,delta_b_d_nt,ref_err_x_rad,\
                                 ref_err_y_rad,ref_err_z_rad,gnss_nis";

/// Errors of a replay.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The log could not be read.
    #[error(transparent)]
    Log(#[from] SensorLogError),
    /// The log records no navigation settings.
    #[error("the log records no navigation settings (written by an older version?)")]
    NoConfig,
    /// The recorded settings do not parse.
    #[error("navigation settings in the log: {0}")]
    Config(String),
    /// An override is not `dotted.key=value` with a TOML value, or names no setting.
    #[error("setting override `{0}`: {1}")]
    Override(String, String),
    /// The settings are invalid.
    #[error(transparent)]
    Nav(#[from] super::NavError),
    /// Writing the output failed.
    #[error("writing the solutions: {0}")]
    Io(#[from] std::io::Error),
    /// A deferred-vision marker names no frame whose vision is out (the log was recorded with
    /// other settings than those replayed, or is corrupt).
    #[error("vision result of the frame at t = {0} µs marked applied, but no such frame is out")]
    VisionMarker(u64),
}

/// What a replay went through.
#[derive(Debug, Clone, Default)]
pub struct ReplaySummary {
    /// Events read from the log.
    pub events: u64,
    /// Solutions the navigator produced.
    pub solutions: u64,
    /// Solutions written out.
    pub written: u64,
    /// The navigator's counters at the end.
    pub nav: NavigatorStats,
    /// The INS counters at the end (`None` if it never started).
    pub ins: Option<InsStats>,
    /// The last solution.
    pub last: Option<NavSolution>,
}

/// The settings as they are recorded in a log.
pub fn config_to_toml(cfg: &NavConfig) -> String {
    // Every field of the settings has a TOML form: this cannot fail.
    toml::to_string(cfg).unwrap_or_default()
}

/// The settings recorded in `reader`'s log.
pub fn config_of<R: Read>(reader: &SensorLogReader<R>) -> Result<NavConfig, ReplayError> {
    let text = reader.nav_config().ok_or(ReplayError::NoConfig)?;
    toml::from_str(text).map_err(|e| ReplayError::Config(e.to_string()))
}

/// The settings recorded in `reader`'s log with `overrides` applied: each `dotted.key=value`
/// (a TOML value: `1e-3`, `true`, `"scaled_imu"`, `[1.0, 2.0]`) replaces that setting, so a
/// recorded flight can be re-run with other filter settings. A key the settings do not have
/// is refused, not ignored.
pub fn config_with_overrides<R: Read>(
    reader: &SensorLogReader<R>,
    overrides: &[String],
) -> Result<NavConfig, ReplayError> {
    let text = reader.nav_config().ok_or(ReplayError::NoConfig)?;
    let mut table: toml::Table =
        toml::from_str(text).map_err(|e| ReplayError::Config(e.to_string()))?;
    for o in overrides {
        apply_override(&mut table, o)?;
    }
    let cfg: NavConfig = toml::Value::Table(table.clone())
        .try_into()
        .map_err(|e: toml::de::Error| ReplayError::Config(e.to_string()))?;
    // Unknown keys are dropped by deserialisation: compare the round trip to catch them.
    let back: toml::Table =
        toml::from_str(&config_to_toml(&cfg)).map_err(|e| ReplayError::Config(e.to_string()))?;
    for o in overrides {
        let key = o.split_once('=').map_or(o.as_str(), |(k, _)| k.trim());
        if lookup(&back, key).is_none() {
            return Err(ReplayError::Override(o.clone(), "no such setting".into()));
        }
    }
    Ok(cfg)
}

fn lookup<'a>(table: &'a toml::Table, dotted: &str) -> Option<&'a toml::Value> {
    let mut parts = dotted.split('.');
    let mut v = table.get(parts.next()?)?;
    for p in parts {
        v = v.as_table()?.get(p)?;
    }
    Some(v)
}

fn apply_override(table: &mut toml::Table, o: &str) -> Result<(), ReplayError> {
    let bad = |why: &str| ReplayError::Override(o.to_owned(), why.to_owned());
    let (key, value) = o.split_once('=').ok_or_else(|| bad("expected key=value"))?;
    // Parsed as the value of a one-key document, so any TOML value is accepted.
    let doc: toml::Table = toml::from_str(&format!("v = {}", value.trim()))
        .map_err(|_| bad("the value is not a TOML value"))?;
    let value = doc.get("v").cloned().ok_or_else(|| bad("empty value"))?;
    let parts: Vec<&str> = key.trim().split('.').collect();
    let (last, path) = parts.split_last().ok_or_else(|| bad("empty key"))?;
    let mut t = table;
    for p in path {
        t = t
            .entry((*p).to_owned())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| bad("a key on the path is not a table"))?;
    }
    t.insert((*last).to_owned(), value);
    Ok(())
}

/// Run every event of `reader` through a navigator built with `cfg`, handing each solution
/// to `on_solution`. With deferred vision ([`NavConfig::vision_deferred`]) each frame's task is
/// run when the navigator hands it out and its result applied where the log's
/// [`SensorEvent::VisionApplied`](crate::sensors::SensorEvent::VisionApplied) marker stands, as
/// the daemon did.
pub fn replay<R: Read>(
    reader: SensorLogReader<R>,
    cfg: &NavConfig,
    on_solution: impl FnMut(&NavSolution) -> Result<(), ReplayError>,
) -> Result<ReplaySummary, ReplayError> {
    replay_with_events(reader, cfg, |_, _| Ok(()), on_solution)
}

/// [`replay`], also handing every event of the log to `on_event` (with the navigator after
/// it), before the solution it gives.
pub fn replay_with_events<R: Read>(
    reader: SensorLogReader<R>,
    cfg: &NavConfig,
    mut on_event: impl FnMut(&crate::sensors::SensorEvent, &Navigator) -> Result<(), ReplayError>,
    mut on_solution: impl FnMut(&NavSolution) -> Result<(), ReplayError>,
) -> Result<ReplaySummary, ReplayError> {
    use crate::sensors::SensorEvent;
    let mut nav = Navigator::new(cfg)?;
    let mut summary = ReplaySummary::default();
    let mut vision_done = None;
    for event in reader {
        let event = event?;
        summary.events += 1;
        if let SensorEvent::VisionApplied(marker) = &event {
            let done = vision_done
                .take()
                .filter(|d: &super::VisionDone| d.frame_t_us() == marker.t_us)
                .ok_or(ReplayError::VisionMarker(marker.t_us))?;
            nav.apply_vision(done)
                .ok_or(ReplayError::VisionMarker(marker.t_us))?;
            continue;
        }
        let sol = nav.push(&event);
        if let Some(task) = nav.take_vision_task() {
            vision_done = Some(task.run());
        }
        on_event(&event, &nav)?;
        if let Some(sol) = sol {
            summary.solutions += 1;
            on_solution(&sol)?;
            summary.last = Some(sol);
        }
    }
    summary.nav = *nav.stats();
    summary.ins = nav.ins_stats().copied();
    Ok(summary)
}

/// Replay `reader` with the settings it records, writing every `every`-th solution (the first
/// included) as CSV to `out`.
pub fn replay_to_csv<R: Read>(
    reader: SensorLogReader<R>,
    every: u64,
    out: &mut impl Write,
) -> Result<ReplaySummary, ReplayError> {
    replay_to_csv_with(reader, &[], every, out)
}

/// [`replay_to_csv`] with setting overrides ([`config_with_overrides`]).
pub fn replay_to_csv_with<R: Read>(
    reader: SensorLogReader<R>,
    overrides: &[String],
    every: u64,
    out: &mut impl Write,
) -> Result<ReplaySummary, ReplayError> {
    replay_to_csvs(reader, overrides, every, out, None)
}

/// [`replay_to_csv_with`], and the INS's internal estimates of the same solutions
/// ([`STATES_HEADER`]) to `states` if given.
pub fn replay_to_csvs<R: Read>(
    reader: SensorLogReader<R>,
    overrides: &[String],
    every: u64,
    out: &mut impl Write,
    mut states: Option<&mut dyn Write>,
) -> Result<ReplaySummary, ReplayError> {
    let cfg = config_with_overrides(&reader, overrides)?;
    writeln!(out, "{CSV_HEADER}")?;
    if let Some(w) = states.as_mut() {
        writeln!(w, "{STATES_HEADER}")?;
    }
    let every = every.max(1);
    let (mut k, mut written, mut line) = (0_u64, 0_u64, String::with_capacity(320));
    let mut summary = replay(reader, &cfg, |sol| {
        if k.is_multiple_of(every) {
            csv_line(sol, &mut line);
            writeln!(out, "{line}")?;
            if let Some(w) = states.as_mut() {
                states_line(sol, &mut line);
                writeln!(w, "{line}")?;
            }
            written += 1;
        }
        k += 1;
        Ok(())
    })?;
    summary.written = written;
    Ok(summary)
}

/// One line (no newline) of the states CSV of `sol` into `line`.
pub fn states_line(sol: &NavSolution, line: &mut String) {
    line.clear();
    let ins = &sol.ins;
    let _ = write!(
        line,
        "{},{},{},{}",
        sol.t_us, ins.tas_mps, ins.aoa_rad, ins.aos_rad
    );
    for v in [
        &ins.wind_ned_mps,
        &ins.f_ib_b_mps2,
        &ins.e_gyr_rps,
        &ins.e_acc_mps2,
        &ins.e_mag_nt,
        &ins.delta_b_n_nt,
        &ins.ref_attitude_err_rad,
    ] {
        let _ = write!(line, ",{},{},{}", v.x, v.y, v.z);
    }
    match ins.gnss_nis {
        Some(nis) => {
            let _ = write!(line, ",{nis}");
        }
        None => line.push(','),
    }
}

/// One CSV line (no newline) of `sol` into `line`.
pub fn csv_line(sol: &NavSolution, line: &mut String) {
    line.clear();
    let q = sol.q_nb.quaternion();
    let p = &sol.cov.position_m2;
    let sd = |i: usize| p[(i, i)].max(0.0).sqrt();
    // `{}` of an f64 is its shortest decimal form that parses back to the same bits.
    let _ = write!(
        line,
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        sol.t_us,
        sol.pos.lat_rad,
        sol.pos.lon_rad,
        sol.pos.h_m,
        sol.v_ned_mps.x,
        sol.v_ned_mps.y,
        sol.v_ned_mps.z,
        q.w,
        q.i,
        q.j,
        q.k,
        sd(0),
        sd(1),
        sd(2),
        u8::from(sol.ins_status.gnss_denied),
        sol.reset_counter
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ins::InsConfig;

    #[test]
    fn the_settings_round_trip_through_their_toml_form() {
        let mut cfg = NavConfig::new(InsConfig::default(), 2025.75);
        cfg.start.restart_airspeed_mps = Some(12.5);
        let back: NavConfig = toml::from_str(&config_to_toml(&cfg)).unwrap();
        assert_eq!(back, cfg);
        let cfg = NavConfig::new(InsConfig::default(), 2025.75);
        let back: NavConfig = toml::from_str(&config_to_toml(&cfg)).unwrap();
        assert_eq!(back, cfg);
    }

    fn log_with(cfg: &NavConfig) -> Vec<u8> {
        let mut w = crate::io::sensor_log::SensorLogWriter::new(Vec::new()).unwrap();
        w.write_nav_config(&config_to_toml(cfg)).unwrap();
        w.finish().unwrap()
    }

    #[test]
    fn overrides_replace_recorded_settings_and_unknown_keys_are_refused() {
        let cfg = NavConfig::new(InsConfig::default(), 2025.75);
        let log = log_with(&cfg);
        let r = SensorLogReader::new(&log[..]).unwrap();
        let set = |s: &str| vec![s.to_owned()];
        let got = config_with_overrides(&r, &set("ins.attitude.q_w_nb_rad2ps2 = 2.5e-3")).unwrap();
        assert_eq!(got.ins.attitude.q_w_nb_rad2ps2, 2.5e-3);
        let mut expected = cfg.clone();
        expected.ins.attitude.q_w_nb_rad2ps2 = 2.5e-3;
        assert_eq!(got, expected, "nothing else changes");
        assert_eq!(config_with_overrides(&r, &[]).unwrap(), cfg);
        for bad in [
            "ins.attitude.no_such_key=1",
            "ins.attitude.q_w_nb_rad2ps2",
            "ins.attitude.q_w_nb_rad2ps2=not a value",
            "ins.attitude.q_w_nb_rad2ps2.x=1",
        ] {
            let err = config_with_overrides(&r, &set(bad));
            assert!(
                matches!(err, Err(ReplayError::Override(..) | ReplayError::Config(_))),
                "{bad}: {err:?}"
            );
        }
    }

    #[test]
    fn vision_settings_are_recorded_and_overridden_and_older_logs_take_the_defaults() {
        let cfg = NavConfig::new(InsConfig::default(), 2025.75);
        let text = config_to_toml(&cfg);
        assert!(text.contains("[vision.pose]"), "{text}");
        let log = log_with(&cfg);
        let r = SensorLogReader::new(&log[..]).unwrap();
        let set = |s: &str| vec![s.to_owned()];
        let got = config_with_overrides(&r, &set("vision.pose.max_iterations=5")).unwrap();
        let mut expected = cfg.clone();
        expected.vision.pose.max_iterations = 5;
        assert_eq!(got, expected, "nothing else changes");
        let got = config_with_overrides(&r, &set("vision.max_keyframes = 20")).unwrap();
        assert_eq!(got.vision.max_keyframes, 20);
        for bad in [
            "vision.no_such_key=1",
            "vision.pose.no_such_key=1",
            "vision.pose.max_iterations.x=1",
        ] {
            let err = config_with_overrides(&r, &set(bad));
            assert!(
                matches!(err, Err(ReplayError::Override(..) | ReplayError::Config(_))),
                "{bad}: {err:?}"
            );
        }
        // An invalid value parses; the navigator refuses it.
        let spoilt = config_with_overrides(&r, &set("vision.pose.tukey_k=0.0")).unwrap();
        assert!(matches!(
            Navigator::new(&spoilt),
            Err(crate::nav::NavError::Vision(_))
        ));
        // A log written before the settings had a `[vision]` table.
        let mut table: toml::Table = toml::from_str(&text).unwrap();
        assert!(table.remove("vision").is_some());
        let mut w = crate::io::sensor_log::SensorLogWriter::new(Vec::new()).unwrap();
        w.write_nav_config(&toml::to_string(&table).unwrap())
            .unwrap();
        let old = w.finish().unwrap();
        let r = SensorLogReader::new(&old[..]).unwrap();
        assert_eq!(config_of(&r).unwrap(), cfg);
        let got = config_with_overrides(&r, &set("vision.pose.max_iterations=5")).unwrap();
        assert_eq!(got, expected);
    }

    #[test]
    fn a_log_without_settings_is_refused_and_a_broken_one_is_an_error() {
        let log = crate::io::sensor_log::SensorLogWriter::new(Vec::new())
            .unwrap()
            .finish()
            .unwrap();
        let r = SensorLogReader::new(&log[..]).unwrap();
        assert!(matches!(
            replay_to_csv(r, 1, &mut Vec::new()),
            Err(ReplayError::NoConfig)
        ));
        let mut w = crate::io::sensor_log::SensorLogWriter::new(Vec::new()).unwrap();
        w.write_nav_config("[ins]\nno_such_key = 1\n").unwrap();
        let log = w.finish().unwrap();
        let r = SensorLogReader::new(&log[..]).unwrap();
        assert!(matches!(
            replay_to_csv(r, 1, &mut Vec::new()),
            Err(ReplayError::Config(_))
        ));
    }
}
