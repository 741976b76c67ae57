//! Why a bridge cannot start or stops: [`BridgeError`].

use messages::topics::TopicId;
use runtime::BusError;

/// A failure of the bridge, by kind: options that cannot work, zenoh's
/// errors (kept as the source, with what was being done), the bus's, and
/// a receiver that takes a sent topic in another layout.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// A topic both sent and received: it would come back to its sender
    /// and go round the link for ever.
    #[error(
        "topic {} is both sent and received; each topic crosses one way",
        .0.name()
    )]
    SentAndReceived(TopicId),
    /// No topic to send nor to receive.
    #[error("nothing to bridge: give --send and/or --receive")]
    NothingToBridge,
    /// No endpoint to listen on nor to connect to.
    #[error("no link: give --listen and/or --connect")]
    NoLink,
    /// A lease (ms) outside 100 ms to 10 min.
    #[error("lease {0} ms is not within 100 ms to 10 min")]
    Lease(u64),
    /// A namespace that is empty or holds a character zenoh gives a meaning
    /// in keys (`*`, `$`, `#`, `?`).
    #[error("namespace {0:?} is not a plain zenoh key")]
    Namespace(String),
    /// The link's security as given cannot work (an endpoint, a
    /// certificate).
    #[error(transparent)]
    Link(#[from] secure_link::LinkError),
    /// Zenoh failed doing `context`.
    #[error("{context}")]
    Zenoh {
        /// What was being done.
        context: String,
        /// Zenoh's error.
        #[source]
        source: zenoh::Error,
    },
    /// The shared-memory bus failed.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// A received topic could not be published here.
    #[error("publishing {} here", .topic.name())]
    Publish {
        /// The topic.
        topic: TopicId,
        /// Why.
        #[source]
        source: BusError,
    },
    /// A receiver on the link takes a sent topic in another layout (the two
    /// hosts run builds that do not agree: nothing of the topic would open).
    #[error(
        "layout mismatch on {}: this side's is {ours}, the receiver {receiver}'s is {theirs}",
        .topic.name()
    )]
    LayoutMismatch {
        /// The topic.
        topic: TopicId,
        /// This side's layout (its versioned type name).
        ours: String,
        /// The receiving bridge's zenoh id.
        receiver: String,
        /// The receiver's layout.
        theirs: String,
    },
    /// A thread of the bridge (`receiving` or `putting`) panicked.
    #[error("the {0} thread panicked")]
    Panicked(&'static str),
}

impl BridgeError {
    /// Zenoh's error `source`, met doing `context`.
    pub(crate) fn zenoh(context: impl Into<String>, source: zenoh::Error) -> Self {
        Self::Zenoh {
            context: context.into(),
            source,
        }
    }
}
