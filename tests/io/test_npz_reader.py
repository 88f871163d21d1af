"""``NpzArchive.read``: the member's values in either memory order, as an array of its own, writable
by default or read-only (``writable=False``), also when the member spans many read chunks."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.io import npz_reader
from pipeline.io.npz_reader import NpzArchive


@pytest.mark.parametrize("order", ["C", "F"])
def test_read_returns_the_values_writable_or_read_only(tmp_path, order):
    values = np.asarray(np.arange(24, dtype=np.float32).reshape(2, 3, 4), order=order)
    path = tmp_path / "params.npz"
    np.savez(path, means3D=values)
    with open(path, "rb") as handle:
        archive = NpzArchive(handle, str(path))
        size = archive.header("means3D").nbytes
        copy = archive.read("means3D", size)
        view = archive.read("means3D", size, writable=False)
    for array in (copy, view):
        assert array.dtype == np.float32
        assert array.shape == (2, 3, 4)
        np.testing.assert_array_equal(array, values)
    assert copy.flags.writeable
    assert not view.flags.writeable
    with pytest.raises(ValueError):
        view[0, 0, 0] = 1.0
    copy[0, 0, 0] = 99.0  # the copy is the caller's own
    np.testing.assert_array_equal(view, values)


def test_a_member_of_many_chunks_is_read_whole(tmp_path, monkeypatch):
    monkeypatch.setattr(npz_reader, "READ_CHUNK_BYTES", 1000)  # 24,000 bytes: 24 pieces
    values = np.random.default_rng(0).normal(size=(3, 1000, 2)).astype(np.float32)
    path = tmp_path / "params.npz"
    np.savez(path, means3D=values)
    with open(path, "rb") as handle:
        archive = NpzArchive(handle, str(path))
        np.testing.assert_array_equal(archive.read("means3D", values.nbytes), values)
