"""The documentation cannot drift from the code: docs/configuration.md is the settings' own table, every
link between the pages resolves, and every command line the README, each topic page and the Makefile
show is accepted by the command it names (options in their current spelling, the audited run as the
positional OUT): its options by that command's parser, its ``--set`` and ``--grid`` keys by the
settings, its ``make`` targets by the Makefile."""

from __future__ import annotations

import importlib
import os
import re
import shlex
from unittest import mock

import pytest

from pipeline import sources
from pipeline.commandline import StrictParser, UsageError, beam_parser
from pipeline.demo import commands as demo_commands
from pipeline.runner.splits import SAMPLE_RELEASE
from pipeline.settings import doc as settings_doc
from pipeline.settings import sections as registry
from pipeline.settings.fields import setting_keys, with_overrides
from pipeline.settings.run_config import RunConfig
from tests.support.cli import REPO

DOCS = os.path.join(REPO, "docs")
README = os.path.join(REPO, "README.md")
PAGES = sorted(
    [README]
    + [os.path.join(root, name) for root, _, names in os.walk(DOCS) for name in names if name.endswith(".md")]
)
# The function each ``python -m`` module runs (``benchmarks/__main__.py`` runs it when imported).
MAINS = {
    "pipeline.audit": "pipeline.audit.__main__",
    "pipeline.viz": "pipeline.viz.__main__",
    "benchmarks": "benchmarks.cli",
}
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.M | re.S)
SHELL = ("bash", "sh", "shell", "console")


def read(path: str) -> str:
    with open(path, encoding="utf-8") as handle:
        return handle.read()


def relative(path: str) -> str:
    return os.path.relpath(path, REPO)


# ----------------------------------------------------------------------------- configuration.md


def test_configuration_md_is_the_settings_table():
    assert settings_doc.markdown() == read(os.path.join(DOCS, "configuration.md")), (
        f"docs/configuration.md is out of date with the settings' dataclasses: run `{settings_doc.COMMAND}`"
    )


def test_a_built_in_source_without_settings_has_no_section():
    """A source's settings section is optional (``settings_of`` gives None): the page leaves it out."""
    settings_of = registry.settings_of
    without_adt = mock.patch.object(
        registry, "settings_of", side_effect=lambda name: None if name == "adt" else settings_of(name)
    )
    with without_adt:
        page = settings_doc.markdown()
    assert "## `adt`" not in page and "| `adt." not in page
    assert "## `pstudio`" in page and "## `drivetrack`" in page


def test_every_setting_is_documented_once():
    text = read(os.path.join(DOCS, "configuration.md"))
    documented = re.findall(r"^\| `([\w.]+)` \|", text, re.M)
    built_in = RunConfig(source_sections={name: sources.settings_of(name)() for name in sources.BUILT_IN})
    assert documented == setting_keys(built_in)


# ----------------------------------------------------------------------------------------- links


def without_code(text: str) -> str:
    """The text with fenced code blocks and inline code spans blanked out."""
    text = FENCE.sub(lambda m: "\n" * m[0].count("\n"), text)
    return re.sub(r"`[^`]*`", "``", text)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    text = heading.strip().lower().replace("`", "")
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: str) -> set[str]:
    return {slug(m[1]) for m in re.finditer(r"^#+ (.+)$", without_code(read(path)), re.M)}


def links(path: str) -> list[str]:
    """The targets of the page's Markdown links and images, outside code."""
    return re.findall(r"!?\[[^\]]*\]\(([^)\s]+)\)", without_code(read(path)))


@pytest.mark.parametrize("page", PAGES, ids=relative)
def test_every_internal_link_resolves(page):
    broken = []
    for target in links(page):
        if re.match(r"[a-z]+:", target):
            continue  # http(s):, mailto:
        path, _, anchor = target.partition("#")
        resolved = os.path.normpath(os.path.join(os.path.dirname(page), path)) if path else page
        if not os.path.exists(resolved):
            broken.append(f"{target}: no file {relative(resolved)}")
        elif anchor and (not resolved.endswith(".md") or anchor not in anchors(resolved)):
            broken.append(f"{target}: no heading #{anchor} in {relative(resolved)}")
    assert not broken, f"{relative(page)}: " + "; ".join(broken)


