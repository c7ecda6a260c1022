#!/usr/bin/env python3
"""The import graph of a crate's modules, and whether it has a cycle; the workspace's crates, and
whether one uses a crate above it.

Reads every .rs file under crates/<crate>/src, takes the paths it names in code (comments and
doc links are not imports) as `crate::a::...`, `super::...` or `<crate>::a::...`, and draws
an arrow from the file's top-level module to the top-level module named. Prints each module with
the modules it uses, then any cycle; exits 1 when there is one.

    python3 scripts/imports.py                    # the runner's top-level modules (cli, commands, ...)
    python3 scripts/imports.py --depth 2          # one level down as well (output::manifest, ...)
    python3 scripts/imports.py --crate magcal-logs
    python3 scripts/imports.py --crates           # the crates' arrows (Cargo.toml), which point down

The crates' layers, bottom first: magcal-core (the math), magcal-logs (files), magcal-report (result
sets read and shown: rows, manifests, pages, figures), magcal-runner (the command line), magcal-py (the Python package, over the command line's calibrate and export). Cargo refuses a cycle between crates; an arrow from a crate to one in a higher layer
is what `--crates` refuses (exit 1).
"""
import argparse
import pathlib
import re
import sys

CRATES = pathlib.Path(__file__).resolve().parent.parent / "crates"
LAYERS = ["magcal-core", "magcal-logs", "magcal-report", "magcal-runner", "magcal-py"]
ROOT = CRATES / "magcal-runner" / "src"
CRATE_PATH = None
SUPER_PATH = re.compile(r"\b((?:super::)+)([a-z_][a-z0-9_]*(?:::[a-z_][a-z0-9_]*)*)")


def module_of(path):
    """`output/manifest.rs` -> ['output', 'manifest']; `output/mod.rs` -> ['output']."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] in ("mod", "lib", "main"):
        parts = parts[:-1]
    return parts


def code_lines(text):
    """The file's lines with comments removed (line comments and doc comments)."""
    for line in text.splitlines():
        stripped = line.lstrip()
        if stripped.startswith("//"):
            continue
        yield re.sub(r"//.*$", "", line)


def braced_items(text, start):
    """Names at the top of the `{...}` that opens at `text[start]`."""
    depth, item, items = 0, "", []
    for ch in text[start:]:
        if ch == "{":
            depth += 1
            if depth == 1:
                continue
        elif ch == "}":
            depth -= 1
            if depth == 0:
                items.append(item)
                break
        if depth == 1 and ch == ",":
            items.append(item)
            item = ""
        elif depth >= 1:
            item += ch
    return [i.strip().split("::")[0].split(" ")[0] for i in items if i.strip()]


def targets(text, here, depth):
    code = "\n".join(code_lines(text))
    found = set()
    for m in CRATE_PATH.finditer(code):
        if m.group(1) == "{":
            names = [[n] for n in braced_items(code, m.end() - 1)]
        else:
            names = [m.group(1).split("::")]
        for parts in names:
            found.add(tuple(parts[:depth]))
    for m in SUPER_PATH.finditer(code):
        ups = m.group(1).count("super::")
        base = here[: len(here) - ups] if ups <= len(here) else []
        found.add(tuple((base + m.group(2).split("::"))[:depth]))
    return found


def cycles(graph):
    """Every elementary cycle found by depth-first search, each once."""
    seen, out = set(), []

    def walk(start, node, path):
        for nxt in sorted(graph.get(node, ())):
            if nxt == start:
                key = frozenset(path)
                if key not in seen:
                    seen.add(key)
                    out.append(path + [start])
            elif nxt not in path and nxt > start:
                walk(start, nxt, path + [nxt])

    for start in sorted(graph):
        walk(start, start, [start])
    return out


def crate_arrows():
    """Each crate with the workspace crates its Cargo.toml depends on; 1 when one points up."""
    up = 0
    for crate in sorted(p.parent.name for p in CRATES.glob("*/Cargo.toml")):
        text = (CRATES / crate / "Cargo.toml").read_text()
        section, uses = "", set()
        for line in text.splitlines():
            if line.startswith("["):
                section = line.strip()
            elif "dependencies" in section and "dev-dependencies" not in section:
                name = line.split("=")[0].strip().split(".")[0]
                if name in LAYERS:
                    uses.add(name)
        if crate not in LAYERS:
            print(f"{crate}: not in a layer of scripts/imports.py")
            up += 1
            continue
        for u in sorted(uses):
            if LAYERS.index(u) >= LAYERS.index(crate):
                print(f"arrow up: {crate} -> {u}")
                up += 1
        print(f"{crate:24} -> {', '.join(sorted(uses)) or '-'}")
    print(f"{len(LAYERS)} layers, {up} arrows up")
    return 1 if up else 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--depth", type=int, default=1, help="module path depth of a node")
    parser.add_argument("--crate", default="magcal-runner", help="the crate whose modules are drawn")
    parser.add_argument("--crates", action="store_true", help="the crates' arrows instead")
    args = parser.parse_args()
    if args.crates:
        return crate_arrows()
    global ROOT, CRATE_PATH
    ROOT = CRATES / args.crate / "src"
    lib = args.crate.replace("-", "_")
    CRATE_PATH = re.compile(r"\b(?:crate|" + lib + r")::((?:[a-z_][a-z0-9_]*::)*[a-z_][a-z0-9_]*|\{)")
    files = sorted(ROOT.rglob("*.rs"))
    nodes = {tuple(module_of(f)[: args.depth]) for f in files} - {()}
    graph = {}
    for f in files:
        here = module_of(f)
        node = tuple(here[: args.depth])
        if not node:
            continue
        for t in targets(f.read_text(), here, args.depth):
            # A path into one of the crate's modules, not into itself or an item of the root.
            if t and t != node and t in nodes:
                graph.setdefault(node, set()).add(t)
    name = "::".join
    for node in sorted(nodes):
        print(f"{name(node):24} -> {', '.join(name(t) for t in sorted(graph.get(node, ()))) or '-'}")
    found = cycles(graph)
    for c in found:
        print("cycle: " + " -> ".join(name(n) for n in c))
    print(f"{len(nodes)} modules, {sum(len(v) for v in graph.values())} arrows, {len(found)} cycles")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
