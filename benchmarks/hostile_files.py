"""``python -m benchmarks.hostile_files [FOLDER]``: every hostile file and fault case run as a user
would (one command each, in a fresh process), as a markdown table.

Per case: what happened (the command's last stderr line), exit code, the command's peak RSS
(``wait4``), files touched outside its output folder (every file under FOLDER other than the
case's output is fingerprinted before and after: path, size, mtime), and marker files created
(a pickle payload creates its marker when unpickled). The tests assert the same behaviours;
this prints the figures.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from benchmarks.hostile_inputs import bomb_clip, savez_bytes, shape_bomb_clip, with_payload
from pipeline.pstudio.sample.dynamic3dgs_files import write_sequence

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


def run_case(root: str, out: str, command: list[str], interrupt: bool = False, small_disk: bool = False):
    """(exit code, peak RSS in MiB, last stderr line (else stdout's), files touched outside ``out``)."""
    before = snapshot(root, out)

    def limits():
        if small_disk:
            resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, 1 << 20))

    with tempfile.TemporaryFile("w+") as err, tempfile.TemporaryFile("w+") as out_lines:
        process = subprocess.Popen(command, cwd=REPO, stdout=out_lines, stderr=err, preexec_fn=limits)
        if interrupt:
            while True:
                out_lines.seek(0)
                if "unit dome/camera_" in out_lines.read() or process.poll() is not None:
                    break
                time.sleep(0.2)
            process.send_signal(signal.SIGINT)
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
    with np.load(path) as archive:
        return {key: archive[key] for key in archive.files}


@dataclasses.dataclass(frozen=True)
class Inputs:
    """What the cases read: the studio sample, a good run's output and two of its clips, the folder
    where a payload leaves its marker when unpickled, and the pipeline's run command."""

    root: str
    sample: str
    good: str
    clips: dict[str, dict[str, np.ndarray]]
    markers: str
    run: list[str]

    def folder(self, name: str, files: dict[str, bytes]) -> str:
        """A folder of clips ``<root>/files/<name>/pstudio/<file>``."""
        path = os.path.join(self.root, "files", name)
        os.makedirs(os.path.join(path, "pstudio"), exist_ok=True)
        for file, data in files.items():
            with open(os.path.join(path, "pstudio", file), "wb") as handle:
                handle.write(data)
        return path

    def payload(self, key: str, clip: str = "dome_3.npz") -> bytes:
        """A good clip whose member ``key`` unpickles into a marker-writing payload."""
        return savez_bytes(with_payload(self.clips[clip], key, os.path.join(self.markers, f"{key}-{clip}")))

    def out(self, name: str) -> str:
        path = os.path.join(self.root, "outs", name)
        shutil.rmtree(path, ignore_errors=True)
        return path


def prepare(root: str) -> Inputs:
    """The studio sample and a good run of it (made once under ``root``)."""
    sample = os.path.join(root, "inputs", "pstudio")
    if not os.path.isdir(sample):
        write_sequence(sample)
    good = os.path.join(root, "good")
    run = [*PYTHON, "pipeline.run", "--source", "pstudio", "--input", sample]
    if not os.path.isdir(os.path.join(good, "pstudio")):
        subprocess.run([*run, "--output", good], cwd=REPO, check=True, capture_output=True)
    clips = {name: plain_load(os.path.join(good, "pstudio", name)) for name in ("dome_3.npz", "dome_8.npz")}
    markers = os.path.join(root, "markers")
    os.makedirs(markers, exist_ok=True)
    return Inputs(root, sample, good, clips, markers, run)


def hostile_folders(inputs: Inputs) -> dict[str, str]:
    """Folders of hostile clips (pickled members, deflate and shape bombs) and a malformed splits file."""
    good_copy = open(os.path.join(inputs.good, "pstudio", "dome_8.npz"), "rb").read()
    clips = inputs.clips
    splits = os.path.join(inputs.root, "files", "splits.json")
    os.makedirs(os.path.dirname(splits), exist_ok=True)
    with open(splits, "w") as handle:
        handle.write('{"minival": {"pstudio": "dome_3.npz"}}')
    return {
        "pickled": inputs.folder(
            "pickled", {"dome_3.npz": inputs.payload("images_jpeg_bytes"), "dome_8.npz": good_copy}
        ),
        "pickled_tracks": inputs.folder(
            "pickled_tracks", {"dome_3.npz": inputs.payload("tracks_XYZ"), "dome_8.npz": good_copy}
        ),
        "pickled_queries": inputs.folder("pickled_queries", {"dome_3.npz": inputs.payload("queries_xyt")}),
        "bombs": inputs.folder(
            "bombs",
            {
                "dome_3.npz": bomb_clip(clips["dome_3.npz"], "queries_xyt", gib=20),
                "dome_8.npz": shape_bomb_clip(clips["dome_8.npz"], "tracks_XYZ", (40, 10**9, 3)),
            },
        ),
        "splits": splits,
    }


