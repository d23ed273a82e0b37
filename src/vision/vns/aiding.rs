//! The IA-VNS's steps inside the frame handler (paper sections "IA-VNS rationale" to "IA-VNS
//! other modifications"; docs/IAVNS.md): with [`AidingConfig`] switched on, the VNS becomes the
//! IA-VNS one change at a time:
//! - `inertial_prediction`: the initial pose `ζ*` is the previous visual pose moved on by the
//!   INS body motion since the previous frame (the INS's absolute position, which drifts, is
//!   never used); it replaces sparse image alignment as the start of feature alignment and
//!   pose optimisation;
//! - `priors`: after the reprojection-only optimisation (stage 1), the PI-inspired activation
//!   ([`crate::vision::iavns::activation`]) compares the visual altitude, pitch and bank with the
//!   INS's and, when active, the joint prior-based optimisation
//!   ([`crate::vision::iavns::prior`]) moves the pose towards the adjusted attitude;
//! - `current_features_in_structure`: structure optimisation also uses the current frame's
//!   observations at its final pose, so the next frame's reprojection does not revert the
//!   adjustment.
//!
//! With every switch off the frame handler is the VNS's, bit for bit.

use nalgebra::{Isometry3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::Vns;
use super::tracking::Attempt;
use crate::math::so3;
use crate::vision::homography::PlaneMotion;
use crate::vision::iavns::activation::{
    Activation, ActivationConfig, ActivationError, Adjustment, AdjustmentErrors, AdjustmentMode,
};
use crate::vision::iavns::prior::{
    AttitudePrior, JointStart, PriorConfig, VisualBodyPose, target_q_ec, target_q_ec_slerp,
};
use crate::vision::pose_opt::optimize_pose;

/// Which of the IA-VNS's changes to SVO are switched on (each alone for the ablation), and
/// their settings.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AidingConfig {
    /// The inertial priors in the pose optimisation (stage 1, activation, joint optimisation).
    pub priors: bool,
    /// The INS motion since the previous frame gives the initial pose `ζ*`, replacing sparse
    /// image alignment (which remains the fallback when `ζ*` does not track).
    pub inertial_prediction: bool,
    /// The current frame's observations join structure optimisation.
    pub current_features_in_structure: bool,
    /// The two-view initialisation triangulates the homography's inliers with the INS relative
    /// pose between its two images (rotation and integrated-velocity translation), which fixes
    /// its scale and path angle, instead of the plane distance from the height over the
    /// terrain.
    pub inertial_initialisation: bool,
    /// The PI-inspired activation (the paper's settings table).
    pub activation: ActivationConfig,
    /// The prior-based pose optimisation.
    pub prior: PriorConfig,
}

impl AidingConfig {
    /// The paper's IA-VNS: every change on, the paper's activation settings (pitch and bank).
    pub fn paper() -> Self {
        Self {
            priors: true,
            inertial_prediction: true,
            current_features_in_structure: true,
            inertial_initialisation: true,
            ..Self::default()
        }
    }

    /// Whether any change needs the INS at each frame.
    pub fn needs_ins(&self) -> bool {
        self.priors || self.inertial_prediction || self.inertial_initialisation
    }

    /// Whether any change is switched on (otherwise the VNS).
    pub fn any(&self) -> bool {
        self.needs_ins() || self.current_features_in_structure
    }
}

/// The INS at a frame's exposure, as the IA-VNS reads it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InertialFrame {
    /// The frame's exposure time, µs.
    pub t_us: u64,
    /// The INS body pose (body → Earth).
    pub zeta_eb: Isometry3<f64>,
    /// The INS ground velocity, Earth axes, m/s. Motions between frames are integrated from
    /// it: while GNSS is available the INS position follows each fix's noise (metres), its
    /// velocity does not.
    pub v_e_mps: nalgebra::Vector3<f64>,
    /// The INS body attitude `q_nb`.
    pub q_nb: UnitQuaternion<f64>,
    /// The INS altitude above the ellipsoid, m.
    pub h_m: f64,
    /// The estimated camera mounting (camera → body).
    pub zeta_bc: Isometry3<f64>,
}

