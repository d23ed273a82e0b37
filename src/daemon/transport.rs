//! Opening the MAVLink connection: the connection string parsed and its address resolved
//! ([`resolve`], also run by `check-config` through [`super::preflight`]), and UDP sockets
//! with a receive buffer sized by us rather than left at the system default ([`open`]).
//!
//! Why the buffer: Linux charges each datagram's full socket-buffer footprint (about 1 kB for
//! a 40-byte MAVLink frame) against `SO_RCVBUF`, so the usual 208 kB default holds about 200
//! datagrams, one second of an autopilot's streams: a reader held up for longer (two busy
//! cores) lost frames. The mavlink crate binds its own socket for `udpin:`/`udpout:`
//! addresses; we build the socket with `socket2` and hand it over with
//! `UdpConfig::from_socket`.
//!
//! TCP: the crate's own sockets keep Nagle's algorithm on, which holds a small message back
//! until the peer acknowledges the previous one; against a peer's delayed acknowledgement
//! (up to 40 ms on Linux) that held the IMU messages 40–45 ms behind the camera frames that
//! went with them (docs/PERFORMANCE.md "Daemon with vision"). MAVLink is many small
//! messages whose latency matters, so we open the TCP stream ourselves with `TCP_NODELAY`
//! and hand it over with `TcpConfig::from_stream`. Serial is opened by the crate.

use std::io;
use std::net::{SocketAddr, ToSocketAddrs};

use mavlink::{AsyncConnectable, TcpConfig, UdpConfig, UdpMode};
use socket2::{Domain, Protocol, SockRef, Socket, Type};

use super::link::Conn;
use mavlink::dialects::ardupilotmega as apm;

/// UDP receive buffer requested, bytes: ≥ 5 s of the requested streams (≈ 200 datagrams/s) at
/// the kernel's per-datagram charge. The kernel caps it at `net.core.rmem_max`; the size
/// granted is logged, with a warning when capped.
pub const UDP_RECV_BUFFER_BYTES: usize = 1 << 20;

/// A connection string with its network address resolved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Endpoint {
    /// `udpin:`: bind here, answer whoever sends first.
    UdpIn(SocketAddr),
    /// `udpout:`: send to this peer from an ephemeral port.
    UdpOut(SocketAddr),
    /// `tcpin:`: listen here, serve the first client.
    TcpIn(SocketAddr),
    /// `tcpout:`: connect to this server.
    TcpOut(SocketAddr),
    /// `serial:` (the device is opened, and retried, by the link: a USB autopilot may appear
    /// after the daemon starts).
    Serial,
}

/// Parse a connection string and resolve its host (a name is looked up, blocking): an address
/// that cannot be resolved is an error here instead of a link retrying forever.
pub fn resolve(connection: &str) -> io::Result<Endpoint> {
    let bad = |what: &str| io::Error::new(io::ErrorKind::InvalidInput, what.to_owned());
    let (scheme, address) = connection
        .split_once(':')
        .ok_or_else(|| bad("must be scheme:address"))?;
    if scheme == "serial" {
        return Ok(Endpoint::Serial);
    }
    let (host, _) = address
        .rsplit_once(':')
        .ok_or_else(|| bad("must be scheme:host:port"))?;
    let addr = address
        .to_socket_addrs()
        .map_err(|e| io::Error::new(e.kind(), format!("cannot resolve {host:?}: {e}")))?
        .next()
        .ok_or_else(|| bad(&format!("{host:?} resolves to no address")))?;
    match scheme {
        "udpin" => Ok(Endpoint::UdpIn(addr)),
        "udpout" => Ok(Endpoint::UdpOut(addr)),
        "tcpin" => Ok(Endpoint::TcpIn(addr)),
        "tcpout" => Ok(Endpoint::TcpOut(addr)),
        _ => Err(bad(
            "unknown scheme: use udpin, udpout, tcpin, tcpout or serial",
        )),
    }
}

