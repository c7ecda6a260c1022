#!/usr/bin/env bash
# Rebuilds the plotly.js the report pages embed (crates/magcal-report/assets/plotly-custom.min.js):
# plotly.js's core and the trace types the pages draw (scripts/plotly-bundle/index.js), bundled and
# minified as plotly.js bundles its own dist files (scripts/plotly-bundle/build.mjs), from the
# versions package-lock.json pins (`npm ci`, checked by their integrity hashes). It writes the
# bundle, plotly.js's licence beside it and the bundle's SHA-256, which the tests check the
# embedded file against. The same lock gives the same bytes. Needs node and npm and the npm
# registry; the build and CI need neither (the bundle is committed).
#   scripts/plotly-bundle.sh [--check]    --check: build into a temporary file and compare
set -euo pipefail
cd "$(dirname "$0")/.."
src="$PWD/scripts/plotly-bundle"
assets="$PWD/crates/magcal-report/assets"
check=0
[ "${1:-}" = "--check" ] && check=1

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cp "$src/package.json" "$src/package-lock.json" "$src/index.js" "$src/build.mjs" "$work/"
(cd "$work" && npm ci --no-audit --no-fund --ignore-scripts --loglevel=error >/dev/null && node build.mjs "$work/out.js")
sum=$(sha256sum "$work/out.js" | cut -d' ' -f1)
version=$(node -p "require('$work/node_modules/plotly.js/package.json').version")
echo "plotly.js $version: $(wc -c <"$work/out.js") bytes, SHA-256 $sum"

if [ "$check" = 1 ]; then
  if cmp -s "$work/out.js" "$assets/plotly-custom.min.js"; then
    echo "the committed bundle is this build, byte for byte"
  else
    echo "the committed bundle differs from this build" >&2
    exit 1
  fi
  exit 0
fi
cp "$work/out.js" "$assets/plotly-custom.min.js"
cp "$work/node_modules/plotly.js/LICENSE" "$assets/plotly.LICENSE"
echo "$sum  plotly-custom.min.js" >"$assets/plotly-custom.min.js.sha256"
