"""What a rule set decides for one source's run: the run's settings from the rule set and ``--set``;
the settings ``rules=release`` or ``rules=refined`` sets (the run-wide ones and that source's
section), their values under the other rule set, and which of them a ``--set`` overrode; the lines a
run prints first, and the record its provenance keeps."""

from __future__ import annotations

import dataclasses

from pipeline.settings import sections as registry
from pipeline.settings.fields import (
    NOT_KNOWN,
    RULE_SETS,
    as_set_value,
    flat_settings,
    release_values,
    with_overrides,
    with_rules,
)
from pipeline.settings.run_config import RunConfig


@dataclasses.dataclass(frozen=True)
class RuleSet:
    """The rule set a run follows and what it decides for the run's source: ``sets``, key -> value of
    each setting the rule set gives (its run-wide ones and the source's); ``other``, key -> that
    setting's value under the other rule set; ``overridden``, key -> the value a ``--set`` gave one of
    them instead; ``not_known``, the source's settings whose release value is not known (ours
    kept)."""

    name: str
    sets: dict[str, object]
    other: dict[str, object]
    overridden: dict[str, object]
    not_known: tuple[str, ...]

    def lines(self) -> list[str]:
        """What the run prints first: the rule set, the settings it sets, and each override."""
        said = ", ".join(f"{key}={as_set_value(value)}" for key, value in self.sets.items())
        other = _other(self.name)
        what = "the original generators' choices" if self.name == "release" else "ours, measured better"
        lines = [f"rules: {self.name} ({what}; docs/release.md): {said or 'no setting of this source'}"]
        if self.sets:
            lines[0] += f" ({other}: {', '.join(as_set_value(value) for value in self.other.values())})"
        if self.name == "release" and self.not_known:
            lines.append(f"rules: the release's value not known, ours kept: {', '.join(self.not_known)}")
        lines += [
            f"rules: --set {key}={as_set_value(value)} wins over rules={self.name} "
            f"({as_set_value(self.sets[key])})"
            for key, value in self.overridden.items()
        ]
        return lines

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "sets": dict(self.sets),
            "overridden": dict(self.overridden),
            "not_known": list(self.not_known),
        }


def _other(rules: str) -> str:
    return next(name for name in RULE_SETS if name != rules)


def assigned_keys(assignments: list[str]) -> frozenset[str]:
    """The keys of ``key=value`` assignments (``--set``)."""
    return frozenset(text.partition("=")[0].strip() for text in assignments)


def configured(assignments: list[str], release_run: bool) -> RunConfig:
    """The run's settings: the rule set's defaults, then ``assignments`` (``--set``). The rule set is
    ``--set rules=...``, else ``release`` on a ``--release`` run and ``refined`` on any other; a
    ``--set`` of one of its settings wins. SettingsError says what is wrong."""
    explicit = assigned_keys(assignments)
    given = with_overrides(RunConfig(), assignments)
    rules = given.rules if "rules" in explicit else "release" if release_run else "refined"
    return with_overrides(with_rules(RunConfig(), rules), assignments)


def rule_set(config: RunConfig, source: str, explicit: frozenset[str]) -> RuleSet:
    """What ``config.rules`` decides for a run of ``source``, the ``explicit`` keys (``--set``)
    aside: every setting with a release mark but those of other sources' sections."""
    others = set(registry.names()) - {source}
    known = {
        key: value
        for key, value in release_values(config).items()
        if key != "rules" and key.split(".", 1)[0] not in others
    }
    governed = sorted(key for key, value in known.items() if value is not NOT_KNOWN)
    values = flat_settings(config)
    rule_values = flat_settings(with_rules(config, config.rules))
    other_values = flat_settings(with_rules(config, _other(config.rules)))
    return RuleSet(
        config.rules,
        {key: rule_values[key] for key in governed},
        {key: other_values[key] for key in governed},
        {key: values[key] for key in governed if key in explicit and values[key] != rule_values[key]},
        tuple(sorted(key for key, value in known.items() if value is NOT_KNOWN)),
    )
