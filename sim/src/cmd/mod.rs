//! The `ianav-sim` commands, one module each, and what several of them share: the flight
//! setup built from the scenario options and the files of `--config-dir`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use ianav_sim::flight::{FlightSetup, NavigationMode};

use crate::{Navigation, SetupArgs};

pub(crate) mod bench;
pub(crate) mod mc;
pub(crate) mod render;
pub(crate) mod report;
pub(crate) mod run;
pub(crate) mod sitl;

fn read_optional(dir: Option<&PathBuf>, name: &str) -> Result<Option<(PathBuf, String)>> {
    let Some(dir) = dir else { return Ok(None) };
    let path = dir.join(name);
    if !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    Ok(Some((path, text)))
}

pub(crate) fn setup(args: &SetupArgs) -> Result<FlightSetup> {
    let mut setup = FlightSetup::builtin(args.scenario)?;
    let dir = args.config_dir.as_ref();
    // Each file in it is optional, so a mistyped directory would silently fly the defaults.
    if let Some(d) = dir {
        let meta = std::fs::metadata(d).with_context(|| format!("--config-dir {}", d.display()))?;
        if !meta.is_dir() {
            bail!("--config-dir {}: not a directory", d.display());
        }
    }
    if let Some((path, text)) =
        read_optional(dir, &format!("scenarios/scenario{}.toml", args.scenario))?
    {
        setup.scenario = ianav_sim::scenario::ScenarioConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "ins.toml")? {
        setup.ins = ianav::ins::InsConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "vision.toml")? {
        // The keys of the navigation settings' `[vision]` table (docs/VNS.md "Settings").
        setup.vision = toml::from_str::<ianav::vision::vns::VnsConfig>(&text)
            .with_context(|| path.display().to_string())?;
        setup
            .vision
            .validate()
            .with_context(|| path.display().to_string())?;
    }
    setup.vision_systems = args.vision_systems.clone();
    setup.navigation = match args.navigation {
        Navigation::Truth => NavigationMode::Truth,
        Navigation::Ins => NavigationMode::Ins,
    };
    if let Some((path, text)) = read_optional(dir, "aircraft.toml")? {
        setup.aircraft = ianav_sim::aircraft::AircraftParams::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "sensors.toml")? {
        setup.sensors = ianav_sim::sensors::SensorsConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some((path, text)) = read_optional(dir, "control.toml")? {
        setup.control = ianav_sim::control::ControlConfig::from_toml_str(&text)
            .with_context(|| path.display().to_string())?;
    }
    if let Some(duration) = args.duration {
        if !(duration.is_finite() && duration > 0.0) {
            bail!("--duration must be a positive number of seconds, got {duration}");
        }
        setup.scenario.duration_s = duration;
    }
    if let Some(factor) = args.turbulence {
        if !(factor.is_finite() && factor >= 0.0) {
            bail!("--turbulence must be a non-negative factor, got {factor}");
        }
        setup.scenario.turbulence_factor = factor;
    }
    if let Some(name) = &args.terrain {
        let zone: ianav_sim::terrain::Zone = name.parse()?;
        let start = zone.start();
        setup.scenario.start.lat_deg = start.lat_deg;
        setup.scenario.start.lon_deg = start.lon_deg;
        let terrain = ianav_sim::terrain::Terrain::new(zone, args.terrain_seed);
        let mut camera = ianav_sim::flight::CameraSetup::new(std::sync::Arc::new(terrain));
        if let Some((path, text)) = read_optional(dir, "camera.toml")? {
            // A relative `calibration_file` is the config directory's.
            let settings =
                ianav::vision::camera::CameraSettings::from_toml_str_in(&text, path.parent())
                    .with_context(|| path.display().to_string())?;
            camera.camera = settings.camera;
            camera.mounting = settings.mounting;
        }
        setup.camera = Some(camera);
    } else if let Some((path, _)) = read_optional(dir, "camera.toml")? {
        eprintln!(
            "note: {} is read only with --terrain (no camera on this flight)",
            path.display()
        );
    }
    setup.scenario.validate()?;
    Ok(setup)
}
