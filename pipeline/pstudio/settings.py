"""The ``pstudio`` section of the run's settings (``--set pstudio.<field>=...``): every choice and
threshold of the source, with its default and its allowed range."""

from __future__ import annotations

import dataclasses

from pipeline.settings.fields import NOT_KNOWN, clip_length, path_setting, ranged


@dataclasses.dataclass(frozen=True)
class PstudioConfig:
    """Panoptic Studio (Dynamic 3D Gaussians) choices (docs/formats.md, section 5).

    params_dir: folder holding ``<sequence>/params.npz``; empty = ``<input>/output/<exp>``
      when ``<input>/output`` holds exactly one experiment.
    cameras: the unit cameras; empty = every camera of train_meta.json.
    clip_frames: frames per clip: a camera's sequence longer than this is cut into consecutive
      windows of this many frames, each a clip named ``<sequence>_<camera>_w<k>`` (k = 0, 1, ...);
      0: the whole sequence (the release's). A training run sets it (``training.clip_frames``).
    min_frames: the last window of a cut sequence, when shorter than clip_frames, makes a clip only
      with at least this many frames.
    depth_delta_m: depth-test tolerance |z - D(u, v)| < delta on the splats' median depth
      (metres); no point is visible where the transmittance never drops below 0.5 (the
      renderer's 15 m background). 0.05 measured best on the sample world (agreement with
      ray-cast truth over every attached body query: 0.02 m 91.3%, 0.03 m 96.7%, 0.04 m 97.4%,
      0.05 m 97.5%, 0.06 m 97.5%, 0.08 m 97.4%, 0.10 m 97.3%): below it, points seen at grazing
      angles fail because a nearer splat of the same surface holds the median; above it,
      points just behind an edge pass.
    max_attach_distance_m: a query whose unprojected point is farther than this from the
      nearest foreground centre is refused (ours; 0: none is, as in the release). The median
      depth is one splat's depth, so the point lies within a footprint of some centre: on the
      sample world median 1.0 cm, 99% under 1.7 cm, 1 query in 2,449 beyond 3 cm (3.3 cm).
    mask_min_agreement: keep a track whose centre lies on the foreground mask in at least this
      fraction of the (frame, camera) pairs where it projects into the image.
    tracks_per_clip, oversample: tracks written per clip; candidates drawn = oversample x that.
    """

    params_dir: str = path_setting()
    cameras: tuple[int, ...] = ranged((), "[0, 999]")
    clip_frames: int = clip_length(0, "[0, 100000]", release_fixed=True)
    min_frames: int = ranged(24, "[1, 100000]")
    depth_delta_m: float = ranged(0.05, "(0, 10]", release=NOT_KNOWN)
    max_attach_distance_m: float = ranged(0.03, "[0, 10]", release=0.0)
    mask_min_agreement: float = ranged(0.75, "[0, 1]")
    tracks_per_clip: int = ranged(50, "[1, 100000]")
    oversample: int = ranged(8, "[1, 10000]", release=NOT_KNOWN)


# The source as the settings page (``python -m pipeline.settings.doc``) titles its section.
TITLE = "Panoptic Studio (Dynamic 3D Gaussians)"
SETTINGS = PstudioConfig
