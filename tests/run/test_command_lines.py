"""A researcher's first hour, command by command: typos and bad values refused in one line before any
work, progress from the first second, a closed pipe that stops the run, quiet workers, a run that
writes nothing saying why, and resume surviving settings that only change the manifests."""

from __future__ import annotations

import fcntl
import json
import os
import pty
import re
import shutil
import struct
import subprocess
import sys
import termios
import time

import psutil
import pytest

from pipeline.runner.splits import parse_release
from tests.support.cli import REPO, clip_bytes, command_in_process, run_in_process

PYTHON = [sys.executable, "-m"]
RESUMED = "finished by an earlier run with these settings; skipped"


def run_command(source: str, input_root: str, output, *extra: str) -> list[str]:
    """The command line of ``python -m pipeline.run`` on ``source``."""
    return [
        *PYTHON,
        "pipeline.run",
        "--source",
        source,
        "--input",
        input_root,
        "--output",
        str(output),
        *extra,
    ]


def command(*args: str, cwd: str = REPO, **kwargs) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=REPO)
    return subprocess.run(
        [*PYTHON, *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=env, **kwargs
    )


# ------------------------------------------------------------------------------------- refusals


def test_a_typo_is_refused_with_the_nearest_option_before_any_work(tmp_path):
    result = command("pipeline.run", "--source", "drivetrack", "--ouput", "out/x", cwd=str(tmp_path))
    assert result.returncode == 2
    assert result.stderr.splitlines() == [
        "python -m pipeline.run: unknown option --ouput (did you mean --output?) (--help lists the options)"
    ]
    assert os.listdir(tmp_path) == []  # no ./tapvid3d_out, no sample world


@pytest.mark.parametrize(
    "option, message",
    [
        ("--runner=NoSuchRunner", "--runner NoSuchRunner: not a Beam runner"),
        ("--runner=DirectRuner", "did you mean DirectRunner?"),
        ("--direct_num_workers=-2", "--direct_num_workers -2: must be at least 0"),
        ("--direct_num_workers=two", "argument --direct_num_workers: invalid int value: 'two'"),
        ("--direct_running_mode=multi_procesing", "invalid choice: 'multi_procesing'"),
    ],
)
def test_bad_beam_options_are_one_line_before_the_sample_world(tmp_path, option, message):
    out = tmp_path / "out"
    result = command_in_process("pipeline.run", "--source", "drivetrack", "--output", str(out), option)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith("python -m pipeline.run: ")
    assert message in line
    assert not out.exists()


def test_every_bad_setting_is_reported_in_one_list(tmp_path):
    settings = ["flicker.max_fraction=abc", "drivetrack.tracks_per_clip=-5", "flicker.max_fracton=1"]
    args = [arg for setting in settings for arg in ("--set", setting)]
    result = run_in_process("drivetrack", "--output", str(tmp_path / "out"), *args)
    assert result.returncode == 2
    lines = result.stderr.splitlines()
    assert lines[0] == "cannot start: 3 problem(s) with the settings:"
    assert lines[1] == "  --set flicker.max_fraction=abc: expected float; must be a number in [0, 1]"
    assert lines[2] == (
        "  --set flicker.max_fracton: unknown setting; did you mean flicker.max_fraction? "
        "every key: docs/configuration.md"
    )
    assert lines[3] == "  --set drivetrack.tracks_per_clip=-5: must be an integer in [1, 100000]"
    assert not (tmp_path / "out").exists()


def test_a_source_without_a_sample_is_refused_before_any_work_saying_how_to_get_it(tmp_path):
    result = run_in_process("adt", "--output", str(tmp_path / "out"))
    assert result.returncode == 2
    assert result.stderr.startswith("adt: there is no embedded ADT sample")
    assert "embedded sample world" not in result.stdout  # never announced first, then refused
    assert not (tmp_path / "out").exists()


def test_an_unknown_scheme_for_queries_from_names_what_is_read(tmp_path):
    result = run_in_process(
        "pstudio", "--output", str(tmp_path / "out"), "--queries-from", "htp://h/x?t=SECRET"
    )
    assert result.returncode == 2
    assert result.stderr.startswith(
        "cannot start: no usable filesystem for htp://h/x: Beam opens local paths"
    )
    assert result.stderr.rstrip().endswith("; http:// and https:// are read directly")
    assert "SECRET" not in result.stderr


def test_a_misspelt_source_gets_the_nearest_name(tmp_path):
    result = run_in_process("drivetrak", "--output", str(tmp_path / "out"))
    assert (result.returncode, result.stderr) == (
        2,
        "python -m pipeline.run: --source drivetrak: unknown; did you mean drivetrack?\n",
    )
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option", ["--release", "--set"])
def test_a_splits_file_naming_no_source_is_refused_at_the_door_as_given(tmp_path, option):
    """A typo in a splits file's source key is said before any work, naming the option the user
    typed; a file that is not there too."""
    splits = tmp_path / "splits.json"
    splits.write_text(json.dumps({"minival": {"pstudio": ["dome_3.npz"]}, "full_eval": {"drivetrak": []}}))
    if option == "--release":
        given, missing = ["--release", str(splits)], ["--release", "missing.json"]
        shown = "--release missing.json"
    else:
        given, missing = ["--set", f"splits_file={splits}"], ["--set", "splits_file=missing.json"]
        shown = "--set splits_file=" + os.path.abspath("missing.json")
    out = tmp_path / "out"
    result = run_in_process("pstudio", "--output", str(out), *given)
    assert result.returncode == 2
    assert result.stderr == (
        f"cannot start: {' '.join(given)}: 'full_eval' names source 'drivetrak', not a source; "
        "did you mean drivetrack?\n"
    )
    result = run_in_process("pstudio", "--output", str(out), *missing)
    assert (result.returncode, result.stderr) == (2, f"cannot start: {shown} does not exist\n")
    assert not out.exists()


def test_an_output_that_is_a_file_is_said_so(tmp_path):
    target = tmp_path / "a_file"
    target.write_text("x")
    result = run_in_process("pstudio", "--output", str(target))
    assert result.returncode == 2
    assert result.stderr.splitlines() == [f"cannot start: --output {target} is a file, not a folder"]


COMMANDS = [
    ("pipeline.run",),
    ("pipeline.validate",),
    ("pipeline.audit",),
    ("pipeline.audit", "sweep"),
    ("pipeline.audit", "release"),
    ("pipeline.audit", "compare"),
    ("pipeline.audit", "report"),
    ("pipeline.viz",),
    ("pipeline.viz", "stats"),
    ("pipeline.settings.doc",),
    ("benchmarks",),
]


@pytest.mark.parametrize("words", COMMANDS, ids=" ".join)
def test_help_goes_to_stdout_as_plain_text_with_exit_0(words):
    result = command_in_process(*words, "--help")
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip()
    assert "``" not in result.stdout  # the docstrings' reStructuredText marks are not shown
    assert not re.search(r"::$", result.stdout, re.M)
    assert result.stderr == ""


@pytest.mark.parametrize("words", [("pipeline.run",), ("benchmarks",)], ids=" ".join)
def test_help_from_a_new_interpreter_is_the_same(words, monkeypatch):
    """``python -m`` itself: the help of ``main`` in this process, exit 0, nothing on stderr (the other
    commands' new interpreters: tests/run/test_closed_output.py and test_faults.py)."""
    monkeypatch.setenv("COLUMNS", "100")  # argparse's width, for both
    shown, expected = command(*words, "--help"), command_in_process(*words, "--help")
    assert (shown.returncode, shown.stdout, shown.stderr) == (0, expected.stdout, "")


@pytest.mark.parametrize("words", COMMANDS, ids=" ".join)
def test_an_unknown_option_is_one_line_with_exit_2(words):
    result = command_in_process(*words, "--no-such-option")
    assert result.returncode == 2
    (line,) = result.stderr.splitlines()
    assert "--no-such-option" in line or "unknown" in line


def test_the_audit_names_the_nearest_command():
    result = command("pipeline.audit", "swep")
    assert (result.returncode, result.stderr.strip()) == (
        2,
        "python -m pipeline.audit: unknown command 'swep'; did you mean sweep?",
    )


def test_grid_problems_are_blamed_on_the_grid_in_one_list(reference_run, capsys):
    from pipeline.audit.__main__ import main as audit_main

    out = reference_run("pstudio")
    grid = [
        "--grid",
        "flicker.max_fracton=0.1",
        "--grid",
        "flicker.max_fraction=abc,2",
        "--grid",
        "pstudio.depth_delta_m=0.1",
    ]
    assert audit_main(["sweep", out, "--source", "pstudio", *grid]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "sweep: 4 problem(s):"
    assert lines[1].startswith(
        "  --grid flicker.max_fracton: unknown key; did you mean flicker.max_fraction?"
    )
    assert lines[2] == "  --grid flicker.max_fraction=abc: expected float; must be a number in [0, 1]"
    assert lines[3] == "  --grid flicker.max_fraction=2: must be a number in [0, 1]"
    assert lines[4].startswith("  --grid pstudio.depth_delta_m: the sweep replays the filter stage only")


def test_validate_takes_one_clip_and_says_what_is_missing(reference_run, tmp_path):
    from pipeline.validate import main as validate_main

    clip = sorted(
        os.path.join(reference_run("pstudio"), "pstudio", n)
        for n in clip_bytes(reference_run("pstudio"), "pstudio")
    )[0]
    assert validate_main([clip]) == 0
    missing = command_in_process("pipeline.validate", str(tmp_path / "absent"))
    assert (missing.returncode, missing.stderr.strip()) == (
        2,
        f"validate: {tmp_path / 'absent'} does not exist",
    )
    empty = command_in_process("pipeline.validate", str(tmp_path))
    assert empty.returncode == 2
    assert "no .npz clips in" in empty.stderr


# ------------------------------------------------------------------------------------- progress


def test_the_first_line_comes_before_the_work(tmp_path):
    """A run without --input names its rules, then the sample world it is about to write; the run
    is stopped there (the world's writing is not what this test is about)."""
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=REPO)
    process = subprocess.Popen(
        [*PYTHON, "pipeline.run", "--source", "pstudio", "--output", str(out)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    try:
        first, second = process.stdout.readline(), process.stdout.readline()
        sample_done = (out / "sample_input" / "pstudio").exists()
    finally:
        process.kill()
        process.communicate(timeout=60)
    assert first.startswith("rules: refined (ours, measured better; docs/release.md): ")
    assert second.startswith(
        f"no --input given: using the embedded sample world in {out}/sample_input/pstudio"
    )
    assert not sample_done  # said before writing it


def test_finished_in_is_the_whole_command(reference_run):
    """'finished in' counts from the command's start, its imports included (a second or two of the
    run): at least 80% of the time its parent saw from the launch to that last line (the
    interpreter's own start is all it leaves out)."""
    finished = float(re.search(r"finished in ([\d.]+) s", reference_run.result("pstudio").stdout)[1])
    assert finished >= 0.8 * reference_run.wall("pstudio")


def test_units_are_reported_on_stdout_with_counts_elapsed_time_and_what_is_left(reference_run):
    result = reference_run.result("pstudio")
    assert result.stderr == ""
    lines = [line for line in result.stdout.splitlines() if line.startswith("[")]
    assert len(lines) == 4
    pattern = (
        r"\[(\d)/4\] unit dome/camera_\d+: 1 of 1 clip\(s\) written, 50 tracks \([\d.]+ s\); elapsed \d+:\d\d"
    )
    assert [int(re.match(pattern, line)[1]) for line in lines] == [1, 2, 3, 4]
    assert all(", about " in line and line.endswith(" left") for line in lines[:3])


def test_a_terminal_gets_a_live_progress_bar(pstudio_sample, tmp_path):
    """stdout and stderr on one terminal: the bar redrawn in place, the unit lines above it."""
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # a 100-column terminal
    result = subprocess.run(
        run_command("pstudio", pstudio_sample[0], tmp_path / "o"),
        cwd=REPO,
        stdout=follower,
        stderr=follower,
        timeout=300,
    )
    os.close(follower)
    shown = b""
    while True:
        try:
            chunk = os.read(leader, 65536)
        except OSError:
            break
        if not chunk:
            break
        shown += chunk
    os.close(leader)
    assert result.returncode == 0
    text = shown.decode(errors="replace")
    assert "\r" in text
    assert "4/4" in text
    assert "unit/s" in text  # tqdm's bar, redrawn in place
    assert "\nunit dome/camera_3: 1 of 1 clip(s) written" in text.replace("\r", "\n")  # the bar counts


def test_workers_are_as_quiet_as_the_main_process(reference_run):
    """The pstudio run on 2 worker processes (tests/pstudio/test_cli.py compares its clips)."""
    _, result = reference_run.multi_processing("pstudio")
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stderr == ""
    lines = [line for line in result.stdout.splitlines() if line.startswith("[")]
    assert len(lines) == 4, result.stdout[-3000:]
    assert "apitools" not in result.stdout
    assert "INFO" not in result.stdout


@pytest.mark.parametrize(
    "mode, same_pipe",
    [
        ([], False),
        ([], True),
        (["--direct_running_mode=multi_processing", "--direct_num_workers=2"], False),
    ],
    ids=["stdout", "stdout and stderr", "multi_processing"],
)
def test_a_closed_output_pipe_stops_the_run_within_five_seconds(sample_split, tmp_path, mode, same_pipe):
    """| head: the reader goes away after the first line (of stdout alone, or of stdout and stderr in
    one pipe: 2>&1 | head); the run stops (exit 141) before its end, no traceback, no worker process
    left behind."""
    env = dict(os.environ, PYTHONPATH=REPO)
    errors = open(tmp_path / "stderr", "w")
    process = subprocess.Popen(
        run_command("drivetrack", sample_split[0], tmp_path / "o", *mode),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT if same_pipe else errors,
        env=env,
    )
    process.stdout.readline()
    children = psutil.Process(process.pid).children(recursive=True)
    process.stdout.close()
    started = time.monotonic()
    code = process.wait(timeout=60)
    assert time.monotonic() - started < 5
    errors.close()
    assert code == 141
    assert (tmp_path / "stderr").read_text() == ""
    assert not (tmp_path / "o" / "run_drivetrack.json").exists()  # stopped before the end
    time.sleep(0.2)
    assert not [child for child in children if child.is_running() and child.status() != psutil.STATUS_ZOMBIE]


# ------------------------------------------------------------------------------------- nothing done


def test_a_run_with_nothing_to_do_says_why_with_its_own_exit_status(pstudio_sample, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    out = str(tmp_path / "out")
    result = run_in_process(
        "pstudio", "--input", pstudio_sample[0], "--output", out, "--queries-from", str(empty)
    )
    assert result.returncode == 3
    assert result.stdout.splitlines()[-1] == (
        f"no clip written: the 4 unit(s) made no clip; --queries-from {empty} holds none of their clips"
    )
    again = run_in_process(
        "pstudio", "--input", pstudio_sample[0], "--output", out, "--queries-from", str(empty)
    )
    assert again.returncode == 0  # every unit finished by the earlier run: nothing left to do
    assert again.stdout.splitlines()[-1].endswith(
        "(4 of them finished by an earlier run with these settings)"
    )


# ------------------------------------------------------------------------------------- resume


@pytest.fixture
def finished(reference_run, tmp_path):
    """A private copy of a finished plain DriveTrack run, and its input."""
    reference = reference_run("drivetrack")
    out = str(tmp_path / "out")
    shutil.copytree(reference, out, ignore=shutil.ignore_patterns("sample_input"))
    return json.load(open(os.path.join(reference, "run_drivetrack.json")))["input"], out


def test_manifest_settings_resume_every_unit_and_rewrite_the_manifests(finished, tmp_path):
    source_input, out = finished
    before = clip_bytes(out, "drivetrack")
    result = run_in_process(
        "drivetrack", "--input", source_input, "--output", out, "--set", "minival_per_source=2"
    )
    assert result.returncode == 0
    assert result.stdout.count(RESUMED) == 3
    assert len(open(os.path.join(out, "manifests", "minival.txt")).read().splitlines()) == 2
    names = sorted(before)
    splits = tmp_path / "splits.json"
    splits.write_text(
        json.dumps({"minival": {"drivetrack": names[:1]}, "full_eval": {"drivetrack": names[1:]}})
    )
    result = run_in_process(
        "drivetrack", "--input", source_input, "--output", out, "--set", f"splits_file={splits}"
    )
    assert result.returncode == 0
    assert result.stdout.count(RESUMED) == 3
    assert open(os.path.join(out, "manifests", "minival.txt")).read() == f"drivetrack/{names[0]}\n"
    assert clip_bytes(out, "drivetrack") == before
    # the release's name for full_test, said once; the manifests' counts of this source, then all
    assert result.stdout.count("full_eval") == 1
    assert f"splits: full_eval in {splits} is full_test here (manifests, verdicts, audits)" in result.stdout
    os.makedirs(os.path.join(out, "pstudio"))
    open(os.path.join(out, "pstudio", "other.npz"), "wb").close()  # another source's clip there
    result = run_in_process("drivetrack", "--input", source_input, "--output", out)
    counts = "minival 4, full_test 0 clip(s) of drivetrack (every source: minival 5, full_test 0)"
    assert f"manifests: {counts}" in result.stdout


def test_a_release_run_resumes_a_plain_runs_units(finished, tmp_path):
    """The release's membership changes no clip's bytes: its run over a plain run's output under the
    same rules (``--set rules=refined``: a release run's own are the release's) redoes no unit, and
    still says why each named clip it does not have is missing."""
    source_input, out = finished
    names = sorted(clip_bytes(out, "drivetrack"))  # crossing, lead, oncoming (camera 1), parked (camera 3)
    segment = names[0].split("_", 1)[1].rsplit("_1_", 1)[0]
    other_camera = f"tapvid3d_{segment}_1_parked_right_DDDDDDDDDDDDDDDDDD.npz"
    release = tmp_path / "release.json"
    splits = {"minival": {"drivetrack": names[:2]}, "full_eval": {"drivetrack": [names[3], other_camera]}}
    release.write_text(json.dumps(splits))
    assert other_camera not in names
    assert parse_release(release.read_text()).names("drivetrack")
    result = run_in_process(
        "drivetrack",
        "--input",
        source_input,
        "--output",
        out,
        "--release",
        str(release),
        "--set",
        "rules=refined",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.count(RESUMED) == 2  # the units of cameras 1 and 3, each named
    with open(os.path.join(out, "release_drivetrack.jsonl")) as handle:
        rows = {row["clip"]: row for row in map(json.loads, handle)}
    assert rows[other_camera[:-4]]["reason"] == (
        "object parked_right_DDDDDDDDDDDDDDDDDD belongs to camera 3 (the one that sees it most), not 1"
    )
    assert [rows[name[:-4]]["status"] for name in (*names[:2], names[3])] == ["written"] * 3
    manifests = os.path.join(out, "manifests")
    assert open(f"{manifests}/minival.txt").read().splitlines() == [f"drivetrack/{n}" for n in names[:2]]
    assert open(f"{manifests}/full_test.txt").read() == f"drivetrack/{names[3]}\n"


def test_an_annotation_setting_redoes_every_unit(finished):
    source_input, out = finished
    result = run_in_process("drivetrack", "--input", source_input, "--output", out, "--set", "seed=7")
    assert result.returncode == 0
    assert result.stdout.count(RESUMED) == 0
    assert len(re.findall(r"^\[\d/3\] unit .* clip\(s\) written", result.stdout, re.M)) == 3
