"""The compiled module loads, reports itself, and its errors form one hierarchy."""

import plantdreamer
from plantdreamer import _core, errors


def test_native_version_matches_package():
    assert _core.__version__ == plantdreamer.__version__
    assert plantdreamer.__version__.count(".") == 2


def test_info_reports_an_optimised_build_with_threads():
    info = _core.info()
    assert info["version"] == plantdreamer.__version__
    assert info["threads"] >= 1
    # make test builds with --release; a debug build would make every benchmark meaningless.
    assert info["debug_build"] is False


def test_error_hierarchy_is_shared_by_native_and_python_errors():
    assert issubclass(errors.InputError, errors.PlantDreamerError)
    assert issubclass(errors.PlyError, errors.PlantDreamerError)
    assert issubclass(errors.ModelNotFoundError, errors.PlantDreamerError)
    assert issubclass(errors.CheckpointError, errors.PlantDreamerError)
    assert issubclass(errors.PlantDreamerError, Exception)
    # Native and Python names are the same objects, not look-alikes.
    assert errors.InputError is _core.InputError


def test_public_names_are_exported():
    for name in plantdreamer.__all__:
        assert hasattr(plantdreamer, name), name
