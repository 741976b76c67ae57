#!/usr/bin/env bash
# The test command: installs what is missing, then formatting, lints, docs,
# and every test of the workspace (benchmarks run once each, in test mode).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# The independent MCAP reader and the official Foxglove schemas, for the
# recording tests; OpenCV 5's stock ArUco detector, the real-image test's
# reference; PyPI zenoh and rosbags, an independent ROS 2 wire (zenoh, CDR,
# type hashes) for the ros2 stage's tests (setup.sh made target/pyenv).
target/pyenv/bin/pip install --quiet --disable-pip-version-check \
    "mcap==1.6.*" "foxglove-schemas-protobuf==0.4.*" "websockets==15.*" \
    "opencv-contrib-python-headless==5.0.0.93" "eclipse-zenoh==1.10.*" "rosbags==0.11.*"
# The official Foxglove WebSocket client library, for the live view's tests.
if [ ! -d target/node/node_modules/@foxglove/ws-protocol ]; then
    npm install --prefix target/node --no-audit --no-fund --silent \
        "@foxglove/ws-protocol@0.8" "ws@8"
fi

# A fresh build gains nothing from incremental state; it only doubles the
# target directory's size on disk.
export CARGO_INCREMENTAL=0

# Each step's start is logged with the time so far, to see where CI time goes.
step() { echo "test.sh: ${SECONDS}s: $*" >&2; "$@"; }
step cargo fmt --all -- --check
step cargo clippy --workspace --all-targets -- -D warnings
RUSTDOCFLAGS="-D warnings" step cargo doc --workspace --no-deps --quiet
step cargo test --workspace --all-targets
step cargo test --workspace --doc
echo "test.sh: ${SECONDS}s: done" >&2
