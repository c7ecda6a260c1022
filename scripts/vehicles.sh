#!/usr/bin/env bash
# Runs the vehicles that are not the paper's, writing results/<scenario>/:
#   ship            rolls +-10, pitches +-5 deg: the up axis is the weak one; outcome counts matter
#   ground-vehicle  roll and pitch +-1 deg: no design identifies the up axis's scale and bias
#   drone           every attitude, a nominal sensor: absolute and heading errors
#   usv             rolls +-15, pitches +-8 deg at Trondheim, 50 nT: the plan to fly
#   usv-paper       the same with [P1]'s residual, which runs off: what works instead
# Extra arguments go to every `magcal run` (e.g. --threads 1).
set -euo pipefail
cd "$(dirname "$0")/.."
# MAGCAL_BIN=PATH runs that binary instead of building one.
if [ -n "${MAGCAL_BIN:-}" ]; then magcal=$MAGCAL_BIN; else
  cargo build --release --locked -p magcal-runner
  magcal=./target/release/magcal
fi
for scenario in ship ground-vehicle drone usv usv-paper; do
  echo "== $scenario"
  "$magcal" run "scenarios/$scenario.toml" "$@"
done
