#!/usr/bin/env python3
"""Runs every command the README and the user's guide show, so that a stale example fails CI.

Usage: scripts/doc-commands.py [--all] [--list] [--keep] [FILE.md ...]

The files are README.md and docs/**/*.md (or those named). Each fenced code block tagged `sh` is
run with bash, in order, `set -e -o pipefail`, from the root of a scratch copy of the repository
(its tracked files and its untracked files that git does not ignore) under target/doc-run/; the
blocks of one file share one copy, so a block may use what the blocks above it wrote. (The copies
are made from one pristine copy per run; results/, most of the bytes and only read by the blocks,
is hard-linked to it rather than copied.) Beside the
copy, `shared` links to the real ../shared, so that `../shared/data/...` resolves. `magcal` on the
PATH is target/release/magcal, or MAGCAL_BIN (which the scripts under scripts/ also honour, running
that binary instead of building one). Nothing is written into the repository itself: `git status`
is compared before and after.

A block may carry a directive on the line just above its fence (an HTML comment: GitHub and mdBook
show nothing of it):

    <!-- doc-commands: exit=3 -->                 the block's status must be 3 (bash without -e;
                                                  the status is the last command's)
    <!-- doc-commands: skip="about 5 min" -->     too long for CI: counted and printed, run by --all
    <!-- doc-commands: needs=PATH|pymagcal -->    skipped, saying why, where PATH (relative to the
                                                  repository's root; `../shared/...` included) is
                                                  absent, or where no python3 imports pymagcal
    <!-- doc-commands: timeout=300 -->            seconds (default 120)

A block that reads ../shared/data needs it without saying so. Blocks tagged otherwise (`text`,
`toml`, `python`, ...) are not run; a fence without a tag is an error, so that a command never goes
unchecked by accident. A `text` block may state what the `sh` block above it prints:

    <!-- doc-commands: expect=last -->            its last line is the output's last line
    <!-- doc-commands: expect=lines -->           each of its lines is a line of the output, in order
    <!-- doc-commands: expect=lines stream=stderr -->   the same, of standard error

In an expected line `...` stands for any text and `~` before a number for any number (a time, a
size): `written (~0.9 MB, ~0.39 s)`. Trailing blanks are ignored.

DOC_SHARED names the folder that stands for ../shared (default: ../shared beside the repository).

Python for `needs=pymagcal`: DOC_PYTHON (a python3 that imports pymagcal), else
target/venv-ci/bin/python3 (made by .ci/run), else python3 itself; its directory goes first on the
PATH of the block.

Exit 1 if a block fails (file and line named, with its standard error), 2 on a malformed directive
or an untagged fence.
"""
import argparse
import os
import pathlib
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
RUN_DIR = ROOT / "target" / "doc-run"
# The folder beside the repository that holds the public logs (data/), as the tests expect it.
SHARED = pathlib.Path(os.environ.get("DOC_SHARED") or ROOT / ".." / "shared").resolve()
DIRECTIVE = re.compile(r"^\s*<!--\s*doc-commands:(.*?)-->\s*$")
FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})(.*)$")
RUNNABLE = {"sh"}
KEYS = {"exit", "skip", "needs", "timeout", "expect", "stream"}


class Block:
    def __init__(self, path, line, lang, info, text, directive):
        self.path, self.line, self.lang, self.info = path, line, lang, info
        self.text, self.directive = text, directive
        self.expect = None  # a text block that states this block's output
        self.stdout = self.stderr = ""
        self.status = None  # ok, FAIL, skip
        self.reason = ""
        self.seconds = 0.0

    def where(self):
        return f"{self.path}:{self.line}"


def parse_directive(text, where):
    try:
        words = shlex.split(text)
    except ValueError as e:
        raise SystemExit(f"doc-commands: {where}: malformed directive: {e}")
    out = {}
    for w in words:
        key, eq, value = w.partition("=")
        if not eq or key not in KEYS:
            raise SystemExit(f"doc-commands: {where}: unknown directive word {w!r} (known: {', '.join(sorted(KEYS))})")
        out[key] = value
    return out


