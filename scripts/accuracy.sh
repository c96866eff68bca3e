#!/usr/bin/env bash
# The accuracy table of BENCHMARKS.md ("Accuracy at default settings"): converts every mesh
# and point cloud of ../shared/models (not nasty/) with default settings, previews each at
# the default and iso views against its mesh, and prints one Markdown row per model.
# Not part of CI. Usage: scripts/accuracy.sh [OUT_DIR]   (default out/accuracy)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/accuracy}
cargo build --release --workspace --quiet
cargo build --release -p sct-integration-tests --example accuracy --quiet
target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')
echo "accuracy: $(date -u '+%Y-%m-%d %H:%M UTC'), $(git rev-parse --short HEAD), $(nproc) cores" >&2
"$target_dir/release/examples/accuracy" --out "$out"
