"""Bad Panoptic Studio input: one run over the good sample sequence ``dome`` and one corrupted
copy of it per case; unit ``<case>/camera_3`` must fail alone with its clear InputError.

| case | how it is made | expected error (after the file's path) |
|---|---|---|
| pickled_member | params.npz seg_colors as object array | member 'seg_colors' is an object array: .. pickle |
| npy_not_npz | params.npz holds one np.save'd array | a single .npy array, not an npz archive |
| mismatched_shapes | means3D [:, :-1] | unnorm_rotations has shape (40, N, 4), expected (40, N-1, 4) |
| truncated_params | params.npz cut to half its bytes | not an .npz archive (..) |
| missing_params | params.npz deleted | <seq>: no params.npz matching <input>/output/*/<seq>/params.npz |
| string_member | log_scales as strings | member 'log_scales' has dtype <U..; only bool, integer, float .. |
| nan_means | one NaN in means3D | means3D holds 1 non-finite value(s) |
| zero_gaussians | every member with N = 0 | no foreground Gaussians |
| bad_json | train_meta.json cut mid-file | not a Dynamic 3D Gaussians train_meta.json (JSONDecodeError: ..) |
| absent_camera | camera 3 not in train_meta | camera 3 is not in train_meta.json (cameras [8, 16, 21]) |
| singular_w2c | camera 8's w2c all zeros | w2c of camera 8 is not a rigid transform |
| nan_intrinsics | camera 8's fx = NaN | k of camera 8 holds non-finite values |
| zero_focal | camera 8's fx = 0 | k of camera 8 has a non-positive focal length |
| escaping_fn | fn[0][0] = "../../dome/ims/3/000000.jpg" | fn entry '../../dome/ims/3/000000.jpg' is not .. |
| corrupt_jpeg | ims/3/000007.jpg cut to half | corrupt JPEG |
| undecodable_jpeg | ims/3/000004.jpg's Huffman table zeroed | corrupt JPEG (cannot be decoded) |
| missing_mask | seg/3/000005.png deleted | missing file <seq>/seg/3/000005.png |
| wrong_mask_size | seg/3/000002.png at 320x180 | mask is 320x180, expected 640x360 |
"""

from __future__ import annotations

import io
import json
import os
import shutil

import cv2
import numpy as np
import pytest

from pipeline.pstudio.sample.dynamic3dgs_files import EXPERIMENT, SEQUENCE
from tests.conftest import link_tree
from tests.support.bad_input import assert_case_error, assert_only_these_units_failed
from tests.support.cli import run_in_process

CAMERA, OTHER = 0, 1  # columns of cameras 3 and 8 in train_meta.json