def parse(path):
    """The fenced code blocks of a Markdown file, with their directives."""
    lines = path.read_text(encoding="utf-8").split("\n")
    rel = path.relative_to(ROOT).as_posix()
    blocks = []
    i = 0
    last_nonblank = None
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            if lines[i].strip():
                last_nonblank = i
            i += 1
            continue
        indent, fence, info = len(m.group(1)), m.group(2), m.group(3).strip()
        start = i
        body = []
        i += 1
        while i < len(lines):
            close = FENCE.match(lines[i])
            if close and close.group(2)[0] == fence[0] and len(close.group(2)) >= len(fence) and not close.group(3).strip():
                break
            body.append(lines[i][indent:] if lines[i][:indent].strip() == "" else lines[i].lstrip())
            i += 1
        else:
            raise SystemExit(f"doc-commands: {rel}:{start + 1}: a fence that is never closed")
        i += 1
        directive = {}
        if last_nonblank is not None and last_nonblank == start - 1:
            d = DIRECTIVE.match(lines[last_nonblank])
            if d:
                directive = parse_directive(d.group(1), f"{rel}:{last_nonblank + 1}")
        if not info:
            raise SystemExit(
                f"doc-commands: {rel}:{start + 1}: a fence without a tag: tag commands `sh` and what they print `text`"
            )
        lang = re.split(r"[\s,{]", info, 1)[0]
        blocks.append(Block(rel, start + 1, lang, info, "\n".join(body) + "\n", directive))
        last_nonblank = i - 1
    # Attach the expectations to the sh block above them.
    previous = None
    for b in blocks:
        if b.lang in RUNNABLE:
            previous = b
        elif "expect" in b.directive:
            if previous is None:
                raise SystemExit(f"doc-commands: {b.where()}: an expectation with no `sh` block above it")
            if b.directive["expect"] not in ("last", "lines"):
                raise SystemExit(f"doc-commands: {b.where()}: expect= takes `last` or `lines`")
            if previous.expect is not None:
                raise SystemExit(f"doc-commands: {b.where()}: a second expectation for {previous.where()}")
            previous.expect = b
    for b in blocks:
        if b.lang in RUNNABLE:
            for key in ("expect", "stream"):
                if key in b.directive:
                    raise SystemExit(f"doc-commands: {b.where()}: {key}= belongs on the `text` block of the output")
    return blocks


NUMBER = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?"


def pattern(expected):
    """A regular expression for one expected line: `...` any text, `~N` any number."""
    out = []
    for part in re.split(r"(\.\.\.|~" + NUMBER + ")", expected.rstrip()):
        if part == "...":
            out.append(".*")
        elif part.startswith("~") and re.fullmatch("~" + NUMBER, part):
            out.append(NUMBER)
        else:
            out.append(re.escape(part))
    return re.compile("^" + "".join(out) + r"\s*$")


def check_expectation(block):
    exp = block.expect
    stream = exp.directive.get("stream", "stdout")
    if stream not in ("stdout", "stderr"):
        return f"{exp.where()}: stream= takes stdout or stderr"
    got = [l for l in (block.stdout if stream == "stdout" else block.stderr).split("\n") if l.strip()]
    want = [l for l in exp.text.split("\n") if l.strip()]
    if not want:
        return f"{exp.where()}: an empty expectation"
    if exp.directive["expect"] == "last":
        if not got:
            return f"{exp.where()}: expected the last line {want[-1]!r}, but the {stream} was empty"
        if not pattern(want[-1]).match(got[-1]):
            return f"{exp.where()}: expected the last line of {stream}\n    {want[-1]}\n  got\n    {got[-1]}"
        return None
    k = 0
    for w in want:
        p = pattern(w)
        while k < len(got) and not p.match(got[k]):
            k += 1
        if k == len(got):
            return f"{exp.where()}: no line of {stream} (after the lines matched before it) matches\n    {w}"
        k += 1
    return None


def python_with_pymagcal():
    candidates = [os.environ.get("DOC_PYTHON"), str(ROOT / "target" / "venv-ci" / "bin" / "python3"), shutil.which("python3")]
    for c in candidates:
        if c and os.path.exists(c):
            done = subprocess.run([c, "-c", "import pymagcal"], capture_output=True)
            if done.returncode == 0:
                return c
    return None


