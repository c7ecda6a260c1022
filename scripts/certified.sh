#!/usr/bin/env bash
# Runs the scenarios of certified designs, writing results/<scenario>/:
#   criteria         D-, A- and E-optimal designs of the AUV by the optimiser and the PSO
#   plan300          the certified approximate design rounded to 300 readings, against 300 uniform
#   execution-error  the AUV designs flown with attitude errors of 0, 1 and 3 degrees
# Extra arguments go to every `magcal run` (e.g. --threads 1).
set -euo pipefail
cd "$(dirname "$0")/.."
# MAGCAL_BIN=PATH runs that binary instead of building one.
if [ -n "${MAGCAL_BIN:-}" ]; then magcal=$MAGCAL_BIN; else
  cargo build --release --locked -p magcal-runner
  magcal=./target/release/magcal
fi
for scenario in criteria plan300 execution-error; do
  echo "== $scenario"
  "$magcal" run "scenarios/$scenario.toml" "$@"
done
