#!/usr/bin/env bash
# The main job: the simulated Nico calibrates against its three mirror
# placements (the paper's protocol: 50 training and 100 test poses each,
# training sizes 3..50), prints the paper's results table beside ours, and
# writes every figure and the learning curves to out/ (or $1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out="${1:-out}"
mkdir -p "$out"
cargo run --release --quiet -p mirror_proc -- experiment --preset nico \
    --json "$out/experiment.json" --plot "$out/learning_curves.svg"
