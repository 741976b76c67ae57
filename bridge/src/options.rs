//! Where the link goes and what crosses it ([`Options`]): what cannot
//! work, the zenoh keys, and the zenoh configuration of the session.

use messages::topics::TopicId;
use secure_link::tls::{self, Allow, Flow, Identity};

use crate::envelope;
use crate::error::BridgeError;

/// Where the link goes and what crosses it.
#[derive(Debug, Clone)]
pub struct Options {
    /// Service prefix of the pipeline on this host.
    pub prefix: String,
    /// First part of every zenoh key; both sides must agree on it. A second
    /// robot uses another.
    pub namespace: String,
    /// Topics read here and sent.
    pub send: Vec<TopicId>,
    /// Topics received and published here.
    pub receive: Vec<TopicId>,
    /// Zenoh endpoints to listen on (e.g. `tcp/0.0.0.0:7447`).
    pub listen: Vec<String>,
    /// Zenoh endpoints to connect to (e.g. `tcp/192.168.1.20:7447`).
    pub connect: Vec<String>,
    /// How frames travel (small messages always as they are).
    pub frame_encoding: envelope::Encoding,
    /// How long the link may stay silent before it counts as cut, ms (then
    /// both sides count what they send as lost, and the connecting side
    /// connects again every 1 to 4 s).
    pub lease_ms: u64,
    /// Mutual TLS: this side's identity and the common name of the other
    /// side's certificate (absent: plain TCP).
    pub tls: Option<Tls>,
    /// Plain TCP off loopback is allowed (and warned about).
    pub insecure: bool,
}

/// Who this side is on a TLS link, and who the other side must be.
#[derive(Debug, Clone)]
pub struct Tls {
    /// This side's CA, certificate and key.
    pub identity: Identity,
    /// The other side's certificate's common name (`robot`, `workstation`).
    pub peer: String,
}

impl Options {
    /// Refuses what cannot work: a topic both sent and received would come
    /// back to its sender and go round the link for ever.
    pub fn check(&self) -> Result<(), BridgeError> {
        if let Some(t) = self.send.iter().find(|t| self.receive.contains(t)) {
            return Err(BridgeError::SentAndReceived(*t));
        }
        if self.send.is_empty() && self.receive.is_empty() {
            return Err(BridgeError::NothingToBridge);
        }
        if self.listen.is_empty() && self.connect.is_empty() {
            return Err(BridgeError::NoLink);
        }
        if !(100..=600_000).contains(&self.lease_ms) {
            return Err(BridgeError::Lease(self.lease_ms));
        }
        if self.namespace.is_empty() || self.namespace.contains(['*', '$', '#', '?']) {
            return Err(BridgeError::Namespace(self.namespace.clone()));
        }
        let endpoints = [&self.listen[..], &self.connect[..]].concat();
        secure_link::endpoint::check(
            &endpoints,
            self.tls.is_some(),
            self.insecure,
            stages::bridge::EXPOSED_ON_PLAIN_TCP,
        )?;
        Ok(())
    }

    /// The zenoh key of `topic`.
    pub fn key(&self, topic: TopicId) -> String {
        format!("{}/{}", self.namespace, topic.name())
    }

    /// The zenoh key on which the bridge `zid` answers round trips.
    pub fn clock_key(&self, zid: &str) -> String {
        format!("{}/_clock/{zid}", self.namespace)
    }

    /// The zenoh key on which the bridge `zid` (or `*`: every bridge) tells
    /// the layout it receives `topic` in.
    pub fn layout_key(&self, topic: TopicId, zid: &str) -> String {
        format!("{}/_layout/{}/{zid}", self.namespace, topic.name())
    }

