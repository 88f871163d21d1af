"""``python -m benchmarks.hostile_files [FOLDER] [--source NAME]``: every hostile file and fault case
run as a user would (one command each, in a fresh process), as a markdown table.

The cases run on one source's embedded sample world, found through the registry: ``--source``, by
default the registry's last source that has one (``Source.has_sample``). The hostile clips are made
from the first two clips of a good run of that sample; the bad settings are the source's first
sweepable threshold and a run-wide setting, each out of its range.

Per case: what happened (the command's last stderr line), exit code, the command's peak RSS
(``wait4``: it starts from the harness's anonymous memory, printed under the table), files
touched outside its output folder (every file under FOLDER other than the case's output is
fingerprinted before and after: path, size, mtime), and marker files created (a pickle payload
creates its marker when unpickled). The tests assert the same behaviours; this prints the figures,
and each case's progress on stderr.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from benchmarks.hostile_inputs import bomb_clip, savez_bytes, shape_bomb_clip, with_payload
from pipeline import sources
from pipeline.commandline import StrictParser
from pipeline.export.layout import clip_folder

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

PYTHON = [sys.executable, "-m"]


def snapshot(root: str, skip: str) -> dict[str, tuple[int, int]]:
    """path -> (size, mtime_ns) of every file under ``root`` outside ``skip``."""
    files = {}
    for folder, dirs, names in os.walk(root):
        dirs[:] = [d for d in dirs if os.path.join(folder, d) != skip]
        for name in names:
            path = os.path.join(folder, name)
            stat = os.stat(path)
            files[path] = (stat.st_size, stat.st_mtime_ns)
    return files


# A line of a run's account once a unit is done (``pipeline.runner.monitor``): ``[1/4] unit <name>: ...``.
UNIT_LINE = re.compile(r"^(?:\[\d+/\d+\] )?unit \S", re.M)
# A run-wide setting out of its range (``RunConfig.min_tracks``: [1, 100000]).
RUN_WIDE_BAD = "min_tracks=0"


def running(pid: int) -> bool:
    """Whether child ``pid`` has not exited yet (it is left unreaped, for ``wait4``)."""
    return os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is None


def run_case(root: str, out: str, command: list[str], interrupt: bool = False, small_disk: bool = False):
    """(exit code, peak RSS in MiB, last stderr line (else stdout's), files touched outside ``out``).
    interrupt: Ctrl-C (SIGINT) once the run reports its first unit."""
    before = snapshot(root, out)

    def limits():
        if small_disk:
            resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, 1 << 20))

    with tempfile.TemporaryFile("w+") as err, tempfile.TemporaryFile("w+") as out_lines:
        process = subprocess.Popen(command, cwd=REPO, stdout=out_lines, stderr=err, preexec_fn=limits)
        if interrupt:
            while running(process.pid):
                out_lines.seek(0)
                if UNIT_LINE.search(out_lines.read()):
                    os.kill(process.pid, signal.SIGINT)  # not Popen's: it would reap the child before wait4
                    break
                time.sleep(0.2)
        _, status, usage = os.wait4(process.pid, 0)
        process.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        out_lines.seek(0)
        lines = [line for line in err.read().splitlines() if line.strip()]
        lines = lines or [line for line in out_lines.read().splitlines() if line.strip()]
    after = snapshot(root, out)
    touched = sum(before.get(path) != value for path, value in after.items()) + len(before.keys() - after)
    return process.returncode, usage.ru_maxrss / 1024, (lines[-1] if lines else ""), touched


def plain_load(path: str) -> dict[str, np.ndarray]:
    """A clip's members, read without pickle (``np.load``'s default refuses object arrays)."""
    with np.load(path) as archive:
        return {key: archive[key] for key in archive.files}


def anonymous_mib() -> float | None:
    """This process's anonymous resident memory now (RssAnon), or None off Linux."""
    try:
        with open("/proc/self/status") as handle:
            return next(int(line.split()[1]) / 1024 for line in handle if line.startswith("RssAnon:"))
    except (OSError, StopIteration):
        return None


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True)
class Inputs:
    """What the cases read: the source, its sample input, a good run's output and the first two of
    its clips (file name -> members), the folder where a payload leaves its marker when unpickled,
    and the pipeline's run command."""

    root: str
    source: str
    sample: str
    good: str
    clips: dict[str, dict[str, np.ndarray]]
    markers: str
    run: list[str]

    @property
    def first(self) -> str:
        return list(self.clips)[0]

    @property
    def second(self) -> str:
        return list(self.clips)[1]

    def folder(self, name: str, files: dict[str, bytes]) -> str:
        """A folder of clips ``<root>/files/<name>/<source>/<file>``."""
        path = os.path.join(self.root, "files", name)
        os.makedirs(clip_folder(path, self.source), exist_ok=True)
        for file, data in files.items():
            with open(os.path.join(clip_folder(path, self.source), file), "wb") as handle:
                handle.write(data)
        return path

    def payload(self, key: str, clip: str, arrays: dict[str, np.ndarray] | None = None) -> bytes:
        """Clip ``clip`` (its members ``arrays``, else the good run's) whose member ``key`` unpickles
        into a marker-writing payload."""
        arrays = self.clips[clip] if arrays is None else arrays
        return savez_bytes(with_payload(arrays, key, os.path.join(self.markers, f"{key}-{clip}")))

    def out(self, name: str) -> str:
        path = os.path.join(self.root, "outs", name)
        shutil.rmtree(path, ignore_errors=True)
        return path


