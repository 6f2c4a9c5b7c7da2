#!/usr/bin/env python3
"""Fails when the docs or the code's comments point at things a reader of
the repository cannot look up: a working session or a tracker issue by its
number, a commit hash (7 to 40 hex digits standing alone as a word) or a
path on a developer's machine (under /work, /root or /home). Comments and
docs say why, in words that stand on their own.

Checked: README.md and every file under docs/ (all of each file); the
`//` comments (`//`, `///`, `//!`) of crates/**/*.rs; every line of
tools/**/*.sh, tools/**/*.py and python/**/*.py (their comments and
docstrings, and code, where such a path is as wrong).

  python3 tools/no_references.py      # prints each offending line, exits 1 if any
"""
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]

PATTERNS = [
    ("a session number", re.compile(r"(?i)\bsessions? [0-9]")),
    ("an issue number", re.compile(r"(?i)\bissues? #?[0-9]+")),
    # 7 to 40 lower-case hex digits with at least one digit and one letter,
    # standing alone as a word (not part of a file name or an identifier).
    ("a commit hash", re.compile(r"(?<![\w./-])(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w-])")),
    ("an absolute path of a machine", re.compile(r"(?<![\w.~])/(?:work|root|home)/")),
]

# Files another change is rewriting right now; they leave this list when it lands.
EXCLUDED = []


def comment(line):
    i = line.find("//")
    return line[i:] if i >= 0 else ""


def targets():
    yield ROOT / "README.md", None
    for p in sorted((ROOT / "docs").rglob("*")):
        if p.is_file() and p.suffix in (".md", ".txt", ".json", ".csv"):
            yield p, None
    for p in sorted((ROOT / "crates").rglob("*.rs")):
        yield p, comment
    for pattern in ("tools/**/*.sh", "tools/**/*.py", "python/**/*.py"):
        for p in sorted(ROOT.glob(pattern)):
            yield p, None


def main():
    bad = 0
    for path, part in targets():
        rel = path.relative_to(ROOT).as_posix()
        if any(rel.startswith(e) for e in EXCLUDED) or "/target/" in f"/{rel}":
            continue
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            text = part(line) if part else line
            for what, rx in PATTERNS:
                m = rx.search(text)
                if m:
                    bad += 1
                    print(f"{rel}:{n}: {what} ({m.group(0)!r}): {line.strip()[:140]}")
                    break
    if bad:
        print(f"{bad} lines name a session, an issue, a commit or a machine's path: say why instead")
        sys.exit(1)
    print("no session or issue numbers, commit hashes or machine paths in the docs and comments")


if __name__ == "__main__":
    main()