def forge_output(inputs: Inputs) -> None:
    """A finished run's output whose clip is a pickle payload its checkpoint vouches for, and whose record
    lists a clip named ``../`` outside the folder; and an output whose manifests folder is a file."""
    forged = inputs.out("forged")
    subprocess.run([*inputs.run, "--output", forged, "--set", "pstudio.cameras=3"], cwd=REPO, check=True)
    data = inputs.payload("tracks_XYZ")
    with open(os.path.join(forged, "pstudio", "dome_3.npz"), "wb") as handle:
        handle.write(data)
    units = os.path.join(forged, "units", "pstudio")
    record_path = os.path.join(units, os.listdir(units)[0])
    record = json.load(open(record_path))
    record["clips"]["dome_3"] = hashlib.sha256(data).hexdigest()  # the record vouches for the payload
    victim = "../../../inputs/pstudio/output/pretrained/dome/params"  # the sample's params.npz
    record["reports"].append(dict(record["reports"][0], clip=victim))
    json.dump(record, open(record_path, "w"))
    manifests_file = inputs.out("manifests_file")
    os.makedirs(manifests_file)
    open(os.path.join(manifests_file, "manifests"), "w").write("a file")


def cases(inputs: Inputs, folders: dict[str, str]) -> list[tuple]:
    """(case, output folder name, command given that folder, options): the folder is the one place
    the command may write."""
    run, pickled, bombs = inputs.run[2:], folders["pickled"], folders["bombs"]
    studio = ["--set", "pstudio.cameras=3"]
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
            lambda o: ["pipeline.viz", os.path.join(pickled, "pstudio", "dome_3.npz"), "--out", f"{o}/v.png"],
        ),
        (
            "viz stats: folder with a pickled clip",
            "stats",
            lambda o: ["pipeline.viz", "stats", pickled, "--out", f"{o}/s.png"],
        ),
        (
            "run --queries-from: pickled queries",
            "qf_pickle",
            lambda o: [*run, "--output", o, "--queries-from", folders["pickled_queries"], *studio],
        ),
        (
            "run --queries-from: 20 GiB deflate bomb (21 MB file)",
            "qf_bomb",
            lambda o: [*run, "--output", o, "--queries-from", bombs, *studio],
        ),
        (
            "resume: forged record (pickled clip, '../' clip name)",
            "forged",
            lambda o: [*run, "--output", o, *studio],
        ),
        (
            "run --set adt.image_size=0",
            "image_size",
            lambda o: [*run, "--output", o, "--set", "adt.image_size=0"],
        ),
        ("run --set adt.focal=-280", "focal", lambda o: [*run, "--output", o, "--set", "adt.focal=-280"]),
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
            lambda o: [*run, "--output", o, *studio],
        ),
        ("run: Ctrl-C during the first unit", "ctrl_c", lambda o: [*run, "--output", o], {"interrupt": True}),
    ]


def table(inputs: Inputs, listed: list[tuple]) -> list[str]:
    """Run each case in a fresh process; one markdown row each."""
    rows = [
        "| case | what happened (last stderr line) | exit | peak RSS | files touched outside --output "
        "| markers |",
        "|---|---|---|---|---|---|",
    ]
    for name, output, command, *options in listed:
        target = os.path.join(inputs.root, "outs", output)
        if output not in ("forged", "manifests_file"):
            shutil.rmtree(target, ignore_errors=True)
        code, rss, line, touched = run_case(
            inputs.root, target, [*PYTHON, *command(target)], **(options[0] if options else {})
        )
        created = len(os.listdir(inputs.markers))
        line = line.split(" ", 1)[1] if line[:2].isdigit() and line[2:3] == ":" else line
        rows.append(
            f"| {name} | {line[:160].replace('|', '/')} | {code} | {rss:.0f} MiB | {touched} | {created} |"
        )
    return rows


def main(argv: list[str]) -> int:
    inputs = prepare(os.path.abspath(argv[0] if argv else tempfile.mkdtemp(prefix="hostile-")))
    folders = hostile_folders(inputs)
    forge_output(inputs)
    print("\n".join(table(inputs, cases(inputs, folders))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
