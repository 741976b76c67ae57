"""The arm driver contract, as the pipeline's Rust code writes it.

``contract.json`` beside this file is generated from the pipeline's topic
table, its bus settings and the arm driver's stage declaration (``cargo test
-p stages`` fails when it is stale). Everything this package needs to know
of the pipeline's wire (service names and limits, topics, type names and
sizes, the driver's arguments, wire values) is read from it.
"""

import json
from pathlib import Path

#: The contract, as a dict.
CONTRACT = json.loads((Path(__file__).parent / "contract.json").read_text())

SERVICE = CONTRACT["service"]
#: The one topic the driver subscribes to (pose goals) and the one it publishes (joint positions).
(GOALS_TOPIC,) = CONTRACT["subscribes"]
(POSITIONS_TOPIC,) = CONTRACT["publishes"]
TOPICS = CONTRACT["topics"]


def service_name(prefix: str, topic: str) -> str:
    """The iceoryx2 publish-subscribe service of ``topic`` in pipeline ``prefix``."""
    return SERVICE["name"].format(prefix=prefix, topic=topic)


def event_name(prefix: str, topic: str) -> str:
    """The iceoryx2 event service of ``topic`` in pipeline ``prefix``."""
    return SERVICE["event_name"].format(prefix=prefix, topic=topic)
