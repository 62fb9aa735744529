#!/usr/bin/env bash
# Developer shortcut: build the extension with the quick `fastdev` profile and drop it into
# python/pointrig/ so that `PYTHONPATH=python python -m pytest` uses this work tree's code.
set -euo pipefail
cd "$(dirname "$0")/.."
profile=${1:-fastdev}
cargo build --profile "$profile" --lib --message-format short
dir=target/$profile
[ "$profile" = dev ] && dir=target/debug
suffix=$(python3 -c "import sysconfig; print(sysconfig.get_config_var('EXT_SUFFIX'))")
cp "$dir/lib_core.so" "python/pointrig/_core$suffix"
