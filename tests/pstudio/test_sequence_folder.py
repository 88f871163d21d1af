"""A sequence's folder is found without listing the input when ``<input>/data/<sequence>`` holds
its train_meta.json (a listing of data/ walks every image and mask), and through the listing
otherwise, with the same answer as the listing gives."""

from __future__ import annotations

import pytest
from apache_beam.io.filesystems import FileSystems

from pipeline.pstudio import reader


def touch(path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("{}")


def test_a_sequence_under_data_is_found_without_a_listing(tmp_path, monkeypatch):
    touch(tmp_path / "data" / "dome" / "train_meta.json")
    expected = FileSystems.join(reader.data_root(str(tmp_path)), "dome")

    def no_listing(*args):
        raise AssertionError("listed")

    monkeypatch.setattr(reader.FileSystems, "match", no_listing)
    assert reader.sequence_folder(str(tmp_path), "dome") == expected == str(tmp_path / "data" / "dome")


@pytest.mark.parametrize(
    "layout, sequence, folder",
    [
        ("flat/dome/train_meta.json", "dome", "flat/dome"),  # no data/: the input is the data root
        ("data/hall/train_meta.json", "dome", "data/dome"),  # data/ holds another: still the root
    ],
)
def test_otherwise_the_listing_decides(tmp_path, layout, sequence, folder):
    touch(tmp_path / layout)
    root = str(tmp_path / layout.split("/")[0]) if layout.startswith("flat") else str(tmp_path)
    assert reader.sequence_folder(root, sequence) == str(tmp_path / folder)
