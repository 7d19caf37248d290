#!/usr/bin/env bash
# Create .venv (Python 3.11) and install harborsight with its test tools. Idempotent: a
# re-run only installs what changed. Used by scripts/demo.sh and scripts/test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
if ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    echo "harborsight needs Python 3.11 (bpy 4.5 does); found $("$PYTHON" --version)" >&2
    exit 1
fi

# Blender (bpy) links against a few X11/GL libraries that a bare Debian/Ubuntu lacks
BPY_DEBS="libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libxext6 libsm6 libice6 libgl1 libglx0 libglvnd0"
# the live dashboard's browser test (tests/test_live.py) runs Debian's headless Chromium
BROWSER_DEBS="chromium chromium-driver"
missing=""
if command -v dpkg-query >/dev/null 2>&1; then
    for deb in $BPY_DEBS $BROWSER_DEBS; do
        dpkg-query -W -f='${Status}' "$deb" 2>/dev/null | grep -q "ok installed" || missing="$missing $deb"
    done
fi
# the live aid's Signal K and RTSP tests run real servers from npm (signalk-server, rtsp-streaming-server)
if ! command -v npm >/dev/null 2>&1; then
    missing="$missing nodejs npm"
fi
if [ -n "$missing" ]; then
    echo "installing system packages (Blender's libraries, Chromium for the browser test, Node.js for Signal K):$missing"
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing
fi

stamp=.venv/.installed
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
# reinstall when the project's requirements changed since the last install
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e ".[dev,train,sim]"
    touch "$stamp"
fi

# npm_tool NAME VERSION DIR: the npm package NAME@VERSION in .tools/DIR, once
npm_tool() {
    if [ ! -f ".tools/$3/.installed-$2" ]; then
        echo "installing $1 $2 (npm) into .tools/$3"
        mkdir -p ".tools/$3"
        npm install --silent --no-audit --no-fund --prefix ".tools/$3" "$1@$2"
        touch ".tools/$3/.installed-$2"
    fi
}
# signalk-server for tests/test_signalk.py (2.23.0: the newest whose dependencies all resolve
# on the npm registry today; 2.32.0 needs an unpublished @signalk/streams)
npm_tool signalk-server 2.23.0 signalk
# rtsp-streaming-server for the live aid's RTSP test (tests/test_live_feeds.py)
npm_tool rtsp-streaming-server 2.1.0 rtsp
