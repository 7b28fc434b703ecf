#!/usr/bin/env bash
# Scaling of the default SLAM (scan_match mode) with particles, map resolution and scan count:
# one `pfslam-dev bench-e2e` per configuration on simulated car drives, one markdown table row each.
# Usage: scripts/scaling.sh [RUNS] > table.md   (needs `cargo build --release` first;
# PFSLAM=path/to/pfslam and PFSLAM_DEV=path/to/pfslam-dev override the binaries). Wall times depend on the machine's load: the
# CPU column (user + system, all threads) is the steadier figure.
set -euo pipefail
RUNS=${1:-1}
BIN=${PFSLAM:-${CARGO_TARGET_DIR:-target}/release/pfslam}
DEV=${PFSLAM_DEV:-${BIN}-dev}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
for d in 30 60 120 240; do
  "$BIN" simulate --duration-s "$d" --out "$WORK/d$d" > /dev/null
done
header='| scans | particles | cell (m) | total wall (s) | total CPU (s) | SLAM wall (s) | SLAM CPU (s) | match wall (s) | scans/s | peak RSS (MB) |'
rule='|---|---|---|---|---|---|---|---|---|---|'
row() { "$DEV" --log warn bench-e2e --dataset "$1" --runs "$RUNS" "${@:2}" | sed -n 's/^row: //p'; }
echo "### Particles (60 s drive, 0.1 m cells)"; echo "$header"; echo "$rule"
for p in 1 10 40 100 200; do row "$WORK/d60" --particles "$p"; done
echo; echo "### Map resolution (60 s drive, 40 particles)"; echo "$header"; echo "$rule"
for r in 1.0 0.5 0.2 0.1 0.05; do row "$WORK/d60" --particles 40 --resolution "$r"; done
echo; echo "### Scan count (40 particles, 0.1 m cells)"; echo "$header"; echo "$rule"
for d in 30 60 120 240; do row "$WORK/d$d" --particles 40; done
