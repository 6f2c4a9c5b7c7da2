#!/usr/bin/env python3
"""Fails when the top-level modules of a crate import each other in a cycle
(issue 28: "no import cycles between the modules of a crate").

A module is `src/NAME.rs` or `src/NAME/` (its submodules count as NAME);
`lib.rs`/`main.rs` are the crate root and are not a module. A reference is
any `crate::NAME` in a module's source outside comments and outside its
trailing `#[cfg(test)]` tests (a `use` or a path in code; a doc link is not
counted). Prints each crate's cycles and exits 1 if
there are any.

  python3 tools/module_cycles.py [CRATE_DIR ...]   (default: crates/*)
"""
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
REF = re.compile(r"\bcrate::(\w+)")
GROUPED = re.compile(r"\bcrate::\{([^}]*)\}", re.S)


def strip_comments(text):
    # A file's unit tests (its trailing `#[cfg(test)] mod`) may use any
    # module of the crate: they are not part of the module's dependencies.
    text = text.split("#[cfg(test)]", 1)[0]
    out = []
    for line in text.splitlines():
        code = line.split("//", 1)[0]
        out.append(code)
    return "\n".join(out)


def modules(src):
    mods = {}
    for p in sorted(src.iterdir()):
        if p.is_file() and p.suffix == ".rs" and p.stem not in ("lib", "main"):
            mods[p.stem] = [p]
        elif p.is_dir():
            mods[p.name] = sorted(p.rglob("*.rs"))
    return mods


def graph(src):
    mods = modules(src)
    edges = {m: set() for m in mods}
    for m, files in mods.items():
        text = "\n".join(strip_comments(f.read_text()) for f in files)
        names = set(REF.findall(text))
        for group in GROUPED.findall(text):
            names |= {g.strip().split("::")[0] for g in group.split(",") if g.strip()}
        edges[m] = {n for n in names if n in mods and n != m}
    return edges


def cycles(edges):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def main():
    crates = [pathlib.Path(a) for a in sys.argv[1:]] or sorted(p for p in (ROOT / "crates").iterdir() if (p / "src").is_dir())
    bad = 0
    for c in crates:
        edges = graph(c / "src")
        for comp in cycles(edges):
            bad += 1
            detail = "; ".join(f"{m} -> {', '.join(sorted(edges[m] & set(comp)))}" for m in comp)
            print(f"{c.name}: import cycle between {', '.join(comp)} ({detail})")
    if bad:
        sys.exit(1)
    print(f"no import cycles between the modules of {len(crates)} crates")


if __name__ == "__main__":
    main()
