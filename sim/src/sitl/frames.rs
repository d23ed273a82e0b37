//! Camera frame stream server of the SITL vehicle (docs/DAEMON.md "Camera sources"; wire
//! format in `ianav::io::frame_stream`): one client at a time, over TCP or a Unix socket,
//! receives the rendered frames, stamped on the vehicle's boot clock. The flight loop hands frames over through a
//! small bounded queue with `try_send`, so a slow or absent client can never hold the flight
//! back: frames that do not fit are dropped and counted. A client may connect late or
//! reconnect at any time; a new connection replaces the current one.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use ianav::io::frame_stream;
use ianav::sensors::Frame;
use tokio::io::{AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, UnixListener};
use tokio::sync::mpsc;

/// Frames the flight loop may queue ahead of the socket (two: 200 ms of frames).
pub const QUEUE_FRAMES: usize = 2;

/// A client that does not take a frame within this time is dropped (and may reconnect).
pub const WRITE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(2);

/// Counters of the frame stream.
#[derive(Debug, Default)]
pub struct FrameStats {
    /// Frames written to a client.
    pub sent: AtomicU64,
    /// Frames dropped because the queue was full (slow client).
    pub dropped: AtomicU64,
    /// Frames produced while no client was connected.
    pub without_client: AtomicU64,
    /// Client connections accepted.
    pub clients: AtomicU64,
}

/// Producer side, owned by the flight loop.
pub struct FrameSender {
    tx: mpsc::Sender<(u32, Frame)>,
    seq: u32,
    stats: Arc<FrameStats>,
}

impl FrameSender {
    /// Offer a frame; never waits. Sequence numbers count every frame produced, so a client
    /// sees drops as gaps.
    pub fn offer(&mut self, frame: Frame) {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        if self.tx.try_send((seq, frame)).is_err() {
            self.stats.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Where the frame server accepts its client.
#[derive(Debug)]
pub enum FrameListener {
    /// TCP (`host:port`).
    Tcp(TcpListener),
    /// A Unix stream socket (`unix:PATH`).
    Unix(UnixListener),
}

/// A connected client, whatever the transport.
type Client = std::pin::Pin<Box<dyn AsyncWrite + Send>>;

impl FrameListener {
    async fn accept(&self) -> std::io::Result<Client> {
        Ok(match self {
            Self::Tcp(l) => {
                let (stream, _) = l.accept().await?;
                // Frames are large and latency matters more than packing.
                let _ = stream.set_nodelay(true);
                Box::pin(stream)
            }
            Self::Unix(l) => Box::pin(l.accept().await?.0),
        })
    }
}

/// Start serving frames on `listener`; the task ends when the sender is dropped.
pub fn spawn(
    listener: FrameListener,
) -> (FrameSender, Arc<FrameStats>, tokio::task::JoinHandle<()>) {
    let (tx, rx) = mpsc::channel(QUEUE_FRAMES);
    let stats = Arc::new(FrameStats::default());
    let task = tokio::spawn(serve(listener, rx, Arc::clone(&stats)));
    (
        FrameSender {
            tx,
            seq: 0,
            stats: Arc::clone(&stats),
        },
        stats,
        task,
    )
}

async fn serve(
    listener: FrameListener,
    mut rx: mpsc::Receiver<(u32, Frame)>,
    stats: Arc<FrameStats>,
) {
    let mut client: Option<Client> = None;
    let mut buf = Vec::new();
    loop {
        tokio::select! {
            accepted = listener.accept() => {
                if let Ok(stream) = accepted {
                    client = Some(stream);
                    stats.clients.fetch_add(1, Ordering::Relaxed);
                }
            }
            next = rx.recv() => {
                let Some((seq, frame)) = next else { break };
                let Some(stream) = client.as_mut() else {
                    stats.without_client.fetch_add(1, Ordering::Relaxed);
                    continue;
                };
                buf.clear();
                if frame_stream::write_frame(&mut buf, &frame, seq).is_err() {
                    stats.dropped.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
                let written =
                    tokio::time::timeout(WRITE_TIMEOUT, stream.write_all(&buf)).await;
                match written {
                    Ok(Ok(())) => {
                        stats.sent.fetch_add(1, Ordering::Relaxed);
                    }
                    Ok(Err(_)) | Err(_) => {
                        // Gone, or stalled for seconds: wait for the next client.
                        stats.dropped.fetch_add(1, Ordering::Relaxed);
                        client = None;
                    }
                }
            }
        }
    }
}
