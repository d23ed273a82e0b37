//! systemd readiness and watchdog notifications (`sd_notify(3)` protocol): one datagram with
//! `READY=1` / `WATCHDOG=1` / `STATUS=…` to the unix socket named by `$NOTIFY_SOCKET` (a path,
//! or an abstract name when it starts with `@`). Without the variable every call is a no-op.

use std::os::unix::net::UnixDatagram;

/// A notifier bound to `$NOTIFY_SOCKET` (or inert).
#[derive(Debug)]
pub struct Notifier {
    target: Option<(UnixDatagram, String)>,
}

impl Notifier {
    /// From the environment.
    pub fn from_env() -> Self {
        Self::new(std::env::var("NOTIFY_SOCKET").ok())
    }

    /// For the given socket name (`None`: inert).
    pub fn new(socket: Option<String>) -> Self {
        let target = socket
            .filter(|s| !s.is_empty())
            .and_then(|s| UnixDatagram::unbound().ok().map(|sock| (sock, s)));
        Self { target }
    }

    /// Whether systemd is listening.
    pub fn active(&self) -> bool {
        self.target.is_some()
    }

    /// Send one notification; errors are returned for logging, never fatal.
    pub fn notify(&self, state: &str) -> std::io::Result<()> {
        let Some((sock, name)) = &self.target else {
            return Ok(());
        };
        if let Some(abstract_name) = name.strip_prefix('@') {
            use std::os::linux::net::SocketAddrExt;
            let addr = std::os::unix::net::SocketAddr::from_abstract_name(abstract_name)?;
            sock.send_to_addr(state.as_bytes(), &addr)?;
        } else {
            sock.send_to(state.as_bytes(), name)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn notifications_reach_the_socket_and_no_socket_is_a_no_op() {
        let dir = std::env::temp_dir().join(format!("ianav-notify-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("notify.sock");
        let _ = std::fs::remove_file(&path);
        let server = UnixDatagram::bind(&path).unwrap();
        let n = Notifier::new(Some(path.to_string_lossy().into_owned()));
        assert!(n.active());
        n.notify("WATCHDOG=1").unwrap();
        let mut buf = [0_u8; 64];
        let len = server.recv(&mut buf).unwrap();
        assert_eq!(&buf[..len], b"WATCHDOG=1");
        let inert = Notifier::new(None);
        assert!(!inert.active());
        inert.notify("READY=1").unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
