//! A sensor log (a daemon's recording, a simulated flight's log) replayed through the
//! navigation core and written as MCAP, the container Foxglove opens (docs/REPLAY.md "MCAP").
//! Messages are JSON with Foxglove's well-known schema names, so its image, map and plot panels
//! show them without configuration:
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/camera/image` | `foxglove.CompressedImage` | each frame the navigator took, PNG |
//! | `/camera/features` | `foxglove.ImageAnnotations` | the features the visual pose of that frame rests on, drawn over it |
//! | `/ianav/position` | `foxglove.LocationFix` | the published (fused) position and its ENU covariance |
//! | `/ins/position` | `foxglove.LocationFix` | the INS's own position and covariance |
//! | `/ianav/vision_fix` | `foxglove.LocationFix` | each new fix of the visual navigation |
//! | `/ianav/status` | `ianav.Status` | source, states, counters and accuracies to plot (and the horizontal error, with a truth) |
//! | `/truth/position` | `foxglove.LocationFix` | a simulated run's true position (`truth.csv`), when given |
//! | `/pose/ianav`, `/pose/ins`, `/pose/vision`, `/pose/truth` | `foxglove.PoseInFrame` | the same four as 3D poses in a local ENU frame (`enu`, origin at the first solution), body axes forward-right-down |
//!
//! Log time is the sensor time of the solution or frame, in nanoseconds.

use std::collections::BTreeMap;
use std::io::{Read, Seek, Write};

use base64::Engine as _;

use super::sensor_log::SensorLogReader;
use crate::nav::replay::{ReplayError, ReplaySummary, replay_with_events};
use crate::nav::{NavConfig, NavSolution, PositionSource};
use crate::sensors::SensorEvent;

/// Topics written.
pub const TOPIC_IMAGE: &str = "/camera/image";
/// The published position.
pub const TOPIC_POSITION: &str = "/ianav/position";
/// The visual navigation's fixes.
pub const TOPIC_VISION_FIX: &str = "/ianav/vision_fix";
/// Status for plots.
pub const TOPIC_STATUS: &str = "/ianav/status";
/// A simulated run's true position.
pub const TOPIC_TRUTH: &str = "/truth/position";
/// The tracked features over each image.
pub const TOPIC_FEATURES: &str = "/camera/features";
/// The INS's own position.
pub const TOPIC_INS: &str = "/ins/position";
/// 3D poses in the local ENU frame.
pub const TOPIC_POSE_FUSED: &str = "/pose/ianav";
/// The INS's pose.
pub const TOPIC_POSE_INS: &str = "/pose/ins";
/// The visual navigation's pose.
pub const TOPIC_POSE_VISION: &str = "/pose/vision";
/// A simulated run's true pose.
pub const TOPIC_POSE_TRUTH: &str = "/pose/truth";
/// Name of the local frame of the poses.
pub const ENU_FRAME: &str = "enu";

/// One true position of a simulated run, at sensor time `t_us`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthFix {
    /// Sensor time, µs (the log's clock).
    pub t_us: u64,
    /// Position.
    pub pos: crate::math::wgs84::Geodetic,
    /// Attitude, body to NED (when the file has `yaw_deg`, `pitch_deg`, `bank_deg`).
    pub q_nb: Option<nalgebra::UnitQuaternion<f64>>,
}

/// The true positions of an `ianav-sim run` directory's `truth.csv` (columns `t_us`, `lat_deg`,
/// `lon_deg`, `h_m`; the attitude too when it has `yaw_deg`, `pitch_deg` and `bank_deg`), in
/// time order; the error names the line.
pub fn truth_from_csv(text: &str) -> Result<Vec<TruthFix>, String> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| h.trim() == name)
            .ok_or_else(|| format!("no column {name}"))
    };
    let (t, lat, lon, h) = (col("t_us")?, col("lat_deg")?, col("lon_deg")?, col("h_m")?);
    let euler = match (col("yaw_deg"), col("pitch_deg"), col("bank_deg")) {
        (Ok(y), Ok(p), Ok(b)) => Some((y, p, b)),
        _ => None,
    };
    let mut out: Vec<TruthFix> = Vec::new();
    for (i, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        let num = |c: usize| -> Result<f64, String> {
            f.get(c)
                .and_then(|v| v.trim().parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("line {}: column {c} is not a number", i + 2))
        };
        let t_us = f
            .get(t)
            .and_then(|v| v.trim().parse::<u64>().ok())
            .ok_or_else(|| format!("line {}: t_us is not a time", i + 2))?;
        if out.last().is_some_and(|p| p.t_us >= t_us) {
            return Err(format!("line {}: times must increase", i + 2));
        }
        let q_nb = match euler {
            Some((y, p, b)) => Some(nalgebra::UnitQuaternion::from_euler_angles(
                num(b)?.to_radians(),
                num(p)?.to_radians(),
                num(y)?.to_radians(),
            )),
            None => None,
        };
        out.push(TruthFix {
            t_us,
            pos: crate::math::wgs84::Geodetic {
                lat_rad: num(lat)?.to_radians(),
                lon_rad: num(lon)?.to_radians(),
                h_m: num(h)?,
            },
            q_nb,
        });
    }
    Ok(out)
}

/// Largest gap between a solution and the true position it is compared with, µs.
const TRUTH_MATCH_US: u64 = 50_000;

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum McapExportError {
    /// Replaying the log failed.
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// Writing MCAP failed.
    #[error("writing MCAP: {0}")]
    Mcap(#[from] mcap::McapError),
}

/// What to write.
#[derive(Debug, Clone, Copy)]
pub struct McapOptions {
    /// Period of the position and status messages, µs (solutions come at the IMU rate).
    pub period_us: u64,
    /// Write every n-th frame the navigator took (1 = all).
    pub frame_every: u64,
}

impl Default for McapOptions {
    fn default() -> Self {
        Self {
            period_us: 100_000,
            frame_every: 1,
        }
    }
}

/// What an export wrote.
#[derive(Debug, Clone, Default)]
pub struct McapSummary {
    /// The replay behind it.
    pub replay: ReplaySummary,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
}

/// A `LocationFix` covariance of type 0 (unknown).
const UNKNOWN_COVARIANCE: [f64; 9] = [0.0; 9];

/// Foxglove's `Time`.
fn stamp(t_us: u64) -> serde_json::Value {
    serde_json::json!({ "sec": t_us / 1_000_000, "nsec": (t_us % 1_000_000) * 1_000 })
}

const TIME_SCHEMA: &str = r#"{"type":"object","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}}}"#;

fn compressed_image_schema() -> String {
    format!(
        r#"{{"title":"foxglove.CompressedImage","type":"object","properties":{{"timestamp":{TIME_SCHEMA},"frame_id":{{"type":"string"}},"data":{{"type":"string","contentEncoding":"base64"}},"format":{{"type":"string"}}}}}}"#
    )
}

fn location_fix_schema() -> String {
    format!(
        r#"{{"title":"foxglove.LocationFix","type":"object","properties":{{"timestamp":{TIME_SCHEMA},"frame_id":{{"type":"string"}},"latitude":{{"type":"number"}},"longitude":{{"type":"number"}},"altitude":{{"type":"number"}},"position_covariance":{{"type":"array","items":{{"type":"number"}},"minItems":9,"maxItems":9}},"position_covariance_type":{{"type":"integer"}}}}}}"#
    )
}

fn status_schema() -> String {
    format!(
        r#"{{"title":"ianav.Status","type":"object","properties":{{"timestamp":{TIME_SCHEMA},"horizontal_source":{{"type":"string"}},"vision_state":{{"type":"string"}},"gnss_denied":{{"type":"boolean"}},"reset_counter":{{"type":"integer"}},"sigma_north_m":{{"type":"number"}},"sigma_east_m":{{"type":"number"}},"sigma_down_m":{{"type":"number"}},"matched":{{"type":"integer"}},"inliers":{{"type":"integer"}},"frames":{{"type":"integer"}},"fused_vision_fixes":{{"type":"integer"}},"vision_restarts":{{"type":"integer"}}}}}}"#
    )
}

fn image_annotations_schema() -> String {
    let color = r#"{"type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"type":"number"}}}"#;
    let point = r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"}}}"#;
    format!(
        r#"{{"title":"foxglove.ImageAnnotations","type":"object","properties":{{"circles":{{"type":"array"}},"points":{{"type":"array","items":{{"type":"object","properties":{{"timestamp":{TIME_SCHEMA},"type":{{"type":"integer"}},"points":{{"type":"array","items":{point}}},"outline_color":{color},"outline_colors":{{"type":"array","items":{color}}},"fill_color":{color},"thickness":{{"type":"number"}}}}}}}},"texts":{{"type":"array"}}}}}}"#
    )
}

fn pose_in_frame_schema() -> String {
    let vector = r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}}"#;
    let quaternion = r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}"#;
    format!(
        r#"{{"title":"foxglove.PoseInFrame","type":"object","properties":{{"timestamp":{TIME_SCHEMA},"frame_id":{{"type":"string"}},"pose":{{"type":"object","properties":{{"position":{vector},"orientation":{quaternion}}}}}}}}}"#
    )
}

/// A `LocationFix` message.
fn location_fix(
    t_us: u64,
    pos: &crate::math::wgs84::Geodetic,
    covariance: [f64; 9],
    covariance_type: u8,
) -> serde_json::Value {
    serde_json::json!({
        "timestamp": stamp(t_us),
        "frame_id": "wgs84",
        "latitude": pos.lat_rad.to_degrees(),
        "longitude": pos.lon_rad.to_degrees(),
        "altitude": pos.h_m,
        "position_covariance": covariance,
        "position_covariance_type": covariance_type,
    })
}

/// The local east-north-up frame of the 3D poses, its origin at the first position given.
#[derive(Debug, Default)]
struct LocalEnu {
    origin: Option<crate::math::wgs84::Geodetic>,
}

impl LocalEnu {
    /// A `PoseInFrame` of the body at `pos` with attitude `q_nb` (identity when unknown).
    fn pose(
        &mut self,
        t_us: u64,
        pos: &crate::math::wgs84::Geodetic,
        q_nb: Option<&nalgebra::UnitQuaternion<f64>>,
    ) -> serde_json::Value {
        let origin = *self.origin.get_or_insert(*pos);
        let ned = crate::math::wgs84::ned_difference_m(&origin, pos);
        // ENU from NED: a half turn about the axis halfway between north and east.
        let q_enu_ned = nalgebra::UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(nalgebra::Vector3::new(1.0, 1.0, 0.0)),
            std::f64::consts::PI,
        );
        let q = q_nb.map_or_else(nalgebra::UnitQuaternion::identity, |q| q_enu_ned * q);
        serde_json::json!({
            "timestamp": stamp(t_us),
            "frame_id": ENU_FRAME,
            "pose": {
                "position": { "x": ned.y, "y": ned.x, "z": -ned.z },
                "orientation": { "x": q.i, "y": q.j, "z": q.k, "w": q.w },
            },
        })
    }
}

/// The `ImageAnnotations` of a frame: its tracked features as points (level-0 pixels, moved
/// from our pixel-centre convention to Foxglove's pixel-corner one).
fn feature_annotations(t_us: u64, features: &[nalgebra::Vector2<f64>]) -> serde_json::Value {
    let points: Vec<serde_json::Value> = features
        .iter()
        .map(|p| serde_json::json!({ "x": p.x + 0.5, "y": p.y + 0.5 }))
        .collect();
    serde_json::json!({
        "circles": [],
        "points": [{
            "timestamp": stamp(t_us),
            "type": 1,
            "points": points,
            "outline_color": { "r": 0.1, "g": 1.0, "b": 0.2, "a": 1.0 },
            "outline_colors": [],
            "fill_color": { "r": 0.1, "g": 1.0, "b": 0.2, "a": 1.0 },
            "thickness": 4.0,
        }],
        "texts": [],
    })
}

/// The ENU covariance of a solution's NED position, row-major.
fn enu_covariance(sol: &NavSolution) -> [f64; 9] {
    let p = &sol.cov.position_m2;
    // ENU = P · NED with P swapping north and east and negating down.
    let m = nalgebra::Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let enu = m * p * m.transpose();
    let mut out = [0.0; 9];
    for (i, v) in out.iter_mut().enumerate() {
        *v = enu[(i / 3, i % 3)];
    }
    out
}

/// One channel per topic, with its sequence counter; the local frame of the poses.
struct Channels {
    ids: BTreeMap<&'static str, u16>,
    counts: BTreeMap<String, u64>,
    enu: LocalEnu,
}

impl Channels {
    fn write<W: Write + Seek>(
        &mut self,
        out: &mut mcap::Writer<W>,
        topic: &'static str,
        t_us: u64,
        msg: &serde_json::Value,
    ) -> Result<(), mcap::McapError> {
        let Some(&channel_id) = self.ids.get(topic) else {
            return Ok(());
        };
        let n = self.counts.entry(topic.to_owned()).or_insert(0);
        *n += 1;
        let t_ns = t_us.saturating_mul(1_000);
        out.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id,
                sequence: u32::try_from(*n).unwrap_or(u32::MAX),
                log_time: t_ns,
                publish_time: t_ns,
            },
            msg.to_string().as_bytes(),
        )
    }
}

/// A frame as PNG, and the features its visual pose rests on when it has one.
fn write_frame<W: Write + Seek>(
    channels: &mut Channels,
    writer: &mut mcap::Writer<W>,
    frame: &crate::sensors::Frame,
    features: Option<&[nalgebra::Vector2<f64>]>,
) -> Result<(), mcap::McapError> {
    let mut png = Vec::new();
    // A frame whose size disagrees with its buffer was refused by the navigator too: skipped.
    if image::write_buffer_with_format(
        &mut std::io::Cursor::new(&mut png),
        &frame.pixels,
        frame.width,
        frame.height,
        image::ExtendedColorType::L8,
        image::ImageFormat::Png,
    )
    .is_err()
    {
        return Ok(());
    }
    let msg = serde_json::json!({
        "timestamp": stamp(frame.t_us),
        "frame_id": "camera",
        "data": base64::engine::general_purpose::STANDARD.encode(&png),
        "format": "png",
    });
    channels.write(writer, TOPIC_IMAGE, frame.t_us, &msg)?;
    if let Some(features) = features {
        let msg = feature_annotations(frame.t_us, features);
        channels.write(writer, TOPIC_FEATURES, frame.t_us, &msg)?;
    }
    Ok(())
}

/// The position and status messages of one solution.
fn write_solution<W: Write + Seek>(
    channels: &mut Channels,
    writer: &mut mcap::Writer<W>,
    sol: &NavSolution,
    stats: &crate::nav::NavigatorStats,
    truth: &[TruthFix],
    truth_next: &mut usize,
) -> Result<(), mcap::McapError> {
    let p = &sol.cov.position_m2;
    let source = match sol.horizontal_source {
        PositionSource::Ins => "ins",
        PositionSource::Vision => "vision",
    };
    let position = location_fix(sol.t_us, &sol.pos, enu_covariance(sol), 3);
    channels.write(writer, TOPIC_POSITION, sol.t_us, &position)?;
    let ins = location_fix(sol.t_us, &sol.ins.pos, UNKNOWN_COVARIANCE, 0);
    channels.write(writer, TOPIC_INS, sol.t_us, &ins)?;
    let pose = channels.enu.pose(sol.t_us, &sol.pos, Some(&sol.q_nb));
    channels.write(writer, TOPIC_POSE_FUSED, sol.t_us, &pose)?;
    let pose = channels
        .enu
        .pose(sol.t_us, &sol.ins.pos, Some(&sol.ins.q_nb));
    channels.write(writer, TOPIC_POSE_INS, sol.t_us, &pose)?;
    let mut status = serde_json::json!({
        "timestamp": stamp(sol.t_us),
        "horizontal_source": source,
        "vision_state": format!("{:?}", sol.vision.state),
        "gnss_denied": sol.ins_status.gnss_denied,
        "reset_counter": sol.reset_counter,
        "sigma_north_m": p[(0, 0)].max(0.0).sqrt(),
        "sigma_east_m": p[(1, 1)].max(0.0).sqrt(),
        "sigma_down_m": p[(2, 2)].max(0.0).sqrt(),
        "matched": sol.vision.n_matched,
        "inliers": sol.vision.n_inliers,
        "frames": stats.frames,
        "fused_vision_fixes": stats.fused_vision_fixes,
        "vision_restarts": stats.vision_restarts,
    });
    // The truth up to this solution, and its horizontal error against the nearest one.
    let mut nearest: Option<&TruthFix> = None;
    while let Some(t) = truth.get(*truth_next)
        && t.t_us <= sol.t_us
    {
        let msg = location_fix(t.t_us, &t.pos, UNKNOWN_COVARIANCE, 0);
        channels.write(writer, TOPIC_TRUTH, t.t_us, &msg)?;
        let pose = channels.enu.pose(t.t_us, &t.pos, t.q_nb.as_ref());
        channels.write(writer, TOPIC_POSE_TRUTH, t.t_us, &pose)?;
        nearest = Some(t);
        *truth_next += 1;
    }
    let next = truth.get(*truth_next);
    let nearest = match (nearest, next) {
        (Some(a), Some(b)) if b.t_us - sol.t_us < sol.t_us - a.t_us => Some(b),
        (None, b) => b,
        (a, _) => a,
    };
    if let Some(t) = nearest.filter(|t| t.t_us.abs_diff(sol.t_us) <= TRUTH_MATCH_US) {
        let d = crate::math::wgs84::ned_difference_m(&t.pos, &sol.pos);
        status["horizontal_error_m"] = serde_json::json!(d.x.hypot(d.y));
        status["altitude_error_m"] = serde_json::json!(-d.z);
    }
    channels.write(writer, TOPIC_STATUS, sol.t_us, &status)
}

/// Replay `reader` with `cfg` and write the MCAP file to `out`; `truth` (a simulated run's,
/// in time order, or empty) adds its track and the errors.
pub fn export_mcap<R: Read, W: Write + Seek>(
    reader: SensorLogReader<R>,
    cfg: &NavConfig,
    out: W,
    options: &McapOptions,
    truth: &[TruthFix],
) -> Result<McapSummary, McapExportError> {
    let mut writer = mcap::Writer::new(out)?;
    let image = writer.add_schema(
        "foxglove.CompressedImage",
        "jsonschema",
        compressed_image_schema().as_bytes(),
    )?;
    let fix = writer.add_schema(
        "foxglove.LocationFix",
        "jsonschema",
        location_fix_schema().as_bytes(),
    )?;
    let status = writer.add_schema("ianav.Status", "jsonschema", status_schema().as_bytes())?;
    let annotations = writer.add_schema(
        "foxglove.ImageAnnotations",
        "jsonschema",
        image_annotations_schema().as_bytes(),
    )?;
    let pose = writer.add_schema(
        "foxglove.PoseInFrame",
        "jsonschema",
        pose_in_frame_schema().as_bytes(),
    )?;
    let none = BTreeMap::new();
    let mut channels = Channels {
        ids: BTreeMap::new(),
        counts: BTreeMap::new(),
        enu: LocalEnu::default(),
    };
    let mut topics = vec![
        (TOPIC_IMAGE, image),
        (TOPIC_FEATURES, annotations),
        (TOPIC_POSITION, fix),
        (TOPIC_INS, fix),
        (TOPIC_VISION_FIX, fix),
        (TOPIC_STATUS, status),
        (TOPIC_POSE_FUSED, pose),
        (TOPIC_POSE_INS, pose),
        (TOPIC_POSE_VISION, pose),
    ];
    if !truth.is_empty() {
        topics.push((TOPIC_TRUTH, fix));
        topics.push((TOPIC_POSE_TRUTH, pose));
    }
    for (topic, schema) in topics {
        let id = writer.add_channel(schema, topic, "json", &none)?;
        channels.ids.insert(topic, id);
    }
    let mut truth_next = 0_usize;
    // The callbacks cannot both borrow the writer mutably: solutions are collected per
    // event and written after it, in log order.
    let pending: std::cell::RefCell<Vec<NavSolution>> = std::cell::RefCell::default();
    let mut frames_seen = 0_u64;
    let mut pending_frame: Option<crate::sensors::Frame> = None;
    let mut last_fix_t_us = None;
    let mut next_solution_us = 0_u64;
    let mut failure: Option<mcap::McapError> = None;
    let replay = replay_with_events(
        reader,
        cfg,
        |event, nav| {
            if failure.is_some() {
                return Ok(());
            }
            let result = (|| {
                if let SensorEvent::Frame(f) = event {
                    frames_seen += 1;
                    // The previous frame, if still waiting for its features: it did not track.
                    if let Some(waiting) = pending_frame.take() {
                        write_frame(&mut channels, &mut writer, &waiting, None)?;
                    }
                    if (frames_seen - 1).is_multiple_of(options.frame_every.max(1)) {
                        pending_frame = Some(f.clone());
                    }
                }
                // A frame is written once the navigating system has its pose (or not at all).
                if let Some(waiting) = &pending_frame
                    && let Some(view) = nav.visual_systems().next()
                    && let Some((t_us, features)) = view.tracked_features()
                    && t_us == waiting.t_us
                {
                    let features: Vec<_> = features.collect();
                    write_frame(&mut channels, &mut writer, waiting, Some(&features))?;
                    pending_frame = None;
                }
                if let Some(fix) = nav.vision_fix()
                    && last_fix_t_us != Some(fix.t_us)
                {
                    last_fix_t_us = Some(fix.t_us);
                    let msg = location_fix(fix.t_us, &fix.pos, UNKNOWN_COVARIANCE, 0);
                    channels.write(&mut writer, TOPIC_VISION_FIX, fix.t_us, &msg)?;
                    let pose = channels.enu.pose(fix.t_us, &fix.pos, Some(&fix.q_nb));
                    channels.write(&mut writer, TOPIC_POSE_VISION, fix.t_us, &pose)?;
                }
                for sol in pending.borrow_mut().drain(..) {
                    write_solution(
                        &mut channels,
                        &mut writer,
                        &sol,
                        nav.stats(),
                        truth,
                        &mut truth_next,
                    )?;
                }
                Ok::<(), mcap::McapError>(())
            })();
            if let Err(e) = result {
                failure = Some(e);
            }
            Ok(())
        },
        |sol| {
            if sol.t_us >= next_solution_us {
                next_solution_us = sol.t_us.saturating_add(options.period_us.max(1));
                pending.borrow_mut().push(*sol);
            }
            Ok(())
        },
    )?;
    if let Some(e) = failure {
        return Err(e.into());
    }
    if let Some(waiting) = pending_frame.take() {
        write_frame(&mut channels, &mut writer, &waiting, None)?;
    }
    for sol in pending.borrow_mut().drain(..) {
        write_solution(
            &mut channels,
            &mut writer,
            &sol,
            &replay.nav,
            truth,
            &mut truth_next,
        )?;
    }
    writer.finish()?;
    Ok(McapSummary {
        replay,
        messages: channels.counts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_truth_csv_is_read_and_bad_ones_named() {
        let text = "t_us,t_s,lat_deg,lon_deg,h_m\n100000,-49.9,34.5,-89.0,2800.5\n\
                    200000,-49.8,34.6,-89.1,2801.0\n";
        let truth = truth_from_csv(text).unwrap();
        assert_eq!(truth.len(), 2);
        assert_eq!(truth[1].t_us, 200_000);
        assert!((truth[0].pos.lat_rad.to_degrees() - 34.5).abs() < 1e-12);
        assert_eq!(truth[1].pos.h_m, 2801.0);
        let no_h = truth_from_csv("t_us,lat_deg,lon_deg\n1,2,3\n").unwrap_err();
        assert!(no_h.contains("h_m"), "{no_h}");
        let repeated = truth_from_csv("t_us,lat_deg,lon_deg,h_m\n5,1,2,3\n5,1,2,3\n").unwrap_err();
        assert!(repeated.contains("line 3"), "{repeated}");
        let nan = truth_from_csv("t_us,lat_deg,lon_deg,h_m\n5,NaN,2,3\n").unwrap_err();
        assert!(nan.contains("line 2"), "{nan}");
        assert!(
            truth_from_csv("t_us,lat_deg,lon_deg,h_m\n")
                .unwrap()
                .is_empty()
        );
    }
}
