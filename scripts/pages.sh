#!/usr/bin/env bash
# The report pages (`magcal report`, `next --report`, `evaluate --report`) of the shipped result
# sets and of calibrations of two public logs, into DIR (default target/pages; each page is a
# self-contained HTML file of a few MB, so they are built on demand, not committed). With
# --shots, also the screenshots the README shows (docs/img/report-*.png), taken in the headless
# Chromium the browser tests use.
#   scripts/pages.sh [DIR] [--shots]
set -euo pipefail
cd "$(dirname "$0")/.."
out="target/pages"
shots=0
for a in "$@"; do
  case "$a" in
    --shots) shots=1 ;;
    *) out="$a" ;;
  esac
done
# MAGCAL_BIN=PATH runs that binary instead of building one.
if [ -n "${MAGCAL_BIN:-}" ]; then magcal=$MAGCAL_BIN; else
  cargo build --release --locked -q -p magcal-runner
  magcal=./target/release/magcal
fi
data=../shared/data
mkdir -p "$out"

echo "== the shipped result sets"
for set in results/*/; do
  name=$(basename "$set")
  [ -f "$set/manifest.json" ] || continue
  $magcal report "$set" --out "$out/$name.html"
done

echo "== calibrations of public logs"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
if [ -f "$data/hamagure/data-set_1.csv" ]; then
  $magcal calibrate "$data/hamagure/data-set_1.csv" --out "$work/cal-hamagure" >/dev/null || [ $? -eq 3 ]
  $magcal report "$work/cal-hamagure" --out "$out/calibration-hamagure.html"
fi
broad="$data/broad/02_undisturbed_slow_rotation_B.csv"
# BROAD trial 02 while it moves, attitudes from the motion capture.
read_broad=(--where movement=1 --columns mx,my,mz --time t_s --quaternion qw,qx,qy,qz --attitude-frame enu)
if [ -f "$broad" ]; then
  $magcal calibrate "$broad" "${read_broad[@]}" --units uT --scenario scenarios/wu2014.toml --out "$work/cal-broad02" >/dev/null || [ $? -eq 3 ]
  $magcal report "$work/cal-broad02" --out "$out/calibration-broad02.html"
fi

echo "== next and evaluate"
if [ -f "$data/hamagure/data-set_2.csv" ]; then
  $magcal calibrate "$data/hamagure/data-set_2.csv" --out "$work/cal-hamagure-2" >/dev/null || [ $? -eq 3 ]
  $magcal next "$work/cal-hamagure-2/calibration.json" "$data/hamagure/data-set_2.csv" \
    --scenario scenarios/drone.toml --report "$out/next-hamagure-2.html" >/dev/null 2>&1
fi
if [ -f "$broad" ]; then
  $magcal evaluate "$work/cal-broad02/calibration.json" "$broad" "${read_broad[@]}" \
    --report "$out/evaluate-broad02.html" >/dev/null
fi

if [ "$shots" = 1 ]; then
  echo "== screenshots for the README"
  mkdir -p docs/img
  shot() { # PAGE ID NAME
    cargo run --release --locked -q -p magcal-runner --example page_shots -- "$out/$1" "$work/shots" "$2" >/dev/null
    cp "$work/shots/$2.png" "docs/img/report-$3.png"
    echo "docs/img/report-$3.png"
  }
  shot calibration-broad02.html raw-box calibration-raw
  shot calibration-broad02.html coverage-box calibration-coverage
  shot calibration-broad02.html roll-pitch-box calibration-attitudes
  shot next-hamagure-2.html coverage-box next-coverage
  shot next-hamagure-2.html attitudes next-attitudes
  shot evaluate-broad02.html error-heading-box evaluate-heading
  shot replay-handheld-02.html dist-heading-rms-deg-box replay-heading-rms
  shot wu2014.html plan-box design-plan
  shot noise-sweep.html sweep-box run-noise-sweep
fi
ls -l "$out"
