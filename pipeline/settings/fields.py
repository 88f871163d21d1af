"""Settings: every threshold is a field with the paper's default and its allowed range.

The machinery for any settings dataclass (the run's own is ``pipeline.settings.RunConfig``, whose
sections come from the sources): fields are overridden from the command line with ``--set
section.field=value``; ``with_overrides`` refuses every value outside its field's range
(``check_ranges``) in one list before any work starts.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import re
import typing
from collections.abc import Mapping

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


@dataclasses.dataclass(frozen=True)
class Choice:
    """The allowed values of a string setting, named."""

    values: tuple[str, ...]

    def admits(self, value, kind, node) -> bool:
        return value in self.values

    def describe(self, kind, node, prefix: str) -> str:
        return "one of " + ", ".join(self.values)


# The rule sets a run follows (the ``rules`` setting): ``release`` makes the original generators'
# choices, ``refined`` ours. A setting's default is its ``refined`` value; ``release=`` names the
# release's value where it differs, or NOT_KNOWN where the release's is not known (ours is kept).
RULE_SETS = ("release", "refined")


class _NotKnown:
    def __repr__(self) -> str:
        return "not known"


NOT_KNOWN = _NotKnown()
_SAME = object()


def _metadata(rule=None, release=_SAME) -> dict:
    return {
        **({} if rule is None else {"range": rule}),
        **({} if release is _SAME else {"release": release}),
    }


def ranged(default, interval: str, *, even: bool = False, nonempty: bool = False, release=_SAME):
    """A field whose value (each item of a tuple) must lie in ``interval``, e.g. ``"(0, 10]"``;
    ``release``: the release's value, where it differs from ``default`` (ours), or NOT_KNOWN."""
    match = _INTERVAL.fullmatch(interval)
    if not match:
        raise ValueError(f"bad interval {interval!r}")
    opening, low, high, closing = match.groups()
    low, high = (text if text.isidentifier() else float(text) for text in (low, high))
    rule = Range(low, high, opening == "(", closing == ")", even, nonempty)
    return dataclasses.field(default=default, metadata=_metadata(rule, release))


def flag(default: bool, *, release=_SAME):
    """A true-or-false field; ``release`` as in ``ranged``."""
    return dataclasses.field(default=default, metadata=_metadata(release=release))


def one_of(default: str, values: tuple[str, ...], *, release=_SAME):
    """A string field that takes one of ``values``; ``release`` as in ``ranged``."""
    return dataclasses.field(default=default, metadata=_metadata(Choice(values), release))


def _declared_metadata(config) -> dict[str, Mapping[str, typing.Any]]:
    """Field name -> its metadata, for each field of the dataclass ``config``."""
    return {field.name: field.metadata for field in dataclasses.fields(config)}


def release_values(config) -> dict[str, object]:
    """Key -> the release's value (or NOT_KNOWN) of every setting of ``config`` whose release value
    is marked (``ranged(..., release=...)``, ``flag``), sections included."""
    return {key: release for key, (_, release) in _marked(config, "release").items()}


def with_rules(config, rules: str, keep: frozenset[str] = frozenset(), prefix: str = ""):
    """``config`` with every setting whose release value is known at its value under ``rules``
    (``release``: the release's; ``refined``: the field's default), except the keys in ``keep``."""
    fields = {field.name: field for field in dataclasses.fields(config)}
    for name, value, _ in settings_items(config):
        key = prefix + name
        if dataclasses.is_dataclass(value):
            config = _with_setting(config, name, with_rules(value, rules, keep, f"{key}."))
            continue
        release = fields[name].metadata.get("release", _SAME) if name in fields else _SAME
        if release is _SAME or release is NOT_KNOWN or key in keep:
            continue
        config = _with_setting(config, name, release if rules == "release" else fields[name].default)
    return config


def not_in_clips(default, interval: str | None = None):
    """A field that never changes a clip's bytes (where manifests or scratch files go, ...): the
    resume fingerprint leaves it out, so changing it redoes no unit (``clip_settings``)."""
    field = ranged(default, interval) if interval else dataclasses.field(default=default)
    return dataclasses.field(default=default, metadata={**field.metadata, "clip_bytes": False})


def clip_length(default: int, interval: str, *, release_fixed: bool = False):
    """A setting of the source's clip length in frames, which a training run sets to
    ``training.clip_frames`` (``clip_lengths``); ``release_fixed``: a ``--release`` run refuses any
    value but ``default``, which makes the release's clips (``release_fixed_changes``)."""
    field = ranged(default, interval)
    fixed = {"release_fixed": default} if release_fixed else {}
    return dataclasses.field(default=default, metadata={**field.metadata, "clip_length": True, **fixed})


def _marked(config, mark: str, prefix: str = "") -> dict[str, tuple[typing.Any, typing.Any]]:
    """Key -> (value, the mark's value) of every setting of ``config`` (sections included) whose
    field's metadata holds ``mark``, in declaration order: the one walk of the marks."""
    declared = _declared_metadata(config)
    found = {}
    for name, value, _ in settings_items(config):
        if dataclasses.is_dataclass(value):
            found.update(_marked(value, mark, f"{prefix}{name}."))
        elif mark in declared.get(name, {}):
            found[prefix + name] = (value, declared[name][mark])
    return found


def clip_lengths(config, section: str) -> dict[str, typing.Any]:
    """Key -> value of the clip-length settings (``clip_length``) of ``config``'s section ``section``,
    in declaration order."""
    return {
        key: value
        for key, (value, _) in _marked(config, "clip_length").items()
        if key.startswith(f"{section}.")
    }


