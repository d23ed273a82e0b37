//! The visual systems of one camera flight in its run directory: `vision.csv` (one row per
//! system per output), their tracks and errors in the plots beside the INS's (the paper's
//! colours: INS blue, VNS red, IA-VNS green), and the report's section.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufWriter, Write as _};
use std::path::Path;

use ianav::math::so3;
use ianav::math::wgs84::Geodetic;
use ianav::nav::{VisionState, VisionStatus};

use super::{OutputError, files, open_csv_once, vision_state_name};
use crate::flight::{TruthSample, VisionOutput};
use crate::metrics::{self, NseSample};
use crate::plots::{PALETTE, Series};
use crate::report::{display_name, system_colour as colour};

/// Columns of `vision.csv`: one row per system per output; the pose and its errors
/// (estimate − truth, as in `navigation.csv`) are empty unless it tracks at that instant.
const VISION_HEADER: &str = "t_s,system,state,matched,inliers,keyframes,points,reproj_rms_px,\
lat_deg,lon_deg,h_m,yaw_deg,pitch_deg,bank_deg,err_yaw_deg,err_pitch_deg,err_bank_deg,\
err_att_deg,err_h_m,err_hor_m,err_hor_pct";

/// One point per second of flight while a system tracks.
#[derive(Debug, Clone, Copy)]
pub(super) struct VisionPoint {
    pub(super) nse: NseSample,
    pub(super) pos: Geodetic,
}

/// One system over the flight.
#[derive(Debug, Clone)]
struct Trace {
    name: &'static str,
    points: Vec<VisionPoint>,
    /// The last tracked point.
    last: Option<VisionPoint>,
    status: VisionStatus,
    relocalising_outputs: usize,
}

/// The systems' file, points and last states.
#[derive(Default)]
pub(super) struct VisionTraces {
    /// Created at the first output with a system running.
    csv: Option<BufWriter<File>>,
    traces: Vec<Trace>,
    line: String,
}

impl VisionTraces {
    /// Whether any system ran.
    pub(super) fn is_empty(&self) -> bool {
        self.traces.is_empty()
    }

    /// The rows of one output; `plot_point` keeps a plot point for each tracking system.
    pub(super) fn rows(
        &mut self,
        dir: &Path,
        first_error: &mut Option<OutputError>,
        truth: &TruthSample,
        t_us: u64,
        systems: &[VisionOutput],
        plot_point: bool,
    ) {
        for out in systems {
            if out.status.state == VisionState::Inactive {
                continue;
            }
            if !open_csv_once(
                &mut self.csv,
                first_error,
                dir,
                files::VISION,
                VISION_HEADER,
            ) {
                return;
            }
            let i = match self.traces.iter().position(|t| t.name == out.name) {
                Some(i) => i,
                None => {
                    self.traces.push(Trace {
                        name: out.name,
                        points: Vec::new(),
                        last: None,
                        status: out.status,
                        relocalising_outputs: 0,
                    });
                    self.traces.len() - 1
                }
            };
            let trace = &mut self.traces[i];
            let v = &out.status;
            trace.status = *v;
            if v.state == VisionState::Relocalising {
                trace.relocalising_outputs += 1;
            }
            self.line.clear();
            let _ = write!(
                self.line,
                "{:.3},{},{},{},{},{},{},{}",
                truth.t_s,
                out.name,
                vision_state_name(v.state),
                v.n_matched,
                v.n_inliers,
                v.n_keyframes,
                v.n_points,
                v.reprojection_rms_px
                    .map_or(String::new(), |r| format!("{r:.3}"))
            );
            match out.fix.filter(|f| f.t_us == t_us) {
                Some(f) => {
                    let e = metrics::nse_pose(truth, &f.pos, &f.q_nb);
                    let euler_deg = so3::euler_zyx(&f.q_nb).map(f64::to_degrees);
                    let _ = write!(
                        self.line,
                        ",{:.9},{:.9},{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.3},{:.3},{}",
                        f.pos.lat_rad.to_degrees(),
                        f.pos.lon_rad.to_degrees(),
                        f.pos.h_m,
                        euler_deg.x,
                        euler_deg.y,
                        euler_deg.z,
                        e.yaw_deg,
                        e.pitch_deg,
                        e.bank_deg,
                        e.att_norm_deg,
                        e.alt_m,
                        e.hor_m,
                        metrics::format_fixed(e.hor_pct, 4)
                    );
                    let point = VisionPoint { nse: e, pos: f.pos };
                    trace.last = Some(point);
                    if truth.t_s >= 0.0 && plot_point {
                        trace.points.push(point);
                    }
                }
                None => self.line.push_str(",,,,,,,,,,,,,"),
            }
            if let Some(w) = self.csv.as_mut()
                && let Err(source) = writeln!(w, "{}", self.line)
            {
                first_error.get_or_insert(OutputError::Io {
                    path: dir.join(files::VISION).display().to_string(),
                    source,
                });
            }
        }
    }