def repo_files():
    done = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT, capture_output=True, check=True,
    )
    return [f for f in done.stdout.decode().split("\0") if f]


def pristine_copy(files):
    """One copy of the repository's files per run, from which each Markdown file's copy is made."""
    base = RUN_DIR / "base"
    if base.exists():
        shutil.rmtree(base)
    base.mkdir(parents=True)
    for f in files:
        src = ROOT / f
        dst = base / f
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            os.symlink(os.readlink(src), dst)
        elif src.is_file():
            shutil.copy2(src, dst)
    return base


# Committed result sets are most of the repository's bytes and the blocks only read them: each
# Markdown file's copy links them (hard links to the run's pristine copy, never to the repository)
# and copies everything else.
LINKED = {"results"}


def scratch_copy(name, base):
    top = RUN_DIR / name
    if top.exists():
        shutil.rmtree(top)
    repo = top / "repo"
    repo.mkdir(parents=True)
    for entry in sorted(base.iterdir()):
        flag = "-al" if entry.name in LINKED else "-a"
        subprocess.run(["cp", flag, str(entry), str(repo / entry.name)], check=True)
    if SHARED.exists():
        os.symlink(SHARED, top / "shared")
    return repo


def git_status():
    return subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True, text=True).stdout


def tail(text, n=30):
    lines = text.rstrip("\n").split("\n")
    return "\n".join(("    | " + l) for l in lines[-n:]) if text.strip() else "    | (nothing)"


