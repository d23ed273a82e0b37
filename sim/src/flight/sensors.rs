//! Sensor sampling of a flight in progress: the IMU, air-data, magnetometer and GNSS samples
//! taken from the truth and fed to the navigator in the order it consumes them, the start
//! alignment offered at the first fix (docs/REFERENCES.md A1.9), the camera frames rendered
//! from the true camera pose, and the estimate guidance and control fly on.

use ianav::math::{so3, wgs84};
use ianav::nav::NavSolution;
use ianav::sensors::{Alignment, Frame, HeightAboveTerrain, SensorErrorPriors, SensorEvent};
use nalgebra::Vector3;

use super::{Flight, FlightCamera, FlightError, FlightObserver, PositionAid};
use crate::aircraft::{Controls, Loads};
use crate::control::{NavEstimate, Navigation, TruthNavigation};
use crate::rng;
use crate::sensors::SensorTruth;
use crate::terrain::render::RenderError;

/// The estimate guidance and control need, from a navigation solution (rates and air data
/// from its INS detail).
pub(crate) fn estimate_from_nav(sol: &NavSolution) -> NavEstimate {
    NavEstimate {
        t_us: sol.t_us,
        pos: sol.pos,
        v_ned_mps: sol.v_ned_mps,
        q_nb: sol.q_nb,
        w_nb_b_rps: sol.ins.w_nb_b_rps,
        tas_mps: sol.ins.tas_mps,
        aoa_rad: sol.ins.aoa_rad,
        aos_rad: sol.ins.aos_rad,
        hp_m: sol.ins.hp_m,
    }
}

/// Replace the horizontal position of `estimate` (at `t_us`) by `aid`, carried from its time
/// of validity to `t_us` with the estimate's ground velocity on the ellipsoid's radii.
fn apply_position_aid(estimate: &mut NavEstimate, aid: &PositionAid, t_us: u64) {
    let dt_s = (t_us as f64 - aid.t_us as f64) * 1e-6;
    let h_m = estimate.pos.h_m;
    let v = estimate.v_ned_mps;
    let lat_rad = aid.lat_rad + v.x * dt_s / (wgs84::radius_meridian_m(aid.lat_rad) + h_m);
    let lon_rad = aid.lon_rad
        + v.y * dt_s / ((wgs84::radius_prime_vertical_m(aid.lat_rad) + h_m) * aid.lat_rad.cos());
    estimate.pos.lat_rad = lat_rad;
    estimate.pos.lon_rad = lon_rad;
}

impl Flight {
    /// The height of the body over the terrain below it, with the flight's drawn error.
    pub(super) fn height_above_terrain(&self, cam: &FlightCamera) -> HeightAboveTerrain {
        let ground_m = cam.terrain.height_m(self.x.pos.lat_rad, self.x.pos.lon_rad);
        HeightAboveTerrain {
            t_us: self.t_us(),
            h_agl_m: self.x.pos.h_m - ground_m + cam.h_agl_error_m,
            sigma_m: cam.h_agl_sigma_m,
        }
    }

    /// The frame seen now from the true camera pose.
    pub(super) fn render_frame(&self, cam: &FlightCamera, k: u64) -> Result<Frame, FlightError> {
        let cg = self.aircraft.cg_from_reference_b_m(self.x.mass_kg);
        let zeta_ec = cam.mounting.truth.zeta_ec(&self.x.pos, &self.x.q_nb, &cg);
        let mut renderer = cam.renderer.clone();
        renderer.set_noise_seed(cam.noise_seed ^ k);
        let img = renderer
            .render(&cam.terrain, &zeta_ec)
            .map_err(|e: RenderError| FlightError::Departed {
                t_s: self.mission_time_s(),
                reason: format!("camera: {e}"),
            })?;
        Ok(Frame {
            t_us: self.t_us(),
            width: img.width,
            height: img.height,
            pixels: img.pixels.into(),
        })
    }

