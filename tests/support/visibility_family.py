"""DriveTrack's visibility on the worlds of ``driving_family`` against ray-cast truth: per world and per
clip, under the release's rules and the refined ones, the agreement of every candidate (frame, track)
pair and the share of candidates the flicker filter drops, on the clip's visibility and on the truth.

    python -m tests.support.visibility_family                  # seeds 0-19, the table in markdown
    python -m tests.support.visibility_family --seeds 3,7 --clips  # and a row per clip

Each world is written once into ``--workdir`` (default ``.cache/family``), 10-15 s of CPU each.
"""

from __future__ import annotations

import dataclasses
import os
import sys

import numpy as np

from pipeline.commandline import StrictParser
from pipeline.filters.flicker import passes_flicker, visibility_flips
from pipeline.settings.fields import with_overrides, with_rules
from pipeline.settings.run_config import RunConfig
from tests.support import driving_family
from tests.support.cli import REPO
from tests.support.units import drivetrack_segment_clips
from tests.support.waymo_truth import true_tracks

RULES = ("release", "refined")


@dataclasses.dataclass(frozen=True)
class ClipScore:
    """One clip against its truth: its object, camera, frames x candidates, mean distance (m), pairs
    agreeing with the truth, candidates the flicker filter drops on its visibility and on the truth."""

    object_id: str
    camera: int
    frames: int
    tracks: int
    distance_m: float
    agree: int
    dropped: int
    dropped_truth: int

    @property
    def agreement(self) -> float:
        return self.agree / (self.frames * self.tracks)


def world_split(workdir: str, seed: int) -> str:
    """The split folder of seed ``seed``'s world, written on first use."""
    folder = os.path.join(workdir, f"seed-{seed}")
    if not os.path.exists(os.path.join(folder, "vehicle_pose")):
        driving_family.write_family_split(folder, seed)
    return folder


def score_world(folder: str, seed: int, rules: str) -> list[ClipScore]:
    """Every clip of the world under ``rules``, scored against its truth."""
    world, _ = driving_family.family_world(seed)
    config = with_overrides(with_rules(RunConfig(), rules), driving_family.OVERRIDES)
    max_fraction = config.flicker.max_fraction
    scores = []
    for camera, clips in drivetrack_segment_clips(folder, driving_family.SEGMENT, (1, 2, 3), config).items():
        for clip in clips:
            positions, _, _, truth, object_id = true_tracks(world, clip, camera)
            ours = clip.visibility
            dropped = [
                int((~passes_flicker(visibility_flips(v), clip.num_frames, max_fraction)).sum())
                for v in (ours, truth)
            ]
            distance = float(np.linalg.norm(positions, axis=2).mean())
            scores.append(
                ClipScore(object_id, camera, *ours.shape, distance, int((ours == truth).sum()), *dropped)
            )
    return scores


def totals(scores: list[ClipScore]) -> tuple[float, float, float]:
    """A world's agreement and its flicker drops, ours and the truth's (shares of its candidates)."""
    pairs = sum(s.frames * s.tracks for s in scores)
    candidates = sum(s.tracks for s in scores)
    agree = sum(s.agree for s in scores) / pairs
    return (
        agree,
        sum(s.dropped for s in scores) / candidates,
        sum(s.dropped_truth for s in scores) / candidates,
    )


def table(found: dict[int, dict[str, list[ClipScore]]], per_clip: bool) -> list[str]:
    """The markdown table: a row per world, release and refined side by side (and a row per clip)."""
    lines = [
        "| world | clips | agreement, release | refined | flicker drops, release | refined | truth |",
        "|---|---|---|---|---|---|---|",
    ]
    for seed, scored in found.items():
        release, refined = totals(scored["release"]), totals(scored["refined"])
        cells = [
            f"{release[0]:.2%}",
            f"{refined[0]:.2%}",
            f"{release[1]:.1%}",
            f"{refined[1]:.1%}",
            f"{refined[2]:.1%}",
        ]
        lines.append(f"| {seed} | {len(scored['refined'])} | " + " | ".join(cells) + " |")
    if per_clip:
        lines += [
            "",
            "| world | object | camera | size | distance | agreement, release | refined |",
            "|---|---|---|---|---|---|---|",
        ]
        for seed, scored in found.items():
            for a, b in zip(scored["release"], scored["refined"], strict=True):
                lines.append(
                    f"| {seed} | {b.object_id.split('_')[0]} | {b.camera} | {b.frames} x {b.tracks} | "
                    f"{b.distance_m:.0f} m | {a.agreement:.2%} | {b.agreement:.2%} |"
                )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(prog="python -m tests.support.visibility_family", description=__doc__)
    parser.add_argument("--seeds", default="0-19", help="seeds: a range a-b or a list (default %(default)s)")
    parser.add_argument("--workdir", default=os.path.join(REPO, ".cache", "family"))
    parser.add_argument("--clips", action="store_true", help="also a row per clip")
    args = parser.parse_args(argv)
    low, _, high = args.seeds.partition("-")
    seeds = list(range(int(low), int(high) + 1)) if high else [int(s) for s in args.seeds.split(",")]
    found = {}
    for seed in seeds:
        folder = world_split(args.workdir, seed)
        found[seed] = {rules: score_world(folder, seed, rules) for rules in RULES}
        print(f"seed {seed}: refined {totals(found[seed]['refined'])[0]:.2%}", file=sys.stderr, flush=True)
    print("\n".join(table(found, args.clips)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
