#!/usr/bin/env bash
# Regression check of every shipped scenario against its committed results (results/<name>/).
# Exit 1 when something moved beyond its tolerance. CI runs only the smoke scenario.
set -euo pipefail
cd "$(dirname "$0")/.."
# MAGCAL_BIN=PATH runs that binary instead of building one.
if [ -n "${MAGCAL_BIN:-}" ]; then magcal=$MAGCAL_BIN; else
  cargo build --release --locked -p magcal-runner
  magcal=./target/release/magcal
fi
status=0
for scenario in "${@:-smoke wu2014 wu2014-yaw90 noise-sweep ship ground-vehicle drone usv usv-paper criteria plan300 execution-error}"; do
  for s in $scenario; do
    if "$magcal" check "scenarios/$s.toml" --quiet; then
      echo "ok      $s: every file of results/$s within its tolerance"
    else
      status=$?
      echo "MOVED   $s (exit $status)"
    fi
  done
done
# The replays of real logs (scripts/replay-broad.sh), where the logs are at hand.
if [ "$#" -eq 0 ] && [ -d ../shared/data/broad ]; then
  for set in results/replay-*/; do
    python3 scripts/check-replay.py "${set%/}" || status=$?
  done
fi
exit $status
