"""The audit page's style and script (plain JavaScript, no library): it reads the page's JSON data
(``report_page.page_html`` embeds it), builds one section per source and recounts on every slider move.

The recount is ``report_data.counts_at`` in JavaScript: per clip, the (flicker bucket, mask bucket)
pair counts with flicker bucket <= the flicker slider's index and mask bucket > the mask slider's
index survive; a clip is written at ``min_tracks`` survivors. The clip table shows, per clip, the
tracks each filter drops at the sliders' values (its columns are ``clipColumns``), and marks a clip
too short for the flicker threshold to mean anything: with T frames and max_fraction x T < 1, a
single visibility flip (one occlusion) drops a track. A source with release verdicts but no audit
table shows its verdicts alone. When the page is built it sets
``document.documentElement.dataset.ready`` and ``window.auditReadyMs`` (ms since navigation).
"""

STYLE = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 0 1.5em 2em; color: #222; }
h1 { font-size: 1.5em; margin: 0.6em 0 0.2em; }
h2 { border-top: 2px solid #ccc; padding-top: 0.6em; margin-top: 1.2em; }
h3 { font-size: 1.05em; margin: 1em 0 0.3em; }
.note { color: #555; font-size: 0.92em; margin: 0.2em 0; }
.bad { color: #b00; font-weight: bold; }
.controls { position: sticky; top: 0; background: #f6f8fb; border: 1px solid #dde; z-index: 2;
  padding: 0.5em 0.8em; display: grid; grid-template-columns: repeat(3, minmax(14em, 1fr)); gap: 0.4em 2em; }
.controls label { display: block; font-weight: 600; }
.controls input[type=range] { width: 100%; }
.controls .value { font-family: monospace; font-weight: normal; }
.controls button { font-size: 0.85em; margin-left: 0.5em; }
.counts { display: flex; flex-wrap: wrap; gap: 0.6em; margin: 0.8em 0; }
.count { border: 1px solid #dde; border-radius: 4px; padding: 0.3em 0.7em; min-width: 8em; }
.count b { display: block; font-size: 1.3em; }
table.funnel td { padding: 1px 0.6em 1px 0; }
table.funnel td.num { text-align: right; font-family: monospace; }
.bar { height: 0.9em; background: #3b7dd8; }
.bar.clips { background: #5a9e5a; }
.hists { display: flex; flex-wrap: wrap; gap: 1.2em; }
.hist { width: 342px; }
.hist svg { background: #fcfcfc; border: 1px solid #eee; }
table.clips { border-collapse: collapse; margin-top: 0.4em; }
table.clips th, table.clips td { border-bottom: 1px solid #eee; padding: 2px 0.5em; text-align: left; }
table.clips td.num { text-align: right; font-family: monospace; }
table.clips td.name { word-break: break-all; max-width: 30em; }
table.clips img { width: 160px; cursor: zoom-in; display: block; }
table.clips img.big { width: 320px; cursor: zoom-out; }
tr.dropped { color: #999; }
td.short { color: #b06000; font-weight: bold; }
.pager button { margin: 0 0.3em; }
"""

SCRIPT = r"""
"use strict";
const DATA = JSON.parse(document.getElementById("audit-data").textContent);
const SPLITS = ["minival", "full_test"];
const FILTERS = ["never_visible", "flicker", "mask"];
const KEPT = "#3b7dd8", DROPPED = "#e0a0a0", PAGE_ROWS = 50;
const fmt = (n) => n.toLocaleString("en-US");

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (key === "text") node.textContent = value;
    else node.setAttribute(key, value);
  }
  for (const child of children) node.append(child);
  return node;
}

function svg(tag, attrs) {
  const node = document.createElementNS("http://www.w3.org/2000/svg", tag);
  for (const [key, value] of Object.entries(attrs)) node.setAttribute(key, value);
  return node;
}

function decode(text, Type) {
  const raw = atob(text), bytes = new Uint8Array(raw.length);
  for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
  return new Type(bytes.buffer);
}

// Exact totals at slider indices (kf, km) and min_tracks mt; per clip, survivors in `alive` and the
// tracks the flicker and mask filters drop in `flickerDropped`, `maskDropped`.
function recount(src, kf, km, mt) {
  const c = src.clips, p = src.pairs, n = c.clip.length;
  const r = { candidates: 0, dropped: { never_visible: 0, flicker: 0, mask: 0 }, passed: 0,
    clips_written: 0, clips_below_target: 0, tracks_written: 0, release: { minival: 0, full_test: 0 } };
  for (let i = 0; i < n; i++) {
    let alive = 0, flicker = 0, mask = 0;
    for (let j = p.offsets[i]; j < p.offsets[i + 1]; j++) {
      if (p.flicker[j] > kf) flicker += p.count[j];
      else if (p.mask[j] <= km) mask += p.count[j];
      else alive += p.count[j];
    }
    src.alive[i] = alive;
    src.flickerDropped[i] = flicker;
    src.maskDropped[i] = mask;
    r.candidates += c.candidates[i];
    r.dropped.never_visible += c.never_visible[i];
    r.dropped.flicker += flicker;
    r.dropped.mask += mask;
    r.passed += alive;
    if (alive >= mt) {
      r.clips_written += 1;
      if (alive < c.target[i]) r.clips_below_target += 1;
      r.tracks_written += Math.min(alive, c.target[i]);
      if (c.split && c.split[i]) r.release[c.split[i]] += 1;
    }
  }
  return r;
}

function unpack(src) {
  const p = src.pairs;
  src.pairs = {
    offsets: decode(p.offsets, Uint32Array),
    flicker: decode(p.flicker, Uint8Array),
    mask: decode(p.mask, Uint8Array),
    count: decode(p.count, p.count_bytes === 2 ? Uint16Array : Uint32Array),
  };
  src.alive = new Int32Array(src.clips.clip.length);
  src.flickerDropped = new Int32Array(src.clips.clip.length);
  src.maskDropped = new Int32Array(src.clips.clip.length);
}

// A clip of T frames at flicker.max_fraction f: a single flip drops a track when f x T < 1 (f > 0).
const tooShort = (frames, f) => f > 0 && f * frames < 1;

function runIndices(src) {
  return src.sliders.map((s) => s.values.indexOf(s.run));
}

function matchesRun(src, r) {
  const s = src.summary;
  return s !== null && r.candidates === s.candidate_tracks && r.passed === s.tracks_passing_filters &&
    r.clips_below_target === s.clips_below_target &&
    FILTERS.every((f) => r.dropped[f] === s.dropped_by_filter[f]);
}

function countBox(id, title) {
  const value = el("b", { id, "data-value": "" });
  return [el("div", { class: "count" }, el("span", { text: title }), value), value];
}

function buildSliders(src, view) {
  const box = el("div", { class: "controls" });
  src.sliders.forEach((s, i) => {
    const input = el("input", { type: "range", min: 0, max: s.values.length - 1, step: 1,
      value: s.values.indexOf(s.run), id: `${src.name}-slider-${s.id}`, "aria-label": s.key });
    const shown = el("span", { class: "value", id: `${src.name}-value-${s.id}` });
    const reset = el("button", { type: "button", text: `run: ${s.run}` });
    reset.title = "back to the run's own value";
    reset.addEventListener("click", () => { input.value = s.values.indexOf(s.run); view.update(); });
    input.addEventListener("input", () => view.update());
    view.inputs[i] = input;
    view.shown[i] = shown;
    box.append(el("div", {}, el("label", { for: input.id }, `${s.key} = `, shown, reset), input,
      el("div", { class: "note", text: s.note })));
  });
  return box;
}

// Bars of counts[] (categories 0..n-1, log scale), a tip per bar; the caller colours bars and moves the line.
function histogram(title, counts, labels, note) {
  const W = 340, H = 150, L = 34, B = 22, n = counts.length, top = Math.max(1, ...counts);
  const root = svg("svg", { width: W, height: H + B + 6, role: "img" });
  const scale = (c) => (Math.log10(1 + c) / Math.log10(1 + top)) * (H - 8);
  const bw = (W - L - 4) / n, bars = [];
  counts.forEach((c, k) => {
    const h = scale(c);
    const bar = svg("rect", { x: L + k * bw, y: H - h, width: Math.max(bw - 0.5, 0.5), height: h });
    const tip = svg("title", {});
    tip.textContent = `${labels[k]}: ${fmt(c)} tracks`;
    bar.append(tip);
    root.append(bar);
    bars.push(bar);
  });
  root.append(svg("line", { x1: L, x2: W - 4, y1: H, y2: H, stroke: "#888" }));
  const axis = (text, x, anchor) => {
    const t = svg("text", { x, y: H + 14, "font-size": 10, "text-anchor": anchor });
    t.textContent = text;
    root.append(t);
  };
  const ymax = svg("text", { x: 2, y: 12, "font-size": 10 });
  ymax.textContent = fmt(top);
  root.append(ymax);
  const line = svg("line", { y1: 0, y2: H, stroke: "#000", "stroke-width": 1.5, "stroke-dasharray": "4 2" });
  root.append(line);
  const box = el("div", { class: "hist" }, el("h3", { text: title }), root,
    el("div", { class: "note", text: note }));
  return { box, bars, line, axis, x: (k) => L + k * bw };
}

function fractionLabels(values, flicker) {
  const last = values.length;
  return Array.from({ length: last + 1 }, (_, k) => {
    if (flicker) return k === last ? `flips/T > ${values[last - 1]}` : k === 0 ? `flips/T <= ${values[0]}` :
      `${values[k - 1]} < flips/T <= ${values[k]}`;
    return k === 0 ? `agreement < ${values[0]}` : k === last ? `agreement >= ${values[last - 1]}` :
      `${values[k - 1]} <= agreement < ${values[k]}`;
  });
}

function gridTicks(hist, values) {
  [0, 0.25, 0.5, 0.75, 1].forEach((v) => {
    const k = values.indexOf(v);
    if (k >= 0) hist.axis(String(v), hist.x(k + 1), "middle");
  });
}

function buildHistograms(src, view) {
  const h = src.histograms, [flick, mask] = src.sliders;
  const f = histogram("flicker: visibility flips / T", h.flicker, fractionLabels(flick.values, true),
    "bar k: tracks first kept at the k-th slider value (kept bars blue); log scale");
  gridTicks(f, flick.values);
  const m = histogram(`mask: ${mask.key.split(".")[0]} mask agreement`, h.mask,
    fractionLabels(mask.values, false),
    `tracks with mask evidence, by agreement (kept blue); ${fmt(h.no_mask_evidence)} more without any ` +
    "(always kept); log scale");
  gridTicks(m, mask.values);
  const vis = h.visible_frames, last = vis.length - 1;
  const v = histogram("never_visible: visible frames", vis, vis.map((_, k) => `${k} visible frames`),
    "a track visible in no frame is dropped (red); log scale");
  v.axis("0", v.x(0.5), "middle");
  v.axis(String(last), v.x(last + 1), "end");
  v.line.setAttribute("x1", v.x(1));
  v.line.setAttribute("x2", v.x(1));
  v.bars.forEach((bar, k) => bar.setAttribute("fill", k > 0 ? KEPT : DROPPED));
  view.hists = { f, m };
  return el("div", { class: "hists" }, v.box, f.box, m.box);
}

function buildFunnel(src, view) {
  const rows = [
    ["candidates", "candidate tracks", ""],
    ["never_visible", "pass never_visible", ""],
    ["flicker", "pass flicker", ""],
    ["mask", "pass mask: pass every filter", ""],
    ["tracks_written", "written tracks (in written clips, at most the target per clip)", ""],
    ["clips", "clips with an audit table", "clips"],
    ["clips_written", "clips written (at least min_tracks pass)", "clips"],
    ["clips_below_target", "written below their target track count", "clips"],
  ];
  const table = el("table", { class: "funnel" });
  view.funnel = {};
  for (const [key, label, kind] of rows) {
    const num = el("td", { class: "num", id: `${src.name}-funnel-${key}` });
    const bar = el("div", { class: `bar ${kind}` });
    table.append(el("tr", {}, el("td", { text: label }), num, el("td", { style: "width: 22em" }, bar)));
    view.funnel[key] = [num, bar];
  }
  return table;
}

// The clip table's columns: header, the cell of clip i at min_tracks mt and flicker fraction f (text,
// and its class). Add a column here.
function clipColumns(src, release) {
  const c = src.clips;
  const written = (i, mt) => src.alive[i] >= mt;
  return [
    { head: "clip", cell: (i) => [c.clip[i], "name"] },
    ...(release ? [{ head: "split", cell: (i) => [c.split[i] || "-", ""] }] : []),
    { head: "frames", cell: (i, mt, f) => tooShort(c.frames[i], f) ?
      [`${fmt(c.frames[i])} *`, "num short"] : [fmt(c.frames[i]), "num"] },
    { head: "candidates", cell: (i) => [fmt(c.candidates[i]), "num"] },
    { head: "dropped: never visible", cell: (i) => [fmt(c.never_visible[i]), "num"] },
    { head: "dropped: flicker", cell: (i) => [fmt(src.flickerDropped[i]), "num"] },
    { head: "dropped: mask", cell: (i) => [fmt(src.maskDropped[i]), "num"] },
    { head: "passing", cell: (i) => [fmt(src.alive[i]), "num"] },
    { head: "target", cell: (i) => [fmt(c.target[i]), "num"] },
    { head: "written", cell: (i, mt) => [written(i, mt) ? (src.alive[i] < c.target[i] ? "yes, below target" :
      "yes") : "no", ""] },
  ];
}

function buildTable(src, view) {
  const c = src.clips, release = src.named !== null, columns = clipColumns(src, release);
  const show = el("select", { id: `${src.name}-table-show` });
  const options = [["thumbs", "clips with a thumbnail"], ["all", "all clips"],
    ["dropped", "clips not written"], ["below", "clips below target"]];
  for (const [value, text] of options) show.append(el("option", { value, text }));
  show.value = Object.keys(src.thumbnails).length ? "thumbs" : "all";
  const order = el("select", { id: `${src.name}-table-order` });
  for (const [value, text] of [["name", "by name"], ["fewest", "fewest passing tracks first"]]) {
    order.append(el("option", { value, text }));
  }
  const head = ["thumbnail", ...columns.map((column) => column.head)];
  const body = el("tbody", { id: `${src.name}-table-body` });
  const header = el("tr", {}, ...head.map((h) => el("th", { text: h })));
  const table = el("table", { class: "clips" }, el("thead", {}, header), body);
  const status = el("span", { class: "note" });
  const short = el("p", { class: "note", id: `${src.name}-short-note` });
  const prev = el("button", { type: "button", text: "previous" });
  const next = el("button", { type: "button", text: "next" });
  let start = 0;
  const render = () => {
    const mt = src.sliders[2].values[view.inputs[2].value];
    const f = src.sliders[0].values[view.inputs[0].value];
    let rows = Array.from({ length: c.clip.length }, (_, i) => i);
    if (show.value === "thumbs") rows = rows.filter((i) => c.clip[i] in src.thumbnails);
    if (show.value === "dropped") rows = rows.filter((i) => src.alive[i] < mt);
    if (show.value === "below") rows = rows.filter((i) => src.alive[i] >= mt && src.alive[i] < c.target[i]);
    if (order.value === "fewest") rows.sort((a, b) => src.alive[a] - src.alive[b]);
    start = Math.min(start, Math.max(0, rows.length - 1 - ((rows.length - 1) % PAGE_ROWS)));
    body.replaceChildren();
    for (const i of rows.slice(start, start + PAGE_ROWS)) {
      const thumb = el("td");
      if (c.clip[i] in src.thumbnails) {
        const img = el("img", { src: `data:image/jpeg;base64,${src.thumbnails[c.clip[i]]}`, alt: c.clip[i] });
        img.addEventListener("click", () => img.classList.toggle("big"));
        thumb.append(img);
      }
      const cells = columns.map((column) => {
        const [text, kind] = column.cell(i, mt, f);
        return el("td", { class: kind, text });
      });
      body.append(el("tr", { class: src.alive[i] >= mt ? "" : "dropped" }, thumb, ...cells));
    }
    status.textContent = rows.length ? ` rows ${start + 1}-${Math.min(start + PAGE_ROWS, rows.length)} of ` +
      `${fmt(rows.length)}` : " no clip";
    const shortClips = c.frames.filter((frames) => tooShort(frames, f)).length;
    short.dataset.value = shortClips;
    short.textContent = shortClips ? `* ${fmt(shortClips)} clip(s) shorter than 1 / ${f} = ` +
      `${fmt(Math.ceil(1 / f - 1e-9))} frames: there flicker.max_fraction x T < 1, so a single visibility ` +
      "flip (one occlusion) drops a track; the flicker threshold cannot tell flicker from occlusion " +
      "on clips this short." : "";
    prev.disabled = start === 0;
    next.disabled = start + PAGE_ROWS >= rows.length;
  };
  prev.addEventListener("click", () => { start = Math.max(0, start - PAGE_ROWS); render(); });
  next.addEventListener("click", () => { start += PAGE_ROWS; render(); });
  show.addEventListener("change", () => { start = 0; render(); });
  order.addEventListener("change", () => { start = 0; render(); });
  view.renderTable = render;
  return el("div", {}, el("div", { class: "pager" }, "show ", show, " ", order, prev, next, status), short,
    table);
}

function buildMissing(src) {
  const rows = (src.missing || []);
  if (!rows.length) return "";
  const table = el("table", { class: "clips" }, el("tr", {}, ...["clip", "split", "status", "reason"].map(
    (h) => el("th", { text: h }))));
  for (const row of rows) table.append(el("tr", {}, ...[row.clip, row.split, row.status, row.reason].map(
    (t) => el("td", { text: t }))));
  return el("div", {}, el("h3", { text: `release clips without an audit table (${fmt(rows.length)}): ` +
    "they survive no threshold" }), table);
}

function buildAgreement(src) {
  const summary = src.agreement;
  if (!summary) return "";
  const counts = el("table", { class: "clips" }, el("tr", {}, ...["split", "release clips", "scored",
    "agree fully", "not in reference", "not made"].map((h) => el("th", { text: h }))));
  for (const row of summary.splits) counts.append(el("tr", {}, ...[row.split, row.clips, row.scored,
    row.agree, row.not_in_ref, row.not_made].map((t) => el("td", { text: String(t) }))));
  const earlier = summary.earlier ? `; ${summary.earlier} clip(s) keep an earlier compare's finding` : "";
  const parts = [el("h3", { text: "agreement with the reference (audit compare)" }),
    el("p", { class: "note", text: "Agree fully: the same query frames and visibility as the " +
      `reference, tracks within ${summary.agree_mm} mm at the 95th percentile. Last compare: ` +
      `${summary.last_ref} at ${summary.last_at}${earlier}.` }), counts];
  if (summary.least.length) {
    const columns = ["query_frames_equal", "visibility", "median_mm", "p95_mm"];
    const least = el("table", { class: "clips" }, el("tr", {}, ...["clip", "split", ...columns].map(
      (h) => el("th", { text: h }))));
    const cell = (v) => (v === null ? "-" : Number(v).toPrecision(4));
    for (const row of summary.least) least.append(el("tr", {}, el("td", { text: row.clip }),
      el("td", { text: row.split }), ...columns.map((c) => el("td", { text: cell(row[c]) }))));
    parts.push(el("h3", { text: "least agreeing clips" }), least);
  }
  return el("div", { id: `${src.name}-agreement` }, ...parts);
}

function buildSource(src) {
  unpack(src);
  const view = { inputs: [], shown: [] };
  const section = el("section", { id: src.name });
  section.append(el("h2", { text: `${src.name}: ${fmt(src.clips.clip.length)} clips` }));
  section.append(el("p", { class: "note", text: src.about }));
  section.append(buildSliders(src, view));
  const boxes = {};
  const counts = el("div", { class: "counts" });
  const shownCounts = [["passed", "kept tracks (pass every filter)"], ["clips-written", "clips written"],
    ["below-target", "clips below target"], ["tracks-written", "tracks written"]];
  if (src.named !== null) {
    SPLITS.forEach((s) => shownCounts.push([`release-${s}`, `release ${s} clips surviving`]));
  }
  for (const [key, title] of shownCounts) {
    const [box, value] = countBox(`${src.name}-${key}`, title);
    counts.append(box);
    boxes[key] = value;
  }
  section.append(counts);
  const check = el("p", { class: "note", id: `${src.name}-run-check` });
  section.append(check);
  section.append(el("h3", { text: "filter funnel" }), buildFunnel(src, view));
  section.append(el("h3", { text: "statistics of all candidate tracks" }), buildHistograms(src, view));
  section.append(el("h3", { text: "clips" }), el("p", { class: "note", text: src.thumbnail_note }));
  section.append(buildTable(src, view), buildMissing(src), buildAgreement(src));
  const run = recount(src, ...runIndices(src).slice(0, 2), src.sliders[2].run);
  if (src.summary === null) {
    check.textContent = `no run_${src.name}.json: the thresholds shown are the defaults`;
  } else if (matchesRun(src, run)) {
    check.textContent = "at the run's own thresholds these counts reproduce " +
      `run_${src.name}.json (candidates, dropped per filter, passed, below target)`;
  } else {
    check.textContent = `at the run's own thresholds these counts DO NOT reproduce run_${src.name}.json`;
    check.classList.add("bad");
  }
  const set = (box, value, text) => { box.dataset.value = value; box.textContent = text ?? fmt(value); };
  view.update = () => {
    const idx = view.inputs.map((input) => Number(input.value));
    src.sliders.forEach((s, i) => { view.shown[i].textContent = String(s.values[idx[i]]); });
    const mt = src.sliders[2].values[idx[2]], r = recount(src, idx[0], idx[1], mt);
    set(boxes.passed, r.passed);
    set(boxes["clips-written"], r.clips_written, `${fmt(r.clips_written)} of ${fmt(src.clips.clip.length)}`);
    set(boxes["below-target"], r.clips_below_target);
    set(boxes["tracks-written"], r.tracks_written);
    if (src.named !== null) SPLITS.forEach((s) => set(boxes[`release-${s}`], r.release[s],
      `${fmt(r.release[s])} of ${fmt(src.named[s])}`));
    let left = r.candidates;
    const stage = (key, value, total, text) => {
      const [num, bar] = view.funnel[key];
      num.textContent = text ?? fmt(value);
      num.dataset.value = value;
      bar.style.width = `${total ? (100 * value) / total : 0}%`;
    };
    stage("candidates", left, r.candidates);
    for (const f of FILTERS) {
      left -= r.dropped[f];
      stage(f, left, r.candidates, `${fmt(left)} (-${fmt(r.dropped[f])})`);
      view.funnel[f][0].dataset.dropped = r.dropped[f];
    }
    stage("tracks_written", r.tracks_written, r.candidates);
    stage("clips", src.clips.clip.length, src.clips.clip.length);
    stage("clips_written", r.clips_written, src.clips.clip.length);
    stage("clips_below_target", r.clips_below_target, src.clips.clip.length);
    const { f, m } = view.hists;
    f.bars.forEach((bar, k) => bar.setAttribute("fill", k <= idx[0] ? KEPT : DROPPED));
    f.line.setAttribute("x1", f.x(idx[0] + 1));
    f.line.setAttribute("x2", f.x(idx[0] + 1));
    m.bars.forEach((bar, k) => bar.setAttribute("fill", k > idx[1] ? KEPT : DROPPED));
    m.line.setAttribute("x1", m.x(idx[1] + 1));
    m.line.setAttribute("x2", m.x(idx[1] + 1));
    view.renderTable();
  };
  view.update();
  return section;
}

// A release run's source without audit tables (no clip annotated): its verdicts alone.
function buildVerdictsOnly(src) {
  const section = el("section", { id: src.name });
  section.append(el("h2", { text: `${src.name}: no audit tables` }));
  section.append(el("p", { class: "note", text: src.about }), buildMissing(src));
  return section;
}

const main = document.getElementById("sources");
for (const src of DATA.sources) main.append(src.verdicts_only ? buildVerdictsOnly(src) : buildSource(src));
document.documentElement.dataset.ready = "true";
window.auditReadyMs = performance.now();
"""
