#!/usr/bin/env bash
# Sets up lunar_drake on a fresh machine (first call) and runs it; usage() below says how.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
cd "$here"
venv="$here/.venv"
py="${PYTHON:-python3}"

system_deps() {
  # open3d's wheel links libusb-1.0 (and libgomp); Debian/Ubuntu names below.
  local libs
  libs="$(ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null || true)"
  if [[ "$libs" != *libusb-1.0.so.0* ]]; then
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    echo "lunar.sh: installing system library libusb-1.0-0 (needed by open3d)" >&2
    $sudo apt-get update -qq >/dev/null 2>&1 || true
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq libusb-1.0-0 libgomp1 >/dev/null
  fi
}

python_deps() {
  local stamp="$venv/.lunar_drake-installed"
  local want
  want="$(sha256sum pyproject.toml | cut -d' ' -f1)"
  if [ ! -x "$venv/bin/python" ]; then
    "$py" -m venv "$venv"
  fi
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "lunar.sh: installing Python dependencies into .venv (first run takes a few minutes)" >&2
    "$venv/bin/python" -m pip install -q --upgrade pip >/dev/null 2>&1 || true
    "$venv/bin/python" -m pip install -q -e ".[dev]"
    echo "$want" > "$stamp"
  fi
}

web_deps() {
  # Open MCT for the mission-control page, from npm (Node and npm from Debian if missing).
  local web="$here/lunar_drake/mission_control/web"
  local stamp="$web/node_modules/.lunar_drake-installed"
  local want
  want="$(sha256sum "$web/package.json" | cut -d' ' -f1)"
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -f "$web/node_modules/openmct/dist/openmct.js" ]; then
    return
  fi
  if ! command -v npm >/dev/null 2>&1; then
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    echo "lunar.sh: installing Node.js and npm (Debian packages) for the mission-control page" >&2
    $sudo apt-get update -qq >/dev/null 2>&1 || true
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq nodejs npm >/dev/null
  fi
  echo "lunar.sh: installing Open MCT (npm) for the mission-control page" >&2
  (cd "$web" && npm install --no-audit --no-fund --ignore-scripts --loglevel=error >/dev/null)
  echo "$want" > "$stamp"
}

malloc_tunables() {
  # glibc's malloc cache raised for everything the tests start (lunar_drake/allocator.py;
  # lunar-drake and the benchmarks do it themselves): unless set already or opted out
  local t
  t="$("$venv/bin/python" -c 'import os; from lunar_drake.allocator import tunables_to_set as t; print(t(os.environ) or "")')"
  if [ -n "$t" ]; then export GLIBC_TUNABLES="$t"; fi
}

browser_deps() {
  # Debian's Chromium for the real-browser tests (Playwright drives it; no browser download).
  if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
    return
  fi
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "lunar.sh: installing Chromium (Debian package) for the browser tests" >&2
  $sudo apt-get update -qq >/dev/null 2>&1 || true
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq chromium >/dev/null
}

setup() { system_deps; python_deps; web_deps; }

usage() {
  cat <<'EOF'
Usage: ./lunar.sh [COMMAND [OPTIONS]]

Sets up lunar_drake on first use (a Python virtual environment in .venv, the system
library libusb-1.0 that open3d needs, and Open MCT from npm for the mission-control page;
a few minutes), then runs COMMAND:

  ./lunar.sh setup                  set-up only
  ./lunar.sh run [OPTIONS]          a mission (the default one if no --scenario; also
                                    what ./lunar.sh alone does): minutes on 2 cores and a
                                    few hundred MB in runs/default; --scenario goto is a
                                    first look in a minute or two
  ./lunar.sh run --serve            a live mission: prints the mission-control URL (Open
                                    MCT), paced to real time; drive the rover from the page
  ./lunar.sh serve RUN_DIR          a finished run in the mission-control page
  ./lunar.sh test [PYTEST OPTIONS]  ruff, then the test suite (installs Debian's Chromium
                                    for the browser tests)
  ./lunar.sh scenarios              the shipped scenarios, one line each
  ./lunar.sh COMMAND [OPTIONS]      any lunar-drake command: run, scenarios, plan, render,
                                    serve, export-mcap, terrain synth, world build,
                                    trade, slip-study, vo-study, slip-fit, ephemeris,
                                    lightmap
  ./lunar.sh COMMAND --help         the options of one command
  ./lunar.sh help | -h | --help     this text (no set-up)
EOF
}

cmd="${1:-run}"
[ $# -gt 0 ] && shift
case "$cmd" in
  help|-h|--help) usage ;;
  setup) setup ;;
  run) setup; exec "$venv/bin/lunar-drake" run "$@" ;;
  test)
    setup
    browser_deps
    malloc_tunables
    "$venv/bin/ruff" check lunar_drake tests benchmarks
    exec "$venv/bin/python" -m pytest -q "$@" ;;
  *) setup; exec "$venv/bin/lunar-drake" "$cmd" "$@" ;;
esac
