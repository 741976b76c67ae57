//! The live view: the viewing channels served over the Foxglove WebSocket
//! protocol (the `foxglove` SDK's server), so Foxglove can watch the robot
//! calibrate while the pipeline runs.

use std::collections::HashMap;
use std::sync::Arc;

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, WebSocketServer};

use crate::view::{ViewMessage, ViewTopic};

/// A running WebSocket server with one channel per viewing topic.
pub struct LiveView {
    channels: HashMap<ViewTopic, Arc<RawChannel>>,
    server: Option<foxglove::WebSocketServerHandle>,
    port: u16,
    // The server holds the context weakly: it must live as long as the view.
    _context: Arc<Context>,
}

impl LiveView {
    /// Serves on `host:port` (port 0 picks a free one).
    pub fn start(host: &str, port: u16) -> Result<Self, String> {
        let context = Context::new();
        let mut channels = HashMap::new();
        for v in ViewTopic::ALL {
            let channel = ChannelBuilder::new(v.name())
                .message_encoding(ViewTopic::message_encoding())
                .schema(v.schema())
                .context(&context)
                .build_raw()
                .map_err(|e| format!("live view channel {}: {e}", v.name()))?;
            channels.insert(v, channel);
        }
        let server = WebSocketServer::new()
            .name("mirror pipeline")
            .bind(host, port)
            .context(&context)
            .start_blocking()
            .map_err(|e| format!("live view on {host}:{port}: {e}"))?;
        Ok(Self {
            channels,
            port: server.port(),
            server: Some(server),
            _context: context,
        })
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Sends one viewing message to the connected clients.
    pub fn log(&self, message: &ViewMessage) {
        if let Some(channel) = self.channels.get(&message.topic) {
            channel.log_with_meta(
                &message.data,
                PartialMetadata {
                    log_time: Some(message.log_time),
                },
            );
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        if let Some(server) = self.server.take() {
            drop(server.stop());
        }
    }
}
