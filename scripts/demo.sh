#!/usr/bin/env bash
# The main job: the simulated Nico calibrates against its three mirror
# placements through the live pipeline (camera, tracker, kinematics and
# mirror stages as separate processes over iceoryx2 shared memory, each
# placement recorded to MCAP), prints
# the paper's table for the run, then reproduces the paper's offline
# experiment (50 training / 100 test poses per placement). Outputs go to
# out/ (or $1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out="${1:-out}"
mkdir -p "$out"
cargo build --release --quiet --bins -p camera_proc -p tracker_proc -p kinematics_proc -p mirror_proc -p pipeline -p recorder
./target/release/pipeline --config pipeline.toml --out "$out/pipeline"
echo
./target/release/mirror_proc experiment --preset nico \
    --json "$out/experiment.json" --plot "$out/learning_curves.svg"
