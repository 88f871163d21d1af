"""Run configuration: every threshold is a field with the paper's default and its allowed range.

Fields are overridden from the command line with ``--set section.field=value``; ``with_overrides``
refuses a value outside its field's range (``check_ranges``) before any work starts.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
import typing

_INTERVAL = re.compile(r"([\[(])\s*([^,\s]+)\s*,\s*([^\])\s]+)\s*([\])])")


@dataclasses.dataclass(frozen=True)
class Range:
    """An interval of allowed values (of each item, for a tuple); a bound is a finite number or the
    name of a sibling field (``[1, chunk_frames]``). NaN fails every comparison, so it is refused."""

    low: float | str
    high: float | str
    low_open: bool
    high_open: bool
    even: bool = False
    nonempty: bool = False

    def _bounds(self, node) -> tuple:
        return tuple(getattr(node, b) if isinstance(b, str) else b for b in (self.low, self.high))

    def admits(self, value, kind, node) -> bool:
        if typing.get_origin(kind) is tuple:
            (item_kind, _) = typing.get_args(kind)
            return (
                isinstance(value, tuple)
                and len(set(value)) == len(value)
                and bool(value or not self.nonempty)
                and all(self.admits(item, item_kind, node) for item in value)
            )
        if isinstance(value, bool) or not isinstance(value, int if kind is int else (int, float)):
            return False
        low, high = self._bounds(node)
        if not all(isinstance(b, (int, float)) for b in (low, high)):
            return True  # a sibling bound that is not a number reports its own violation
        above = value > low if self.low_open else value >= low
        below = value < high if self.high_open else value <= high
        return above and below and not (self.even and value % 2)

    def describe(self, kind, node, prefix: str) -> str:
        if typing.get_origin(kind) is tuple:
            noun = ("one or more " if self.nonempty else "") + "distinct integers"
        else:
            noun = "an integer" if kind is int else "a number"
        low, high = (
            f"{prefix}{b}={getattr(node, b)}" if isinstance(b, str) else _number(b)
            for b in (self.low, self.high)
        )
        interval = f"{'(' if self.low_open else '['}{low}, {high}{')' if self.high_open else ']'}"
        return f"{noun} in {interval}" + (" and even" if self.even else "")


def _number(bound: float) -> str:
    return str(int(bound)) if bound == int(bound) else str(bound)


def ranged(default, interval: str, *, even: bool = False, nonempty: bool = False):
    """A field whose value (each item of a tuple) must lie in ``interval``, e.g. ``"(0, 10]"``."""
    match = _INTERVAL.fullmatch(interval)
    if not match:
        raise ValueError(f"bad interval {interval!r}")
    opening, low, high, closing = match.groups()
    low, high = (text if text.isidentifier() else float(text) for text in (low, high))
    rule = Range(low, high, opening == "(", closing == ")", even, nonempty)
    return dataclasses.field(default=default, metadata={"range": rule})


def not_in_clips(default, interval: str | None = None):
    """A field that never changes a clip's bytes (where manifests or scratch files go, ...): the
    resume fingerprint leaves it out, so changing it redoes no unit (``clip_settings``)."""
    field = ranged(default, interval) if interval else dataclasses.field(default=default)
    return dataclasses.field(default=default, metadata={**field.metadata, "clip_bytes": False})


@dataclasses.dataclass(frozen=True)
class FlickerConfig:
    """Drop a track whose visibility changes state more than ``max_fraction`` x T times."""

    max_fraction: float = ranged(0.10, "[0, 1]")


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
    undistort_frames: Waymo's frames carry lens distortion (up to ~8 px at the corners of a
      1920x1280 frame), which no pinhole ``fx_fy_cx_cy`` describes. True writes each frame
      undistorted with OpenCV (same intrinsics, re-encoded JPEG), so the pinhole projection of
      ``tracks_XYZ`` lands on the point in the stored frame; false keeps Waymo's JPEGs as the
      release did, and queries sit where the point appears in them, off the pinhole projection by
      the distortion (``pipeline.validate`` reports it per clip). Tracks and queries include the
      rolling shutter either way (drivetrack/camera_model.py).
    """

    cameras: tuple[int, ...] = ranged((1, 2, 3), "[1, 5]", nonempty=True)
    object_types: tuple[int, ...] = ranged((1,), "[1, 4]", nonempty=True)
    box_shrink_m: float = ranged(0.1, "[0, 10]")
    min_contiguous_frames: int = ranged(24, "[1, 100000]")
    max_corner_distance_m: float = ranged(50.0, "(0, 10000]")
    occlusion_margin: float = ranged(0.05, "[0, 1)")
    facing_test: bool = True
    tracks_per_clip: int = ranged(256, "[1, 100000]")
    oversample: int = ranged(4, "[1, 10000]")
    mask_min_agreement: float = ranged(0.5, "[0, 1]")
    masks_dir: str = ""
    mask_closing_px: int = ranged(0, "[0, 1000]")
    undistort_frames: bool = True


