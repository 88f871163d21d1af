"""``python -m pipeline.audit report``: the audit page, opened in headless Chromium, shows at each slider
value the counts ``python -m pipeline.audit sweep`` computes there (kept tracks, dropped per filter,
clips written, below target, surviving release clips per split); its folded counts equal the sweep's
``evaluate`` at every value of the flicker, mask and min_tracks sliders; it writes only ``--out``.

One output folder holds a Panoptic Studio sample run and a ``--release`` DriveTrack sample run whose
splits file names three real clips and two the run cannot make."""

from __future__ import annotations

import base64
import dataclasses
import json
import os
import re
import shutil

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from selenium import webdriver
from selenium.common.exceptions import WebDriverException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import Select, WebDriverWait

from pipeline import sources
from pipeline.audit.__main__ import main as audit_main
from pipeline.audit.report_data import counts_at, run_config, source_data
from pipeline.audit.sweep import evaluate, load_statistics, release_of, run_provenance
from pipeline.drivetrack.sample.waymo_world import SEGMENT
from pipeline.runner.command import main as run_main
from pipeline.settings.fields import with_overrides
from pipeline.viz.__main__ import main as viz_main
from pipeline.viz.clip_figure import load_clip

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
FLAGS = (
    "--headless=new --no-sandbox --disable-gpu --disable-dev-shm-usage --disable-background-networking "
    "--disable-component-update --no-first-run --disable-sync"
).split()
LEAD = f"tapvid3d_{SEGMENT}_1_lead_car_AAAAAAAAAAAAAAAAAAAAAA"
CROSSING = f"tapvid3d_{SEGMENT}_1_crossing_car_BBBBBBBBBBBBBBBBBB"
PARKED = f"tapvid3d_{SEGMENT}_3_parked_right_DDDDDDDDDDDDDDDDDD"
RELEASE = {
    "minival": {"drivetrack": [f"{LEAD}.npz", f"{CROSSING}.npz"]},
    "full_eval": {
        "drivetrack": [
            f"{PARKED}.npz",
            f"tapvid3d_{SEGMENT}_2_no_such_object.npz",
            "tapvid3d_1234567890_0_000_20_000_1_someone.npz",
        ]
    },
}
# Sweep grids the browser test replays: each value moves some count on its sample.
GRIDS = {
    "pstudio": ["flicker.max_fraction=0.02,0.1", "pstudio.mask_min_agreement=0.9,0.95", "min_tracks=1,380"],
    "drivetrack": [
        "flicker.max_fraction=0.05,0.3",
        "drivetrack.mask_min_agreement=0.2,0.8",
        "min_tracks=1,117",
    ],
}


@pytest.fixture(scope="module")
def out(reference_run, sample_split, tmp_path_factory):
    """A Panoptic Studio run (a copy of the plain one) and a DriveTrack --release run, in one output
    folder; the release run compared with itself (``audit compare``: every clip it wrote agrees
    fully)."""
    splits = tmp_path_factory.mktemp("splits") / "splits.json"
    splits.write_text(json.dumps(RELEASE))
    folder = tmp_path_factory.mktemp("page") / "run"
    shutil.copytree(reference_run("pstudio"), folder)
    release = ["--release", str(splits)]
    assert (
        run_main(["--source", "drivetrack", "--input", sample_split[0], "--output", str(folder), *release])
        == 0
    )
    compare = tmp_path_factory.mktemp("compare") / "compare"
    assert audit_main(["compare", str(folder), str(folder), "--out", str(compare)]) == 0
    return folder


@pytest.fixture(scope="module")
def page(out, tmp_path_factory):
    path = tmp_path_factory.mktemp("page") / "report.html"
    assert audit_main(["report", str(out), "--out", str(path)]) == 0
    return path


def embedded(path) -> dict:
    """The JSON data the page carries."""
    text = path.read_text()
    found = re.search(r'<script type="application/json" id="audit-data">(.*?)</script>', text, re.S)
    return json.loads(found.group(1))


def sweep_clips(out, source: str):
    """The sweep's inputs: its clips (the release's only, on a release run), its splits, the run's config."""
    record = run_provenance(str(out), source)
    release = release_of(None, record)
    splits = dict(release.clips[source]) if release is not None else None
    clips = [c for c in load_statistics(str(out), source) if splits is None or c.clip in splits]
    return clips, splits, run_config(record)


