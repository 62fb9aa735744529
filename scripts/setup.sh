#!/usr/bin/env bash
# Set up the development environment, idempotently (a second run only rebuilds what changed):
#   .venv (Python 3.11) with the Python dependencies (pyproject.toml's runtime, dev and capture
#   lists at the versions of constraints.txt), then the Rust extension, built with the release
#   profile (the one `make test-rust` tests with, so the dependencies compile once) and
#   pointrig installed editable, with its `pointrig` command in .venv/bin.
#
#   .venv-blender (Python 3.11) with Blender as a Python module (bpy, constraints-blender.txt),
#   the real client the Blender import tests drive: about 1 GB on disk, 40 s to install from
#   the package index (once; then only when constraints-blender.txt changes).
#
#   Headless Chromium from Debian's packages (chromium-headless-shell, when neither it nor
#   chromium is on PATH): the real browser tests/test_report.py opens report.html in, driven by
#   playwright (whose own browser download is not used). About 290 MB on disk, 30 s with
#   apt-get (once); needs root (or sudo) and apt-get.
#
#   bash scripts/setup.sh                 # everything
#   bash scripts/setup.sh --python-only   # the venvs and their packages, no Rust build
#
# Needs python3.11 (or python3 >= 3.11; PYTHON=... to choose) and a Rust toolchain (cargo).
set -euo pipefail
cd "$(dirname "$0")/.."

python_only=0
case "${1:-}" in
  "") ;;
  --python-only) python_only=1 ;;
  *) echo "usage: bash scripts/setup.sh [--python-only]" >&2; exit 2 ;;
esac

PY=${PYTHON:-}
if [ -z "$PY" ]; then
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1; then PY=$cand; break; fi
  done
fi
[ -n "$PY" ] || { echo "setup: python3.11 not found (set PYTHON=...)" >&2; exit 1; }
"$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
  || { echo "setup: $PY is older than Python 3.11" >&2; exit 1; }

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $("$PY" --version)"
  "$PY" -m venv .venv
fi

# The packages: installed again only when the lists or the pinned versions change.
stamp=.venv/.pointrig-deps
reqs=$(.venv/bin/python - <<'PYEOF'
import tomllib
with open("pyproject.toml", "rb") as fh:
    doc = tomllib.load(fh)
project = doc["project"]
print("\n".join(doc["build-system"]["requires"] + project["dependencies"]
                + project["optional-dependencies"]["dev"]
                + project["optional-dependencies"]["capture"]))
PYEOF
)
want=$(printf '%s\n' "$reqs" | cat - constraints.txt | sha256sum | cut -c1-16)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing the Python packages (pyproject.toml, pinned by constraints.txt)"
  printf '%s\n' "$reqs" > .venv/.pointrig-requirements.txt
  .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt \
    -r .venv/.pointrig-requirements.txt
  rm -f .venv/.pointrig-installed  # the package's own install follows the new list
  echo "$want" > "$stamp"
fi

# Headless Chromium for the report's browser test; a failed install does not stop the set-up:
# tests/test_report.py fails with its reason
if ! command -v chromium-headless-shell >/dev/null 2>&1 && ! command -v chromium >/dev/null 2>&1
then
  sudo=""
  [ "$(id -u)" = 0 ] || { command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null && sudo=sudo; }
  if command -v apt-get >/dev/null 2>&1 && { [ "$(id -u)" = 0 ] || [ -n "$sudo" ]; }; then
    echo "setup: installing headless Chromium (Debian's chromium-headless-shell, about 290 MB)"
    apt_install() {
      $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        chromium-headless-shell >/dev/null
    }
    apt_install || { $sudo apt-get update -qq && apt_install; } \
      || echo "setup: could not install chromium-headless-shell; the report's browser test will fail" >&2
  else
    echo "setup: install chromium-headless-shell or chromium (root and apt-get are needed here);" \
      "the report's browser test fails until then" >&2
  fi
fi

# Blender as a Python module, in a venv of its own (it pins its own numpy)
bstamp=.venv-blender/.pointrig-deps
bwant=$(sha256sum constraints-blender.txt | cut -c1-16)
if [ "$(cat "$bstamp" 2>/dev/null)" != "$bwant" ]; then
  echo "setup: installing Blender's Python module (bpy, about 1 GB) into .venv-blender"
  # a failed install does not stop the set-up: tests/test_blender.py fails with its reason
  if { [ -x .venv-blender/bin/python ] || "$PY" -m venv .venv-blender; } \
      && .venv-blender/bin/python -m pip install -q --disable-pip-version-check \
        -r constraints-blender.txt; then
    echo "$bwant" > "$bstamp"
  else
    echo "setup: could not install bpy into .venv-blender; the Blender tests will fail" >&2
  fi
fi
[ "$python_only" = 1 ] && exit 0

command -v cargo >/dev/null 2>&1 || { [ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"; }
command -v cargo >/dev/null 2>&1 \
  || { echo "setup: cargo (Rust toolchain) not found; install it with rustup" >&2; exit 1; }

# The extension, in place in python/pointrig/. The first run also installs pointrig editable
# (its .pth and the `pointrig` command), with maturin's pip step quiet (the packages are in
# already); later runs only rebuild the extension.
export VIRTUAL_ENV="$PWD/.venv" PATH="$PWD/.venv/bin:$PATH"
echo "setup: building the Rust extension (release profile; the first build takes minutes)"
if [ -f .venv/.pointrig-installed ]; then
  maturin develop --release --skip-install
else
  PIP_QUIET=1 maturin develop --release
  touch .venv/.pointrig-installed
fi

if ! out=$(.venv/bin/pointrig --version 2>&1); then
  echo "setup: .venv/bin/pointrig does not start: $out" >&2
  exit 1
fi
echo "setup: ready ($out). Run it as .venv/bin/pointrig, or after 'source .venv/bin/activate' as pointrig"
