#!/usr/bin/env bash
# One-shot, idempotent setup for policy-composer on a fresh Debian bookworm machine (run as root).
#  1. System packages: Mesa >= 24.3 (lavapipe, SAPIEN's CPU Vulkan renderer) from bookworm-backports,
#     FFmpeg libraries (torchcodec decoding of LeRobot videos), Chromium (the report's headless-browser test).
#  2. Python: a virtual environment in .venv, built with a Python 3.12 interpreter (lerobot 0.6 needs it), with the
#     pinned packages and the project (editable). Set PYTHON=/path/to/python3.12 to choose the interpreter.
# A second run checks stamps and finishes in seconds.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
VENV="$ROOT/.venv"
PY_WANT=3.12

log() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }

mesa_ok() {
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  [ -n "$v" ] && dpkg --compare-versions "$v" ge 24.3
}

system_packages() {
  local need=()
  mesa_ok || need+=(mesa)
  dpkg-query -W -f='${Status}' ffmpeg 2>/dev/null | grep -q "ok installed" || need+=(ffmpeg)
  dpkg-query -W -f='${Status}' chromium 2>/dev/null | grep -q "ok installed" || need+=(chromium)
  if [ ${#need[@]} -eq 0 ]; then log "system packages present"; return; fi
  if [ "$(id -u)" != 0 ]; then
    echo "setup: system packages missing (${need[*]}); run this script as root" >&2; exit 1
  fi
  if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    # Reuse the machine's own Debian mirror rather than hard-coding one.
    local uri
    uri=$(grep -hE '^URIs:' /etc/apt/sources.list.d/*.sources 2>/dev/null | grep -v security | head -n1 | awk '{print $2}')
    [ -n "$uri" ] || uri=$(grep -hE '^deb ' /etc/apt/sources.list 2>/dev/null | grep -v security | head -n1 | awk '{print $2}')
    [ -n "$uri" ] || { echo "setup: cannot find the machine's Debian mirror in /etc/apt" >&2; exit 1; }
    log "enabling bookworm-backports from $uri"
    cat > /etc/apt/sources.list.d/bookworm-backports.sources <<SRC
Types: deb
URIs: $uri
Suites: bookworm-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
SRC
  fi
  log "apt-get install: ${need[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
  apt-get install -y -qq ffmpeg chromium >/dev/null
  mesa_ok || { echo "setup: mesa-vulkan-drivers >= 24.3 did not install" >&2; exit 1; }
}

is_py_want() { "$1" -c "import sys; sys.exit(sys.version_info[:2] != (3, 12))" 2>/dev/null; }

# A Python 3.12 interpreter: $PYTHON, python3.12 or python3 on PATH, pyenv's or uv's installs.
find_python() {
  local c
  for c in ${PYTHON:-} python$PY_WANT python3 \
           "$(pyenv root 2>/dev/null)"/versions/$PY_WANT*/bin/python$PY_WANT \
           "$HOME"/.pyenv/versions/$PY_WANT*/bin/python$PY_WANT \
           "$(uv python find $PY_WANT 2>/dev/null)"; do
    [ -n "$c" ] && command -v "$c" >/dev/null 2>&1 && is_py_want "$c" && { command -v "$c"; return; }
  done
  echo "setup: no Python $PY_WANT interpreter found (lerobot 0.6 needs it). Install one (for example" \
       "'uv python install $PY_WANT' or your distribution's python$PY_WANT) or point PYTHON= at it." >&2
  exit 1
}

python_packages() {
  local stamp="$VENV/.setup-stamp" want
  want=$(cat pyproject.toml plugins/*/pyproject.toml scripts/setup.sh | sha256sum | cut -c1-16)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then log "virtual environment up to date"; return; fi
  if [ -x "$VENV/bin/python" ] && ! is_py_want "$VENV/bin/python"; then
    log "rebuilding .venv with Python $PY_WANT (it was built with $("$VENV/bin/python" -V 2>&1))"; rm -rf "$VENV"
  fi
  if [ ! -x "$VENV/bin/python" ]; then
    local py; py=$(find_python)
    log "creating .venv with $py"; "$py" -m venv "$VENV"
  fi
  "$VENV/bin/python" -m pip install -q --upgrade pip uv
  log "installing Python packages into .venv (first time: several minutes, torch is large)"
  # The project with Ray (the tests start a local cluster), and its LeRobot plugins: the env (lerobot-eval
  # --env.type=gear_assembly) and the paper's policy (lerobot-train --policy.type=cnn_mdn).
  VIRTUAL_ENV="$VENV" "$VENV/bin/uv" pip install --python "$VENV/bin/python" -e ".[test,distributed]" \
    -e plugins/lerobot_env_gear_assembly -e plugins/lerobot_policy_cnn_mdn
  # Bytecode compiled once: each new process (a worker, a subprocess) then starts seconds sooner, also where
  # PYTHONDONTWRITEBYTECODE keeps Python from caching what it compiles at import.
  log "compiling the installed packages' bytecode"
  local site; site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_path("purelib"))')
  "$VENV/bin/python" -W ignore -m compileall -q -j 0 "$site" >/dev/null
  echo "$want" > "$stamp"
}

system_packages
python_packages
log "done: activate with 'source .venv/bin/activate'"