    /// The zenoh configuration: a peer at the given endpoints, without
    /// multicast scouting (the endpoints are explicit, and a robot's network
    /// should not join whatever zenoh peers it hears).
    pub fn zenoh_config(&self) -> Result<zenoh::Config, BridgeError> {
        let mut config = zenoh::Config::default();
        let json = |v: &[String]| format!("{v:?}");
        let mut set = |key: &str, value: String| {
            config
                .insert_json5(key, &value)
                .map_err(|e| BridgeError::zenoh(format!("zenoh config {key} = {value}"), e))
        };
        set("mode", "\"peer\"".into())?;
        set("scouting/multicast/enabled", "false".into())?;
        set("listen/endpoints", json(&self.listen))?;
        set("connect/endpoints", json(&self.connect))?;
        set("transport/link/tx/lease", self.lease_ms.to_string())?;
        // Frames travel on their own priority queue, below the small
        // messages, so joint states never wait behind a frame's fragments.
        // That queue holds a whole frame (16 batches of 64 KiB), and a frame
        // is dropped only when the link has had no room for it for a while:
        // zenoh's default (1 ms a batch) dropped frames on a busy two-core
        // machine whenever its sending thread was not scheduled for a moment.
        set(
            "transport/link/tx/queue/size/data_low",
            FRAME_QUEUE_BATCHES.to_string(),
        )?;
        set(
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop",
            FRAME_WAIT_US.to_string(),
        )?;
        set(
            "transport/link/tx/queue/congestion_control/drop/max_wait_before_drop_fragments",
            FRAME_WAIT_MAX_US.to_string(),
        )?;
        if let Some(tls) = &self.tls {
            tls.identity.configure(&mut config)?;
            tls::restrict_to(&mut config, &tls.peer, &self.allowed())?;
        }
        Ok(config)
    }

    /// What the other side may do, from what this one sends and receives
    /// (as the stage table decided them): send only the topics this side
    /// receives, subscribe only to those it sends, and ask and answer the
    /// clock and layout questions about them. The same holds in reverse
    /// for what this side may do (zenoh's access control filters both ways).
    pub fn allowed(&self) -> Vec<Allow> {
        let keys = |topics: &[TopicId], key: &dyn Fn(TopicId) -> String| -> Vec<String> {
            topics.iter().map(|&t| key(t)).collect()
        };
        let topic = |t| self.key(t);
        let layout = |t| self.layout_key(t, "*");
        let clock = vec![self.clock_key("*")];
        let allow = |id, messages, flow, keys| Allow {
            id,
            messages,
            flow,
            keys,
        };
        vec![
            // The topics, each one way.
            allow(
                "put_in",
                &["put"],
                Flow::Ingress,
                keys(&self.receive, &topic),
            ),
            allow(
                "subscribe_out",
                &["declare_subscriber"],
                Flow::Egress,
                keys(&self.receive, &topic),
            ),
            allow("put_out", &["put"], Flow::Egress, keys(&self.send, &topic)),
            allow(
                "subscribe_in",
                &["declare_subscriber"],
                Flow::Ingress,
                keys(&self.send, &topic),
            ),
            // Layouts: a sender asks the receivers of its topics.
            allow(
                "layout_answer_out",
                &["declare_queryable", "reply"],
                Flow::Egress,
                keys(&self.receive, &layout),
            ),
            allow(
                "layout_question_in",
                &["query"],
                Flow::Ingress,
                keys(&self.receive, &layout),
            ),
            allow(
                "layout_answer_in",
                &["declare_queryable", "reply"],
                Flow::Ingress,
                keys(&self.send, &layout),
            ),
            allow(
                "layout_question_out",
                &["query"],
                Flow::Egress,
                keys(&self.send, &layout),
            ),
            // Clocks: each side answers round trips and a receiver asks.
            allow(
                "clock_out",
                &["declare_queryable", "reply", "query"],
                Flow::Egress,
                clock.clone(),
            ),
            allow(
                "clock_in",
                &["declare_queryable", "reply", "query"],
                Flow::Ingress,
                clock,
            ),
        ]
    }
}

/// Batches of 64 KiB the link queues for frames: zenoh's most.
const FRAME_QUEUE_BATCHES: usize = 16;

/// How long a frame waits for room on the link before it is dropped, per
/// batch, us: longer than a busy machine leaves a thread unscheduled.
const FRAME_WAIT_US: u64 = 20_000;

/// The most a frame of many batches waits in all, us: about two frame
/// periods at 30 fps (a frame later than that is stale).
const FRAME_WAIT_MAX_US: u64 = 66_000;