def test_the_pages_are_found_and_linked():
    assert {relative(p) for p in PAGES} >= {"README.md", "docs/configuration.md", "docs/sources/adt.md"}
    assert not os.path.exists(os.path.join(DOCS, "performance-history.md"))
    assert len(read(README).splitlines()) < 200, "README.md is the newcomer's page: keep it under 200 lines"


# --------------------------------------------------------------------------------- command lines


class _Parsed(BaseException):
    """Raised by the patched ``StrictParser.parse_args``: the parser a command built, and its args."""

    def __init__(self, parser: StrictParser, args):
        super().__init__()
        self.parser, self.args = parser, list(args)


def command_parser(module: str, argv: list[str]) -> tuple[StrictParser, list[str]]:
    """The parser ``python -m <module> <argv>`` parses its arguments with, and the arguments it gives
    it (a subcommand's own), found by running the command's ``main`` up to its parse."""

    def capture(self, args=None, namespace=None):
        raise _Parsed(self, args)

    main = importlib.import_module(MAINS.get(module, module)).main
    with mock.patch.object(StrictParser, "parse_args", capture):
        try:
            main(list(argv))
        except _Parsed as parsed:
            return parsed.parser, parsed.args
    raise AssertionError(f"python -m {module} {shlex.join(argv)}: reached no StrictParser")


def setting_assignments(argv: list[str], option: str) -> list[str]:
    """The values given to ``option`` (``--set KEY=VALUE`` or ``--set=KEY=VALUE``)."""
    found = [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg == option]
    return found + [arg.split("=", 1)[1] for arg in argv if arg.startswith(f"{option}=")]


def check_settings(argv: list[str]) -> None:
    """Every ``--set`` assignment applies (known key, value in range); every ``--grid`` key is known."""
    with_overrides(RunConfig(), setting_assignments(argv, "--set"))
    keys = setting_keys(RunConfig())
    for grid in setting_assignments(argv, "--grid"):
        assert grid.split("=", 1)[0] in keys, f"--grid {grid}: unknown setting"


def check_command(module: str, argv: list[str]) -> None:
    """``python -m <module> <argv>`` parses as the command parses it, before any work."""
    if module == "pipeline.run":
        from pipeline.runner import command as run

        try:
            run.parse_args(argv)
        except UsageError as problem:
            raise AssertionError(f"python -m pipeline.run: {problem}") from None
    else:
        parser, args = command_parser(module, argv)
        try:
            parser.parse_args(args)
        except SystemExit:
            raise AssertionError(f"python -m {module} {shlex.join(argv)}: refused (stderr above)") from None
    check_settings(argv)


def run_options() -> set[str]:
    """Every option ``python -m pipeline.run`` accepts: its own and Beam's (the Dask runner's too)."""
    from apache_beam.runners.dask import dask_runner  # noqa: F401 - defines the Dask options

    from pipeline.runner.command import command_parser as run_parser

    beam = {name for action in beam_parser()._actions for name in action.option_strings}  # noqa: SLF001
    return set(run_parser().option_names()) | beam


def shell_commands(text: str) -> list[list[str]]:
    """Each command line of the text's shell code blocks, as words (continuations joined, comments
    dropped)."""
    commands = []
    for match in FENCE.finditer(text):
        if match[1] not in SHELL:
            continue
        for line in match[2].replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words:
                commands.append(words)
    return commands


def python_module(words: list[str]) -> tuple[str, list[str]] | None:
    """(module, arguments) of ``python -m <module> ...``, None for any other command."""
    if len(words) >= 3 and os.path.basename(words[0]).startswith("python") and words[1] == "-m":
        return words[2], words[3:]
    return None


def makefile_targets() -> set[str]:
    return set(re.findall(r"^([A-Za-z][\w-]*):", read(os.path.join(REPO, "Makefile")), re.M))


README_COMMANDS = shell_commands(read(README))
# Every shell command of every page: the README's, then the topic pages'.
PAGE_COMMANDS = [(relative(page), words) for page in PAGES for words in shell_commands(read(page))]


def test_the_readme_shows_the_commands_a_newcomer_needs():
    modules = [found[0] for words in README_COMMANDS if (found := python_module(words))]
    for module in ("pipeline.run", "pipeline.audit", "pipeline.validate", "pipeline.viz"):
        assert module in modules, f"README.md shows no python -m {module} command"
    assert ["make", "demo"] in README_COMMANDS and ["make", "test"] in README_COMMANDS


