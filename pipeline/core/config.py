"""Run configuration: every threshold is a field with the paper's default.

Fields are overridden from the command line with ``--set section.field=value``.
"""

from __future__ import annotations

import dataclasses
import typing


@dataclasses.dataclass(frozen=True)
class FlickerConfig:
    """Drop a track whose visibility changes state more than ``max_fraction`` x T times."""

    max_fraction: float = 0.10


@dataclasses.dataclass(frozen=True)
class DriveTrackConfig:
    """DriveTrack (Balasingam et al., CVPR 2024) choices, as the TAPVid-3D release used them.

    facing_test is ours, not the generator's: a track is also invisible where its surface
    (normal estimated from the lidar points) faces away from the camera. Beyond ~30 m the
    5% depth margin exceeds a car's width, so the depth test alone calls the far side of a
    car visible. Set it false to reproduce the generator's decisions exactly.

    mask_min_agreement: keep a track when (visible frames on the object's mask) / (visible
      frames) >= this. 0.5 trims 1-3% of the sample world's candidates, the share the
      generator's Segment Anything masks trimmed (2-3%); 0.8 trimmed 13-22% there, mostly true
      surface points the one-sweep lidar silhouette missed.
    masks_dir: optional per-frame masks instead of the default lidar silhouette,
      read as ``<masks_dir>/<clip name>/<frame id>.png`` (non-zero = object).
    mask_closing_px: kernel of the morphological closing of the lidar silhouette;
      0 picks it from the spacing of the projected lidar points in each frame.
    """

    cameras: tuple[int, ...] = (1, 2, 3)
    object_types: tuple[int, ...] = (1,)
    box_shrink_m: float = 0.1
    min_contiguous_frames: int = 24
    max_corner_distance_m: float = 50.0
    occlusion_margin: float = 0.05
    facing_test: bool = True
    tracks_per_clip: int = 256
    oversample: int = 4
    mask_min_agreement: float = 0.5
    masks_dir: str = ""
    mask_closing_px: int = 0


@dataclasses.dataclass(frozen=True)
class AdtConfig:
    """Aria Digital Twin choices, as the TAPVid-3D release made them (SOURCES.md section 4).

    chunk_frames: frames per clip (chunk k = frames [k * chunk_frames, (k + 1) * chunk_frames)
      of the RGB frames strictly inside the ground-truth window).
    min_frames: a chunk with fewer frames (the end of a sequence) is skipped.
    with_skeleton: read the depth and segmentation that render the wearer's body and hands.
    max_gt_offset_ms: the largest time between an RGB frame and the depth, segmentation and
      poses used for it (projectaria-tools' CLOSEST sample); a frame beyond it fails its unit.
      Real sequences are within 0.1 ms; the shared 3-frame excerpt needs 40 (its depth stops
      one frame early, 33.2 ms before its last RGB frame).
    image_size, focal: the square pinhole camera every frame is re-rendered to, then rotated
      90 degrees clockwise; intrinsics (focal, focal, size / 2, size / 2).
    depth_delta_m: depth-test tolerance |z - D(u, v)| < delta. On the real sample, points on
      objects carried between its two depth frames match the rendered depth within 2.1 mm
      (95%), 11.3 mm (99%), with 99.5% under 2 cm; points that land on another object's pixels
      are 95 mm (10th percentile) from its depth. 2 cm (the release's value) keeps 99.5% of the
      genuinely visible points.
    dynamic_share: share of each frame's queries drawn on dynamic objects when any are in view.
    mask_min_agreement: keep a track when (visible frames on its own object's id) /
      (visible frames) >= this.
    tracks_per_clip, oversample: tracks written per clip; candidates drawn = oversample x that.
    """

    chunk_frames: int = 300
    min_frames: int = 300
    with_skeleton: bool = True
    max_gt_offset_ms: float = 5.0
    image_size: int = 512
    focal: float = 280.0
    depth_delta_m: float = 0.02
    dynamic_share: float = 0.5
    mask_min_agreement: float = 0.5
    tracks_per_clip: int = 1024
    oversample: int = 4