/// Counters of the IA-VNS's steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AidingCounters {
    /// Frames started from the inertial prediction `ζ*`.
    pub inertial_starts: u64,
    /// Frames whose inertial start did not track, tracked (or lost) from sparse alignment.
    pub inertial_start_failures: u64,
    /// Frames on which the activation ran.
    pub activations_evaluated: u64,
    /// Frames with an active prior (the joint optimisation ran).
    pub priors_active: u64,
    /// Active frames whose joint optimisation failed or lost the quality test; the
    /// reprojection-only pose was kept.
    pub joint_failures: u64,
    /// Frames whose adjustment errors were rejected (not finite, time not increasing).
    pub activation_rejections: u64,
}

/// The IA-VNS's state between frames.
#[derive(Debug, Clone)]
pub(super) struct AidingState {
    pub(super) activation: Activation,
    /// The INS at the last tracked frame (the inertial prediction's origin).
    pub(super) last_ins: Option<InertialFrame>,
    pub(super) counters: AidingCounters,
    /// The latest adjustment (for logs and outputs).
    pub(super) last_adjustment: Option<Adjustment>,
}

impl AidingState {
    pub(super) fn new(cfg: &AidingConfig) -> Result<Self, ActivationError> {
        Ok(Self {
            activation: Activation::new(cfg.activation)?,
            last_ins: None,
            counters: AidingCounters::default(),
            last_adjustment: None,
        })
    }
}

/// The INS displacement from `from` to `to`, Earth axes, m: the trapezoidal integral of its
/// ground velocity (`None` for a time that does not increase or a non-finite velocity).
pub(super) fn inertial_displacement_e(
    from: &InertialFrame,
    to: &InertialFrame,
) -> Option<nalgebra::Vector3<f64>> {
    let dt_s = to.t_us.checked_sub(from.t_us)? as f64 * 1e-6;
    let d = (from.v_e_mps + to.v_e_mps) * (0.5 * dt_s);
    (dt_s > 0.0 && d.iter().all(|x| x.is_finite())).then_some(d)
}

/// The INS body motion from `from` to `to` in `from`'s body axes: the rotation between the
/// two attitudes and the integrated velocity ([`inertial_displacement_e`]).
pub(super) fn inertial_motion_b(
    from: &InertialFrame,
    to: &InertialFrame,
) -> Option<Isometry3<f64>> {
    let d_e = inertial_displacement_e(from, to)?;
    let to_e = Isometry3::from_parts(
        nalgebra::Translation3::from(from.zeta_eb.translation.vector + d_e),
        to.zeta_eb.rotation,
    );
    Some(from.zeta_eb.inverse() * to_e)
}

/// The two-view motion of the IA-VNS's initialisation: the INS camera rotation between the two
/// images (`zeta_ec1`'s and `q_ec2`) and the INS camera displacement `t_ins_e` (Earth axes, m)
/// as a plane motion at unit plane distance (`t/d = t`), so that triangulating at height 1
/// gives the metric map; the homography's plane normal is kept. The homography's own rotation
/// is not used: for a nadir camera it trades against the translation (a pitch error of 0.07°
/// is 2.7 % of depth at the initialisation's 0.045-rad parallax). `None` for a displacement
/// that is not finite or zero.
pub(super) fn inertial_motion(
    homography: &PlaneMotion,
    zeta_ec1: &Isometry3<f64>,
    q_ec2: &UnitQuaternion<f64>,
    t_ins_e: &nalgebra::Vector3<f64>,
) -> Option<PlaneMotion> {
    let norm = t_ins_e.norm();
    if !(norm.is_finite() && norm > 0.0) {
        return None;
    }
    let q_c2c1 = q_ec2.inverse() * zeta_ec1.rotation;
    // p_c2 = R p_c1 + t with the second camera's centre at c = R_ec1ᵀ T in C1: t = −R c.
    let centre_c1 = zeta_ec1.rotation.inverse() * t_ins_e;
    Some(PlaneMotion {
        q_c2c1,
        t_c2c1_c2_over_d: -(q_c2c1 * centre_c1),
        ..*homography
    })
}

/// `a − b` wrapped to (−π, π].
fn angle_difference(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    if d > std::f64::consts::PI {
        d - std::f64::consts::TAU
    } else {
        d
    }
}

