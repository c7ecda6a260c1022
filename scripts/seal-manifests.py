#!/usr/bin/env python3
"""Adds the own hash (`manifest_sha256`) to result-set manifests written before magcal recorded it.

The field is appended as the manifest's last member, exactly as magcal writes it (two spaces of
indentation, the other bytes untouched), and holds the SHA-256 of the file with the field's value
empty (`"manifest_sha256": ""`); see crates/magcal-report/src/manifest.rs. Only the manifest
changes: no other file of the set is read or written, so the file hashes it records stay true.
A manifest that already has the field is left as it is.

    python3 scripts/seal-manifests.py                  # every results/*/manifest.json
    python3 scripts/seal-manifests.py DIR/manifest.json ...
"""

import hashlib
import json
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
WHITE = b" \t\r\n"


def seal(path: pathlib.Path) -> bool:
    """Seals the manifest at `path`; False when it was sealed already."""
    data = path.read_bytes()
    manifest = json.loads(data)
    if not isinstance(manifest, dict):
        raise SystemExit(f"{path}: not a JSON object")
    if "manifest_sha256" in manifest:
        return False
    end = data.rstrip(WHITE)
    if not end.endswith(b"}"):
        raise SystemExit(f"{path}: does not end with '}}'")
    body = end[:-1].rstrip(WHITE)
    # White space before the final brace and after it, as they were.
    before_brace = end[len(body) : -1]
    after = data[len(end) :]

    def with_value(value: bytes) -> bytes:
        member = b',\n  "manifest_sha256": "' + value + b'"'
        return body + member + before_brace + b"}" + after

    digest = hashlib.sha256(with_value(b"")).hexdigest().encode()
    sealed = with_value(digest)
    if json.loads(sealed) != {**manifest, "manifest_sha256": digest.decode()}:
        raise SystemExit(f"{path}: sealing would change the manifest")
    path.write_bytes(sealed)
    return True


def main() -> None:
    paths = [pathlib.Path(p) for p in sys.argv[1:]] or sorted(ROOT.glob("results/*/manifest.json"))
    for path in paths:
        print(f"{path}: {'sealed' if seal(path) else 'already sealed'}")


if __name__ == "__main__":
    main()