@dataclasses.dataclass(frozen=True)
class PstudioConfig:
    """Panoptic Studio (Dynamic 3D Gaussians) choices (SOURCES.md section 5).

    params_dir: folder holding ``<sequence>/params.npz``; empty = ``<input>/output/<exp>``
      when ``<input>/output`` holds exactly one experiment.
    cameras: the unit cameras; empty = every camera of train_meta.json.
    depth_delta_m: depth-test tolerance |z - D(u, v)| < delta on the splat depth (metres).
      0.05 measured best on the sample world (agreement with ray-cast truth over all body
      candidates: 0.02 m 94.6%, 0.03 m 97.0%, 0.04 m 97.4%, 0.05 m 97.5%, 0.06 m 97.4%,
      0.08 m 97.3%): below it, points seen at grazing angles fail because nearer splats of
      the same surface blend into their depth; above it, points just behind an edge pass.
    min_alpha: a pixel whose accumulated alpha is below this has no surface (depth unknown).
    max_attach_distance_m: a query whose unprojected point is farther than this from the
      nearest foreground centre is refused (ours): at silhouettes the normalised depth blends
      the body with what lies behind it, and the point lands in mid-air (up to 18 cm away on
      the sample world; the median is under 1 cm).
    mask_min_agreement: keep a track whose centre lies on the foreground mask in at least this
      fraction of the (frame, camera) pairs where it projects into the image.
    """

    params_dir: str = ""
    cameras: tuple[int, ...] = ()
    depth_delta_m: float = 0.05
    min_alpha: float = 0.5
    max_attach_distance_m: float = 0.03
    mask_min_agreement: float = 0.75
    tracks_per_clip: int = 50
    oversample: int = 8


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything that decides a run's output besides its input.

    queries_from: a folder of existing clips whose queries are re-annotated instead of sampling
      new ones (``--queries-from``); only clips found there are made.
    export_depth: also write the depth each visibility test read (``--export-depth``).
    """

    seed: int = 0
    splits_file: str = ""
    queries_from: str = ""
    export_depth: bool = False
    minival_per_source: int = 50
    flicker: FlickerConfig = dataclasses.field(default_factory=FlickerConfig)
    adt: AdtConfig = dataclasses.field(default_factory=AdtConfig)
    drivetrack: DriveTrackConfig = dataclasses.field(default_factory=DriveTrackConfig)
    pstudio: PstudioConfig = dataclasses.field(default_factory=PstudioConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _parse_value(text: str, kind: typing.Any, key: str):
    if typing.get_origin(kind) is tuple:
        (item_kind, _) = typing.get_args(kind)
        return tuple(_parse_value(part, item_kind, key) for part in text.split(",") if part)
    if kind is bool:
        if text.lower() in ("1", "true", "yes"):
            return True
        if text.lower() in ("0", "false", "no"):
            return False
        raise ValueError(f"--set {key}: expected true/false, got {text!r}")
    try:
        return kind(text)
    except ValueError as error:
        raise ValueError(f"--set {key}: expected {kind.__name__}, got {text!r}") from error


def _keys(config, prefix: str = "") -> list[str]:
    keys = []
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            keys += _keys(value, f"{prefix}{field.name}.")
        else:
            keys.append(prefix + field.name)
    return keys


def with_overrides(config, assignments: list[str]):
    """Return ``config`` with ``section.field=value`` assignments applied (types checked)."""
    for assignment in assignments:
        key, sep, text = assignment.partition("=")
        if not sep:
            raise ValueError(f"--set {assignment!r}: expected key=value")
        config = _replace_path(config, key.strip().split("."), text.strip(), key, config)
    return config


def _replace_path(node, path: list[str], text: str, key: str, root):
    hints = typing.get_type_hints(type(node))
    name = path[0]
    if name not in hints:
        valid = ", ".join(_keys(root))
        raise ValueError(f"--set {key}: unknown setting; valid keys: {valid}")
    current = getattr(node, name)
    if dataclasses.is_dataclass(current):
        if len(path) == 1:
            raise ValueError(f"--set {key}: is a section; name one of its fields")
        value = _replace_path(current, path[1:], text, key, root)
    elif len(path) > 1:
        raise ValueError(f"--set {key}: {name} has no fields")
    else:
        value = _parse_value(text, hints[name], key)
    return dataclasses.replace(node, **{name: value})


def config_from_dict(kind, values: dict):
    """Rebuild a config dataclass of type ``kind`` from ``to_dict()`` output (e.g. a run.json)."""
    hints = typing.get_type_hints(kind)
    fields = {}
    for field in dataclasses.fields(kind):
        if field.name not in values:
            continue
        value = values[field.name]
        if dataclasses.is_dataclass(hints[field.name]):
            value = config_from_dict(hints[field.name], value)
        elif typing.get_origin(hints[field.name]) is tuple:
            value = tuple(value)
        fields[field.name] = value
    return kind(**fields)