    pub(super) fn sample_sensors(
        &mut self,
        controls: &Controls,
        observer: &mut impl FlightObserver,
    ) -> Result<(), FlightError> {
        let t_us = self.t_us();
        let loads: Loads = self.aircraft.loads(&self.x, controls, &self.air);
        let v_ned_mps = self.x.q_nb * self.x.v_b_mps;
        if let Ok(model_ned_nt) = self.magnetic_grid.field_ned_nt(&self.x.pos) {
            self.mag_ned_nt = model_ned_nt + self.magnetic.error_ned_nt;
        }
        let mag_ned_nt = self.mag_ned_nt;
        let truth = SensorTruth {
            t_us,
            pos: self.x.pos,
            v_ned_mps,
            q_nb: self.x.q_nb,
            w_ib_b_rps: self.x.w_ib_b_rps,
            w_dot_ib_b_rps2: loads.w_dot_ib_b_rps2,
            f_ib_b_mps2: loads.f_ib_b_mps2,
            cg_from_ref_b_m: self.aircraft.cg_from_reference_b_m(self.x.mass_kg),
            mag_ned_nt,
            tas_mps: loads.air.tas_mps,
            aoa_rad: loads.air.aoa_rad,
            aos_rad: loads.air.aos_rad,
            p_pa: self.air.p_pa,
            temp_k: self.air.temp_k,
        };
        let k = self.step_index;
        // Aiding samples first, then the IMU sample on which the INS steps, so that samples
        // taken at the same instant are fused in the same INS step.
        let mut events = std::mem::take(&mut self.pending_events);
        events.clear();
        if k.is_multiple_of(self.steps_per_air) {
            events.push(SensorEvent::Air(self.sensors.sample_air(&truth)));
        }
        if k.is_multiple_of(self.steps_per_mag) {
            events.push(SensorEvent::Mag(self.sensors.sample_mag(&truth)));
        }
        let fix_now = k.is_multiple_of(self.steps_per_gnss) && t_us <= self.gnss_loss_us;
        let w_in_n =
            wgs84::omega_ie_n(self.x.pos.lat_rad) + wgs84::omega_en_n(&self.x.pos, &v_ned_mps);
        let truth_estimate =
            TruthNavigation::from_truth(t_us, &self.x, &loads.air, &w_in_n, self.hp_m).estimate();
        if fix_now {
            events.push(SensorEvent::Gnss(self.sensors.sample_gnss(&truth)));
        }
        if k.is_multiple_of(self.steps_per_sensor) {
            events.push(SensorEvent::Imu(self.sensors.sample_imu(&truth)));
        }
        // The navigator starts the INS at the first GNSS fix (as the authors' filters do) from
        // the start alignment offered just before it; guidance flies on the truth until then
        // (the first second). Drawn after the IMU sample: the true sensor errors it is drawn
        // about are those of this instant's samples.
        if fix_now && self.nav.as_ref().is_some_and(|n| !n.is_initialised()) {
            let alignment = self.start_alignment(&truth_estimate);
            let at = events
                .iter()
                .position(|e| matches!(e, SensorEvent::Gnss(_)))
                .unwrap_or(events.len());
            events.insert(at, SensorEvent::Alignment(Box::new(alignment)));
        }
        self.sensor_events += events
            .iter()
            .filter(|e| !matches!(e, SensorEvent::Alignment(_)))
            .count() as u64;
        for event in &events {
            observer.sensor_event(event);
            if let Some(solution) = self.nav.as_mut().and_then(|nav| nav.push(event)) {
                self.nav_solution = Some(solution);
            }
        }
        self.pending_events = events;
        self.estimate = match &self.nav_solution {
            Some(sol) => estimate_from_nav(sol),
            None => truth_estimate,
        };
        self.position_aid_used = false;
        if let (Some((aid, max_age_us)), Some(_)) = (self.position_aid, &self.nav_solution)
            && t_us.abs_diff(aid.t_us) <= max_age_us
        {
            apply_position_aid(&mut self.estimate, &aid, t_us);
            self.position_aid_used = true;
        }
        Ok(())
    }

    /// The start alignment the simulated vehicle offers at the first fix, with the initial
    /// errors of docs/REFERENCES.md A1.9: attitude off by 0.1°·N about a random axis,
    /// sensor-error estimates within 1 % (10 % for the magnetic-model error) of the truth.
    fn start_alignment(&mut self, truth: &NavEstimate) -> Alignment {
        let r = &mut self.ins_init_rng;
        let axis = Vector3::new(rng::normal(r), rng::normal(r), rng::normal(r));
        let angle_rad = (0.1_f64).to_radians() * rng::normal(r);
        let q_err = so3::exp(&(axis.try_normalize(1e-12).unwrap_or(Vector3::x()) * angle_rad));
        let errors = self.sensors.true_errors();
        let mut scaled = |v: Vector3<f64>, rel: f64| -> (Vector3<f64>, Vector3<f64>) {
            (
                v.map(|x| x * (1.0 + rel * rng::normal(r))),
                v.map(|x| (rel * x).abs()),
            )
        };
        let (e_gyr_rps, e_gyr_sigma_rps) = scaled(errors.e_gyr_rps, 0.01);
        let (e_acc_mps2, e_acc_sigma_mps2) = scaled(errors.e_acc_mps2, 0.01);
        let (e_mag_nt, e_mag_sigma_nt) = scaled(errors.e_mag_nt, 0.01);
        let (delta_b_n_nt, delta_b_n_sigma_nt) = scaled(-self.magnetic.error_ned_nt, 0.1);
        Alignment {
            t_us: truth.t_us,
            q_nb: q_err * truth.q_nb,
            aoa_rad: truth.aoa_rad,
            priors: SensorErrorPriors {
                e_gyr_rps,
                e_gyr_sigma_rps,
                e_acc_mps2,
                e_acc_sigma_mps2,
                e_mag_nt,
                e_mag_sigma_nt,
                delta_b_n_nt,
                delta_b_n_sigma_nt,
            },
        }
    }
}