@pytest.mark.parametrize(
    ("page", "words"),
    PAGE_COMMANDS,
    ids=[f"{page}: {shlex.join(words)[:90]}" for page, words in PAGE_COMMANDS],
)
def test_each_shown_command_is_accepted(page, words):
    if words[0] == "make":
        targets = [word for word in words[1:] if "=" not in word and not word.startswith("-")]
        assert set(targets) <= makefile_targets(), f"{shlex.join(words)}: no such Makefile target"
        return
    found = python_module(words)
    if found is not None:
        check_command(*found)


def inline_commands(text: str) -> list[tuple[str, str, list[str]]]:
    """(span, module, arguments) of each inline code span of the prose that starts ``python -m``."""
    found = []
    for span in re.findall(r"`(python -m [^`]+)`", FENCE.sub("", text)):
        words = span.replace("[", " ").replace("]", " ").split()
        found.append((" ".join(words), words[2], words[3:]))
    return found


@pytest.mark.parametrize("page", PAGES, ids=relative)
def test_every_option_a_page_names_inline_exists(page):
    """Inline spans of the package's commands may be fragments (``python -m pipeline.validate DIR``):
    each option they name must exist on the command they name (an old spelling, ``audit sweep
    --output``, does not), and each setting they assign must be known (``KEY`` stands for any)."""
    unknown = []
    for span, module, words in inline_commands(read(page)):
        if module.split(".")[0] != "pipeline" and module != "benchmarks":
            continue  # another tool (python -m build), or a benchmark script run as it is
        options = {word.split("=", 1)[0] for word in words if word.startswith("--")}
        if module == "pipeline.run":
            valid = run_options()
        else:
            valid = set(command_parser(module, words)[0].option_names())
        unknown += [f"{option} (in `{span}`)" for option in sorted(options - valid)]
        keys = setting_keys(RunConfig())
        assigned = setting_assignments(words, "--set") + setting_assignments(words, "--grid")
        named = [
            key.split("=")[0] for key in assigned if not key.split("=")[0].isupper()
        ]  # KEY: a placeholder
        unknown += [f"{key} (in `{span}`)" for key in named if key not in keys]
    for target in re.findall(r"`make (?:[A-Z]+=\S+ )*([a-z][\w-]*)", read(page)):
        if target not in makefile_targets():
            unknown.append(f"make {target}")
    assert not unknown, f"{relative(page)} names what no command accepts: " + ", ".join(unknown)


def makefile_commands() -> list[tuple[str, list[str]]]:
    """(module, arguments) of each of the package's commands (``$(PY) -m pipeline...`` or
    ``benchmarks``) the Makefile's recipes run, its variables given the values they take
    (continuations joined, the shell's ``;`` ending a command)."""
    text = read(os.path.join(REPO, "Makefile")).replace("\\\n", " ")
    values = dict(re.findall(r"^([A-Z_]+) *[?:]?= *(.*)$", text, re.M))
    recipes = "\n".join(line for line in text.splitlines() if line.startswith("\t"))
    commands = []
    for line in re.findall(r"\$\(PY\) -m ((?:pipeline|benchmarks)[^;\n]*)", recipes):
        words = shlex.split(re.sub(r"\$\(([A-Z_]+)\)", lambda m: values.get(m[1], "x"), line))
        commands.append((words[0], words[1:]))
    return commands


MAKEFILE_COMMANDS = makefile_commands()


@pytest.mark.parametrize(
    ("module", "words"), MAKEFILE_COMMANDS, ids=[f"{m} {shlex.join(w)[:80]}" for m, w in MAKEFILE_COMMANDS]
)
def test_each_command_the_makefile_runs_is_accepted(module, words):
    check_command(module, words)


def test_the_makefile_commands_are_found():
    demo = ("pipeline.demo", ["--output", "out/demo", "--release", "pipeline/runner/sample_splits.json"])
    assert demo in MAKEFILE_COMMANDS


DEMO_COMMANDS = [(command[0], command[1:]) for command in demo_commands("out/demo", SAMPLE_RELEASE)]


@pytest.mark.parametrize(
    ("module", "words"), DEMO_COMMANDS, ids=[f"{m} {shlex.join(w)[:80]}" for m, w in DEMO_COMMANDS]
)
def test_each_command_the_demo_runs_is_accepted(module, words):
    check_command(module, words)
