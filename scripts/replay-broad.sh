#!/usr/bin/env bash
# The paper's Monte Carlo on the real readings of the BROAD trials (../shared/data/broad/):
# writes results/replay-<scenario>-<trial>/ for each trial and scenario (magcal replay).
# The README's "Real-data truth" tables come from these sets; scripts/check.sh replays them again.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -p magcal-runner
broad=../shared/data/broad
if [ ! -d "$broad" ]; then
  echo "skipped: $broad is absent (the public logs)"; exit 0
fi
read_broad=(--where movement=1 --columns mx,my,mz --time t_s --quaternion qw,qx,qy,qz --attitude-frame enu --units uT)
for trial in 02_undisturbed_slow_rotation_B 05_undisturbed_slow_rotation_with_breaks_B 10_undisturbed_slow_translation_A 30_disturbed_stationary_magnet_C 33_disturbed_attached_magnet_2cm; do
  short=${trial%%_*}
  ./target/release/magcal replay scenarios/replay-handheld.toml "$broad/$trial.csv" "${read_broad[@]}" \
    --truth impose --within-deg 10 --out "results/replay-handheld-$short" --quiet
  echo "written results/replay-handheld-$short"
done
./target/release/magcal replay scenarios/replay-auv.toml "$broad/02_undisturbed_slow_rotation_B.csv" "${read_broad[@]}" \
  --truth impose --within-deg 10 --out results/replay-auv-02 --quiet
echo "written results/replay-auv-02"