impl Vns {
    /// `ζ*`: the previous visual camera pose moved on by the INS body motion since the
    /// previous tracked frame, `ζ*_ec = ζ°_eb,i−1 ∘ Δζ̂_b ∘ ζ_bc` ([`inertial_motion_b`]).
    pub(super) fn inertial_prediction(
        &self,
        last_zeta_ec: &Isometry3<f64>,
        ins: &InertialFrame,
    ) -> Option<Isometry3<f64>> {
        if !self.cfg.aiding.inertial_prediction {
            return None;
        }
        let previous = self.aiding.as_ref()?.last_ins?;
        let motion_b = inertial_motion_b(&previous, ins)?;
        let visual_eb = last_zeta_ec * ins.zeta_bc.inverse();
        Some(crate::math::se3::renormalized(
            &(visual_eb * motion_b * ins.zeta_bc),
        ))
    }

    /// Stage 1's body pose, the activation and, when active, the joint optimisation of an
    /// attempt that tracked; the attempt is replaced by the joint solution when that passes
    /// the same quality test.
    pub(super) fn apply_priors(&mut self, t_us: u64, attempt: &mut Attempt, ins: &InertialFrame) {
        if !self.cfg.aiding.priors {
            return;
        }
        let Some(state) = self.aiding.as_mut() else {
            return;
        };
        let body = VisualBodyPose::from_camera(&attempt.zeta_ec, &ins.zeta_bc);
        let ins_euler = so3::euler_zyx(&ins.q_nb);
        let errors = AdjustmentErrors {
            dh_m: body.h_m() - ins.h_m,
            dtheta_rad: body.euler_rad[1] - ins_euler[1],
            dbank_rad: angle_difference(body.euler_rad[2], ins_euler[2]),
            dphi_rad: so3::log(&(body.q_nb.inverse() * ins.q_nb)).norm(),
        };
        state.counters.activations_evaluated += 1;
        let adjustment = match state.activation.update(t_us, &errors) {
            Ok(a) => a,
            Err(_) => {
                state.counters.activation_rejections += 1;
                return;
            }
        };
        state.last_adjustment = Some(adjustment);
        if !adjustment.is_active() {
            return;
        }
        state.counters.priors_active += 1;
        let target = match self.cfg.aiding.activation.mode {
            AdjustmentMode::Slerp => target_q_ec_slerp(
                &body,
                &ins.q_nb,
                adjustment.slerp_rad,
                adjustment.pitch_rad,
                &ins.zeta_bc.rotation,
            ),
            AdjustmentMode::Pitch | AdjustmentMode::PitchBank => target_q_ec(
                &body,
                adjustment.pitch_rad,
                adjustment.bank_rad,
                &ins.zeta_bc.rotation,
            ),
        };
        let prior_cfg = self.cfg.aiding.prior;
        let joint = AttitudePrior::at_initial_pose(
            &self.camera,
            &attempt.start,
            &attempt.observations,
            &target,
            &prior_cfg,
        )
        .and_then(|prior| {
            let from = match prior_cfg.joint_start {
                JointStart::InitialPose => attempt.start,
                JointStart::ReprojectionOnly => attempt.zeta_ec,
            };
            optimize_pose(
                &self.camera,
                &from,
                &attempt.observations,
                &self.cfg.pose,
                Some(&prior),
            )
            .ok()
        });
        let accepted = joint.and_then(|opt| {
            let inliers: Vec<_> = attempt
                .matches
                .iter()
                .zip(&opt.inliers)
                .filter(|(_, ok)| **ok)
                .map(|(m, _)| *m)
                .collect();
            (inliers.len() >= self.cfg.min_matches).then_some((opt, inliers))
        });
        match accepted {
            Some((opt, inliers)) => {
                attempt.zeta_ec = opt.zeta_ec;
                attempt.inliers = inliers;
                attempt.rms_px = opt.inlier_rms_px;
            }
            None => {
                if let Some(s) = self.aiding.as_mut() {
                    s.counters.joint_failures += 1;
                }
            }
        }
    }

    /// Remember the INS pose of a tracked frame (the next prediction's origin).
    pub(super) fn remember_ins(&mut self, ins: Option<&InertialFrame>) {
        if let Some(state) = self.aiding.as_mut() {
            state.last_ins = ins.copied();
        }
    }

    /// Counters of the IA-VNS's steps (`None` for the plain VNS).
    pub fn aiding_counters(&self) -> Option<&AidingCounters> {
        self.aiding.as_ref().map(|s| &s.counters)
    }

