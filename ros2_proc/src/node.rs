//! A ROS 2 node on rmw_zenoh: a zenoh client session, the node's liveliness
//! token, and typed publishers and subscriptions that speak rmw_zenoh's
//! keys, CDR and attachments (see [`crate::wire`]).

use std::marker::PhantomData;
use std::path::PathBuf;
use std::sync::atomic::{AtomicI64, AtomicU32, Ordering};
use std::time::Duration;

use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh_ext::{AdvancedPublisher, AdvancedPublisherBuilderExt, CacheConfig, MissDetectionConfig};

use crate::clock::wall_ns;
use crate::types::{HUMBLE_HASH, RosType, TypeInfo};
use crate::wire::{self, Attachment, EntityKind, NodeId, Qos, WireError};

/// What stops a node.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    /// Zenoh refused something; `what` says what we asked.
    #[error("{what}: {source}")]
    Zenoh {
        /// What was asked.
        what: String,
        /// Zenoh's reason.
        source: zenoh::Error,
    },
    /// A message could not be encoded.
    #[error("{0}")]
    Wire(#[from] WireError),
    /// TLS to the router as given cannot work.
    #[error("{0}")]
    Tls(String),
    /// A certificate file or an endpoint is unusable.
    #[error(transparent)]
    Link(#[from] secure_link::LinkError),
}

fn zenoh_err(what: impl Into<String>) -> impl FnOnce(zenoh::Error) -> Ros2Error {
    let what = what.into();
    move |source| Ros2Error::Zenoh { what, source }
}

/// Where the graph is and who we are on it.
#[derive(Debug, Clone)]
pub struct NodeOptions {
    /// Zenoh endpoint to connect to (the router, `rmw_zenohd`).
    pub endpoint: String,
    /// `ROS_DOMAIN_ID`.
    pub domain: u32,
    /// The node's namespace.
    pub namespace: String,
    /// The node's name.
    pub name: String,
    /// For a `tls/` endpoint: the CA the router's certificate is signed by.
    pub tls_ca: Option<PathBuf>,
    /// Our certificate and key, for a router that requires one.
    pub tls_identity: Option<(PathBuf, PathBuf)>,
}

impl NodeOptions {
    /// TLS to the router as given: a `tls/` endpoint needs the CA; a
    /// certificate of ours is shown when asked for (mutual TLS).
    fn configure_tls(&self, config: &mut zenoh::Config) -> Result<(), Ros2Error> {
        let tls = secure_link::endpoint::exposure(&self.endpoint)?
            == secure_link::endpoint::Exposure::Tls;
        match (&self.tls_ca, &self.tls_identity) {
            (None, _) if tls => Err(Ros2Error::Tls(format!(
                "{} is tls/: give the CA of the router's certificate (--tls-ca)",
                self.endpoint
            ))),
            (Some(_), _) if !tls => Err(Ros2Error::Tls(format!(
                "--tls-ca was given but {} is not tls/",
                self.endpoint
            ))),
            (None, _) => Ok(()),
            (Some(ca), None) => Ok(secure_link::tls::trust(config, ca)?),
            (Some(ca), Some((cert, key))) => Ok(secure_link::tls::Identity {
                ca: ca.clone(),
                cert: cert.clone(),
                key: key.clone(),
            }
            .configure(config)?),
        }
    }
}

/// A node on the graph.
pub struct Node {
    session: zenoh::Session,
    id: NodeId,
    endpoint: String,
    next_entity: AtomicU32,
    _token: LivelinessToken,
}

impl Node {
    /// Connects as a zenoh client to `options.endpoint` and declares the
    /// node's token. The session has timestamping on and multicast scouting
    /// off, as rmw_zenoh's own session config
    /// (`DEFAULT_RMW_ZENOH_SESSION_CONFIG.json5:143,215-221`).
    pub fn open(options: &NodeOptions) -> Result<Node, Ros2Error> {
        let mut config = zenoh::Config::default();
        let mut set = |key: &str, value: String| {
            config
                .insert_json5(key, &value)
                .map_err(zenoh_err(format!("zenoh config {key} = {value}")))
        };
        set("mode", "\"client\"".into())?;
        set("connect/endpoints", format!("[{:?}]", options.endpoint))?;
        set("scouting/multicast/enabled", "false".into())?;
        set(
            "timestamping/enabled",
            "{ router: true, peer: true, client: true }".into(),
        )?;
        options.configure_tls(&mut config)?;
        let session = zenoh::open(config).wait().map_err(zenoh_err(format!(
            "cannot reach the ROS 2 graph at {} (is rmw_zenohd running there?)",
            options.endpoint
        )))?;
        let id = NodeId {
            domain: options.domain,
            zid: session.zid().to_string(),
            nid: 0,
            namespace: options.namespace.clone(),
            name: options.name.clone(),
        };
        let token = session
            .liveliness()
            .declare_token(id.token())
            .wait()
            .map_err(zenoh_err("declare the node's liveliness token"))?;
        Ok(Node {
            session,
            id,
            endpoint: options.endpoint.clone(),
            next_entity: AtomicU32::new(1),
            _token: token,
        })
    }

    /// The endpoint it is connected to.
    pub fn endpoint(&self) -> &str {
        &self.endpoint
    }

    /// The node's identity.
    pub fn id(&self) -> &NodeId {
        &self.id
    }

    /// The zenoh session.
    pub fn session(&self) -> &zenoh::Session {
        &self.session
    }

    /// The fully qualified name of `topic`.
    pub fn qualified(&self, topic: &str) -> String {
        wire::qualified(&self.id.namespace, topic)
    }

    fn entity_token(&self, kind: EntityKind, topic: &str, ty: &TypeInfo, qos: Qos) -> String {
        let id = self.next_entity.fetch_add(1, Ordering::Relaxed);
        self.id.endpoint_token(id, kind, topic, ty, qos)
    }

    fn declare_token(&self, token: &str) -> Result<LivelinessToken, Ros2Error> {
        self.session
            .liveliness()
            .declare_token(token.to_string())
            .wait()
            .map_err(zenoh_err(format!("declare liveliness token {token}")))
    }

    /// A publisher of `M` on `topic`, with its token.
    pub fn publisher<M: RosType>(
        &self,
        topic: &str,
        qos: Qos,
    ) -> Result<RosPublisher<M>, Ros2Error> {
        let topic = self.qualified(topic);
        let ty = M::info();
        let token = self.entity_token(EntityKind::Publisher, &topic, &ty, qos);
        let key = wire::topic_key(self.id.domain, &topic, &ty);
        // Every rmw_zenoh publisher is an advanced publisher; a
        // TRANSIENT_LOCAL one keeps its last `depth` samples for late
        // subscribers, announces itself and, if reliable, sends sporadic
        // heartbeats (`D/rmw_publisher_data.cpp:49,114-150`).
        let mut builder = self.session.declare_publisher(key.clone()).advanced();
        if qos.transient_local {
            builder = builder
                .cache(CacheConfig::default().max_samples(qos.depth as usize))
                .publisher_detection();
            if qos.reliable {
                builder = builder.sample_miss_detection(
                    MissDetectionConfig::default().sporadic_heartbeat(Duration::from_millis(500)),
                );
            }
        }
        let publisher = builder
            .wait()
            .map_err(zenoh_err(format!("declare a publisher on {key}")))?;
        Ok(RosPublisher {
            gid: wire::gid(&token),
            _token: self.declare_token(&token)?,
            publisher,
            sequence: AtomicI64::new(0),
            topic,
            _type: PhantomData,
        })
    }

    /// A subscription to `M` on `topic`, with its token, queueing at most
    /// `capacity` samples. It listens to every type hash of the type, so
    /// that a publisher of another definition is named, not missed.
    pub fn subscriber<M: RosType>(
        &self,
        topic: &str,
        qos: Qos,
        capacity: usize,
    ) -> Result<RosSubscriber<M>, Ros2Error> {
        let (admission, key, token) = self.subscription::<M>(topic, qos);
        let subscriber = self
            .session
            .declare_subscriber(key.clone())
            .with(zenoh::handlers::FifoChannel::new(capacity))
            .wait()
            .map_err(zenoh_err(format!("subscribe to {key}")))?;
        Ok(RosSubscriber {
            _token: self.declare_token(&token)?,
            subscriber,
            admission,
            _type: PhantomData,
        })
    }

    /// A subscription to `M` on `topic` that hands each raw sample to
    /// `sink` on zenoh's receiving thread, for a caller that decodes it
    /// itself (an image's pixels are borrowed, not copied) or merges
    /// several topics into one queue. Check each sample with the
    /// [`Admission`] returned.
    pub fn subscribe_raw<M: RosType>(
        &self,
        topic: &str,
        qos: Qos,
        sink: impl Fn(Sample) + Send + Sync + 'static,
    ) -> Result<(RawSubscription, Admission), Ros2Error> {
        let (admission, key, token) = self.subscription::<M>(topic, qos);
        let subscriber = self
            .session
            .declare_subscriber(key.clone())
            .callback(sink)
            .wait()
            .map_err(zenoh_err(format!("subscribe to {key}")))?;
        Ok((
            RawSubscription {
                _token: self.declare_token(&token)?,
                _subscriber: subscriber,
            },
            admission,
        ))
    }

    /// The admission check, key (any type hash) and token of a new
    /// subscription to `M` on `topic`.
    fn subscription<M: RosType>(&self, topic: &str, qos: Qos) -> (Admission, String, String) {
        let topic = self.qualified(topic);
        let ty = M::info();
        let token = self.entity_token(EntityKind::Subscription, &topic, &ty, qos);
        let key = wire::topic_key_any_hash(self.id.domain, &topic, &ty);
        (
            Admission {
                topic,
                hash: ty.hash,
            },
            key,
            token,
        )
    }
}

/// A subscription whose samples go to a callback; it ends when dropped.
pub struct RawSubscription {
    _subscriber: Subscriber<()>,
    _token: LivelinessToken,
}

/// Publishes `M` on one topic, each sample with its attachment.
pub struct RosPublisher<M> {
    publisher: AdvancedPublisher<'static>,
    gid: [u8; 16],
    sequence: AtomicI64,
    topic: String,
    _token: LivelinessToken,
    _type: PhantomData<fn(&M)>,
}

impl<M: RosType> RosPublisher<M> {
    /// Publishes `message`.
    pub fn publish(&self, message: &M) -> Result<(), Ros2Error> {
        let payload = wire::encode(message)?;
        let attachment = Attachment {
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed) + 1,
            source_ns: wall_ns(),
            gid: self.gid,
        };
        self.publisher
            .put(payload)
            .attachment(attachment.to_bytes().to_vec())
            .wait()
            .map_err(zenoh_err(format!("publish on {}", self.topic)))
    }

    /// The fully qualified topic.
    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// Why a sample that arrived is not a message.
#[derive(Debug, thiserror::Error)]
pub enum Refusal {
    /// Published by a Humble graph, which has no type hashes.
    #[error(
        "{topic} comes from a ROS 2 Humble graph (type hash {HUMBLE_HASH}); rmw_zenoh on Humble is not supported: use Jazzy or later"
    )]
    Humble {
        /// The topic.
        topic: String,
    },
    /// Published with another type hash: another definition of the type.
    #[error(
        "{topic} is published with type hash {theirs}, ours is {ours}: another definition of the type"
    )]
    OtherHash {
        /// The topic.
        topic: String,
        /// The publisher's hash.
        theirs: String,
        /// Ours.
        ours: &'static str,
    },
    /// No attachment, a bad one, or a malformed payload.
    #[error("{topic}: {source}")]
    Wire {
        /// The topic.
        topic: String,
        /// What is wrong.
        source: WireError,
    },
}

