"""Shared fixtures: the real data in ../shared/data and the release binary
the package is compared with. A missing input fails the test loudly; it is
never skipped."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
SHARED = pathlib.Path(os.environ.get("NST3D_SHARED", REPO.parent / "shared"))
DATA = SHARED / "data"
STYLE = DATA / "styles" / "starry_night.jpg"


def need(path: pathlib.Path) -> pathlib.Path:
    if not path.exists():
        raise FileNotFoundError(f"test data missing: {path} (../shared must sit beside the checkout)")
    return path


@pytest.fixture(scope="session")
def data() -> pathlib.Path:
    return need(DATA)


@pytest.fixture(scope="session")
def style() -> pathlib.Path:
    return need(STYLE)


@pytest.fixture(scope="session")
def nst3d_bin() -> pathlib.Path:
    """The release binary (tools/test_python.sh builds it; $NST3D_BIN overrides)."""
    path = pathlib.Path(os.environ.get("NST3D_BIN", REPO / "target" / "release" / "nst3d"))
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: run `cargo build --release -p nst3d-cli` first")
    return path


def run_cli(binary, *args, check=True):
    return subprocess.run([str(binary), *map(str, args)], capture_output=True, text=True, check=check)
