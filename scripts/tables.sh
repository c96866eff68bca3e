#!/usr/bin/env bash
# Regenerates every figure of BENCHMARKS.md "The paper's tables" (thesis Table 8, §6.12,
# §6.7): builds the release binaries, runs them on the shared bunny (median of RUNS runs),
# and writes the Markdown tables to out/tables/tables.md (also printed).
# Usage: scripts/tables.sh [RUNS]     (needs ../shared/models beside the repository)
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
cargo build --release --quiet -p voxelize -p build-tree -p inspect -p render-preview
cargo build --release --quiet -p sct-integration-tests --example tables
mkdir -p out/tables
target/release/examples/tables --out out/tables --runs "$runs" | tee out/tables/tables.md
echo "tables: written to out/tables/tables.md" >&2
