#!/usr/bin/env python3
"""Fails when modules of a crate import each other in a cycle, at every level
of the module tree: the top-level modules of each crate, and the submodules
of each module folder among themselves (`pipeline/color_stage.rs` and
`pipeline/multiscale.rs` are two modules of `pipeline`).

At each level, a module is `NAME.rs` or `NAME/` beside it (its submodules
count as NAME); the parent's own file (`lib.rs`, `main.rs`, `mod.rs` or
`parent.rs`) is the root of that level and not a module. A reference is a path
(`crate::a::b`, `super::b`, `self::b`, or a `use` tree of them) in a module's
source outside comments and outside its trailing `#[cfg(test)]` tests (a doc
link is not counted), resolved to the module it names.

  python3 tools/module_cycles.py [--allow CRATE:MODA<->MODB ...] [CRATE_DIR ...]
      (default: crates/*)

`--allow` accepts one known cycle whose members are exactly those two
modules (module paths inside the crate, `::`-separated, e.g.
`strands:pipeline::color_stage<->pipeline::multiscale`); it is still printed,
marked as allowed. Exits 1 if any other cycle is found, or if an allowed
cycle no longer exists (so the allow list cannot go stale).
"""
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
PATH = re.compile(r"\b(crate|super|self)((?:::\w+)+)")
USE = re.compile(r"\buse\s+([^;]*);", re.S)


def strip_comments(text):
    # A file's unit tests (its trailing `#[cfg(test)] mod`) may use any
    # module of the crate: they are not part of the module's dependencies.
    text = text.split("#[cfg(test)]", 1)[0]
    return "\n".join(line.split("//", 1)[0] for line in text.splitlines())


def expand_use(tree):
    """`a::{b, c::{d, e}}` -> ['a::b', 'a::c::d', 'a::c::e'] (globs and `as` dropped)."""
    tree = re.sub(r"\s+as\s+\w+", "", tree)
    tree = re.sub(r"\s+", "", tree)
    out = []

    def walk(prefix, s):
        depth, start, parts = 0, 0, []
        for i, ch in enumerate(s):
            if ch == "{":
                depth += 1
            elif ch == "}":
                depth -= 1
            elif ch == "," and depth == 0:
                parts.append(s[start:i])
                start = i + 1
        parts.append(s[start:])
        for p in parts:
            if not p:
                continue
            if "{" in p:
                head, body = p.split("{", 1)
                walk(prefix + head, body[: body.rfind("}")])
            else:
                out.append((prefix + p).rstrip(":*").rstrip(":"))

    walk("", tree)
    return out


def module_files(src):
    """{module path tuple: file} for every module file of a crate's src."""
    mods = {}
    for f in sorted(src.rglob("*.rs")):
        rel = f.relative_to(src).with_suffix("")
        parts = rel.parts
        if parts[-1] == "mod":
            parts = parts[:-1]
        if parts in (("lib",), ("main",)):
            parts = ()
        if len(parts) >= 1 and parts[0] == "bin":
            continue
        mods[parts] = f
    return mods


def references(mod, text, known):
    """Module paths (tuples) that `mod`'s code refers to."""
    paths = []
    for u in USE.findall(text):
        paths += expand_use(u)
    paths += [m.group(1) + m.group(2) for m in PATH.finditer(text)]
    out = set()
    for p in paths:
        segs = [s for s in p.split("::") if s]
        if not segs:
            continue
        if segs[0] == "crate":
            base, rest = (), segs[1:]
        elif segs[0] in ("super", "self"):
            base = mod
            while segs and segs[0] in ("super", "self"):
                if segs[0] == "super":
                    base = base[:-1]
                segs = segs[1:]
            rest = segs
        else:
            # A bare path in a parent's file: its own child modules.
            if mod + (segs[0],) in known:
                base, rest = mod, segs
            else:
                continue
        target = base
        for s in rest:
            if target + (s,) in known:
                target = target + (s,)
            else:
                break
        out.add(target)
    return out


def graphs(src):
    """For every module with submodules: the graph between its children."""
    known = module_files(src)
    refs = {m: references(m, strip_comments(f.read_text()), known) for m, f in known.items()}
    levels = {}
    for parent in sorted(known):
        children = sorted(m for m in known if len(m) == len(parent) + 1 and m[: len(parent)] == parent)
        if len(children) < 2:
            continue
        edges = {c: set() for c in children}
        for m, targets in refs.items():
            if len(m) <= len(parent) or m[: len(parent)] != parent:
                continue
            src_child = m[: len(parent) + 1]
            for t in targets:
                if len(t) > len(parent) and t[: len(parent)] == parent:
                    dst = t[: len(parent) + 1]
                    if dst != src_child:
                        edges[src_child].add(dst)
        levels[parent] = edges
    return levels


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


def name(m):
    return "::".join(m) or "(crate root)"


def main():
    args = sys.argv[1:]
    allowed = set()
    crates = []
    while args:
        a = args.pop(0)
        if a == "--allow":
            spec = args.pop(0)
            crate, pair = spec.split(":", 1)
            left, right = pair.split("<->")
            allowed.add((crate, frozenset((left.strip(), right.strip()))))
        elif a.startswith("--allow="):
            args.insert(0, a.split("=", 1)[1])
            args.insert(0, "--allow")
        else:
            crates.append(pathlib.Path(a))
    crates = crates or sorted(p for p in (ROOT / "crates").iterdir() if (p / "src").is_dir())
    bad, seen_allowed, levels = 0, set(), 0
    for c in crates:
        for parent, edges in graphs(c / "src").items():
            levels += 1
            for comp in cycles(edges):
                names = [name(m) for m in comp]
                detail = "; ".join(f"{name(m)} -> {', '.join(name(t) for t in sorted(edges[m] & set(comp)))}" for m in comp)
                key = (c.name, frozenset(names))
                where = f"inside {name(parent)}" if parent else "at the top level"
                if key in allowed:
                    seen_allowed.add(key)
                    print(f"{c.name}: known import cycle {where}, allowed: {' <-> '.join(names)} ({detail})")
                else:
                    bad += 1
                    print(f"{c.name}: import cycle {where} between {', '.join(names)} ({detail})")
    for crate, pair in sorted(allowed - seen_allowed, key=str):
        bad += 1
        print(f"{crate}: --allow {' <-> '.join(sorted(pair))} names no cycle any more: drop it from the allow list")
    if bad:
        sys.exit(1)
    print(f"no import cycles between the modules of {len(crates)} crates ({levels} module levels checked"
          + (f", {len(seen_allowed)} known cycle allowed)" if seen_allowed else ")"))


if __name__ == "__main__":
    main()
