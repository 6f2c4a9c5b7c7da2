"""The package as an IDE sees it: every public function documented and
annotated, stubs for the native module shipped."""

import inspect
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
