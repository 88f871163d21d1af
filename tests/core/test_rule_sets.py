"""What a rule set decides for one source's run: its own section's and the run-wide settings, never
another source's; the values under the other rule set; a --set that wins, said."""

from __future__ import annotations

import pytest

from pipeline.settings.fields import with_overrides, with_rules
from pipeline.settings.rule_sets import rule_set
from pipeline.settings.run_config import RunConfig

RELEASE = with_rules(RunConfig(), "release")


@pytest.mark.parametrize("source", ["adt", "drivetrack", "pstudio"])
def test_a_rule_set_governs_the_run_wide_settings_and_the_sources_own(source):
    decided = rule_set(RELEASE, source, frozenset())
    keys = [*decided.sets, *decided.not_known]
    assert keys and all("." not in key or key.startswith(f"{source}.") for key in keys)
    assert {"seed", "min_tracks"} <= set(decided.not_known)


def test_release_and_refined_values_of_adt_and_an_override():
    assert rule_set(RELEASE, "adt", frozenset()).sets == {"adt.max_gt_offset_ms": 0.0}
    decided = rule_set(RunConfig(), "adt", frozenset())
    assert (decided.sets, decided.other) == ({"adt.max_gt_offset_ms": 5.0}, {"adt.max_gt_offset_ms": 0.0})
    overridden = rule_set(
        with_overrides(RELEASE, ["adt.max_gt_offset_ms=40"]), "adt", frozenset({"adt.max_gt_offset_ms"})
    )
    assert overridden.lines()[0] == (
        "rules: release (the original generators' choices; docs/release.md): adt.max_gt_offset_ms=0.0 "
        "(refined: 5.0)"
    )
    assert overridden.lines()[-1] == "rules: --set adt.max_gt_offset_ms=40.0 wins over rules=release (0.0)"


def test_drivetrack_release_flags_are_shown_as_set_takes_them():
    line = rule_set(RELEASE, "drivetrack", frozenset()).lines()[0]
    assert "drivetrack.refined_visibility=false" in line and "(refined: true, " in line
