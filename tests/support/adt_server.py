"""A real ADT sequence folder served the way the ADT website's download-URLs JSON describes it.

``write_layout(source, sequence, folder, base_url)`` writes into ``folder`` one file per data group
(the recording as a plain ``.vrs``, every other group a zip of its files) and ``urls.json``
pointing at ``base_url`` with their real SHA-1s and sizes. ``serve(folder)`` serves them over HTTP with faults
on demand (``benchmarks/file_server.py``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pathlib
import urllib.parse
import zipfile
from collections.abc import Mapping

RECORDING = "video.vrs"
# The excerpt's files by data group, as ADT ships them: the recording alone, the ground truth,
# depth and segmentation (each with and without the wearer's body), the synthetic rendering.
GROUPS = {
    "main_groundtruth": (
        "2d_bounding_box.csv",
        "2d_bounding_box_with_skeleton.csv",
        "3d_bounding_box.csv",
        "Skeleton_T.json",
        "aria_trajectory.csv",
        "eyegaze.csv",
        "instances.json",
        "metadata.json",
        "scene_objects.csv",
        "skeleton_aria_association.json",
    ),
    "depth": ("depth_images.vrs", "depth_images_with_skeleton.vrs"),
    "segmentation": ("segmentations.vrs", "segmentations_with_skeleton.vrs"),
    "synthetic": ("synthetic_video.vrs",),
}
# projectaria-tools' own MPS groups (listed by the library, not by data_groups) and the folder of
# the sequence their zip's top-level members come from.
MPS_GROUPS = {"mps_eye_gaze": "mps/eye_gaze"}


def entry_of(path: pathlib.Path, base_url: str) -> dict:
    """The URLs-JSON entry of a served file: URL, name, SHA-1 and size of its bytes."""
    data = path.read_bytes()
    return {
        "download_url": f"{base_url}/{urllib.parse.quote(path.name)}",
        "filename": path.name,
        "sha1sum": hashlib.sha1(data).hexdigest(),
        "file_size_bytes": len(data),
    }


def write_zip(path: pathlib.Path, members: Mapping[str, bytes]) -> pathlib.Path:
    """A zip of ``members`` (name -> bytes) at ``path``, deflated as ADT's are."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for name, data in members.items():
            archive.writestr(zipfile.ZipInfo(name, (2023, 5, 30, 14, 9, 26)), data, zipfile.ZIP_DEFLATED)
    return path


@dataclasses.dataclass
class Layout:
    """The served files of one sequence and its URLs JSON (``data``, written at ``url_file``)."""

    folder: pathlib.Path
    sequence: str
    base_url: str
    data: dict

    @property
    def url_file(self) -> pathlib.Path:
        return self.folder / "urls.json"

    def entry(self, group: str) -> dict:
        return self.data["sequences"][self.sequence][group]

    def filename(self, group: str) -> str:
        return self.entry(group)["filename"]

    def variant(self, name: str, group: str, entry: dict | None = None, **fields) -> pathlib.Path:
        """A copy of the URLs JSON, ``<name>.json``, whose ``group`` entry is ``entry`` (None: the
        group removed from the sequence) updated with ``fields``."""
        data = json.loads(json.dumps(self.data))
        groups = data["sequences"][self.sequence]
        if entry is None and not fields:
            del groups[group]
        else:
            groups[group] = {**(entry or groups[group]), **fields}
        path = self.folder / f"{name}.json"
        path.write_text(json.dumps(data, indent=1))
        return path

    def add_zip(self, name: str, members: Mapping[str, bytes]) -> dict:
        """Serve a zip of ``members`` as ``name``; its URLs-JSON entry."""
        return entry_of(write_zip(self.folder / name, members), self.base_url)


def write_layout(
    source: pathlib.Path, sequence: str, folder: pathlib.Path, base_url: str, mps: bool = True
) -> Layout:
    """Lay the sequence folder ``source`` out in ``folder`` as the URLs JSON describes it: the
    recording ``<sequence>_main_recording.vrs``, a zip ``<sequence>_<group>.zip`` per group (MPS
    eye gaze too when ``mps``), and ``urls.json`` with their URLs under ``base_url``."""
    recording = folder / f"{sequence}_main_recording.vrs"
    recording.write_bytes((source / RECORDING).read_bytes())
    entries = {"main_vrs": entry_of(recording, base_url)}
    zips = {group: {name: (source / name).read_bytes() for name in names} for group, names in GROUPS.items()}
    if mps:
        zips.update(
            {g: {p.name: p.read_bytes() for p in (source / f).iterdir()} for g, f in MPS_GROUPS.items()}
        )
    for group, members in zips.items():
        entries[group] = entry_of(write_zip(folder / f"{sequence}_{group}.zip", members), base_url)
    config = {
        "main": {"recording": RECORDING, "mps": "mps" if mps else "None"},
        "data_groups": {group: list(names) for group, names in GROUPS.items()},
    }
    layout = Layout(folder, sequence, base_url, {"sequences": {sequence: entries}, "sequence_config": config})
    layout.url_file.write_text(json.dumps(layout.data, indent=1))
    return layout
