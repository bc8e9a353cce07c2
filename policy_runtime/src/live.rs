//! The live view (`--live [ADDR]`): a flight's log channels streamed as they are written, over
//! the Foxglove WebSocket protocol (subprotocol `foxglove.websocket.v1`) by the Foxglove SDK's
//! server, so Foxglove (or any client of the protocol) watches a flight as it happens.
//!
//! ```text
//! flight loop ─► FlightLog ─► McapRecorder ─┬─► the MCAP file (when logging)
//!                                           └─► LiveTap ─(bounded queue, never waits)─►
//!                        publisher thread ─► SDK channels ─► WebSocket server ─► viewers
//! ```
//!
//! The tap copies each message (topic, log time, payload exactly as in the file) into a
//! bounded queue with a non-blocking send: when the queue is full the message is dropped and
//! counted ([`LiveStats::dropped`]), so the flight loop never waits for a viewer. Channel
//! advertisements go through their own (small, unbounded) queue and are never dropped. The
//! publisher thread hands messages to the SDK, whose server keeps a bounded backlog per
//! viewer (1024 messages) and drops a slow viewer's oldest messages (the SDK does not count
//! those). A flight with or without a live view flies the same: the view only reads what the
//! log writes.
//!
//! Times: log time is the flight's own clock (simulated time from 0 in the twin), as in the
//! file — not the wall clock.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{
    self, Receiver, RecvTimeoutError, Sender, SyncSender, TryRecvError, TrySendError,
};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use foxglove::{Context, PartialMetadata, RawChannel, Schema, WebSocketServer};

use crate::record::{ChannelInfo, Tap};

/// Where `--live` serves when given no address.
pub const DEFAULT_LIVE_ADDR: &str = "127.0.0.1:8765";

/// Messages the tap's queue holds before it drops: about 1.4 s of a 120 Hz flight logging
/// ~24 messages a tick.
pub const QUEUE_CAPACITY: usize = 4096;

/// The live view could not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The address is not `HOST:PORT` with an IP host.
    #[error("--live: '{0}' is not an address of the form IP:PORT (e.g. 127.0.0.1:8765)")]
    Address(String),
    /// The server could not start (the port taken, …).
    #[error("--live {addr}: the WebSocket server could not start: {message}")]
    Server {
        /// The address asked for.
        addr: String,
        /// The SDK's reason.
        message: String,
    },
}

/// Parses `--live`'s address (`IP:PORT`; port 0 picks a free one).
pub fn parse_addr(text: &str) -> Result<SocketAddr, LiveError> {
    text.parse()
        .map_err(|_| LiveError::Address(text.to_owned()))
}

/// What the live view did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct LiveStats {
    /// Messages handed to the server (sent to every viewer subscribed to their channel).
    pub published: u64,
    /// Messages dropped because the queue was full (the publisher behind the flight).
    pub dropped: u64,
}

#[derive(Debug, Default)]
struct Counters {
    published: AtomicU64,
    dropped: AtomicU64,
}

/// One recorder's view of a channel: its session (one per tap, so two flights' channel ids
/// do not mix) and its id.
type Key = (u64, u16);

#[derive(Debug)]
struct Advertise {
    key: Key,
    info: ChannelInfo,
}

#[derive(Debug)]
struct Message {
    key: Key,
    log_time_ns: u64,
    payload: Vec<u8>,
}

/// The bounded queue between a recorder and the publisher.
#[derive(Debug)]
pub struct LiveTap {
    session: u64,
    advertise: Sender<Advertise>,
    messages: SyncSender<Message>,
    counters: Arc<Counters>,
}

impl Tap for LiveTap {
    fn channel(&mut self, channel: &ChannelInfo) {
        // Unbounded and tiny (a few per flight): never dropped, never blocks.
        let _ = self.advertise.send(Advertise {
            key: (self.session, channel.id),
            info: channel.clone(),
        });
    }