/// A message and what came with it.
#[derive(Debug)]
pub struct Received<M> {
    /// The message.
    pub message: M,
    /// Its attachment.
    pub attachment: Attachment,
}

/// Whether a sample on a subscription's topic is a message we read: the
/// type hash is ours and it carries rmw_zenoh's attachment.
#[derive(Debug, Clone)]
pub struct Admission {
    topic: String,
    hash: &'static str,
}

impl Admission {
    /// The sample's attachment, or why the sample is refused.
    pub fn check(&self, sample: &Sample) -> Result<Attachment, Refusal> {
        let theirs = sample.key_expr().as_str().rsplit('/').next().unwrap_or("");
        if theirs == HUMBLE_HASH {
            return Err(Refusal::Humble {
                topic: self.topic.clone(),
            });
        }
        if theirs != self.hash {
            return Err(Refusal::OtherHash {
                topic: self.topic.clone(),
                theirs: theirs.to_string(),
                ours: self.hash,
            });
        }
        let attachment = sample
            .attachment()
            .ok_or_else(|| self.wire(WireError::NoAttachment))?;
        Attachment::parse(&attachment.to_bytes()).map_err(|e| self.wire(e))
    }

    /// A malformed sample's refusal.
    pub fn wire(&self, source: WireError) -> Refusal {
        Refusal::Wire {
            topic: self.topic.clone(),
            source,
        }
    }

