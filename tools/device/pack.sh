#!/usr/bin/env bash
# Packs what tools/device/ff_device.sh needs on the lent GPU machine (no
# network, no MPI of known ABI, a 64 MiB limit on what travels) into .devdata/
# (ignored by git; name it in the call's `carry`):
#   nst3d-mpi        the MPI build (tools/build_mpi.sh)
#   ompi/            Debian's Open MPI and PMIx runtime with every library they
#                    load that is not glibc's, relocated with OPAL_PREFIX
#   vgg_cut.pth      the normalised VGG-19 up to relu4_1 (all the loss reads), f16
#   frames/*.npz     the example models' training frames (tools/ff_ref/vdb_npz.py)
#   plume48/         frames 20-40 of the shared plume, for the MPI scaling runs
#   styles/          the three paintings
#
#   bash tools/device/pack.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
D=.devdata
P=${NST3D_PLUMES:-$HOME/.cache/nst3d/plumes}
PY=${NST3D_PYTHON:-.venv-torch/bin/python}
mkdir -p "$D/frames" "$D/plume48" "$D/styles"
cp target/release/nst3d-mpi "$D/"
strip "$D/nst3d-mpi"
cp ../shared/data/styles/*.jpg "$D/styles/"
for f in $(seq -f %04g 20 40); do cp "../shared/data/volumes/plume48/fluid_data_$f.vdb" "$D/plume48/"; done
# In half precision to fit the limit (the reference converts it back to f32).
"$PY" - "$D/vgg_cut.pth" <<'PY'
import os, sys, torch
sd = torch.load(os.path.expanduser("~/.cache/nst3d/vgg_normalised.pth"), map_location="cpu")
torch.save({k: v.half() for k, v in sd.items() if int(k.split(".")[0]) < 31}, sys.argv[1])
PY
frames() { # NAME PATTERN FIRST LAST
  for i in $(seq "$3" "$4"); do
    f=$(printf "$2" "$i")
    [ -f "$D/frames/$1_$(printf %04d "$i").npz" ] ||
      /usr/bin/python3 tools/ff_ref/vdb_npz.py read "$f" "$D/frames/$1_$(printf %04d "$i").npz"
  done
}
frames plume48 ../shared/data/volumes/plume48/fluid_data_%04d.vdb 1 40
frames plumeB "$P/plumeB/data/fluid_data_%04d.vdb" 1 48
frames plume96 "$P/plume96/data/fluid_data_%04d.vdb" 1 40
# Open MPI: the packages' files, then the libraries they load, glibc's left out.
O=$D/ompi
rm -rf "$O" && mkdir -p "$O/lib"
for pkg in libopenmpi3 openmpi-bin openmpi-common libpmix2; do
  dpkg -L "$pkg" | while read -r f; do
    [ -f "$f" ] || [ -L "$f" ] || continue
    case "$f" in /usr/share/doc/*|/usr/share/man/*|/usr/share/lintian/*) continue ;; esac
    mkdir -p "$O$(dirname "$f")" && cp -a "$f" "$O$f"
  done
done
for alt in mpirun mpiexec; do ln -sf orterun "$O/usr/bin/$alt"; done
# One machine, shared memory only: no fabric, InfiniBand or UCX transports, no
# OpenSHMEM, Fortran or Java bindings (and none of the libraries they pull in).
find "$O" \( -name '*ucx*' -o -name '*ofi*' -o -name '*psm*' -o -name '*openib*' -o -name '*verbs*' \
  -o -name '*oshmem*' -o -name '*spml*' -o -name '*sshmem*' -o -name '*scoll*' -o -name '*atomic_*' \
  -o -name '*usnic*' -o -name '*mpifh*' -o -name '*usempi*' -o -name '*java*' -o -name '*fortran*' \) \
  -exec rm -rf {} +
find "$O/usr" -type f \( -name '*.so*' -o -perm -u+x \) -print0 | xargs -0 ldd 2>/dev/null |
  awk '$2 == "=>" && $3 ~ /^\// {print $3}' | sort -u | while read -r lib; do
  case "$(basename "$lib")" in
    libc.so*|libm.so*|libpthread.so*|libdl.so*|librt.so*|ld-linux*|libresolv.so*) continue ;;
    libstdc++.so*|libgcc_s.so*|libpmix.so*|liboshmem.so*) continue ;; # the machine's own, or above
  esac
  case "$lib" in */openmpi/*|*/pmix2/*|*/libmpi*|*/libopen-*|*/libmca_*) continue ;; esac
  cp -L "$lib" "$O/lib/"
done || true # ldd fails on the scripts among the executables
du -sh "$D" "$D"/*