def main():
    ap = argparse.ArgumentParser(description="Run the commands of the README and the guide.")
    ap.add_argument("files", nargs="*", help="Markdown files (default: README.md and docs/**/*.md)")
    ap.add_argument("--all", action="store_true", help="also run the blocks marked skip=")
    ap.add_argument("--list", action="store_true", help="list the blocks and their directives, run nothing")
    ap.add_argument("--keep", action="store_true", help="keep the scratch copies under target/doc-run/")
    args = ap.parse_args()

    if args.files:
        paths = [pathlib.Path(f).resolve() for f in args.files]
    else:
        paths = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))
    per_file = [(p, parse(p)) for p in paths]

    if args.list:
        for p, blocks in per_file:
            for b in blocks:
                if b.lang in RUNNABLE:
                    extra = " ".join(f"{k}={v}" for k, v in b.directive.items())
                    exp = f" expect={b.expect.directive['expect']}@{b.expect.line}" if b.expect else ""
                    print(f"{b.where():40s} {extra}{exp}")
        return 0

    magcal = os.environ.get("MAGCAL_BIN") or str(ROOT / "target" / "release" / "magcal")
    magcal = os.path.abspath(magcal)
    if not os.access(magcal, os.X_OK):
        print(f"doc-commands: {magcal} is missing: build it (cargo build --release -p magcal-runner) or set MAGCAL_BIN", file=sys.stderr)
        return 2
    bindir = RUN_DIR / "bin"
    bindir.mkdir(parents=True, exist_ok=True)
    link = bindir / "magcal"
    if link.is_symlink() or link.exists():
        link.unlink()
    os.symlink(magcal, link)
    shared_data = SHARED / "data"
    have_shared = shared_data.is_dir() and any(shared_data.iterdir())
    pymagcal_python = None
    pymagcal_looked = False

    before = git_status()
    base = None
    all_blocks = []
    t_all = time.monotonic()
    for p, blocks in per_file:
        runnable = [b for b in blocks if b.lang in RUNNABLE]
        if not runnable:
            continue
        rel = p.relative_to(ROOT).as_posix()
        repo = None
        for b in runnable:
            all_blocks.append(b)
            d = b.directive
            if "skip" in d and not args.all:
                b.status, b.reason = "skip", d["skip"] or "marked skip"
            needs = [n for n in d.get("needs", "").split(",") if n]
            if "../shared/data" in b.text and "../shared/data" not in " ".join(needs):
                needs.append("../shared/data")
            if b.status is None:
                for n in needs:
                    if n == "pymagcal":
                        if not pymagcal_looked:
                            pymagcal_python, pymagcal_looked = python_with_pymagcal(), True
                        if pymagcal_python is None:
                            b.status, b.reason = "skip", "no python3 imports pymagcal (pip install ./crates/magcal-py, or DOC_PYTHON)"
                    elif n.startswith("../shared/data") and not have_shared:
                        b.status, b.reason = "skip", "../shared/data (the public logs) is absent"
                    elif not n.startswith("../shared/") and not (ROOT / n).exists():
                        b.status, b.reason = "skip", f"{n} is absent"
                    elif n.startswith("../shared/") and not (SHARED / n[len("../shared/"):]).exists():
                        b.status, b.reason = "skip", f"{n} is absent"
                    if b.status:
                        break
            if b.status == "skip":
                print(f"skip  {b.where():44s} {b.reason}", flush=True)
                continue
            if base is None:
                base = pristine_copy(repo_files())
            if repo is None:
                repo = scratch_copy(re.sub(r"[^A-Za-z0-9]+", "-", rel).strip("-"), base)
            env = dict(os.environ)
            path = [str(bindir)]
            if "pymagcal" in needs and pymagcal_python:
                path.insert(0, str(pathlib.Path(pymagcal_python).parent))
            env["PATH"] = os.pathsep.join(path + [env.get("PATH", "")])
            env["MAGCAL_BIN"] = magcal
            expected_exit = int(d.get("exit", "0"))
            prelude = "set -o pipefail\n" if "exit" in d else "set -e -o pipefail\n"
            timeout = float(d.get("timeout", "120"))
            t0 = time.monotonic()
            proc = subprocess.Popen(
                ["bash", "-c", prelude + b.text], cwd=repo, env=env, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, start_new_session=True,
            )
            try:
                b.stdout, b.stderr = proc.communicate(timeout=timeout)
                code = proc.returncode
                problem = None if code == expected_exit else f"exit {code}, expected {expected_exit}"
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)  # the block's bash and everything it started
                b.stdout, b.stderr = proc.communicate()
                problem = f"timed out after {timeout:.0f} s"
            b.seconds = time.monotonic() - t0
            if problem is None and b.expect is not None:
                problem = check_expectation(b)
            if problem is None:
                b.status = "ok"
                print(f"ok    {b.where():44s} {b.seconds:6.1f} s", flush=True)
            else:
                b.status, b.reason = "FAIL", problem
                print(f"FAIL  {b.where():44s} {b.seconds:6.1f} s  {problem}", flush=True)
                print("  the block:\n" + "\n".join("    $ " + l for l in b.text.rstrip().split("\n")), flush=True)
                print("  its standard error (last lines):\n" + tail(b.stderr), flush=True)
                print("  its standard output (last lines):\n" + tail(b.stdout, 10), flush=True)
        if repo is not None and not args.keep:
            shutil.rmtree(repo.parent, ignore_errors=True)
    if base is not None and not args.keep:
        shutil.rmtree(base, ignore_errors=True)
    total = time.monotonic() - t_all

    after = git_status()
    ran = [b for b in all_blocks if b.status in ("ok", "FAIL")]
    skipped = [b for b in all_blocks if b.status == "skip"]
    failed = [b for b in all_blocks if b.status == "FAIL"]
    print()
    print(f"{len(all_blocks)} blocks: {len(ran)} run ({len(ran) - len(failed)} ok, {len(failed)} failed), "
          f"{len(skipped)} skipped; {sum(b.seconds for b in ran):.1f} s in the blocks, {total:.1f} s in all")
    reasons = {}
    for b in skipped:
        reasons.setdefault(b.reason, []).append(b.where())
    for reason, where in reasons.items():
        print(f"  skipped {len(where)}: {reason}: {', '.join(where)}")
    for b in failed:
        print(f"  FAILED {b.where()}: {b.reason.splitlines()[0]}")
    status = 1 if failed else 0
    if after != before:
        was, now = set(before.splitlines()), set(after.splitlines())
        changed = sorted(("+ " + l) for l in now - was) + sorted(("- " + l) for l in was - now)
        print("doc-commands: the repository's `git status` changed during the run (the blocks must"
              " write only into their scratch copy; or someone else changed the work tree):", file=sys.stderr)
        print(tail("\n".join(changed) or "(the same entries, in another order)"), file=sys.stderr)
        status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
