"""The package as an IDE sees it: every public function documented and
annotated, stubs for the native module shipped."""

import importlib.metadata
import inspect
import json
import pathlib

import nst3d


def test_every_public_name_is_documented_and_typed():
    for name in nst3d.__all__:
        obj = getattr(nst3d, name)
        if name == "__version__":
            assert isinstance(obj, str)
            continue
        if inspect.isfunction(obj):
            assert obj.__doc__, name
            sig = inspect.signature(obj)
            assert sig.return_annotation is not inspect.Signature.empty, name
            for p in sig.parameters.values():
                assert p.annotation is not inspect.Parameter.empty, f"{name}({p.name})"


def test_installed_from_a_wheel_file_with_complete_metadata():
    """tools/test_python.sh builds the wheel with `maturin build` and installs that file."""
    dist = importlib.metadata.distribution("nst3d")
    url = json.loads(dist.read_text("direct_url.json") or "{}").get("url", "")
    assert url.startswith("file://") and url.endswith(".whl"), url
    md = dist.metadata
    assert md["Version"] == nst3d.__version__
    assert md["Summary"] and md["License"] == "MIT OR Apache-2.0" and md["Requires-Python"] == ">=3.9"
    assert md["Description-Content-Type"].startswith("text/markdown")
    assert "stylize_vdb" in (md.get_payload() or md["Description"] or ""), "the readme is the long description"
    urls = dict(u.split(", ", 1) for u in md.get_all("Project-URL"))
    assert set(urls) >= {"Documentation", "Homepage", "Source"}, urls
    # The repository's own documents, relative to its root, and they exist.
    repo = pathlib.Path(__file__).resolve().parents[2]
    assert all((repo / u).exists() for u in urls.values()), urls
    assert "Typing :: Typed" in md.get_all("Classifier")


def test_stubs_and_marker_ship_with_the_package():
    root = pathlib.Path(nst3d.__file__).parent
    assert (root / "py.typed").exists()
    assert (root / "_nst3d.pyi").exists()


def test_precision_is_the_command_lines_setting():
    before = nst3d.precision()
    try:
        assert nst3d.set_precision("fp32") == "fp32"
        assert nst3d.precision() == "fp32"
        assert nst3d.set_precision("bf16").startswith("bf16")
        try:
            nst3d.set_precision("half")
        except ValueError as e:
            assert "auto, bf16, fp32" in str(e)
        else:
            raise AssertionError("a bad precision was accepted")
    finally:
        nst3d.set_precision("auto")
    assert before