/// A UDP socket with [`UDP_RECV_BUFFER_BYTES`] requested, bound to `bind` and, for
/// `udpout`, connected to `peer` (the crate takes a handed-over `udpout` socket's peer as its
/// destination; a connected socket also drops datagrams from any other address).
pub fn udp_socket(bind: SocketAddr, peer: Option<SocketAddr>) -> io::Result<std::net::UdpSocket> {
    let sock = Socket::new(Domain::for_address(bind), Type::DGRAM, Some(Protocol::UDP))?;
    sock.set_recv_buffer_size(UDP_RECV_BUFFER_BYTES)?;
    sock.bind(&bind.into())?;
    if let Some(p) = peer {
        sock.connect(&p.into())?;
    }
    sock.set_nonblocking(true)?;
    let sock = std::net::UdpSocket::from(sock);
    log_recv_buffer(&sock);
    Ok(sock)
}

/// The TCP stream of a `tcpin:` (its first client) or `tcpout:` endpoint, with `TCP_NODELAY`
/// set; any other endpoint is an error.
pub async fn tcp_stream(endpoint: Endpoint) -> io::Result<std::net::TcpStream> {
    let stream = match endpoint {
        Endpoint::TcpOut(server) => tokio::net::TcpStream::connect(server).await?,
        Endpoint::TcpIn(bind) => tokio::net::TcpListener::bind(bind).await?.accept().await?.0,
        other => {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{other:?} is not a TCP endpoint"),
            ));
        }
    };
    stream.set_nodelay(true)?;
    stream.into_std()
}

fn log_recv_buffer(sock: &std::net::UdpSocket) {
    match SockRef::from(sock).recv_buffer_size() {
        // Linux reports twice the size set (its bookkeeping share): capped means below that.
        Ok(got) if got < 2 * UDP_RECV_BUFFER_BYTES => tracing::warn!(
            requested = UDP_RECV_BUFFER_BYTES,
            granted = got,
            "UDP receive buffer capped by the kernel: raise net.core.rmem_max"
        ),
        Ok(got) => tracing::info!(granted = got, "UDP receive buffer"),
        Err(e) => tracing::warn!("UDP receive buffer size unknown: {e}"),
    }
}