# --------------------------------------------------------------------------- exact folded counts


@pytest.mark.parametrize("source", ["pstudio", "drivetrack"])
def test_folded_counts_equal_the_sweeps_at_every_slider_value(out, source):
    """Every flicker value (mask at the run's), every mask value (flicker at the run's), every
    min_tracks value, and a coarse product of the two fractions."""
    data = source_data(str(out), sources.get(source))
    clips, splits, base = sweep_clips(out, source)
    (flicker, fgrid), (mask, mgrid), (_, tgrid) = data.grids.items()
    run_f, run_m = (
        fgrid.index(base.flicker.max_fraction),
        mgrid.index(base.source_sections[source].mask_min_agreement),
    )
    points = [(k, run_m, base.min_tracks) for k in range(len(fgrid))]
    points += [(run_f, k, base.min_tracks) for k in range(len(mgrid))]
    points += [(run_f, run_m, t) for t in tgrid]
    points += [(f, m, 1) for f in range(0, len(fgrid), 10) for m in range(0, len(mgrid), 10)]
    passed = set()
    for f, m, t in points:
        config = with_overrides(base, [f"{flicker}={fgrid[f]}", f"{mask}={mgrid[m]}", f"min_tracks={t}"])
        expected = evaluate(clips, sources.get(source), config, splits)
        got = counts_at(data, f, m, t)
        assert got == expected, (fgrid[f], mgrid[m], t)
        passed.add(expected.passed)
    assert len(passed) > 20  # the grids do move the counts
    assert len(fgrid) == len(mgrid) == 101
    assert len(tgrid) == max(c.stats.count for c in clips)


@pytest.mark.parametrize("source", ["pstudio", "drivetrack"])
def test_tracks_written_at_the_run_thresholds_are_the_runs(out, source):
    data = source_data(str(out), sources.get(source))
    thresholds = data.thresholds
    indices = [grid.index(thresholds[key]) for key, grid in list(data.grids.items())[:2]]
    summary = json.loads((out / f"run_{source}.json").read_text())["summary"]
    assert counts_at(data, *indices, thresholds["min_tracks"]).tracks_written == summary["tracks_written"]


def test_a_run_value_between_steps_is_a_slider_value_counted_exactly(out, tmp_path):
    """A run at flicker 0.125 and mask 0.905 (between the 0.01 steps): both are slider values, exact."""
    copy = tmp_path / "out"
    (copy / "audit").mkdir(parents=True)
    os.symlink(out / "audit" / "pstudio", copy / "audit" / "pstudio")
    record = json.loads((out / "run_pstudio.json").read_text())
    record["config"]["flicker"]["max_fraction"] = 0.125
    record["config"]["pstudio"]["mask_min_agreement"] = 0.905
    (copy / "run_pstudio.json").write_text(json.dumps(record))
    data = source_data(str(copy), sources.get("pstudio"))
    fgrid, mgrid, _ = data.grids.values()
    assert len(fgrid) == len(mgrid) == 102
    assert fgrid == sorted(fgrid)
    clips, splits, base = sweep_clips(copy, "pstudio")
    counts = set()
    for m in range(mgrid.index(0.9), mgrid.index(0.91) + 1):
        f = fgrid.index(0.125)
        config = with_overrides(
            base, [f"flicker.max_fraction={fgrid[f]}", f"pstudio.mask_min_agreement={mgrid[m]}"]
        )
        got = counts_at(data, f, m, 1)
        assert got == evaluate(clips, sources.get("pstudio"), config, splits)
        counts.add(got.passed)
    assert len(counts) == 3  # 0.9, 0.905 and 0.91 keep different numbers of tracks


# ------------------------------------------------------------------------------- the command


