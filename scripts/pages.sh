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
cargo build --release --locked -q -p magcal-runner
magcal=./target/release/magcal
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
if [ -f "$broad" ]; then
  # The moving readings with an attitude (the trial's `movement` flag, a capture quaternion).
  awk -F, 'NR == 1 || ($NF == 1 && $11 != "")' "$broad" > "$work/broad02.csv"
  $magcal calibrate "$work/broad02.csv" --columns mx,my,mz --quaternion qw,qx,qy,qz \
    --attitude-frame enu --units uT --scenario scenarios/wu2014.toml --out "$work/cal-broad02" >/dev/null || [ $? -eq 3 ]
  $magcal report "$work/cal-broad02" --out "$out/calibration-broad02.html"
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
fi
ls -l "$out"