@dataclasses.dataclass(frozen=True)
class AdtConfig:
    """Aria Digital Twin choices, as the TAPVid-3D release made them (docs/formats.md, section 4).

    chunk_frames: frames per clip (chunk k = frames [k * chunk_frames, (k + 1) * chunk_frames)
      of the RGB frames strictly inside the ground-truth window).
    min_frames: a chunk with fewer frames (the end of a sequence) is skipped.
    with_skeleton: read the depth and segmentation that render the wearer's body and hands.
    max_gt_offset_ms: the largest time between an RGB frame and the depth, segmentation and
      poses used for it (projectaria-tools' CLOSEST sample); a frame beyond it fails its unit.
      Real sequences are within 0.1 ms; the shared 3-frame excerpt needs 40 (its depth stops
      one frame early, 33.2 ms before its last RGB frame).
    image_size, focal: the square pinhole camera every frame is re-rendered to (principal point
      size / 2 in projectaria-tools' integer-centre pixels, as the release's generator), then
      rotated 90 degrees clockwise; written intrinsics are the stored frames' true ones,
      (focal, focal, size / 2 - 0.5, size / 2 + 0.5) with pixel centres at +0.5.
    depth_delta_m: depth-test tolerance |z - D(u, v)| < delta. On the real sample, points on
      objects carried between its two depth frames match the rendered depth within 2.1 mm
      (95%), 11.3 mm (99%), with 99.5% under 2 cm; points that land on another object's pixels
      are 95 mm (10th percentile) from its depth. 2 cm (the release's value) keeps 99.5% of the
      genuinely visible points.
    dynamic_share: share of each frame's queries drawn on dynamic objects when any are in view.
    mask_min_agreement: keep a track when (visible frames on its own object's id) /
      (visible frames) >= this.
    tracks_per_clip, oversample: tracks written per clip; candidates drawn = oversample x that.
    scratch_dir: where sequences fetched from a download-URLs JSON (``--input``) are unpacked, one
      at a time per worker, and deleted after; empty = a folder under the system's temporary folder.
    download_retries, download_backoff_s: a download that fails with 429, a 5xx answer or a lost
      connection is retried this many times, waiting backoff x 2^(n-1) s before the n-th retry but
      the first.
    """

    chunk_frames: int = ranged(300, "[1, 100000]")
    min_frames: int = ranged(300, "[1, chunk_frames]")
    with_skeleton: bool = True
    max_gt_offset_ms: float = ranged(5.0, "(0, 1000]")
    image_size: int = ranged(512, "[2, 8192]", even=True)
    focal: float = ranged(280.0, "(0, 100000]")
    depth_delta_m: float = ranged(0.02, "(0, 10]")
    dynamic_share: float = ranged(0.5, "[0, 1]")
    mask_min_agreement: float = ranged(0.5, "[0, 1]")
    tracks_per_clip: int = ranged(1024, "[1, 100000]")
    oversample: int = ranged(4, "[1, 10000]")
    scratch_dir: str = not_in_clips("")
    download_retries: int = not_in_clips(5, "[0, 100]")
    download_backoff_s: float = not_in_clips(2.0, "[0, 600]")