    /// Flush the file.
    pub(super) fn flush(&mut self) -> std::io::Result<()> {
        match self.csv.as_mut() {
            Some(w) => w.flush(),
            None => Ok(()),
        }
    }

    /// Each system's ground track (dashed, over the solid truth), east and north in km.
    pub(super) fn tracks(&self, to_km: &dyn Fn(&Geodetic) -> (f64, f64)) -> Vec<Series> {
        self.traces
            .iter()
            .enumerate()
            .filter(|(_, t)| !t.points.is_empty())
            .map(|(i, t)| Series {
                label: format!("{} estimate", display_name(t.name)),
                points: t.points.iter().map(|p| to_km(&p.pos)).collect(),
                rgb: colour(t.name, i),
                dashed: true,
            })
            .collect()
    }

    /// One line per system (and the INS, given as `ins`) of the error `f` against time.
    pub(super) fn error_series(
        &self,
        ins: Vec<(f64, f64)>,
        f: fn(&NseSample) -> f64,
    ) -> Vec<Series> {
        let mut series = vec![Series {
            label: "INS".to_owned(),
            points: ins,
            rgb: PALETTE[0],
            dashed: false,
        }];
        series.extend(self.traces.iter().enumerate().map(|(i, t)| Series {
            label: display_name(t.name),
            points: t.points.iter().map(|p| (p.nse.t_s, f(&p.nse))).collect(),
            rgb: colour(t.name, i),
            dashed: false,
        }));
        series
    }

    /// The report's section: each system's last state and its errors at its last tracked
    /// output beside the INS's at the end.
    pub(super) fn report(&self, r: &mut String, ins_end: Option<&NseSample>) {
        if self.traces.is_empty() {
            return;
        }
        let names: Vec<String> = self.traces.iter().map(|t| display_name(t.name)).collect();
        let _ = writeln!(
            r,
            "\n## Visual navigation\n\n{} on the same frames. The VNS is the paper's baseline \
             (semi-direct visual odometry from the images and the initial estimate at its first \
             image only); the IA-VNS adds the INS priors, its motion prediction and \
             initialisation (docs/IAVNS.md).\n",
            names.join(", ")
        );
        let _ = writeln!(
            r,
            "| system | last state | outputs relocalising | at t [s] | yaw [deg] | pitch [deg] | bank [deg] | attitude norm [deg] | altitude [m] | horizontal [m] | horizontal [% of distance] |\n|---|---|---|---|---|---|---|---|---|---|---|"
        );
        let row = |r: &mut String, name: &str, state: &str, reloc: &str, e: Option<&NseSample>| {
            let cells = match e {
                Some(e) => format!(
                    "{:.1} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} | {:.1} | {}",
                    e.t_s,
                    e.yaw_deg,
                    e.pitch_deg,
                    e.bank_deg,
                    e.att_norm_deg,
                    e.alt_m,
                    e.hor_m,
                    metrics::format_fixed(e.hor_pct, 2)
                ),
                None => "never tracked | | | | | | | ".to_owned(),
            };
            let _ = writeln!(r, "| {name} | {state} | {reloc} | {cells} |");
        };
        if let Some(e) = ins_end {
            row(r, "INS (end)", "", "", Some(e));
        }
        for (t, name) in self.traces.iter().zip(&names) {
            row(
                r,
                name,
                vision_state_name(t.status.state),
                &t.relocalising_outputs.to_string(),
                t.last.as_ref().map(|p| &p.nse),
            );
        }
    }
}
