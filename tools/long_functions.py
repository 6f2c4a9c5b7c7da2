#!/usr/bin/env python3
"""Lists the library crates' functions longer than a limit (100 lines by
default), longest first: `crates/*/src/**/*.rs` of every crate except the
command-line binary (`crates/cli`), leaving out `#[cfg(test)]` modules,
`tests/`, `examples/` and `benches/`. A function's length is counted from
its `fn` line to its closing brace, both included; a function nested in
another is counted on its own and inside its parent.

  python3 tools/long_functions.py [--max N] [--report-only]

Exits 1 when a function is over the limit, unless `--report-only` (then it
prints the same list and the count, and exits 0).
"""
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
FN = re.compile(r"\bfn\s+(\w+)")
TEST_MOD = re.compile(r"#\[cfg\(test\)\]\s*(?:#\[[^\]]*\]\s*)*(?:pub(?:\([^)]*\))?\s+)?mod\s+\w+\s*\{")


def mask(text):
    """The source with comments, strings and char literals blanked (newlines kept)."""
    out, i, n = [], 0, len(text)

    def blank(s):
        return "".join("\n" if c == "\n" else " " for c in s)

    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(blank(text[i:j]))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(blank(text[i:j]))
            i = j
        elif re.match(r"b?r#*\"", text[i:i + 20]) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            m = re.match(r"b?r(#*)\"", text[i:])
            end = '"' + m.group(1)
            j = text.find(end, i + m.end())
            j = n if j < 0 else j + len(end)
            out.append(blank(text[i:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append(blank(text[i:j + 1]))
            i = j + 1
        elif c == "'":
            m = re.match(r"'(\\(x[0-9a-fA-F]{2}|u\{[0-9a-fA-F]+\}|.)|[^\\'])'", text[i:i + 12])
            if m:
                out.append(blank(m.group(0)))
                i += m.end()
            else:  # a lifetime
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def closing(code, open_at):
    depth = 0
    for j in range(open_at, len(code)):
        if code[j] == "{":
            depth += 1
        elif code[j] == "}":
            depth -= 1
            if depth == 0:
                return j
    return len(code) - 1


def functions(path):
    code = mask(path.read_text())
    skip = [(m.start(), closing(code, m.end() - 1)) for m in TEST_MOD.finditer(code)]
    out = []
    for m in FN.finditer(code):
        if any(a <= m.start() <= b for a, b in skip):
            continue
        # The body starts at the first `{` after the signature; a `;` first
        # means a declaration without a body (a trait method, an extern fn).
        # (`[f32; 3]` in a signature is not the end of one).
        j, depth = m.end(), 0
        while j < len(code) and not (depth == 0 and code[j] in "{;"):
            depth += {"(": 1, "[": 1, ")": -1, "]": -1}.get(code[j], 0)
            j += 1
        if j >= len(code) or code[j] == ";":
            continue
        end = closing(code, j)
        first = code.count("\n", 0, m.start()) + 1
        last = code.count("\n", 0, end) + 1
        out.append((last - first + 1, m.group(1), first))
    return out


def main():
    args = sys.argv[1:]
    limit = int(args[args.index("--max") + 1]) if "--max" in args else 100
    report_only = "--report-only" in args
    long = []
    for crate in sorted((ROOT / "crates").iterdir()):
        if crate.name == "cli" or not (crate / "src").is_dir():
            continue
        for f in sorted((crate / "src").rglob("*.rs")):
            for lines, name, line in functions(f):
                if lines > limit:
                    long.append((lines, f"{f.relative_to(ROOT)}:{line}", name))
    for lines, where, name in sorted(long, key=lambda t: (-t[0], t[1])):
        print(f"{lines:5}  {name}  {where}")
    print(f"{len(long)} library functions over {limit} lines")
    if long and not report_only:
        sys.exit(1)


if __name__ == "__main__":
    main()