/// Open the connection: UDP on a socket of ours ([`udp_socket`]), TCP on a stream of ours
/// without Nagle's delay ([`tcp_stream`]), serial by the mavlink crate.
pub async fn open(connection: &str) -> io::Result<Conn> {
    let (sock, mode) = match resolve(connection)? {
        Endpoint::UdpIn(addr) => (udp_socket(addr, None)?, UdpMode::Udpin),
        Endpoint::UdpOut(peer) => {
            let any: SocketAddr = if peer.is_ipv6() {
                (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
            } else {
                (std::net::Ipv4Addr::UNSPECIFIED, 0).into()
            };
            (udp_socket(any, Some(peer))?, UdpMode::Udpout)
        }
        Endpoint::TcpIn(_) | Endpoint::TcpOut(_) => {
            let stream = tcp_stream(resolve(connection)?).await?;
            return TcpConfig::from_stream(stream)?
                .connect_async::<apm::MavMessage>()
                .await;
        }
        Endpoint::Serial => {
            return mavlink::connect_async::<apm::MavMessage>(connection).await;
        }
    };
    UdpConfig::from_socket(sock, mode)?
        .connect_async::<apm::MavMessage>()
        .await
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::{AsyncMavConnection, MavHeader};

    #[test]
    fn addresses_resolve_or_are_refused() {
        assert_eq!(
            resolve("udpin:127.0.0.1:14540").unwrap(),
            Endpoint::UdpIn("127.0.0.1:14540".parse().unwrap())
        );
        assert!(matches!(
            resolve("tcpout:localhost:5760").unwrap(),
            Endpoint::TcpOut(_)
        ));
        assert_eq!(
            resolve("tcpin:127.0.0.1:5760").unwrap(),
            Endpoint::TcpIn("127.0.0.1:5760".parse().unwrap())
        );
        assert_eq!(
            resolve("serial:/dev/ttyS9:57600").unwrap(),
            Endpoint::Serial
        );
        // Retried forever at run time before this check.
        let e = resolve("udpin:999.1.1.1:14540").unwrap_err().to_string();
        assert!(e.contains("999.1.1.1"), "{e}");
        assert!(resolve("udpin:127.0.0.1").is_err());
        assert!(resolve("udp:127.0.0.1:1").is_err());
    }

    fn granted(sock: &std::net::UdpSocket) -> usize {
        SockRef::from(sock).recv_buffer_size().unwrap()
    }

    #[test]
    fn udp_sockets_get_the_receive_buffer_the_kernel_allows() {
        let rmem_max: usize = std::fs::read_to_string("/proc/sys/net/core/rmem_max")
            .ok()
            .and_then(|s| s.trim().parse().ok())
            .unwrap_or(0);
        let sock = udp_socket("127.0.0.1:0".parse().unwrap(), None).unwrap();
        let default = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        // Linux doubles the value set; it caps the request at rmem_max.
        let expect = 2 * UDP_RECV_BUFFER_BYTES.min(rmem_max);
        assert!(
            granted(&sock) >= expect,
            "granted {} < {expect} (rmem_max {rmem_max}, default socket {})",
            granted(&sock),
            granted(&default)
        );
    }

    fn heartbeat() -> apm::MavMessage {
        apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA::default())
    }

    /// `tcpin` and `tcpout` streams are ours, without Nagle's delay, and carry frames both ways.
    #[tokio::test]
    async fn tcp_streams_have_no_nagle_delay_and_carry_frames_both_ways() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let wait = std::time::Duration::from_secs(5);
        let tcpin = format!("tcpin:127.0.0.1:{port}");
        let server = tokio::spawn(async move { open(&tcpin).await.unwrap() });
        let client = tokio::time::timeout(wait, async {
            loop {
                match open(&format!("tcpout:127.0.0.1:{port}")).await {
                    Ok(c) => break c,
                    // The server task may not be listening yet.
                    Err(_) => tokio::time::sleep(std::time::Duration::from_millis(10)).await,
                }
            }
        })
        .await
        .unwrap();
        let server = tokio::time::timeout(wait, server).await.unwrap().unwrap();
        heartbeats_go_both_ways(&client, &server).await;

        // The streams handed to the crate: both ends with TCP_NODELAY.
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        drop(listener);
        let accepting = tokio::spawn(tcp_stream(Endpoint::TcpIn(addr)));
        let out = tokio::time::timeout(wait, async {
            loop {
                match tcp_stream(Endpoint::TcpOut(addr)).await {
                    Ok(s) => break s,
                    Err(_) => tokio::time::sleep(std::time::Duration::from_millis(10)).await,
                }
            }
        })
        .await
        .unwrap();
        let inn = tokio::time::timeout(wait, accepting)
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        assert!(out.nodelay().unwrap() && inn.nodelay().unwrap());
        assert!(tcp_stream(Endpoint::Serial).await.is_err());
    }

    /// The handed-over sockets behave as the crate's own: `udpin` answers its first sender,
    /// `udpout` sends to its peer and hears back from it.
    #[tokio::test]
    async fn udpin_and_udpout_carry_frames_both_ways() {
        let port = std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let server = open(&format!("udpin:127.0.0.1:{port}")).await.unwrap();
        let client = open(&format!("udpout:127.0.0.1:{port}")).await.unwrap();
        heartbeats_go_both_ways(&client, &server).await;
    }

    /// A HEARTBEAT from `client` reaches `server`, and one back (5 s each at most).
    async fn heartbeats_go_both_ways(client: &Conn, server: &Conn) {
        let header = MavHeader {
            system_id: 7,
            component_id: 1,
            sequence: 0,
        };
        let wait = std::time::Duration::from_secs(5);
        client.send(&header, &heartbeat()).await.expect("send");
        let got = tokio::time::timeout(wait, server.recv_raw())
            .await
            .expect("a frame within 5 s")
            .expect("a frame");
        assert_eq!(got.system_id(), 7);
        server.send(&header, &heartbeat()).await.expect("send back");
        let back = tokio::time::timeout(wait, client.recv_raw())
            .await
            .expect("a frame back within 5 s")
            .expect("a frame back");
        assert_eq!(back.component_id(), 1);
    }
}
