#!/usr/bin/env bash
# Reproduces [P1]: builds magcal and runs the paper's scenarios, writing results/<scenario>/.
#   wu2014        Table II designs, the Table I PSO and the D-optimum; 1000 trials at 30 nT; Fig. 4 runs
#   wu2014-yaw90  the same with yaw_offset_deg = 90 (the reading that matches the Uniformity figures)
#   noise-sweep   the same designs at sigma = 1 ... 300 nT
# The build takes minutes from a fresh clone (5.4 min on 2 busy cores), the runs about a minute and
# a half. Extra arguments go to every `magcal run` (e.g. --threads 1). Each result set's run.json
# (revision, threads, timings) is ignored by git, so a second run leaves the tree clean.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -p magcal-runner
for scenario in wu2014 wu2014-yaw90 noise-sweep; do
  echo "== $scenario"
  ./target/release/magcal run "scenarios/$scenario.toml" "$@"
done