def run_or_stop(command: list[str]) -> None:
    """Run a setup command; stop with its last stderr lines when it fails."""
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
    if done.returncode:
        tail = "\n".join(done.stderr.strip().splitlines()[-5:])
        raise SystemExit(f"{' '.join(command[2:])}: exit status {done.returncode}\n{tail}")


def with_sample() -> list[str]:
    """The registry's sources that have an embedded sample world, in its order."""
    return [name for name in sources.names() if sources.get(name).has_sample]


def prepare(root: str, source: str) -> Inputs:
    """The source's sample input (written once under ``root``) and a good run of it (resumed when
    made before)."""
    say(f"writing {source}'s sample input under {root}/inputs")
    sample = sources.get(source).sample_input(os.path.join(root, "inputs", source))
    good = os.path.join(root, "good")
    run = [*PYTHON, "pipeline.run", "--source", source, "--input", sample]
    say("a good run of the sample")
    run_or_stop([*run, "--output", good])
    folder = clip_folder(good, source)
    names = sorted(name for name in os.listdir(folder) if name.endswith(".npz"))[:2]
    if len(names) < 2:
        raise SystemExit(f"{source}'s sample run made {len(names)} clip(s) in {folder}; the cases need two")
    clips = {name: plain_load(os.path.join(folder, name)) for name in names}
    markers = os.path.join(root, "markers")
    os.makedirs(markers, exist_ok=True)
    return Inputs(root, source, sample, good, clips, markers, run)


def hostile_folders(inputs: Inputs) -> dict[str, str]:
    """Folders of hostile clips (pickled members, deflate and shape bombs) and a malformed splits file."""
    first, second = inputs.first, inputs.second
    with open(os.path.join(clip_folder(inputs.good, inputs.source), second), "rb") as handle:
        good_copy = handle.read()
    clips = inputs.clips
    splits = os.path.join(inputs.root, "files", "splits.json")
    os.makedirs(os.path.dirname(splits), exist_ok=True)
    with open(splits, "w") as handle:
        handle.write(json.dumps({"minival": {inputs.source: first}}))  # a name where a list belongs
    return {
        "pickled": inputs.folder(
            "pickled", {first: inputs.payload("images_jpeg_bytes", first), second: good_copy}
        ),
        "pickled_tracks": inputs.folder(
            "pickled_tracks", {first: inputs.payload("tracks_XYZ", first), second: good_copy}
        ),
        "pickled_queries": inputs.folder("pickled_queries", {first: inputs.payload("queries_xyt", first)}),
        "bombs": inputs.folder(
            "bombs",
            {
                first: bomb_clip(clips[first], "queries_xyt", gib=20),
                second: shape_bomb_clip(clips[second], "tracks_XYZ", (40, 10**9, 3)),
            },
        ),
        "splits": splits,
    }