    fn message(&mut self, id: u16, log_time_ns: u64, payload: &[u8]) {
        let message = Message {
            key: (self.session, id),
            log_time_ns,
            payload: payload.to_vec(),
        };
        match self.messages.try_send(message) {
            Ok(()) => {}
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// The queues' receiving ends and the channels made of them (the publisher's state).
struct Publisher {
    context: Arc<Context>,
    advertise: Receiver<Advertise>,
    channels: BTreeMap<Key, Arc<RawChannel>>,
    by_topic: BTreeMap<String, Arc<RawChannel>>,
    counters: Arc<Counters>,
}

impl Publisher {
    /// Makes the SDK channels of every advertisement queued so far (a topic already
    /// advertised by an earlier flight is reused).
    fn take_advertisements(&mut self) {
        loop {
            match self.advertise.try_recv() {
                Ok(a) => {
                    let channel = match self.by_topic.get(&a.info.topic) {
                        Some(c) => Some(c.clone()),
                        None => self
                            .context
                            .channel_builder(a.info.topic.clone())
                            .message_encoding(a.info.message_encoding.clone())
                            .schema(Schema::new(
                                a.info.schema_name.clone(),
                                a.info.schema_encoding.clone(),
                                a.info.schema.clone(),
                            ))
                            .build_raw()
                            .ok(),
                    };
                    if let Some(c) = channel {
                        self.by_topic.insert(a.info.topic.clone(), c.clone());
                        self.channels.insert(a.key, c);
                    }
                }
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return,
            }
        }
    }

    fn publish(&mut self, m: &Message) {
        if !self.channels.contains_key(&m.key) {
            self.take_advertisements();
        }
        if let Some(channel) = self.channels.get(&m.key) {
            channel.log_with_meta(
                &m.payload,
                PartialMetadata {
                    log_time: Some(m.log_time_ns),
                },
            );
            self.counters.published.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The live view's server and publisher. Shared (`Arc`) by the flights that stream to it: a
/// `bench` streams every rollout to one server.
pub struct LiveServer {
    addr: SocketAddr,
    server: Mutex<Option<foxglove::WebSocketServerHandle>>,
    advertise: Sender<Advertise>,
    messages: SyncSender<Message>,
    publisher: Mutex<Option<JoinHandle<()>>>,
    counters: Arc<Counters>,
    stop: Arc<AtomicBool>,
    sessions: AtomicU64,
}

impl std::fmt::Debug for LiveServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveServer")
            .field("addr", &self.addr)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl LiveServer {
    /// Starts the server on `addr` (port 0: a free port, see [`Self::addr`]) and the
    /// publisher thread.
    pub fn start(addr: SocketAddr) -> Result<Self, LiveError> {
        Self::start_with_capacity(addr, QUEUE_CAPACITY)
    }

    /// [`Self::start`] with a queue of `capacity` messages.
    pub fn start_with_capacity(addr: SocketAddr, capacity: usize) -> Result<Self, LiveError> {
        let context = Context::new();
        let server = WebSocketServer::new()
            .name(format!("amstack {}", crate::record::AMSTACK_VERSION))
            .bind(addr.ip().to_string(), addr.port())
            .context(&context)
            .start_blocking()
            .map_err(|e| LiveError::Server {
                addr: addr.to_string(),
                message: e.to_string(),
            })?;
        let bound = SocketAddr::new(addr.ip(), server.port());
        let (advertise_tx, advertise_rx) = mpsc::channel();
        let (messages_tx, messages_rx) = mpsc::sync_channel::<Message>(capacity);
        let counters = Arc::new(Counters::default());
        let stop = Arc::new(AtomicBool::new(false));
        let mut publisher = Publisher {
            context,
            advertise: advertise_rx,
            channels: BTreeMap::new(),
            by_topic: BTreeMap::new(),
            counters: counters.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("amstack-live".to_owned())
            .spawn({
                let stop = stop.clone();
                move || {
                    loop {
                        match messages_rx.recv_timeout(std::time::Duration::from_millis(50)) {
                            Ok(m) => publisher.publish(&m),
                            // Stops once the queue is empty and the server is finishing.
                            Err(RecvTimeoutError::Timeout) if stop.load(Ordering::Relaxed) => break,
                            Err(RecvTimeoutError::Timeout) => {}
                            Err(RecvTimeoutError::Disconnected) => break,
                        }
                    }
                }
            })
            .map_err(|e| LiveError::Server {
                addr: addr.to_string(),
                message: format!("cannot start the publisher thread: {e}"),
            })?;
        Ok(Self {
            addr: bound,
            server: Mutex::new(Some(server)),
            advertise: advertise_tx,
            messages: messages_tx,
            publisher: Mutex::new(Some(thread)),
            counters,
            stop,
            sessions: AtomicU64::new(0),
        })
    }

    /// The address served (with the port picked for port 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// A tap for one recorder (one flight): [`crate::record::McapRecorder::with_tap`].
    pub fn tap(&self) -> Box<dyn Tap> {
        Box::new(LiveTap {
            session: self.sessions.fetch_add(1, Ordering::Relaxed) + 1,
            advertise: self.advertise.clone(),
            messages: self.messages.clone(),
            counters: self.counters.clone(),
        })
    }

    /// What was published and dropped so far.
    pub fn stats(&self) -> LiveStats {
        LiveStats {
            published: self.counters.published.load(Ordering::Relaxed),
            dropped: self.counters.dropped.load(Ordering::Relaxed),
        }
    }

    /// Publishes what is queued, stops the server and reports (again: the same figures).
    pub fn finish(&self) -> LiveStats {
        // The publisher drains the queue, then ends.
        self.stop.store(true, Ordering::Relaxed);
        let publisher = self.publisher.lock().ok().and_then(|mut p| p.take());
        if let Some(t) = publisher {
            let _ = t.join();
        }
        let server = self.server.lock().ok().and_then(|mut s| s.take());
        if let Some(server) = server {
            server.stop().wait_blocking();
        }
        self.stats()
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.finish();
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    fn info(id: u16) -> ChannelInfo {
        ChannelInfo {
            id,
            topic: format!("/t{id}"),
            schema_name: "amstack.Test".to_owned(),
            schema_encoding: "jsonschema".to_owned(),
            schema: b"{}".to_vec(),
            message_encoding: "json".to_owned(),
        }
    }

    #[test]
    fn a_full_queue_drops_and_counts_without_waiting() {
        // A publisher that never runs: the queue's receiving end held, never read.
        let (advertise, _advertised) = mpsc::channel();
        let (messages, _stalled) = mpsc::sync_channel(8);
        let counters = Arc::new(Counters::default());
        let mut tap = LiveTap {
            session: 1,
            advertise,
            messages,
            counters: counters.clone(),
        };
        tap.channel(&info(1));
        for k in 0..20u64 {
            tap.message(1, k, b"{}");
        }
        assert_eq!(
            counters.dropped.load(Ordering::Relaxed),
            12,
            "20 sent, 8 held"
        );
    }

    #[test]
    fn bad_addresses_are_refused_by_name() {
        for bad in ["localhost", "127.0.0.1", "8765", "127.0.0.1:99999"] {
            let e = parse_addr(bad).unwrap_err().to_string();
            assert!(e.contains(bad) && e.contains("IP:PORT"), "{e}");
        }
        assert_eq!(parse_addr(DEFAULT_LIVE_ADDR).unwrap().port(), 8765);
    }

    #[test]
    fn the_server_serves_on_a_free_port_and_publishes_what_it_is_given() {
        let server = LiveServer::start(parse_addr("127.0.0.1:0").unwrap()).unwrap();
        assert_ne!(server.addr().port(), 0);
        let mut tap = server.tap();
        tap.channel(&info(1));
        for k in 0..5u64 {
            tap.message(1, k, b"{\"x\":1}");
        }
        drop(tap);
        let stats = server.finish();
        assert_eq!(
            stats,
            LiveStats {
                published: 5,
                dropped: 0
            }
        );
    }
}
