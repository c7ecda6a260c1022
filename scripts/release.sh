#!/usr/bin/env bash
# Builds the `magcal` binary for users (the `dist` profile: the release build, thin LTO, no symbol
# table) for every target the toolchain here has installed (`rustup target list --installed`),
# copies each into target/dist/<target>/, and prints its size. A target whose standard library is
# not installed is named and skipped, not silently left out. Usage: scripts/release.sh [TARGET...]
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$#" -gt 0 ]; then targets=("$@"); else mapfile -t targets < <(rustup target list --installed); fi
for target in "${targets[@]}"; do
  if ! rustup target list --installed | grep -qx "$target"; then
    echo "$target: skipped: its standard library is not installed (rustup target add $target)" >&2
    continue
  fi
  echo "== $target"
  if ! cargo build --locked --profile dist -p magcal-runner --target "$target"; then
    echo "$target: not built: see the error above (another target needs its linker, e.g. mingw-w64 for windows-gnu)" >&2
    continue
  fi
  exe=magcal
  case "$target" in *windows*) exe=magcal.exe ;; esac
  mkdir -p "target/dist/$target"
  cp "target/$target/dist/$exe" "target/dist/$target/$exe"
  bytes=$(wc -c < "target/dist/$target/$exe")
  printf '%s: target/dist/%s/%s, %d bytes (%.1f MiB)\n' "$target" "$target" "$exe" "$bytes" "$(awk -v b="$bytes" 'BEGIN { print b / 1048576 }')"
done