def release_fixed_changes(config, section: str) -> dict[str, typing.Any]:
    """Key -> value of the ``release_fixed`` settings of ``config``'s section ``section`` that are not
    at their default."""
    return {
        key: value
        for key, (value, default) in _marked(config, "release_fixed").items()
        if key.startswith(f"{section}.") and value != default
    }


def path_setting(default: str = "", label: str = "", clip_bytes: bool = True):
    """A string field naming a file or folder the run reads, checked to exist before any work
    (``path_settings``); ``label`` names it in messages (default: its key)."""
    metadata = {"path": label or True, **({} if clip_bytes else {"clip_bytes": False})}
    return dataclasses.field(default=default, metadata=metadata)


def path_settings(config) -> dict[str, str]:
    """The paths the run reads: label (or key) -> value of every set ``path_setting`` of ``config``."""
    return {
        label if isinstance(label, str) else key: value
        for key, (value, label) in _marked(config, "path").items()
        if value and label
    }


def sections(default_factory):
    """A field holding named sections (name -> settings dataclass), each addressed like a field of
    its own (``--set <name>.<field>=...``): the sources' sections of the run's settings."""
    return dataclasses.field(default_factory=default_factory, hash=False, metadata={"sections": True})


def settings_items(node) -> list[tuple[str, typing.Any, typing.Any]]:
    """(name, value, declared type) of each setting of the dataclass ``node``: its fields, and the
    sections held by a ``sections`` field (each a dataclass)."""
    hints = typing.get_type_hints(type(node))
    items = []
    for field in dataclasses.fields(node):
        value = getattr(node, field.name)
        if field.metadata.get("sections"):
            items += [(name, section, type(section)) for name, section in value.items()]
        else:
            items.append((field.name, value, hints[field.name]))
    return items


def settings_dict(node) -> dict:
    """``node`` as plain JSON values, a section as a dict of its own under its name."""
    return {
        name: settings_dict(value) if dataclasses.is_dataclass(value) else value
        for name, value, _ in settings_items(node)
    }


def setting(node, name: str) -> typing.Any:
    """Setting ``name`` of the dataclass ``node``: a field, or a section held by its ``sections``
    field."""
    for field in dataclasses.fields(node):
        if field.metadata.get("sections") and name in getattr(node, field.name):
            return getattr(node, field.name)[name]
    return getattr(node, name)


def value_at(config, key: str) -> typing.Any:
    """The value of the dotted settings key ``key`` (``adt.chunk_frames``) in ``config``."""
    node = config
    for part in key.split("."):
        node = setting(node, part)
    return node


def _with_setting(node, name: str, value):
    """``node`` with setting ``name`` (a field, or a held section) set to ``value``."""
    fields = {field.name: field for field in dataclasses.fields(node)}
    if name in fields:
        return dataclasses.replace(node, **{name: value})
    holder = next(field.name for field in fields.values() if field.metadata.get("sections"))
    return dataclasses.replace(node, **{holder: {**getattr(node, holder), name: value}})


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
    return next(
        (field.metadata.get("range") for field in dataclasses.fields(node) if field.name == name), None
    )


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
    """(key, value, what it must be) for every setting of ``node`` outside its range."""
    found = []
    for name, value, kind in settings_items(node):
        if dataclasses.is_dataclass(kind):
            found += _violations(value, f"{prefix}{name}.")
        elif not _admits(node, name, kind):
            found.append((prefix + name, value, _need(node, name, kind, prefix)))
    return found


def as_set_value(value) -> str:
    """``value`` as it would be written after ``--set key=``."""
    if isinstance(value, bool):
        return str(value).lower()
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
        f"{shown.get(key, f'{key}={as_set_value(value)}')}: must be {need}"
        for key, value, need in _violations(config)
    ]


def check_ranges(config, assigned: dict[str, str] | None = None) -> None:
    """Raise SettingsError naming every field of ``config`` outside its range, its value and the range."""
    problems = range_problems(config, assigned)
    if problems:
        raise SettingsError(problems)


def setting_keys(config) -> list[str]:
    """Every field of ``config`` as ``section.field`` (or ``field``)."""
    return list(flat_settings(config))


def flat_settings(config, prefix: str = "") -> dict[str, typing.Any]:
    """Dotted key (``section.field`` or ``field``) -> value of every setting of ``config``."""
    flat: dict[str, typing.Any] = {}
    for name, value, _ in settings_items(config):
        if dataclasses.is_dataclass(value):
            flat.update(flat_settings(value, f"{prefix}{name}."))
        else:
            flat[prefix + name] = value
    return flat


def add_set_argument(parser: argparse.ArgumentParser, help: str) -> None:
    """The repeatable ``--set KEY=VALUE`` option, gathered in ``args.overrides`` for ``with_overrides``."""
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help=help
    )


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
    hints = {name: kind for name, _, kind in settings_items(node)}
    name = path[0]
    if name not in hints:
        valid = setting_keys(root)
        near = difflib.get_close_matches(key, valid, n=1, cutoff=0.6)
        hint = f"did you mean {near[0]}? " if near else ""
        raise ValueError(f"{option} {key}: unknown setting; {hint}every key: docs/configuration.md")
    current = setting(node, name)
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
    return _with_setting(node, name, value)


def config_from_dict(kind, values: dict):
    """Rebuild a config dataclass of type ``kind`` from ``settings_dict`` output (e.g. a run's provenance's);
    a section is rebuilt when the defaults hold one of its name (an unknown one is dropped);
    ``check_ranges`` tells whether its values are allowed."""
    config = kind()
    for name, _, declared in settings_items(config):
        if name not in values:
            continue
        value = values[name]
        if dataclasses.is_dataclass(declared):
            value = config_from_dict(declared, value)
        elif typing.get_origin(declared) is tuple:
            value = tuple(value)
        config = _with_setting(config, name, value)
    return config
