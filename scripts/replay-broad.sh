#!/usr/bin/env bash
# The paper's Monte Carlo on the real readings of the BROAD trials (../shared/data/broad/), for each
# trial and scenario (magcal replay): results/replay-<scenario>-<trial>/.
# The guide's "Findings on real data" tables come from these sets; scripts/check.sh replays them again.
#
# Each set is replayed into target/replay-broad/<set>/ first and compared with the committed one as
# scripts/check-replay.py compares (the same rows, numbers within 1e-9 relative). A committed set
# that still holds is left byte for byte as it is, so a run leaves `git status` clean: a replay
# set's manifest.json records the git revision of the build and the command line, which differ
# from run to run (the fresh set, with them, stays under target/). A set that moved, or that is not
# committed yet, is replayed into results/ and shows in `git status`. --write replays every set
# into results/ whatever the comparison says.
#   scripts/replay-broad.sh [--write]
# MAGCAL_BIN=PATH runs that binary instead of building one. The six replays took 3 min 3 s on 2 cores
# under a load average of 6 to 8 (trial 02's alone about 3 s on quiet cores).
set -euo pipefail
cd "$(dirname "$0")/.."
write=0
for a in "$@"; do
  case "$a" in
    --write) write=1 ;;
    *) echo "usage: scripts/replay-broad.sh [--write]" >&2; exit 2 ;;
  esac
done
if [ -n "${MAGCAL_BIN:-}" ]; then magcal=$MAGCAL_BIN; else
  cargo build --release --locked -p magcal-runner
  magcal=./target/release/magcal
fi
export MAGCAL_BIN=$magcal   # for scripts/check-replay.py
broad=../shared/data/broad
if [ ! -d "$broad" ]; then
  echo "skipped: $broad is absent (the public logs)"; exit 0
fi
read_broad=(--where movement=1 --columns mx,my,mz --time t_s --quaternion qw,qx,qy,qz --attitude-frame enu --units uT)
fresh=target/replay-broad
mkdir -p "$fresh"

replay() { # SCENARIO TRIAL SET
  local scenario=$1 trial=$2 set=$3
  local args=("scenarios/$scenario.toml" "$broad/$trial.csv" "${read_broad[@]}" --truth impose --within-deg 10)
  if [ "$write" = 0 ] && [ -f "results/$set/manifest.json" ]; then
    "$magcal" replay "${args[@]}" --out "$fresh/$set" --quiet
    if python3 scripts/check-replay.py --against "$fresh/$set" "results/$set" >/dev/null; then
      echo "unchanged results/$set (within 1e-9 of this run's $fresh/$set)"
      return
    fi
    echo "moved   results/$set: written again"
  fi
  "$magcal" replay "${args[@]}" --out "results/$set" --quiet
  echo "written results/$set"
}

for trial in 02_undisturbed_slow_rotation_B 05_undisturbed_slow_rotation_with_breaks_B 10_undisturbed_slow_translation_A 30_disturbed_stationary_magnet_C 33_disturbed_attached_magnet_2cm; do
  replay replay-handheld "$trial" "replay-handheld-${trial%%_*}"
done
replay replay-auv 02_undisturbed_slow_rotation_B replay-auv-02
