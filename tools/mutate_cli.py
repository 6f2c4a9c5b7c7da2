#!/usr/bin/env python3
"""Black-box mutation of real files through the release binary, the way a
user meets a damaged file: `nst3d preview --input MUTANT` (which reads,
validates and draws VDBs and grooms). Complements the in-process fuzzer
(tools/fuzz.sh) by going through the whole command: argument handling,
reading, validation, set-up, drawing, exit status.

    python3 tools/mutate_cli.py [--count N] [--timeout S] [--seed K] FILE...

Each mutant flips, overwrites, inserts or deletes a few bytes, or truncates
the file. Counted per file: clean refusals (exit 1, one `nst3d: error:`
line), accepted mutants (exit 0), panics (a `panicked` message or exit 101),
crashes (killed by a signal), time-outs, and the slowest run. Exits 1 if any
mutant panicked, crashed or timed out.
"""
import argparse
import os
import random
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def mutate(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.random()
        if not b:
            break
        i = rng.randrange(len(b))
        if op < 0.4:
            b[i] ^= 1 << rng.randrange(8)
        elif op < 0.6:
            b[i] = rng.choice([0x00, 0xFF, 0x7F, 0x80, rng.randrange(256)])
        elif op < 0.7:
            # An integer field set to something large.
            b[i : i + 4] = rng.choice([b"\xff\xff\xff\x7f", b"\x00\x00\x00\x80", b"\xff\xff\xff\xff"])
        elif op < 0.8:
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        elif op < 0.9:
            del b[i : i + rng.randint(1, 16)]
        else:
            del b[rng.randrange(len(b)) :]
    return bytes(b)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--count", type=int, default=400)
    ap.add_argument("--timeout", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--nst3d", default=os.path.join(ROOT, "target", "release", "nst3d"))
    args = ap.parse_args()
    if not os.access(args.nst3d, os.X_OK):
        sys.exit(f"mutate_cli.py: no binary at {args.nst3d} (cargo build --release -p nst3d-cli)")
    bad = 0
    print("file\tmutants\trefused\taccepted\tpanics\tcrashes\ttimeouts\tslowest_s")
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.files:
            with open(path, "rb") as f:
                data = f.read()
            ext = os.path.splitext(path)[1]
            rng = random.Random(f"{args.seed}:{os.path.basename(path)}")
            counts = dict(refused=0, accepted=0, panics=0, crashes=0, timeouts=0)
            slowest = 0.0
            for n in range(args.count):
                mutant = os.path.join(tmp, f"m{n}{ext}")
                with open(mutant, "wb") as f:
                    f.write(mutate(data, rng))
                out = os.path.join(tmp, "p.png")
                start = time.monotonic()
                try:
                    r = subprocess.run(
                        [args.nst3d, "--threads", "1", "preview", "--input", mutant, "--out", out, "--height", "64"],
                        capture_output=True,
                        timeout=args.timeout,
                    )
                except subprocess.TimeoutExpired:
                    counts["timeouts"] += 1
                    os.replace(mutant, os.path.join(tmp, f"timeout{n}{ext}"))
                    print(f"  time-out: mutant {n} of {path}", file=sys.stderr)
                    continue
                slowest = max(slowest, time.monotonic() - start)
                err = r.stderr.decode(errors="replace")
                if "panicked" in err or r.returncode == 101:
                    counts["panics"] += 1
                    print(f"  panic: mutant {n} of {path}: {err.strip()[:300]}", file=sys.stderr)
                elif r.returncode < 0:
                    counts["crashes"] += 1
                    print(f"  crash (signal {-r.returncode}): mutant {n} of {path}", file=sys.stderr)
                elif r.returncode == 0:
                    counts["accepted"] += 1
                elif r.returncode == 1 and sum(l.startswith("nst3d: error:") for l in err.splitlines()) == 1:
                    counts["refused"] += 1
                else:
                    counts["panics"] += 1
                    print(f"  unclean exit {r.returncode}: mutant {n} of {path}: {err.strip()[:300]}", file=sys.stderr)
                os.remove(mutant)
            bad += counts["panics"] + counts["crashes"] + counts["timeouts"]
            c = counts
            print(
                f"{os.path.basename(path)}\t{args.count}\t{c['refused']}\t{c['accepted']}\t{c['panics']}\t"
                f"{c['crashes']}\t{c['timeouts']}\t{slowest:.2f}",
                flush=True,
            )
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
