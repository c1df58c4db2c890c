# shellcheck shell=bash
# Sourced by scripts/demo and scripts/test, or by hand (`source scripts/bootstrap.sh`): creates
# .venv on first use and (re)installs the package and its dependencies whenever
# requirements.txt, setup.py or setup.cfg change, then puts .venv/bin first on PATH. The
# caller's shell options are left as they were: the installation runs in a subshell of its own
# (set -euo pipefail there only), and a failure returns 1 instead of ending the caller's shell.
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV="$ROOT/.venv"
if ! (
  set -euo pipefail
  PYTHON=${PYTHON:-python3}
  stamp="$VENV/.installed"
  want=$(cat "$ROOT/requirements.txt" "$ROOT/setup.py" "$ROOT/setup.cfg" | sha256sum | cut -d' ' -f1)
  if [ ! -x "$VENV/bin/python" ]; then
    echo "bootstrap: creating $VENV" >&2
    "$PYTHON" -m venv "$VENV"
  fi
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    echo "bootstrap: installing dependencies into $VENV (about a minute)" >&2
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip 2>&1 \
      | grep -v 'is ignored' >&2 || true
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r "$ROOT/requirements.txt" 2>&1 \
      | grep -v 'is ignored' >&2 || true
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps -e "$ROOT" 2>&1 \
      | grep -v 'is ignored' >&2 || true
    "$VENV/bin/python" -c 'import rclpy, numba, curve_formation' \
      || { echo 'bootstrap: installation failed' >&2; exit 1; }
    echo "$want" > "$stamp"
  fi
); then
  echo "bootstrap: could not set up $VENV" >&2
  return 1 2>/dev/null || exit 1
fi
export PATH="$VENV/bin:$PATH"
# DDS traffic stays on this machine unless the caller says otherwise.
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
export NUMBA_CACHE_DIR=${NUMBA_CACHE_DIR:-$VENV/numba-cache}