def victim(inputs: Inputs, clips: str) -> str:
    """A file of the sample input as a clip name relative to the clip folder ``clips``: the first
    ``.npz`` under the input, without the suffix the pipeline adds to a clip name; else its first file."""
    files = sorted(
        os.path.relpath(os.path.join(folder, name), inputs.sample)
        for folder, _, names in os.walk(inputs.sample)
        for name in names
    )
    npz = [name for name in files if name.endswith(".npz")]
    target = os.path.join(inputs.sample, npz[0].removesuffix(".npz") if npz else files[0])
    return os.path.relpath(target, clips)


def forge_output(inputs: Inputs) -> None:
    """A finished run's output in which one unit's clip is a pickle payload its checkpoint vouches
    for (SHA-256 and size, as ``pipeline.runner.ledger`` checks them: resuming the unit trusts it),
    and another unit's checkpoint lists a clip named ``../`` to a file of the sample input; and an
    output whose manifests folder is a file."""
    forged = inputs.out("forged")
    run_or_stop([*inputs.run, "--output", forged])
    units = os.path.join(forged, "units", inputs.source)
    paths = sorted(os.path.join(units, name) for name in os.listdir(units) if name.endswith(".json"))
    records = {}
    for path in paths:
        with open(path) as handle:
            records[path] = json.load(handle)
    vouching = next(path for path in paths if any(r["written_tracks"] > 0 for r in records[path]["reports"]))
    record = records[vouching]
    report = next(r for r in record["reports"] if r["written_tracks"] > 0)
    clip_file = os.path.join(clip_folder(forged, inputs.source), f"{report['clip']}.npz")
    data = inputs.payload("tracks_XYZ", os.path.basename(clip_file), plain_load(clip_file))
    with open(clip_file, "wb") as handle:
        handle.write(data)
    record["clips"][report["clip"]] = hashlib.sha256(data).hexdigest()  # the record vouches for the payload
    record["sizes"][report["clip"]] = len(data)
    # the '../' name in another unit's record (a record naming one is refused whole), else in the same
    listing = records[next((path for path in paths if path != vouching), vouching)]
    listing["reports"].append(dict(report, clip=victim(inputs, clip_folder(forged, inputs.source))))
    for path, value in records.items():
        with open(path, "w") as handle:
            json.dump(value, handle)
    manifests_file = inputs.out("manifests_file")
    os.makedirs(manifests_file)
    with open(os.path.join(manifests_file, "manifests"), "w") as handle:
        handle.write("a file")


def cases(inputs: Inputs, folders: dict[str, str]) -> list[tuple]:
    """(case, output folder name, command given that folder, options): the folder is the one place
    the command may write."""
    run, pickled, bombs = inputs.run[2:], folders["pickled"], folders["bombs"]
    sweepable = sources.get(inputs.source).sweepable
    threshold = f"{sweepable[0]}=2" if sweepable else "flicker.max_fraction=2"  # a threshold in [0, 1]
    return [
        (
            "validate: pickled frames member + a good clip",
            "validate1",
            lambda o: ["pipeline.validate", pickled],
        ),
        ("validate: 20 GiB deflate bomb + shape bomb", "validate2", lambda o: ["pipeline.validate", bombs]),
        (
            "compare: prediction with pickled tracks",
            "compare1",
            lambda o: [
                "pipeline.audit",
                "compare",
                inputs.good,
                folders["pickled_tracks"],
                "--out",
                f"{o}/report",
            ],
        ),
        (
            "compare: reference with pickled frames",
            "compare2",
            lambda o: ["pipeline.audit", "compare", pickled, inputs.good, "--out", f"{o}/report"],
        ),
        (
            "viz: pickled frames member",
            "viz",
            lambda o: [
                "pipeline.viz",
                os.path.join(clip_folder(pickled, inputs.source), inputs.first),
                "--out",
                f"{o}/v.png",
            ],
        ),
        (
            "viz stats: folder with a pickled clip",
            "stats",
            lambda o: ["pipeline.viz", "stats", pickled, "--out", f"{o}/s.png"],
        ),
        (
            "run --queries-from: pickled queries",
            "qf_pickle",
            lambda o: [*run, "--output", o, "--queries-from", folders["pickled_queries"]],
        ),
        (
            "run --queries-from: 20 GiB deflate bomb (21 MB file)",
            "qf_bomb",
            lambda o: [*run, "--output", o, "--queries-from", bombs],
        ),
        (
            "resume: forged records (pickled clip vouched for, '../' clip name)",
            "forged",
            lambda o: [*run, "--output", o],
        ),
        (f"run --set {threshold}", "threshold", lambda o: [*run, "--output", o, "--set", threshold]),
        (f"run --set {RUN_WIDE_BAD}", "run_wide", lambda o: [*run, "--output", o, "--set", RUN_WIDE_BAD]),
        (
            "run: malformed splits_file",
            "splits",
            lambda o: [*run, "--output", o, "--set", f"splits_file={folders['splits']}"],
        ),
        (
            "run: full disk (1 MiB file-size limit)",
            "full_disk",
            lambda o: [*run, "--output", o],
            {"small_disk": True},
        ),
        ("run: gs:// output without the gcp extra", "gs", lambda o: [*run, "--output", "gs://bucket/out"]),
        (
            "run: manifests folder is a file (output error at the end)",
            "manifests_file",
            lambda o: [*run, "--output", o],
        ),
        ("run: Ctrl-C after the first unit", "ctrl_c", lambda o: [*run, "--output", o], {"interrupt": True}),
    ]


