#!/usr/bin/env python3
"""Writes the workspace's crate graph into docs/ARCHITECTURE.md, between the
`<!-- crate-graph begin -->` and `<!-- crate-graph end -->` markers, from
`cargo metadata` (normal dependencies between workspace members; dev
dependencies left out). Crates are listed in layers: a crate's layer is one
more than its highest dependency's, so everything a crate uses is listed
below it. Each line names every direct dependency of the crate.

  python3 tools/crate_graph.py           # rewrites the block
  python3 tools/crate_graph.py --check   # exits 1 if the committed block is stale
"""
import json
import pathlib
import re
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "ARCHITECTURE.md"
BEGIN, END = "<!-- crate-graph begin -->", "<!-- crate-graph end -->"


def short(name):
    return name.removeprefix("nst3d-")


def graph():
    meta = json.loads(subprocess.run(
        ["cargo", "metadata", "--no-deps", "--format-version", "1", "--offline"],
        cwd=ROOT, check=True, capture_output=True, text=True).stdout)
    members = {p["name"] for p in meta["packages"]}
    return {
        short(p["name"]): sorted({short(d["name"]) for d in p["dependencies"]
                                  if d["name"] in members and d["kind"] is None})
        for p in meta["packages"]
    }


def block(deps):
    layer = {}

    def depth(c):
        if c not in layer:
            layer[c] = 1 + max((depth(d) for d in deps[c]), default=-1)
        return layer[c]

    for c in deps:
        depth(c)
    width = max(len(c) for c in deps)
    lines = [BEGIN, "```text",
             "layer  crate" + " " * (width - 5) + "  uses (normal dependencies, from `cargo metadata`)"]
    for c in sorted(deps, key=lambda c: (-layer[c], c)):
        lines.append(f"{layer[c]:>5}  {c:<{width}}  {', '.join(deps[c]) or '—'}")
    lines += ["```", END]
    return "\n".join(lines)


def main():
    text = DOC.read_text()
    pattern = re.compile(re.escape(BEGIN) + ".*?" + re.escape(END), re.S)
    if not pattern.search(text):
        sys.exit(f"{DOC.relative_to(ROOT)}: no {BEGIN} ... {END} block")
    new = pattern.sub(lambda _: block(graph()), text)
    if "--check" in sys.argv[1:]:
        if new != text:
            sys.exit(f"{DOC.relative_to(ROOT)}: the crate graph is stale; run python3 tools/crate_graph.py")
        print("the crate graph in docs/ARCHITECTURE.md matches cargo metadata")
        return
    DOC.write_text(new)


if __name__ == "__main__":
    main()