@dataclasses.dataclass(frozen=True)
class PstudioConfig:
    """Panoptic Studio (Dynamic 3D Gaussians) choices (docs/formats.md, section 5).

    params_dir: folder holding ``<sequence>/params.npz``; empty = ``<input>/output/<exp>``
      when ``<input>/output`` holds exactly one experiment.
    cameras: the unit cameras; empty = every camera of train_meta.json.
    depth_delta_m: depth-test tolerance |z - D(u, v)| < delta on the splats' median depth
      (metres); no point is visible where the transmittance never drops below 0.5 (the
      renderer's 15 m background). 0.05 measured best on the sample world (agreement with
      ray-cast truth over every attached body query: 0.02 m 91.3%, 0.03 m 96.7%, 0.04 m 97.4%,
      0.05 m 97.5%, 0.06 m 97.5%, 0.08 m 97.4%, 0.10 m 97.3%): below it, points seen at grazing
      angles fail because a nearer splat of the same surface holds the median; above it,
      points just behind an edge pass.
    max_attach_distance_m: a query whose unprojected point is farther than this from the
      nearest foreground centre is refused (ours). The median depth is one splat's depth, so
      the point lies within a footprint of some centre: on the sample world median 1.0 cm,
      99% under 1.7 cm, 1 query in 2,449 beyond 3 cm (3.3 cm).
    mask_min_agreement: keep a track whose centre lies on the foreground mask in at least this
      fraction of the (frame, camera) pairs where it projects into the image.
    """

    params_dir: str = ""
    cameras: tuple[int, ...] = ranged((), "[0, 999]")
    depth_delta_m: float = ranged(0.05, "(0, 10]")
    max_attach_distance_m: float = ranged(0.03, "(0, 10]")
    mask_min_agreement: float = ranged(0.75, "[0, 1]")
    tracks_per_clip: int = ranged(50, "[1, 100000]")
    oversample: int = ranged(8, "[1, 10000]")


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything that decides a run's output besides its input.

    seed: every random choice is seeded from it and the clip's name.
    splits_file: the release's splits JSON: the manifests follow its membership where clip names
      match (``--release`` also restricts the run to its clips).
    queries_from: a folder of existing clips whose queries are re-annotated instead of sampling
      new ones (``--queries-from``); only clips found there are made.
    export_depth: also write the depth each visibility test read (``--export-depth``).
    minival_per_source: without a splits file, minival is a seeded draw of this many clips per
      source; full_test holds every other clip.
    min_tracks: a clip is written only when at least this many tracks pass the filters.
    """

    seed: int = ranged(0, "[0, 4294967295]")
    splits_file: str = not_in_clips("")
    queries_from: str = ""
    export_depth: bool = not_in_clips(False)
    minival_per_source: int = not_in_clips(50, "[0, 1000000]")
    min_tracks: int = ranged(1, "[1, 100000]")
    flicker: FlickerConfig = dataclasses.field(default_factory=FlickerConfig)
    adt: AdtConfig = dataclasses.field(default_factory=AdtConfig)
    drivetrack: DriveTrackConfig = dataclasses.field(default_factory=DriveTrackConfig)
    pstudio: PstudioConfig = dataclasses.field(default_factory=PstudioConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


_EXPECTED = {bool: "bool", int: "int", float: "float", tuple[int, ...]: "comma-separated ints"}


def _parse_value(text: str, kind: typing.Any):
    if typing.get_origin(kind) is tuple:
        (item_kind, _) = typing.get_args(kind)
        return tuple(_parse_value(part.strip(), item_kind) for part in text.split(",") if part.strip())
    if kind is bool:
        if text.lower() in ("1", "true", "yes"):
            return True
        if text.lower() in ("0", "false", "no"):
            return False
        raise ValueError(text)
    return kind(text)


def _rule(node, name: str) -> Range | None:
    return next(field.metadata.get("range") for field in dataclasses.fields(node) if field.name == name)


def _admits(node, name: str, kind) -> bool:
    rule, value = _rule(node, name), getattr(node, name)
    if rule is not None:
        return rule.admits(value, kind, node)
    return isinstance(value, bool if kind is bool else str)


def _need(node, name: str, kind, prefix: str) -> str:
    """What field ``name`` of ``node`` must be, in words."""
    rule = _rule(node, name)
    if rule is not None:
        return rule.describe(kind, node, prefix)
    return "true or false" if kind is bool else "a string"


def _violations(node, prefix: str = "") -> list[tuple[str, typing.Any, str]]:
    """(key, value, what it must be) for every field of ``node`` outside its range."""
    hints = typing.get_type_hints(type(node))
    found = []
    for field in dataclasses.fields(node):
        value = getattr(node, field.name)
        if dataclasses.is_dataclass(hints[field.name]):
            found += _violations(value, f"{prefix}{field.name}.")
        elif not _admits(node, field.name, hints[field.name]):
            found.append((prefix + field.name, value, _need(node, field.name, hints[field.name], prefix)))
    return found


def _show(value) -> str:
    """``value`` as it would be written after ``--set key=``."""
    return ",".join(str(v) for v in value) if isinstance(value, tuple) else str(value)


class SettingsError(ValueError):
    """Every problem of a set of assignments (``problems``, one line each), reported together."""

    def __init__(self, problems: list[str]):
        super().__init__("; ".join(problems))
        self.problems = problems


def range_problems(config, assigned: dict[str, str] | None = None, option: str = "--set") -> list[str]:
    """One line per field of ``config`` outside its range, with its value and the range.

    ``assigned`` maps the keys given with ``option`` to their text, which the message quotes.
    """
    assigned = assigned or {}
    shown = {key: f"{option} {key}={text}" for key, text in assigned.items()}
    return [
        f"{shown.get(key, f'{key}={_show(value)}')}: must be {need}"
        for key, value, need in _violations(config)
    ]


def check_ranges(config, assigned: dict[str, str] | None = None) -> None:
    """Raise SettingsError naming every field of ``config`` outside its range, its value and the range."""
    problems = range_problems(config, assigned)
    if problems:
        raise SettingsError(problems)


def setting_keys(config) -> list[str]:
    """Every field of ``config`` as ``section.field`` (or ``field``)."""
    return _keys(config)


def _keys(config, prefix: str = "") -> list[str]:
    keys = []
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            keys += _keys(value, f"{prefix}{field.name}.")
        else:
            keys.append(prefix + field.name)
    return keys


def with_overrides(config, assignments: list[str], option: str = "--set"):
    """Return ``config`` with ``section.field=value`` assignments applied, types and ranges checked;
    SettingsError listing every problem (``option`` names where the assignments came from)."""
    assigned, problems = {}, []
    for assignment in assignments:
        key, sep, text = assignment.partition("=")
        if not sep:
            problems.append(f"{option} {assignment!r}: expected key=value")
            continue
        key, text = key.strip(), text.strip()
        try:
            config = _replace_path(config, key.split("."), text, key, config, option)
        except ValueError as error:
            problems.append(str(error))
            continue
        assigned[key] = text
    problems += range_problems(config, assigned, option)
    if problems:
        raise SettingsError(problems)
    return config


def _replace_path(node, path: list[str], text: str, key: str, root, option: str, prefix: str = ""):
    hints = typing.get_type_hints(type(node))
    name = path[0]
    if name not in hints:
        valid = setting_keys(root)
        near = difflib.get_close_matches(key, valid, n=1, cutoff=0.6)
        hint = f"did you mean {near[0]}? " if near else ""
        raise ValueError(f"{option} {key}: unknown setting; {hint}valid keys: {', '.join(valid)}")
    current = getattr(node, name)
    if dataclasses.is_dataclass(current):
        if len(path) == 1:
            raise ValueError(f"{option} {key}: is a section; name one of its fields")
        value = _replace_path(current, path[1:], text, key, root, option, f"{prefix}{name}.")
    elif len(path) > 1:
        raise ValueError(f"{option} {key}: {name} has no fields")
    else:
        try:
            value = _parse_value(text, hints[name])
        except ValueError:
            expected, need = _EXPECTED[hints[name]], _need(node, name, hints[name], prefix)
            raise ValueError(f"{option} {key}={text}: expected {expected}; must be {need}") from None
    return dataclasses.replace(node, **{name: value})


def config_from_dict(kind, values: dict):
    """Rebuild a config dataclass of type ``kind`` from ``to_dict()`` output (e.g. a run.json);
    ``check_ranges`` tells whether its values are allowed."""
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
