#!/usr/bin/env python3
"""Converts between the reference's PyTorch state dict and nst3d's model file.

  to_nst3d.py pt2st REF.pt TEMPLATE.safetensors OUT.safetensors   (metadata from TEMPLATE)
  to_nst3d.py st2pt MODEL.safetensors OUT.pt
"""
import json, struct, sys
import numpy as np
import torch

NAMES = {f"mid.{i}": f"m{i + 1}" for i in range(4)}


def read_st(path):
    b = open(path, "rb").read()
    n = struct.unpack("<Q", b[:8])[0]
    h = json.loads(b[8:8 + n])
    meta = h.pop("__metadata__", {})
    t = {}
    for k, v in h.items():
        s, e = v["data_offsets"]
        t[k] = np.frombuffer(b[8 + n + s:8 + n + e], np.float32).reshape(v["shape"])
    return meta, t


def write_st(path, meta, tensors):
    header, blobs, off = {"__metadata__": meta}, [], 0
    for k in sorted(tensors):
        a = np.ascontiguousarray(tensors[k], np.float32)
        header[k] = {"dtype": "F32", "shape": list(a.shape), "data_offsets": [off, off + a.nbytes]}
        blobs.append(a.tobytes())
        off += a.nbytes
    h = json.dumps(header).encode()
    h += b" " * ((-len(h)) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)) + h + b"".join(blobs))


def main():
    if sys.argv[1] == "pt2st":
        sd = torch.load(sys.argv[2])
        meta, _ = read_st(sys.argv[3])
        out = {}
        for k, v in sd.items():
            mod, what = k.rsplit(".", 1)
            out[f"{NAMES.get(mod, mod)}.{what}"] = v.numpy()
        write_st(sys.argv[4], meta, out)
    else:
        _, t = read_st(sys.argv[2])
        back = {v: k for k, v in NAMES.items()}
        sd = {}
        for k, v in t.items():
            mod, what = k.rsplit(".", 1)
            sd[f"{back.get(mod, mod)}.{what}"] = torch.from_numpy(v.copy())
        torch.save(sd, sys.argv[3])


if __name__ == "__main__":
    main()
