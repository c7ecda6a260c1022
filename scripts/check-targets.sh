#!/usr/bin/env bash
# Type-checks the libraries and the binary for macOS and Windows (`cargo check --target`), so that
# the code off Unix or off Linux (liveness, file identity, memory, standard input) compiles there.
# Needs each target's standard library (`rustup target add x86_64-apple-darwin
# x86_64-pc-windows-gnu`); a target without it is named and skipped. Not run by CI: about 2 min of
# CPU a target. The Python package and the tests (Unix-only by design) are not checked.
set -euo pipefail
cd "$(dirname "$0")/.."
status=0
for target in x86_64-apple-darwin aarch64-apple-darwin x86_64-pc-windows-gnu; do
  if ! rustup target list --installed | grep -qx "$target"; then
    echo "$target: skipped: its standard library is not installed (rustup target add $target)"
    continue
  fi
  if cargo check --locked --quiet --target "$target" --workspace --exclude magcal-py; then
    echo "$target: ok"
  else
    echo "$target: FAILED"
    status=1
  fi
done
exit $status