    /// The latest activation output (`None` before the first, or for the plain VNS).
    pub fn last_adjustment(&self) -> Option<&Adjustment> {
        self.aiding
            .as_ref()
            .and_then(|s| s.last_adjustment.as_ref())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::wgs84;
    use crate::vision::test_scene::Ground;
    use crate::vision::vns::tests::{pose_at, small_vns, start_at, zeta_ew};
    use crate::vision::vns::{VnsConfig, VnsOutput, VnsStart, VnsState};

    /// The INS at scene frame `k`: the true body pose (the camera is the body here,
    /// `zeta_bc` = identity) with its altitude moved by `dh_m`.
    fn ins_at(k: u64, dh_m: f64) -> InertialFrame {
        let zeta_eb = zeta_ew() * pose_at(k);
        let pos = wgs84::ecef_to_geodetic(&zeta_eb.translation.vector);
        // The scene flies 30 m/s along x and 1.5 m/s along y of the local level frame.
        let v_e_mps = zeta_ew().rotation * nalgebra::Vector3::new(30.0, 1.5, 0.0);
        InertialFrame {
            t_us: 1_000_000 + k * 100_000,
            zeta_eb,
            v_e_mps,
            q_nb: wgs84::q_en(pos.lat_rad, pos.lon_rad).inverse() * zeta_eb.rotation,
            h_m: pos.h_m + dh_m,
            zeta_bc: Isometry3::identity(),
        }
    }

    /// Fly `frames` frames of the straight scene flight with `aiding`, the INS `dh_m` off in
    /// altitude; every output and the VNS.
    fn fly(aiding: AidingConfig, frames: u64, dh_m: f64) -> (Vec<VnsOutput>, Vns) {
        fly_from(aiding, frames, dh_m, 1_000.0)
    }

    /// [`fly`] with the height over the terrain in `x̊₀` given (the truth is 1,000 m).
    fn fly_from(
        aiding: AidingConfig,
        frames: u64,
        dh_m: f64,
        h_agl_m: f64,
    ) -> (Vec<VnsOutput>, Vns) {
        let (cam, vns) = small_vns();
        let cfg = VnsConfig {
            aiding,
            ..vns.config().clone()
        };
        let mut vns = Vns::new(cam, cfg, 7).unwrap();
        let ground = Ground {
            seed: 11,
            ground_z_m: 0.0,
        };
        let zeta_ew = zeta_ew();
        let mut outputs = Vec::new();
        for k in 0..frames {
            let pose_w = pose_at(k);
            let frame = ground.frame(&cam, &pose_w, 1_000_000 + k * 100_000);
            let ins = ins_at(k, dh_m);
            let start = VnsStart {
                h_agl_m,
                ..start_at(&zeta_ew, &pose_w)
            };
            let out = vns.process(&frame, Some(&start), Some(&ins)).unwrap();
            outputs.extend(out);
        }
        (outputs, vns)
    }

    /// With every change switched off the IA-VNS is the VNS, bit for bit, whatever its
    /// activation settings and whether or not it is handed the INS.
    #[test]
    fn with_every_change_off_the_iavns_is_the_vns_bit_for_bit() {
        let off = AidingConfig {
            activation: crate::vision::iavns::activation::ActivationConfig {
                dh_low_m: 1.0,
                ..Default::default()
            },
            ..AidingConfig::default()
        };
        let (aided, _) = fly(off, 60, 100.0);
        let (cam, mut vns) = small_vns();
        let ground = Ground {
            seed: 11,
            ground_z_m: 0.0,
        };
        let plain: Vec<VnsOutput> = (0..60)
            .filter_map(|k| {
                let pose_w = pose_at(k);
                let frame = ground.frame(&cam, &pose_w, 1_000_000 + k * 100_000);
                vns.process(&frame, Some(&start_at(&zeta_ew(), &pose_w)), None)
                    .unwrap()
            })
            .collect();
        assert!(plain.len() > 30);
        // Debug text: the first output's RMS is NaN, which `==` never equals.
        assert_eq!(format!("{aided:?}"), format!("{plain:?}"));
    }

    /// The paper's IA-VNS on an exact INS: every frame after the initialisation starts from
    /// the inertial prediction and tracks from it, the activation stays inside its dead bands
    /// (the visual errors are centimetres and millidegrees), and the pose follows the truth as
    /// the VNS's does (1 % of the distance plus 2 m, 0.1°).
    #[test]
    fn the_iavns_on_an_exact_ins_tracks_from_the_inertial_prediction() {
        let (outputs, vns) = fly(AidingConfig::paper(), 120, 0.0);
        let c = *vns.aiding_counters().unwrap();
        let tracked = outputs
            .iter()
            .filter(|o| o.state == VnsState::Tracking)
            .count() as u64;
        assert!(tracked > 80, "{tracked}");
        // ζ* is the truth moved by the visual pose's own error: it may miss the quality test
        // now and then (a keyframe's inlier drop), never often.
        assert!(
            c.inertial_start_failures * 20 <= c.inertial_starts,
            "{c:?} for {tracked} tracked"
        );
        // Every tracked frame but the initialisation's.
        assert_eq!(c.inertial_starts + 1, tracked, "{c:?}");
        assert_eq!(c.activations_evaluated + 1, tracked, "{c:?}");
        assert_eq!(c.priors_active, 0, "{c:?}");
        for o in &outputs {
            let k = (o.t_us - 1_000_000) / 100_000;
            let truth = zeta_ew() * pose_at(k);
            let travelled = 30.0_f64.hypot(1.5) * k as f64 * 0.1;
            let err_m = (o.zeta_ec.translation.vector - truth.translation.vector).norm();
            let err_deg = o.zeta_ec.rotation.angle_to(&truth.rotation).to_degrees();
            assert!(
                err_m < 0.01 * travelled + 2.0 && err_deg < 0.1,
                "frame {k}: {err_m} m, {err_deg}°"
            );
        }
    }

    /// An INS 60 m below the visual altitude (beyond twice the 25-m dead band) saturates the
    /// altitude term: each image's target pitch is 0.0005° below the visual one, and the joint
    /// optimisation runs on every tracked frame without failing. Against the same flight with
    /// the INS 60 m above (the opposite adjustment), the visual pitch ends lower: a nose-down
    /// correction of a visual altitude that is too high. Only part of each image's adjustment
    /// survives the next frame's reprojection against the map (measured: ≈ 5 % here, 160
    /// frames), so the bound asks for 1 % of the most the adjustments could add up to.
    #[test]
    fn a_visual_altitude_too_high_pitches_the_iavns_down() {
        let priors = AidingConfig {
            priors: true,
            current_features_in_structure: true,
            ..AidingConfig::default()
        };
        let frames = 160;
        let (high, vns) = fly(priors, frames, -60.0);
        let (low, vns_low) = fly(priors, frames, 60.0);
        let c = *vns.aiding_counters().unwrap();
        assert!(c.priors_active > 100, "{c:?}");
        assert_eq!(c.joint_failures, 0, "{c:?}");
        let limit = 0.0005_f64.to_radians();
        let a = vns.last_adjustment().unwrap();
        assert!((a.altitude_term_rad + limit).abs() < 1e-15, "{a:?}");
        let a = vns_low.last_adjustment().unwrap();
        assert!((a.altitude_term_rad - limit).abs() < 1e-15, "{a:?}");
        let pitch = |o: &VnsOutput| {
            let pos = wgs84::ecef_to_geodetic(&o.zeta_ec.translation.vector);
            let q_nb = wgs84::q_en(pos.lat_rad, pos.lon_rad).inverse() * o.zeta_ec.rotation;
            so3::euler_zyx(&q_nb)[1]
        };
        let (last_high, last_low) = (high.last().unwrap(), low.last().unwrap());
        assert_eq!(last_high.t_us, last_low.t_us);
        let dpitch_deg = (pitch(last_high) - pitch(last_low)).to_degrees();
        let most = 2.0 * 0.0005 * c.priors_active as f64;
        eprintln!("pitch {dpitch_deg}° apart, at most {most}°");
        assert!(
            dpitch_deg < -0.01 * most && dpitch_deg > -1.5 * most,
            "pitch {dpitch_deg}° apart over {} active images",
            c.priors_active
        );
    }

    /// A height over the terrain 20 % high scales the VNS's whole reconstruction, and so its
    /// distance flown, by 1.2 (≈ 20 % of the distance in position error); the IA-VNS takes the
    /// scale from the INS distance between the two initialisation images and keeps the VNS
    /// test's tolerance (1 % of the distance plus 2 m). The path angle is the INS's too.
    #[test]
    fn the_inertial_initialisation_takes_the_scale_from_the_ins_distance() {
        let only_init = AidingConfig {
            inertial_initialisation: true,
            ..AidingConfig::default()
        };
        let frames = 80;
        let error_at_end = |aiding| {
            let (outputs, _) = fly_from(aiding, frames, 0.0, 1_200.0);
            let o = outputs.last().unwrap();
            let k = (o.t_us - 1_000_000) / 100_000;
            let truth = zeta_ew() * pose_at(k);
            let travelled = (pose_at(k).translation.vector - pose_at(0).translation.vector).norm();
            let err_m = (o.zeta_ec.translation.vector - truth.translation.vector).norm();
            (err_m, travelled)
        };
        let (vns_m, travelled) = error_at_end(AidingConfig::default());
        let (iavns_m, _) = error_at_end(only_init);
        eprintln!("after {travelled:.0} m: VNS {vns_m:.1} m, IA-VNS {iavns_m:.1} m");
        assert!(vns_m > 0.1 * travelled, "VNS {vns_m} m after {travelled} m");
        assert!(
            iavns_m < 0.01 * travelled + 2.0,
            "IA-VNS {iavns_m} m after {travelled} m"
        );
    }

    /// The INS motion between two frames comes from the integrated velocity, not from the
    /// positions: a position that jumps by metres at a GNSS fix (here 3 m between the two
    /// frames) leaves it unchanged.
    #[test]
    fn the_inertial_motion_integrates_the_velocity_not_the_position_jumps() {
        let a = ins_at(10, 0.0);
        let mut b = ins_at(11, 0.0);
        b.zeta_eb.translation.vector += nalgebra::Vector3::new(3.0, 0.0, 0.0);
        b.v_e_mps = a.v_e_mps * 1.1;
        let m = inertial_motion_b(&a, &b).unwrap();
        let expected_e = (a.v_e_mps + b.v_e_mps) * 0.05;
        let got_e = a.zeta_eb.rotation * m.translation.vector;
        // ECEF coordinates of 6e6 m carry ~1e-9 m of rounding each.
        assert!((got_e - expected_e).amax() < 1e-6, "{got_e:?}");
        assert!(
            m.rotation
                .angle_to(&(a.zeta_eb.rotation.inverse() * b.zeta_eb.rotation))
                < 1e-12
        );
        assert!(inertial_motion_b(&b, &a).is_none(), "time must increase");
    }

    /// The initialisation's motion: the INS rotation between the two cameras and the INS
    /// displacement seen from the second camera (`p_c2 = R p_c1 + t`: the second camera's
    /// centre maps to the origin); the homography's normal is kept.
    #[test]
    fn the_inertial_motion_is_the_ins_relative_pose() {
        let homography = PlaneMotion {
            q_c2c1: UnitQuaternion::from_euler_angles(0.01, -0.02, 0.03),
            t_c2c1_c2_over_d: nalgebra::Vector3::new(0.05, 0.0, 0.001),
            n_c1: nalgebra::Unit::new_normalize(nalgebra::Vector3::new(0.01, 0.0, 1.0)),
        };
        let zeta_ec1 = zeta_ew() * pose_at(3);
        let t_ins_e = zeta_ew().rotation * nalgebra::Vector3::new(45.0, 2.0, -0.5);
        let q_ec2 = zeta_ec1.rotation * UnitQuaternion::from_euler_angles(0.002, 0.001, -0.003);
        let m = inertial_motion(&homography, &zeta_ec1, &q_ec2, &t_ins_e).unwrap();
        assert!(m.q_c2c1.angle_to(&(q_ec2.inverse() * zeta_ec1.rotation)) < 1e-15);
        assert_eq!(m.n_c1, homography.n_c1);
        let zeta_c2c1 = m.zeta_c2c1(1.0);
        let centre_c1 = zeta_ec1.rotation.inverse() * t_ins_e;
        let mapped = zeta_c2c1 * nalgebra::Point3::from(centre_c1);
        assert!(mapped.coords.norm() < 1e-12, "{mapped:?}");
        assert!((zeta_c2c1.translation.vector.norm() - t_ins_e.norm()).abs() < 1e-12);
        assert!(
            inertial_motion(&homography, &zeta_ec1, &q_ec2, &nalgebra::Vector3::zeros()).is_none()
        );
    }

    #[test]
    fn bank_differences_wrap_across_pi() {
        let pi = std::f64::consts::PI;
        assert!((angle_difference(pi - 0.01, -pi + 0.01) + 0.02).abs() < 1e-12);
        assert!((angle_difference(-pi + 0.01, pi - 0.01) - 0.02).abs() < 1e-12);
        assert!((angle_difference(0.3, 0.1) - 0.2).abs() < 1e-15);
    }
}
