#!/usr/bin/env bash
# Reproduces [P1]: builds magcal and runs the paper's scenarios, writing results/<scenario>/.
#   wu2014        Table II designs, the Table I PSO and the D-optimum; 1000 trials at 30 nT; Fig. 4 runs
#   wu2014-yaw90  the same with yaw_offset_deg = 90 (the reading that matches the Uniformity figures)
#   noise-sweep   the same designs at sigma = 1 ... 300 nT
# From a fresh clone on 2 shared cores (load average 1.8 to 2.4) it took 4 min 42 s: about 4 min
# building and 40 s running (an earlier build on busier cores took 5.4 min); the runs alone took
# 131 s under a load average of 8 (docs/research/paper.md). Extra arguments go to every
# `magcal run` (e.g. --threads 1). Each result set's run.json (revision, threads, timings) is
# ignored by git, so a second run leaves the tree clean.
set -euo pipefail
cd "$(dirname "$0")/.."
# MAGCAL_BIN=PATH runs that binary instead of building one.
if [ -n "${MAGCAL_BIN:-}" ]; then magcal=$MAGCAL_BIN; else
  cargo build --release --locked -p magcal-runner
  magcal=./target/release/magcal
fi
for scenario in wu2014 wu2014-yaw90 noise-sweep; do
  echo "== $scenario"
  "$magcal" run "scenarios/$scenario.toml" "$@"
done