def table(inputs: Inputs, listed: list[tuple]) -> list[str]:
    """Run each case in a fresh process; one markdown row each."""
    rows = [
        "| case | what happened (last stderr line) | exit | peak RSS | files touched outside --output "
        "| markers |",
        "|---|---|---|---|---|---|",
    ]
    for number, (name, output, command, *options) in enumerate(listed, 1):
        target = os.path.join(inputs.root, "outs", output)
        if output not in ("forged", "manifests_file"):
            shutil.rmtree(target, ignore_errors=True)
        say(f"[{number}/{len(listed)}] {name}")
        started = time.monotonic()
        code, rss, line, touched = run_case(
            inputs.root, target, [*PYTHON, *command(target)], **(options[0] if options else {})
        )
        created = len(os.listdir(inputs.markers))
        say(f"[{number}/{len(listed)}] exit {code} in {time.monotonic() - started:.0f} s")
        line = line.split(" ", 1)[1] if line[:2].isdigit() and line[2:3] == ":" else line
        rows.append(
            f"| {name} | {line[:160].replace('|', '/')} | {code} | {rss:.0f} MiB | {touched} | {created} |"
        )
    return rows


def parse(argv: list[str]):
    parser = StrictParser(
        prog="python -m benchmarks.hostile_files",
        description="Every hostile file and fault case run as a user would, one command each in a fresh "
        "process, on a source's embedded sample world; prints a markdown table.",
    )
    parser.add_argument(
        "folder",
        nargs="?",
        metavar="FOLDER",
        help="where the sample input, the hostile files and each case's output go (reused when given "
        "again); default: a new temporary folder",
    )
    parser.add_argument(
        "--source",
        choices=sources.names(),
        help="the source whose sample world the cases run on; default: the registry's last source "
        "with an embedded sample world (Source.has_sample)",
    )
    args = parser.parse_args(argv)
    if args.source is None:
        having = with_sample()
        if not having:
            parser.error("no source has an embedded sample world to run the cases on")
        args.source = having[-1]
    elif not sources.get(args.source).has_sample:
        parser.error(
            f"--source {args.source}: has no embedded sample world to run the cases on; sources with one: "
            + (", ".join(with_sample()) or "none")
        )
    return args


def main(argv: list[str]) -> int:
    args = parse(argv)
    root = os.path.abspath(args.folder or tempfile.mkdtemp(prefix="hostile-"))
    inputs = prepare(root, args.source)
    folders = hostile_folders(inputs)
    say("a forged output to resume")
    forge_output(inputs)
    floor = anonymous_mib()  # a forked child starts with its parent's anonymous pages
    rows = table(inputs, cases(inputs, folders))
    if floor is not None:
        rows.append(f"\npeak RSS: each command's ru_maxrss, from about {floor:.0f} MiB (this harness's own)")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
