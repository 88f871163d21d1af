"""Strict command lines: an unknown option, a typo or a bad value is refused in one line (with the
nearest valid name), exit status 2, before any work; ``--help`` prints to stdout and exits 0.

Every command of the package parses with ``StrictParser``; ``pipeline.run`` also checks the options it
hands to Beam (``check_beam_args``): the runner's name, the worker count, and every other option
against the option classes Beam and the named runner define.
"""

from __future__ import annotations

import argparse
import difflib
import re
import sys
from collections.abc import Iterable
from typing import NoReturn


class UsageError(Exception):
    """A command line that cannot run; the message is one line."""


def closest(name: str, valid: Iterable[str], cutoff: float = 0.6) -> str | None:
    """The valid name nearest to ``name`` (a likely typo of it), or None."""
    found = difflib.get_close_matches(name, list(valid), n=1, cutoff=cutoff)
    return found[0] if found else None


def did_you_mean(value: str, valid: Iterable[str], what: str) -> str:
    """One line refusing ``value`` (``what``: the option that gave it, e.g. ``--source``), with the
    nearest valid name, else the valid names."""
    valid = list(valid)
    near = closest(value, valid)
    hint = f"did you mean {near}?" if near else f"valid: {', '.join(valid)}"
    return f"{what} {value}: unknown; {hint}"


def plain_text(text: str) -> str:
    """A docstring as ``--help`` shows it: reStructuredText's double backticks dropped, a ``::`` that
    opens a literal block shown as ``:``."""
    return re.sub(r"::$", ":", text.replace("``", ""), flags=re.M)


def unknown_message(unknown: list[str], valid: Iterable[str], renamed: dict[str, str] | None = None) -> str:
    """One line naming the unknown arguments, each with the nearest valid option or, for an option
    ``renamed`` lists, what replaced it (a plain argument right after an unknown option is taken for
    its value)."""
    valid = sorted(set(valid))
    renamed = renamed or {}
    parts = []
    for index, argument in enumerate(unknown):
        if not argument.startswith("-"):
            if index == 0 or not unknown[index - 1].startswith("-") or "=" in unknown[index - 1]:
                parts.append(f"unexpected argument {argument!r}")
            continue
        name = argument.split("=", 1)[0]
        near = closest(name, valid)
        if name in renamed:
            parts.append(f"{name} {renamed[name]}")
        else:
            parts.append(f"unknown option {name}" + (f" (did you mean {near}?)" if near else ""))
    return "; ".join(parts) + " (--help lists the options)"


class StrictParser(argparse.ArgumentParser):
    """An ArgumentParser that takes no abbreviation, names the nearest valid option of an unknown one
    (or, for an old spelling in ``renamed``, what replaced it: ``{"--report": "is now --out"}``),
    reports every problem in one line on stderr with exit status 2, and shows its help as plain text."""

    def __init__(self, *args, renamed: dict[str, str] | None = None, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self.renamed = dict(renamed or {})

    def format_help(self) -> str:
        return plain_text(super().format_help())

    def _check_value(self, action, value):  # argparse's check of ``choices``: name the nearest one
        if action.choices is not None and value not in action.choices:
            what = action.option_strings[0] if action.option_strings else action.dest
            raise argparse.ArgumentError(None, did_you_mean(value, action.choices, what))

    def option_names(self) -> list[str]:
        return [name for action in self._actions for name in action.option_strings]

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: {message}", file=sys.stderr)
        raise SystemExit(2)

    def parse_args(self, args=None, namespace=None):
        args = sys.argv[1:] if args is None else list(args)
        self.refuse_unknown_options(args)
        parsed, unknown = self.parse_known_args(args, namespace)
        if unknown:
            self.error(unknown_message(unknown, self.option_names(), self.renamed))
        return parsed

    def refuse_unknown_options(self, args: list[str], also_valid: Iterable[str] = ()) -> None:
        """Name an unknown option first, before any other problem (a missing argument) hides it."""
        valid = {*self.option_names(), *also_valid}
        unknown = [a for a in args if a.startswith("--") and a != "--" and a.split("=", 1)[0] not in valid]
        if unknown:
            self.error(unknown_message(unknown, valid, self.renamed))


def beam_parser(error_class=UsageError) -> argparse.ArgumentParser:
    """An argument parser holding every option Beam's loaded option classes define (import a
    runner's module first for its own options: ``check_beam_args`` does)."""
    from apache_beam.options.pipeline_options import PipelineOptions, _BeamArgumentParser

    class Parser(_BeamArgumentParser):
        def error(self, message: str) -> NoReturn:
            raise error_class(message)

    parser = Parser(allow_abbrev=False, add_help=False)
    classes: dict[str, type[PipelineOptions]] = {}
    for kind in PipelineOptions.__subclasses__():
        classes.setdefault(str(kind), kind)
    for kind in classes.values():
        kind._add_argparse_args(parser)  # noqa: SLF001 - how Beam itself collects its options
    return parser


def check_beam_args(beam_args: list[str], own_options: Iterable[str]) -> None:
    """UsageError (one line) unless ``beam_args`` name a known runner and only options Beam or that
    runner define, with valid values (a worker count of at least 0: 0 means one per core)."""
    from apache_beam.options.pipeline_options import DirectOptions, PipelineOptions, StandardOptions
    from apache_beam.runners.runner import create_runner

    runner = PipelineOptions(beam_args).view_as(StandardOptions).runner or "DirectRunner"
    try:
        create_runner(runner)  # imports the runner's module, which defines its options
    except (ValueError, ImportError) as error:
        known = (
            "DirectRunner",
            "DaskRunner",
            "DataflowRunner",
            "FlinkRunner",
            "SparkRunner",
            "PortableRunner",
        )
        near = closest(runner.rsplit(".", 1)[-1], known, cutoff=0.8)
        hint = f"; did you mean {near}?" if near else f"; known runners include {', '.join(known)}"
        raise UsageError(f"--runner {runner}: not a Beam runner ({type(error).__name__}){hint}") from None
    parser = beam_parser()
    _, unknown = parser.parse_known_args(beam_args)
    if unknown:
        raise UsageError(unknown_message(unknown, [*own_options, *_option_strings(parser)]))
    workers = PipelineOptions(beam_args).view_as(DirectOptions).direct_num_workers
    if workers is not None and workers < 0:
        raise UsageError(f"--direct_num_workers {workers}: must be at least 0 (0: one worker per core)")


def _option_strings(parser: argparse.ArgumentParser) -> list[str]:
    return [name for action in parser._actions for name in action.option_strings]  # noqa: SLF001
