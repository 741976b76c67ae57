#!/usr/bin/env bash
# Installs what the workspace needs on a fresh Debian 12 machine: OpenCV 4.6
# with the contrib aruco module, clang for the opencv crate's bindings,
# Python with venv for the tests' independent MCAP reader, and Node.js with
# npm for the tests' Foxglove client (unless a Node.js is already there),
# iproute2 for the bridge tests' network namespaces.
# Installs the Python arm-driver SDK (python/mirror_driver, on PyPI's
# iceoryx2 bindings) into target/pyenv. Does nothing when everything is
# already there.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(pkg-config clang libclang-dev libopencv-dev libopencv-contrib-dev python3 python3-venv iproute2)
# A Node.js installed otherwise (NodeSource, nvm) brings its own npm; Debian's would conflict.
command -v npm >/dev/null || packages+=(nodejs npm)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing ${missing[*]}" >&2
    sudo=""
    [ "$(id -u)" -ne 0 ] && sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

command -v cargo >/dev/null || { echo "setup: cargo not found; install Rust (https://rustup.rs)" >&2; exit 1; }
for component in rustfmt clippy; do
    if ! cargo "${component/rustfmt/fmt}" --version >/dev/null 2>&1; then
        echo "setup: adding rustup component $component" >&2
        rustup component add "$component"
    fi
done

# The Python arm-driver SDK, editable: target/pyenv/bin/python runs a driver
# such as python/examples/sim_arm.py against the repository's SDK.
if [ ! -x target/pyenv/bin/python ]; then
    python3 -m venv target/pyenv
fi
if ! target/pyenv/bin/python -c "import mirror_driver" 2>/dev/null; then
    echo "setup: installing the Python driver SDK into target/pyenv" >&2
    target/pyenv/bin/pip install --quiet --disable-pip-version-check \
        --editable python/mirror_driver
fi
