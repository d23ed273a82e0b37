//! `ianav-sim sitl`: the simulator as a MAVLink vehicle for the ianav daemon (`docs/SITL.md`).

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};

use super::setup;
use crate::{AutopilotArg, SitlArgs};

/// Milliseconds of an option → µs (finite, ≥ 0).
fn option_ms_to_us(name: &str, ms: f64) -> anyhow::Result<u64> {
    if !(ms.is_finite() && ms >= 0.0) {
        anyhow::bail!("{name} must be a non-negative number of ms, got {ms}");
    }
    Ok((ms * 1e3).round() as u64)
}

pub(crate) fn sitl(args: &SitlArgs) -> Result<()> {
    use ianav_sim::sitl::{self, Autopilot, FramesListen, SitlOptions, VehicleConfig};
    if !(args.speed.is_finite() && args.speed >= 0.0) {
        bail!("--speed must be a non-negative factor, got {}", args.speed);
    }
    if !(args.estimate_timeout.is_finite() && args.estimate_timeout > 0.0) {
        bail!(
            "--estimate-timeout must be a positive number of seconds, got {}",
            args.estimate_timeout
        );
    }
    let setup = setup(&args.fly.setup)?;
    let autopilot = match args.autopilot {
        AutopilotArg::Px4 => Autopilot::Px4,
        AutopilotArg::Ardupilot => Autopilot::ArduPilot,
        AutopilotArg::Ideal => Autopilot::Ideal,
    };
    let mut vehicle = VehicleConfig {
        system_id: args.system_id,
        fly_on_estimates: !args.no_external_position,
        estimate_timeout_us: (args.estimate_timeout * 1e6).round() as u64,
        ..VehicleConfig::for_autopilot(autopilot)
    }
    .with_latency_us(option_ms_to_us("--latency-ms", args.latency_ms)?);
    if let Some(on) = args.gyro_drift {
        vehicle.gyro_drift = on;
    }
    if let Some(t_s) = args.airspeed_unhealthy_from {
        let boot_s = setup.scenario.warmup_s + t_s;
        if !(boot_s.is_finite() && boot_s >= 0.0) {
            bail!("--airspeed-unhealthy-from must be a mission time in seconds, got {t_s}");
        }
        vehicle.airspeed_unhealthy_from_us = Some((boot_s * 1e6).round() as u64);
    }
    if let Some(ms) = args.gnss_lag_ms {
        vehicle.gnss_lag_us = option_ms_to_us("--gnss-lag-ms", ms)?;
    }
    for spec in &args.stream_latency {
        let Some((name, ms)) = spec.split_once('=') else {
            bail!("--stream-latency wants NAME=MS, got {spec:?}");
        };
        let Some(i) = sitl::streams::stream_index_by_name(name.trim()) else {
            bail!(
                "--stream-latency: unknown stream {name:?} (one of {})",
                sitl::streams::stream_names().join(", ")
            );
        };
        let ms: f64 = ms
            .trim()
            .parse()
            .map_err(|e| anyhow::anyhow!("--stream-latency {spec:?}: {e}"))?;
        vehicle.latency_us[i] = option_ms_to_us("--stream-latency", ms)?;
    }
    let options = SitlOptions {
        connect: args.connect.clone(),
        vehicle,
        speed: args.speed,
        frames: args.frames_listen.clone().map(FramesListen::Addr),
        out_dir: args.out.clone(),
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {wide_bar} {pos}/{len} s {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let pace = if args.speed == 0.0 {
        "as fast as possible".to_owned()
    } else {
        format!("at {}× real time", args.speed)
    };
    println!(
        "sitl: scenario {} seed {} as {:?} on {} {pace}",
        args.fly.setup.scenario, args.fly.seed, args.autopilot, args.connect
    );
    // Without a terminal the bar is hidden (and drops its log lines): print plain lines,
    // a status line every 10 s of mission time.
    let plain = bar.is_hidden();
    let mut next_status_s = 0.0;
    let summary = runtime.block_on(sitl::run(&setup, args.fly.seed, options, |p, notices| {
        bar.set_length(p.end_s.max(0.0).ceil() as u64);
        bar.set_position(p.t_s.max(0.0) as u64);
        for n in notices {
            if plain {
                println!("{n}");
            } else {
                bar.println(n);
            }
        }
        let err = p.hor_err_m.map_or_else(
            || "no estimate yet".to_owned(),
            |e| format!("hor err {e:.1} m"),
        );
        let lag = if p.lag_s > 0.5 {
            format!(", {:.1} s behind", p.lag_s)
        } else {
            String::new()
        };
        let status = format!(
            "t {:.0} s, {err}, {:.0} Hz, flying on {}{lag}",
            p.t_s,
            p.estimate_rate_hz,
            if p.aided { "daemon" } else { "own INS" }
        );
        if plain && p.t_s >= next_status_s {
            println!("{status}");
            next_status_s = (p.t_s / 10.0).floor() * 10.0 + 10.0;
        }
        bar.set_message(status);
    }))?;
    bar.finish();
    let v = &summary.vehicle;
    println!(
        "flew {:.0} s in {:.1} s wall (max lag {:.2} s); sent {} messages ({} dropped, {} errors), received {}; TIMESYNC: {} requests answered, {} answers to ours",
        summary.mission_s,
        summary.wall_s,
        summary.max_lag_s,
        summary.sent,
        summary.send_dropped,
        summary.send_errors,
        v.received,
        v.timesync_answered,
        v.timesync_pairs
    );
    println!(
        "daemon estimates: {} used, {} refused, mean rate {}; flew on the daemon's position {:.0} % of the time after GNSS loss",
        v.estimates,
        v.estimates_refused,
        summary
            .estimate_rate_hz
            .map_or_else(|| "-".to_owned(), |r| format!("{r:.1} Hz")),
        if v.ticks_after_loss > 0 {
            100.0 * v.aided_ticks as f64 / v.ticks_after_loss as f64
        } else {
            0.0
        }
    );
    if let Some(rms) = summary.hor_err_rms_after_loss_m {
        println!(
            "horizontal error after GNSS loss: RMS {rms:.1} m, last {:.1} m",
            summary.last_hor_err_m.unwrap_or(f64::NAN)
        );
    }
    if v.frames > 0 {
        println!(
            "camera frames: {} rendered, {} sent, {} dropped (slow client), {} without a client",
            v.frames, summary.frames_sent, summary.frames_dropped, summary.frames_without_client
        );
    }
    Ok(())
}
