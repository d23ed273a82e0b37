//! `ianav-sim render`: one camera image of a procedural terrain zone, from a given pose (paper
//! section "Influence of Terrain Type"; docs/TERRAIN.md).

use std::time::Instant;

use anyhow::{Context, Result, bail};

use crate::RenderArgs;

pub(crate) fn render(args: &RenderArgs) -> Result<()> {
    use ianav::math::{so3, wgs84::Geodetic};
    use ianav::vision::camera::{Camera, MountingConfig};
    use ianav_sim::terrain::{Terrain, Zone, render::Renderer};
    let zone: Zone = args.terrain.parse()?;
    let terrain = Terrain::new(zone, args.terrain_seed);
    let start = zone.start();
    let lat_deg = args.lat.unwrap_or(start.lat_deg);
    let lon_deg = args.lon.unwrap_or(start.lon_deg);
    for (name, v) in [
        ("--lat", lat_deg),
        ("--lon", lon_deg),
        ("--yaw", args.yaw),
        ("--pitch", args.pitch),
        ("--bank", args.bank),
    ] {
        if !v.is_finite() {
            bail!("{name} must be a finite number, got {v}");
        }
    }
    if !(-90.0..=90.0).contains(&lat_deg) {
        bail!("--lat must be within ±90°, got {lat_deg}");
    }
    let (lat_rad, lon_rad) = (lat_deg.to_radians(), lon_deg.to_radians());
    let h_m = match args.h {
        Some(h) => h,
        None => terrain.height_m(lat_rad, lon_rad) + 2_700.0,
    };
    let pos = Geodetic {
        lat_rad,
        lon_rad,
        h_m,
    };
    let q_nb = so3::from_euler_zyx(
        args.yaw.to_radians(),
        args.pitch.to_radians(),
        args.bank.to_radians(),
    );
    let mounting = MountingConfig::default().nominal();
    let zeta_ec = mounting.zeta_ec(&pos, &q_nb, &nalgebra::Vector3::zeros());
    let renderer = Renderer::new(Camera::paper());
    let started = Instant::now();
    let (image, stats) = renderer.render_with_stats(&terrain, &zeta_ec)?;
    let elapsed = started.elapsed();
    image
        .save_png(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let ground_m = terrain.height_m(lat_rad, lon_rad);
    println!(
        "{}: {}x{} px from {:.0} m ({:.0} m above the terrain) in {:.1} ms ({} sky px, {} marched rays, {} exact albedo samples); {}",
        zone,
        image.width,
        image.height,
        h_m,
        h_m - ground_m,
        elapsed.as_secs_f64() * 1e3,
        stats.sky,
        stats.marched,
        stats.exact_albedo,
        args.out.display()
    );
    Ok(())
}
