"""Bad input to `atm` that is not an image file: one line, no traceback."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_cli import atm
from tests.test_cli_outputs import refused, scene  # noqa: F401 (scene is a fixture)


def test_deeply_nested_metadata_is_one_line(scene, tmp_path):
    deep = '{"a": ' + "[" * 5000 + "]" * 5000 + "}"
    refused(atm("encode", scene, tmp_path / "m.atm", "--metadata", deep), "--metadata is nested too deeply")
    assert not (tmp_path / "m.atm").exists()


@pytest.mark.parametrize("array", [np.zeros((8, 8), bool), np.zeros((8, 8), np.complex64), np.zeros(8, np.uint8)])
def test_compare_refuses_arrays_that_are_not_images_in_one_line(tmp_path, array):
    np.save(tmp_path / "x.npy", array)
    r = atm("compare", tmp_path / "x.npy", tmp_path / "x.npy")
    err = r.stderr.decode()
    assert r.returncode == 1 and err.startswith("atm: error: cannot compare an array") and err.count("\n") == 1
