"""What every bad-input run must show: each bad unit fails alone with its own clear error, the good
units finish with valid clips, and no partial file is left behind."""

from __future__ import annotations

import json
import os
import subprocess

from pipeline.validate import main as validate_main


def failures_by_unit(out: str, source: str) -> dict[str, str]:
    """unit name (``unit (clip)`` for one clip's failure) -> error text, from
    ``failures_<source>.jsonl`` (one line per unit, stage and clip)."""
    with open(os.path.join(out, f"failures_{source}.jsonl")) as handle:
        records = [json.loads(line) for line in handle]
    errors: dict[str, str] = {}
    for record in records:
        key = f"{record['unit']} ({record['clip']})" if record.get("clip") else record["unit"]
        errors[key] = " | ".join(filter(None, (errors.get(key), record["error"])))
    return errors


def partial_files(out: str) -> list[str]:
    """Leftovers of interrupted writes anywhere under ``out``."""
    found = (os.path.join(folder, name) for folder, _, names in os.walk(out) for name in names)
    return sorted(path for path in found if ".partial" in os.path.basename(path))


def assert_only_these_units_failed(
    result: subprocess.CompletedProcess, out: str, source: str, expected: dict[str, list[str]]
) -> dict[str, str]:
    """A run over good and bad units: it exits 1, exactly the units of ``expected`` (unit name ->
    substrings of its error) failed, every written clip validates, and no partial file remains.
    Returns the failures by unit, for each case's own check (``assert_case_error``)."""
    assert result.returncode == 1, result.stderr[-3000:]
    errors = failures_by_unit(out, source)
    assert set(errors) == set(expected), f"failed units {sorted(errors)} != expected {sorted(expected)}"
    assert partial_files(out) == []
    assert validate_main([out]) == 0
    return errors


def assert_case_error(errors: dict[str, str], unit: str, needles: list[str]) -> None:
    """Unit ``unit`` failed with an InputError (a clear message, not a crash) holding every needle."""
    assert unit in errors, f"{unit} did not fail; failures: {sorted(errors)}"
    assert errors[unit].startswith("InputError"), f"{unit}: {errors[unit]}"
    for needle in needles:
        assert needle in errors[unit], f"{unit}: {needle!r} not in {errors[unit]!r}"