class Sequence:
    """A corrupted copy of the good sequence (images and masks copied, params.npz hard-linked;
    every change replaces a file, so the shared sample is never written)."""

    def __init__(self, root: str, name: str):
        self.data = os.path.join(root, "data", name)
        self.params = os.path.join(root, "output", EXPERIMENT, name, "params.npz")
        self.original = os.path.join(root, "output", EXPERIMENT, SEQUENCE, "params.npz")
        shutil.copytree(os.path.join(root, "data", SEQUENCE), self.data)
        os.makedirs(os.path.dirname(self.params))
        os.link(self.original, self.params)

    def replace(self, path: str, data: bytes) -> None:
        os.remove(path)
        with open(path, "wb") as handle:
            handle.write(data)

    def cut(self, path: str) -> None:
        with open(path, "rb") as handle:
            data = handle.read()
        self.replace(path, data[: len(data) // 2])

    def change_params(self, change) -> None:
        with np.load(self.original) as params:
            arrays = dict(params)
        change(arrays)
        os.remove(self.params)
        np.savez(self.params, **arrays)

    def change_meta(self, change) -> None:
        path = os.path.join(self.data, "train_meta.json")
        with open(path) as handle:
            meta = json.load(handle)
        change(meta)
        self.replace(path, json.dumps(meta).encode())


def set_camera(meta: dict, key: str, column: int, value) -> None:
    for row in meta[key]:
        row[column] = value


def drop_camera(meta: dict, column: int) -> None:
    for key in ("k", "w2c", "fn", "cam_id"):
        for row in meta[key]:
            del row[column]


def set_fx(meta: dict, value: float) -> None:
    for row in meta["k"]:
        row[OTHER][0][0] = value


def set_fn(meta: dict) -> None:
    meta["fn"][0][CAMERA] = "../../dome/ims/3/000000.jpg"


def no_gaussians(arrays: dict) -> None:
    for name in ("means3D", "rgb_colors", "unnorm_rotations"):
        arrays[name] = arrays[name][:, :0]
    for name in ("seg_colors", "logit_opacities", "log_scales"):
        arrays[name] = arrays[name][:0]


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def zero_huffman_tables(sequence: Sequence, path: str) -> None:
    """The JPEG at ``path`` with its first Huffman table zeroed: its start, end and frame header
    stay whole, so only decoding it refuses it."""
    with open(path, "rb") as handle:
        data = handle.read()
    at = data.index(b"\xff\xc4") + 4
    sequence.replace(path, data[:at] + bytes(20) + data[at + 20 :])


def small_mask(sequence: Sequence, path: str) -> None:
    sequence.replace(path, cv2.imencode(".png", np.full((180, 320), 255, np.uint8))[1].tobytes())


def make_cases(root: str, count: int) -> dict[str, list[str]]:
    """Write one corrupted sequence per case; returns unit name -> substrings of its error."""
    cases = {
        "pickled_member": (
            lambda s: s.change_params(lambda a: a.update(seg_colors=np.array([{"x": 1}], dtype=object))),
            ["params.npz: member 'seg_colors' is an object array: loading it would need pickle; refused"],
        ),
        "npy_not_npz": (
            lambda s: s.replace(s.params, npy_bytes(np.zeros(3))),
            ["params.npz: a single .npy array, not an npz archive"],
        ),
        "mismatched_shapes": (
            lambda s: s.change_params(lambda a: a.update(means3D=a["means3D"][:, :-1])),
            [f"params.npz: unnorm_rotations has shape (40, {count}, 4), expected (40, {count - 1}, 4)"],
        ),
        "truncated_params": (
            lambda s: s.cut(s.params),
            ["params.npz: not an .npz archive ("],
        ),
        "missing_params": (
            lambda s: os.remove(s.params),
            ["missing_params: no params.npz matching", "missing_params/params.npz"],
        ),
        "string_member": (
            lambda s: s.change_params(lambda a: a.update(log_scales=a["log_scales"].astype(str))),
            ["params.npz: member 'log_scales' has dtype <U", "only bool, integer, float and bytes arrays"],
        ),
        "nan_means": (
            lambda s: s.change_params(lambda a: a["means3D"].__setitem__((5, 7, 0), np.nan)),
            ["params.npz: means3D holds 1 non-finite value(s)"],
        ),
        "zero_gaussians": (
            lambda s: s.change_params(no_gaussians),
            ["params.npz: no foreground Gaussians"],
        ),
        "bad_json": (
            lambda s: s.cut(os.path.join(s.data, "train_meta.json")),
            ["train_meta.json: not a Dynamic 3D Gaussians train_meta.json (JSONDecodeError"],
        ),
        "absent_camera": (
            lambda s: s.change_meta(lambda m: drop_camera(m, CAMERA)),
            ["absent_camera: camera 3 is not in train_meta.json (cameras [8, 16, 21])"],
        ),
        "singular_w2c": (
            lambda s: s.change_meta(lambda m: set_camera(m, "w2c", OTHER, np.zeros((4, 4)).tolist())),
            ["train_meta.json: w2c of camera 8 is not a rigid transform"],
        ),
        "nan_intrinsics": (
            lambda s: s.change_meta(lambda m: set_fx(m, float("nan"))),
            ["train_meta.json: k of camera 8 holds non-finite values"],
        ),
        "zero_focal": (
            lambda s: s.change_meta(lambda m: set_fx(m, 0.0)),
            ["train_meta.json: k of camera 8 has a non-positive focal length"],
        ),
        "escaping_fn": (
            lambda s: s.change_meta(set_fn),
            ["train_meta.json: fn entry '../../dome/ims/3/000000.jpg' is not a file inside"],
        ),
        "corrupt_jpeg": (
            lambda s: s.cut(os.path.join(s.data, "ims", "3", "000007.jpg")),
            ["corrupt_jpeg/ims/3/000007.jpg: corrupt JPEG"],
        ),
        "undecodable_jpeg": (
            lambda s: zero_huffman_tables(s, os.path.join(s.data, "ims", "3", "000004.jpg")),
            ["undecodable_jpeg/ims/3/000004.jpg: corrupt JPEG (cannot be decoded)"],
        ),
        "missing_mask": (
            lambda s: os.remove(os.path.join(s.data, "seg", "3", "000005.png")),
            ["missing file", "missing_mask/seg/3/000005.png"],
        ),
        "wrong_mask_size": (
            lambda s: small_mask(s, os.path.join(s.data, "seg", "3", "000002.png")),
            ["wrong_mask_size/seg/3/000002.png: mask is 320x180, expected 640x360"],
        ),
    }
    for name, (corrupt, _) in cases.items():
        corrupt(Sequence(root, name))
    return {f"{name}/camera_3": needles for name, (_, needles) in cases.items()}


CASE_NAMES = (
    "pickled_member",
    "npy_not_npz",
    "mismatched_shapes",
    "truncated_params",
    "missing_params",
    "string_member",
    "nan_means",
    "zero_gaussians",
    "bad_json",
    "absent_camera",
    "singular_w2c",
    "nan_intrinsics",
    "zero_focal",
    "escaping_fn",
    "corrupt_jpeg",
    "undecodable_jpeg",
    "missing_mask",
    "wrong_mask_size",
)


@pytest.fixture(scope="module")
def bad_run(pstudio_sample, tmp_path_factory):
    """(expected unit -> needles, failures by unit) of one run over the good sequence and one corrupted
    copy per case (hard links to the shared sample, never written: see Sequence)."""
    root = str(tmp_path_factory.mktemp("bad_pstudio") / "root")
    link_tree(pstudio_sample[0], root)
    expected = make_cases(root, len(pstudio_sample[1].part_of_gaussian))
    out = root + "_out"
    result = run_in_process("pstudio", "--input", root, "--output", out, "--set", "pstudio.cameras=3")
    errors = assert_only_these_units_failed(result, out, "pstudio", expected)
    return expected, errors, out


def test_the_cases_are_the_table():
    assert set(CASE_NAMES) == {
        row.split("|")[1].strip() for row in __doc__.splitlines()[4:] if row.startswith("| ")
    }


@pytest.mark.parametrize("case", CASE_NAMES)
def test_a_bad_sequence_fails_alone_with_its_error(bad_run, case):
    expected, errors, _ = bad_run
    assert_case_error(errors, f"{case}/camera_3", expected[f"{case}/camera_3"])


def test_only_the_good_unit_writes_a_clip(bad_run):
    expected, _, out = bad_run
    assert {unit.split("/")[0] for unit in expected} == set(CASE_NAMES)
    assert os.listdir(os.path.join(out, "pstudio")) == ["dome_3.npz"]  # the good unit's, and only it
