"""A run's provenance file, ``<out>/run_<source>.json`` (``layout.provenance_path``): where the run
came from (``Provenance``), its summary and its Beam counters; every URL in its settings is kept
without its query string (a token)."""

from __future__ import annotations

import dataclasses
import json
import platform
import time
from typing import TYPE_CHECKING

import apache_beam as beam
import numpy as np

import pipeline
from pipeline.io.http import scrub

if TYPE_CHECKING:
    from pipeline.settings.rule_sets import RuleSet
    from pipeline.settings.run_config import RunConfig


def library_versions() -> dict[str, str]:
    """The versions of Python and of the libraries that decide a clip's bytes."""
    return {"python": platform.python_version(), "numpy": np.__version__, "apache_beam": beam.__version__}


def utc_now() -> str:
    """The time now, as the provenance file keeps it (UTC, to the second)."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


@dataclasses.dataclass(frozen=True)
class Provenance:
    """Where a run came from, as its provenance file keeps it: the package and version, the source, input and
    output, every setting and the rule set's account of them, the release it was restricted to, its
    units, the Beam options, the libraries' versions and when it started (both taken when the record
    is made)."""

    source: str
    input: str
    output: str
    config: RunConfig
    rules: RuleSet
    release: str | None
    units: tuple[str, ...]
    beam_options: tuple[str, ...]
    environment: dict = dataclasses.field(default_factory=library_versions)
    started: str = dataclasses.field(default_factory=utc_now)
    package: str = "tapvid3d-pipeline"
    version: str = pipeline.__version__


def scrubbed(values: dict) -> dict:
    """Settings as a run's provenance keeps them: every URL without its query string (a token)."""
    return {
        key: scrubbed(value) if isinstance(value, dict) else scrub(value) if isinstance(value, str) else value
        for key, value in values.items()
    }


def provenance_file(provenance: Provenance, summary: dict, metrics: dict[str, int] | None) -> bytes:
    """The provenance file's bytes: ``provenance``, the run's ``summary`` (``RunSummary.to_json``) and
    its Beam counters (``metrics``; None: the runner reports none, and the file says so)."""
    record = {field.name: getattr(provenance, field.name) for field in dataclasses.fields(provenance)}
    record |= {
        "config": scrubbed(provenance.config.to_dict()),
        "rules": provenance.rules.to_json(),
        "units": list(provenance.units),
        "beam_options": list(provenance.beam_options),
        "summary": summary,
        "metrics": "not reported by this runner" if metrics is None else metrics,
    }
    return json.dumps(record, indent=2, sort_keys=True).encode()
