#!/usr/bin/env bash
# Set up a local development environment from scratch, idempotently:
#   .venv (Python 3.11), the Python dependencies, and a release build of the Rust extension.
# Needs: python3.11 (or python3 >= 3.11) and a Rust toolchain (cargo). Installs open3d's one
# system library (libusb) with apt-get when it is missing and we are root.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-}
if [ -z "$PY" ]; then
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1; then PY=$cand; break; fi
  done
fi
[ -n "$PY" ] || { echo "setup: python3.11 not found" >&2; exit 1; }
command -v cargo >/dev/null 2>&1 || { [ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"; }
command -v cargo >/dev/null 2>&1 || { echo "setup: cargo (Rust toolchain) not found; install rustup" >&2; exit 1; }

# open3d's wheel links libusb-1.0 at import time.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing libusb-1.0-0 (needed by open3d)"
    (apt-get update -qq && apt-get install -y -qq libusb-1.0-0 libgomp1) >/dev/null
  else
    echo "setup: warning: libusb-1.0 missing; open3d may fail to import" >&2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=.venv/.pointrig-deps
# constraints.txt pins every package to the versions the tests and benchmarks were run with
want=$(cat pyproject.toml constraints.txt | sha256sum | cut -c1-16)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -c constraints.txt "maturin>=1.9.4,<2"
  # dependencies from pyproject (runtime + dev); the package itself is built below
  .venv/bin/python - <<'PYEOF' > .venv/.reqs
import tomllib
d = tomllib.load(open("pyproject.toml", "rb"))["project"]
print("\n".join(d["dependencies"] + d["optional-dependencies"]["dev"]))
PYEOF
  .venv/bin/python -m pip install -q -c constraints.txt -r .venv/.reqs
  echo "$want" > "$stamp"
fi
VIRTUAL_ENV="$PWD/.venv" PATH="$PWD/.venv/bin:$PATH" .venv/bin/maturin develop --release -q
