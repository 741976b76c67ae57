//! The live view: the viewing channels served over the Foxglove WebSocket
//! protocol (the `foxglove` SDK's server), so Foxglove can watch the robot
//! calibrate while the pipeline runs.
//!
//! A viewer that connects mid-run gets the current state at once: the
//! latest message of each state channel (camera calibrations, transforms,
//! the calibrated mirror and cameras, located objects) is kept and sent to
//! each client when it subscribes, from the server's subscribe callback.
//! Streams (images, detections, predictions) only flow from then on.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{ChannelBuilder, ChannelId, Context, PartialMetadata, RawChannel, WebSocketServer};

use crate::view::{ViewMessage, ViewTopic};

/// Why the live view could not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveViewError {
    /// A viewing channel could not be made.
    #[error("live view channel {channel}")]
    Channel {
        /// The channel's name.
        channel: String,
        /// The SDK's error.
        #[source]
        source: foxglove::FoxgloveError,
    },
    /// The server could not start (the port is taken, say).
    #[error("live view on {host}:{port}")]
    Server {
        /// The host it was to listen on.
        host: String,
        /// The port it was to listen on.
        port: u16,
        /// The SDK's error.
        #[source]
        source: foxglove::FoxgloveError,
    },
}

/// A running WebSocket server with one channel per viewing topic.
pub struct LiveView {
    state: Arc<State>,
    server: Option<foxglove::WebSocketServerHandle>,
    port: u16,
    // The server holds the context weakly: it must live as long as the view.
    _context: Arc<Context>,
}

/// The channels, and the latest message of each state channel.
struct State {
    channels: HashMap<ViewTopic, Arc<RawChannel>>,
    by_id: HashMap<ChannelId, ViewTopic>,
    latest: Mutex<HashMap<ViewTopic, ViewMessage>>,
}

impl State {
    fn send(&self, message: &ViewMessage, client: Option<&Client>) {
        if let Some(channel) = self.channels.get(&message.topic) {
            channel.log_with_meta_to_sink(
                &message.data,
                PartialMetadata {
                    log_time: Some(message.log_time),
                },
                client.and_then(Client::sink_id),
            );
        }
    }
}

impl ServerListener for State {
    /// A late joiner gets the channel's current state at once.
    fn on_subscribe(&self, client: Client, channel: ChannelView<'_>) {
        let Some(topic) = self.by_id.get(&channel.id()) else {
            return;
        };
        let latest = self.latest.lock().ok().and_then(|l| l.get(topic).cloned());
        if let Some(message) = latest {
            self.send(&message, Some(&client));
        }
    }
}

impl LiveView {
    /// Serves on `host:port` (port 0 picks a free one).
    pub fn start(host: &str, port: u16) -> Result<Self, LiveViewError> {
        let context = Context::new();
        let mut channels = HashMap::new();
        let mut by_id = HashMap::new();
        for v in ViewTopic::ALL {
            let channel = ChannelBuilder::new(v.name())
                .message_encoding(ViewTopic::message_encoding())
                .schema(v.schema())
                .context(&context)
                .build_raw()
                .map_err(|source| LiveViewError::Channel {
                    channel: v.name(),
                    source,
                })?;
            by_id.insert(channel.id(), v);
            channels.insert(v, channel);
        }
        let state = Arc::new(State {
            channels,
            by_id,
            latest: Mutex::new(HashMap::new()),
        });
        let server = WebSocketServer::new()
            .name("mirror pipeline")
            .bind(host, port)
            .context(&context)
            .listener(state.clone())
            .start_blocking()
            .map_err(|source| LiveViewError::Server {
                host: host.to_string(),
                port,
                source,
            })?;
        Ok(Self {
            state,
            port: server.port(),
            server: Some(server),
            _context: context,
        })
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Sends one viewing message to the connected clients, and keeps it for
    /// later ones if its channel carries state.
    pub fn log(&self, message: &ViewMessage) {
        if message.topic.is_state()
            && let Ok(mut latest) = self.state.latest.lock()
        {
            latest.insert(message.topic, message.clone());
        }
        self.state.send(message, None);
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        if let Some(server) = self.server.take() {
            drop(server.stop());
        }
    }
}
