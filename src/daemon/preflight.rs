//! Everything `ianav run` checks before it opens the link. `ianav check-config` calls the same
//! function, so a file it accepts cannot be refused by `run` for a reason known at start-up.

use std::path::Path;

use crate::daemon::config::{ConfigError, DaemonConfig, invalid, parse_log_filter};

/// A configuration that passed every start-up check, and what `run` needs from them.
#[derive(Debug)]
pub struct Preflight {
    /// The validated configuration.
    pub config: DaemonConfig,
    /// The log filter `run` installs.
    pub log_filter: tracing_subscriber::EnvFilter,
    /// The link's address, resolved.
    pub endpoint: super::transport::Endpoint,
}

/// Read and check `path` as `run` does, in its order:
/// 1. the file: TOML, keys, ranges (rates and periods included), the INS file it names, the
///    syntax of `logging.level` and of `mavlink.connection` ([`DaemonConfig::from_file`]);
/// 2. the log filter in force: `RUST_LOG` when set and not empty (a developer's override),
///    else `logging.level`; either must parse;
/// 3. `mavlink.connection` resolved to an address ([`super::transport::resolve`]);
/// 4. the navigation core built from the INS configuration.
///
/// Not checked, because the link retries them by design: whether a serial device exists yet, a
/// peer answers or a camera source is there.
pub fn preflight(path: &Path) -> Result<Preflight, ConfigError> {
    let config = DaemonConfig::from_file(path)?;
    let log_filter = log_filter(&config, std::env::var_os("RUST_LOG"))?;
    let endpoint = super::transport::resolve(&config.mavlink.connection).map_err(|e| {
        invalid(
            "mavlink.connection",
            format!("{:?}", config.mavlink.connection),
            e.to_string(),
        )
    })?;
    crate::nav::Navigator::new(&super::nav_config(
        &config,
        config.navigation.mag_decimal_year,
    ))
    .map_err(|e| invalid("ins", "[table]", e.to_string()))?;
    Ok(Preflight {
        config,
        log_filter,
        endpoint,
    })
}

/// The filter `run` logs with: `rust_log` (the `RUST_LOG` variable) when set and not empty,
/// else `logging.level`. The unit file does not set `RUST_LOG`, so under systemd the
/// configuration decides.
pub fn log_filter(
    cfg: &DaemonConfig,
    rust_log: Option<std::ffi::OsString>,
) -> Result<tracing_subscriber::EnvFilter, ConfigError> {
    match rust_log.filter(|v| !v.is_empty()) {
        Some(v) => {
            let shown = format!("{v:?}");
            let s = v
                .into_string()
                .map_err(|_| invalid("RUST_LOG (environment)", &shown, "not UTF-8"))?;
            parse_log_filter(&s).map_err(|r| invalid("RUST_LOG (environment)", shown, r))
        }
        None => parse_log_filter(&cfg.logging.level)
            .map_err(|r| invalid("logging.level", format!("{:?}", cfg.logging.level), r)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rust_log_replaces_the_configured_level_only_when_set() {
        let cfg = DaemonConfig::from_toml_str(
            "[mavlink]\nconnection = \"udpin:127.0.0.1:1\"\n[output]\nrate_hz = 30\n\
             [logging]\nlevel = \"warn,ianav=debug\"\n",
            None,
        )
        .unwrap();
        assert!(log_filter(&cfg, None).is_ok());
        assert!(log_filter(&cfg, Some("".into())).is_ok());
        assert!(log_filter(&cfg, Some("ianav=trace".into())).is_ok());
        let e = log_filter(&cfg, Some("ianav=loud".into()))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("RUST_LOG (environment) = \"ianav=loud\""),
            "{e}"
        );
    }
}