def test_help_and_one_line_refusals(out, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        audit_main(["report", "--help"])
    assert stop.value.code == 0
    assert "--thumbnails" in capsys.readouterr().out
    with pytest.raises(SystemExit) as stop:
        audit_main(["report", str(out), "--out", str(tmp_path / "p.html"), "--thumbnail", "3"])
    error = capsys.readouterr().err
    assert stop.value.code == 2
    assert "did you mean --thumbnails?" in error
    assert error.count("\n") == 1
    assert audit_main(["report", str(tmp_path), "--out", str(tmp_path / "p.html")]) == 2
    error = capsys.readouterr().err
    assert error.startswith("report: no audit tables")
    assert error.count("\n") == 1
    assert not (tmp_path / "p.html").exists()


def test_an_unwritable_out_is_named_as_given_never_its_temporary(out, tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    target = blocker / "p.html"
    assert audit_main(["report", str(out), "--out", str(target), "--thumbnails", "0"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"report: cannot write --out {target} (")
    assert ".partial" not in line
    with pytest.raises(SystemExit) as stop:
        audit_main(["report", str(out), "--out", f"{tmp_path}/new.html/", "--thumbnails", "0"])
    assert stop.value.code == 2
    assert "is a folder: name the HTML file to write" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["a_file"]


def tree(folder) -> dict:
    """path -> (size, mtime) of every file under ``folder``."""
    found = {}
    for root, _, files in os.walk(folder):
        for name in files:
            stat = os.stat(os.path.join(root, name))
            found[os.path.join(root, name)] = (stat.st_size, stat.st_mtime_ns)
    return found


def test_writes_only_its_page_with_evenly_spaced_thumbnails(out, tmp_path):
    before = tree(out)
    page = tmp_path / "page.html"
    assert audit_main(["report", str(out), "--out", str(page), "--thumbnails", "2"]) == 0
    assert tree(out) == before
    assert os.listdir(tmp_path) == ["page.html"]
    text = page.read_text()
    assert "<script src" not in text
    assert "<link" not in text
    assert not re.search(r'(src|href)="(https?:)?//', text)
    pages = {s["name"]: s for s in embedded(page)["sources"]}
    assert set(pages["pstudio"]["thumbnails"]) == {"dome_16", "dome_8"}  # first and last by name
    assert set(pages["drivetrack"]["thumbnails"]) == {CROSSING, PARKED}
    figure = tmp_path / "figure.png"  # python -m pipeline.viz draws the clip's middle frame
    assert viz_main([str(out / "pstudio" / "dome_8.npz"), "--out", str(figure)]) == 0
    drawn = cv2.cvtColor(cv2.imread(str(figure)), cv2.COLOR_BGR2RGB)
    height, width = load_clip(str(out / "pstudio" / "dome_8.npz")).image(0).shape[:2]
    jpeg = np.frombuffer(base64.b64decode(pages["pstudio"]["thumbnails"]["dome_8"]), np.uint8)
    thumb = cv2.cvtColor(cv2.imdecode(jpeg, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    expected = cv2.resize(drawn[:height, :width], thumb.shape[1::-1], interpolation=cv2.INTER_AREA)
    assert thumb.shape[1] == 320
    assert np.abs(thumb.astype(int) - expected).mean() < 3
    assert thumb.std() > 10


# ------------------------------------------------------------------------------- in the browser


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """Headless Chromium through chromedriver; the tests below skip where either is missing."""
    for path in (CHROMIUM, CHROMEDRIVER):
        if not os.path.exists(path):
            pytest.skip(f"no {path} (make setup installs Debian's chromium and chromium-driver)")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in [*FLAGS, f"--user-data-dir={tmp_path_factory.mktemp('chromium')}", "--window-size=1300,1500"]:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    try:
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    except WebDriverException as error:
        pytest.skip(f"headless Chromium does not start: {(error.msg or str(error)).splitlines()[0]}")
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def loaded(browser, page):
    browser.get(page.as_uri())
    WebDriverWait(browser, 30).until(
        lambda driver: driver.execute_script("return document.documentElement.dataset.ready") == "true"
    )
    return browser


def severe(driver) -> list[dict]:
    return [entry for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]


def test_the_page_loads_offline_without_errors(loaded, tmp_path):
    assert severe(loaded) == []
    assert loaded.execute_script("return performance.getEntriesByType('resource').length") == 0
    assert loaded.find_element(By.ID, "drivetrack-run-check").text.startswith(
        "at the run's own thresholds these counts reproduce run_drivetrack.json"
    )
    shot = tmp_path / "page.png"
    assert loaded.save_screenshot(str(shot))
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert shot.stat().st_size > 20_000


def move(driver, source: str, slider: str, index: int, last: int, now: int | None = None) -> None:
    """Put a slider at ``index`` with the keyboard, as few keys as it takes: arrows from ``now``
    (its index, when known), or Home or End, then arrows."""
    ways = [Keys.HOME + Keys.ARROW_RIGHT * index, Keys.END + Keys.ARROW_LEFT * (last - index)]
    if now is not None:
        ways.append(Keys.ARROW_RIGHT * (index - now) if index >= now else Keys.ARROW_LEFT * (now - index))
    keys = min(ways, key=len)
    if keys:
        driver.find_element(By.ID, f"{source}-slider-{slider}").send_keys(keys)


# What the page shows, read from its document in one call: element id -> its attribute, or "text".
READ_SHOWN = """
const [wanted, dropped] = arguments;
const read = {};
for (const [id, field] of Object.entries(wanted)) {
  const element = document.getElementById(id);
  read[id] = field === "text" ? element.textContent : element.getAttribute(field);
}
read.dropped_rows = document.querySelectorAll("#" + dropped + " tr.dropped").length;
return read;
"""


@pytest.mark.parametrize("source", ["pstudio", "drivetrack"])
def test_sliders_show_the_sweeps_counts(loaded, out, source, tmp_path):
    grid = [arg for value in GRIDS[source] for arg in ("--grid", value)]
    command = ["sweep", str(out), "--source", source, *grid, "--out", str(tmp_path)]
    assert audit_main(command) == 0
    rows = pq.read_table(tmp_path / "sweep.parquet").to_pylist()
    clips = len(load_statistics(str(out), source))
    Select(loaded.find_element(By.ID, f"{source}-table-show")).select_by_value("all")
    keys = ["flicker.max_fraction", f"{source}.mask_min_agreement", "min_tracks"]
    sliders = ("flicker", "mask", "min_tracks")
    lasts = [100, 100, int(loaded.find_element(By.ID, f"{source}-slider-min_tracks").get_attribute("max"))]
    counts = {"passed": "passed", "clips-written": "clips_written", "below-target": "clips_below_target"}
    if source == "drivetrack":
        counts |= {f"release-{split}": f"release_{split}" for split in ("minival", "full_test")}
    funnel = ("never_visible", "flicker", "mask")
    wanted = {f"{source}-value-{slider}": "text" for slider in sliders}
    wanted |= {f"{source}-{name}": "data-value" for name in counts}
    wanted |= {f"{source}-funnel-{name}": "data-dropped" for name in funnel}
    now: list[int | None] = [None, None, None]
    for row in rows:
        # Independently of the page's data: fractions step by 0.01 from 0, min_tracks by 1 from 1.
        positions = [
            round(float(row[keys[0]]) * 100),
            round(float(row[keys[1]]) * 100),
            int(row["min_tracks"]) - 1,
        ]
        for slider, index, last, at in zip(sliders, positions, lasts, now, strict=True):
            move(loaded, source, slider, index, last, at)
        now = list(positions)
        read = loaded.execute_script(READ_SHOWN, wanted, f"{source}-table-body")
        assert [read[f"{source}-value-{slider}"] for slider in sliders] == [row[key] for key in keys]
        for name, column in counts.items():
            assert int(read[f"{source}-{name}"]) == row[column], (name, row)
        for name in funnel:
            assert int(read[f"{source}-funnel-{name}"]) == row[f"dropped_{name}"], row
        assert read["dropped_rows"] == clips - row["clips_written"]
    assert len({row["passed"] for row in rows}) > 4
    assert len({row["clips_written"] for row in rows}) > 1
    assert severe(loaded) == []


def test_the_clip_table_shows_each_filters_drops_and_marks_clips_too_short(loaded, out, page):
    """At the run's thresholds each clip's drops per filter are its verdict's; at flicker 0.02 a clip
    of fewer than 50 frames is marked (0.02 x T < 1: one flip drops a track) and the note counts them."""
    source = "drivetrack"
    for index, slider in enumerate(("flicker", "mask", "min_tracks")):
        data = {s["name"]: s for s in embedded(page)["sources"]}[source]["sliders"][index]
        move(loaded, source, slider, data["values"].index(data["run"]), len(data["values"]) - 1)
    Select(loaded.find_element(By.ID, f"{source}-table-show")).select_by_value("all")
    heads = [th.text for th in loaded.find_elements(By.CSS_SELECTOR, f"#{source} table.clips thead th")]
    table = loaded.find_element(By.ID, f"{source}-table-body")
    rows = [
        [td.text for td in tr.find_elements(By.TAG_NAME, "td")]
        for tr in table.find_elements(By.TAG_NAME, "tr")
    ]
    verdicts = {row["clip"]: row for row in map(json.loads, (out / f"release_{source}.jsonl").open())}
    assert len(rows) == 3
    for cells in rows:
        row = dict(zip(heads, cells, strict=True))
        dropped = verdicts[row["clip"]]["dropped"]
        for name, head in (("never_visible", "never visible"), ("flicker", "flicker"), ("mask", "mask")):
            assert int(row[f"dropped: {head}"].replace(",", "")) == dropped[name], (row["clip"], name)
    assert sum(verdicts[cells[heads.index("clip")]]["dropped"]["flicker"] for cells in rows) > 0
    note = loaded.find_element(By.ID, f"{source}-short-note")
    assert (note.get_attribute("data-value"), note.text) == ("0", "")  # 0.1 x T >= 1 on every clip
    move(loaded, source, "flicker", 2, 100)
    assert loaded.find_element(By.ID, f"{source}-value-flicker").text == "0.02"
    frames = {s["name"]: s for s in embedded(page)["sources"]}[source]["clips"]["frames"]
    short = sum(count < 50 for count in frames)
    assert short > 0
    assert int(note.get_attribute("data-value")) == short
    assert note.text.startswith(f"* {short} clip(s) shorter than 1 / 0.02 = 50 frames")
    assert len(table.find_elements(By.CSS_SELECTOR, "td.short")) == short


def test_the_agreement_table_shows_each_splits_clips_agreeing_fully(loaded, out):
    """The page's agreement table (``audit compare`` of the run with itself) counts, per split, the
    release clips and those that agree fully: the written ones."""
    rows = [json.loads(line) for line in (out / "release_drivetrack.jsonl").read_text().splitlines()]
    table = loaded.find_element(By.ID, "drivetrack-agreement").find_element(By.TAG_NAME, "table")
    shown_rows = [
        [cell.text for cell in row.find_elements(By.TAG_NAME, "td")]
        for row in table.find_elements(By.TAG_NAME, "tr")
    ][1:]
    expected = []
    for split in ("minival", "full_test", "all"):
        chosen = [row for row in rows if split in ("all", row["split"])]
        written = sum(row["status"] == "written" for row in chosen)
        expected.append([split, str(len(chosen)), str(written), str(written), "0", "0"])
    assert shown_rows == expected


@pytest.mark.parametrize("source", ["pstudio", "drivetrack"])
def test_the_pages_recount_is_the_pythons_at_every_slider_position(loaded, out, source):
    """The page's recount (JavaScript's ``recount``) against the Python one the page's data is made
    for (``report_data.counts_at``), over every flicker and mask slider position (a seventh of
    them, each once) and several min_tracks."""
    data = source_data(str(out), sources.get(source))
    index = [src["name"] for src in loaded.execute_script("return DATA.sources")].index(source)
    steps = len(data.grids["flicker.max_fraction"])
    positions = [
        (kf, km, mt) for kf in range(0, steps, 7) for km in range(0, steps, 7) for mt in (1, 50, 200)
    ]
    script = (
        "const src = DATA.sources[arguments[0]];"
        "return arguments[1].map(([kf, km, mt]) => recount(src, kf, km, mt));"
    )
    shown = loaded.execute_script(script, index, positions)
    for position, page in zip(positions, shown, strict=True):
        totals = dataclasses.asdict(counts_at(data, *position))
        python = {key: value for key, value in totals.items() if value is not None}
        assert {key: page[key] for key in python} == python, position