    /// The fully qualified topic.
    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// Receives `M` from one topic.
pub struct RosSubscriber<M> {
    subscriber: Subscriber<FifoChannelHandler<Sample>>,
    admission: Admission,
    _token: LivelinessToken,
    _type: PhantomData<fn() -> M>,
}

impl<M: RosType> RosSubscriber<M> {
    /// The next sample within `timeout`: `None` if none came, else the
    /// message or why it is refused.
    pub fn recv_timeout(&self, timeout: Duration) -> Option<Result<Received<M>, Refusal>> {
        let sample = self.subscriber.handler().recv_timeout(timeout).ok()??;
        Some(self.admit(&sample))
    }

    /// The next sample already queued, if any.
    pub fn try_recv(&self) -> Option<Result<Received<M>, Refusal>> {
        let sample = self.subscriber.handler().try_recv().ok()??;
        Some(self.admit(&sample))
    }

    fn admit(&self, sample: &Sample) -> Result<Received<M>, Refusal> {
        let attachment = self.admission.check(sample)?;
        let payload = sample.payload().to_bytes();
        let message = wire::decode::<M>(&payload).map_err(|e| self.admission.wire(e))?;
        Ok(Received {
            message,
            attachment,
        })
    }

    /// The fully qualified topic.
    pub fn topic(&self) -> &str {
        self.admission.topic()
    }
}
