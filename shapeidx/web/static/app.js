// shapeidx serve: the page. Views by URL hash: #/query?id=..., #/compare?a=...&b=..., #/browse?...
"use strict";

const QUERY_COLOUR = "#1f77b4", HIT_COLOUR = "#d62728", XMAX = 3.0, BINS_PER_MEAN = 50;
const HISTOGRAMS = ["all", "in", "out", "mixed"];
const state = {info: null, cache: new Map()};
// the metric registry's labels, from /api/store (one record per metric on the server)
function metricLabel(name) {
  const found = state.info && state.info.metrics.find(m => m.name === name);
  return found ? found.label : name;
}

function h(tag, attrs, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k === "text") el.textContent = v;
    else if (k.startsWith("on")) el.addEventListener(k.slice(2), v);
    else if (k === "dataset") Object.assign(el.dataset, v);
    else el.setAttribute(k, v);
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) el.append(c);
  return el;
}

function svg(tag, attrs) {
  const el = document.createElementNS("http://www.w3.org/2000/svg", tag);
  for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, v);
  return el;
}

async function api(url, options) {
  const response = await fetch(url, options);
  let body;
  try { body = await response.json(); } catch (e) { body = {error: `${response.status} ${response.statusText}`}; }
  if (!response.ok) throw new Error(body.error || `${response.status} ${response.statusText}`);
  return body;
}

function showError(message) {
  const el = document.getElementById("error");
  el.textContent = message;
  el.hidden = false;
}
function clearError() { document.getElementById("error").hidden = true; }
function busy(on) { document.getElementById("busy").hidden = !on; }

function params() { return new URLSearchParams(location.hash.split("?")[1] || ""); }
function metricValue() { return document.getElementById("metric").value || (state.info ? state.info.query_metric : ""); }
function topValue() { return document.getElementById("top").value || "10"; }
// the where field: conditions separated by ";" (KEY=VALUE, KEY>=N, KEY~GLOB, ...)
// "1" when the sub-parts are ranked (the checkbox, shown only when the store has them)
function partsValue() { return state.info && state.info.parts && document.getElementById("parts").checked ? "1" : ""; }
// "1" for where used: the files holding a sub-part like the query (no where conditions then)
function usesValue() { return state.info && state.info.parts && document.getElementById("uses").checked ? "1" : ""; }
// "1" for the same-part order: the hits ranked with the exact measures' gap (query --same-part)
function samePartValue() { return !usesValue() && document.getElementById("same-part").checked ? "1" : ""; }
function setSearch(search) {
  if (usesValue()) { search.set("uses", "1"); search.delete("where"); }
  else {
    if (partsValue()) search.set("parts", "1");
    if (samePartValue()) search.set("same_part", "1");
    for (const w of whereValue()) search.append("where", w);
  }
  return search;
}
function subPartLine(part) {
  if (!part.parent) return null;
  // the sub-part's own picture is the card's; its whole file is drawn small beside the line
  const whole = part.parent_thumbnail ? h("img", {class: "parent-thumb", src: part.parent_thumbnail, width: 40, height: 40,
    alt: `the whole file ${part.parent}`, title: `the whole file: ${part.parent}`, loading: "lazy",
    dataset: {testid: "parent-thumbnail"}}) : null;
  return h("div", {class: "subpart"}, whole,
    h("span", {dataset: {testid: "sub-part"}, text: `sub-part of ${part.parent} (×${part.count})`}));
}
function whereValue() { return document.getElementById("where").value.split(";").map(s => s.trim()).filter(s => s); }
function withWhere(values) { return setSearch(new URLSearchParams(values)); }
// Sub-parts and Where used are two ways of ranking sub-parts: one at a time. Where used takes no
// where conditions (they select files) and no same-part order (it keeps the query's size itself),
// so those are disabled while it is ticked.
function showWhereUsed() {
  document.getElementById("where").disabled = !!usesValue();
  document.getElementById("same-part").disabled = !!usesValue();
}
function chooseRanking(ev) {
  const other = document.getElementById(ev.target.id === "uses" ? "parts" : "uses");
  if (ev.target.checked) other.checked = false;
  // where used has its own default distance (the command's); the user may pick another after
  if (ev.target.id === "uses" && ev.target.checked && state.info) document.getElementById("metric").value = state.info.where_used_metric;
  showWhereUsed();
  requery();
}
function metadataLine(metadata) {
  const entries = Object.entries(metadata || {});
  if (!entries.length) return null;
  return h("div", {class: "metadata", dataset: {testid: "metadata"}},
    ...entries.flatMap(([k, v], i) => [i ? " · " : "", h("b", {text: k}), ` ${v}`]));
}
function go(view, values) {
  const search = new URLSearchParams(values);
  if (view === "query") { search.delete("where"); setSearch(search); }
  location.hash = `#/${view}?` + search.toString();
}

function pct(x) { return (100 * x).toFixed(1) + "%"; }
function fractions(fr) {
  const bar = h("div", {class: "bar"});
  for (const c of ["in", "out", "mixed"]) { const s = h("span", {class: c, title: `${c.toUpperCase()} ${pct(fr[c])}`}); s.style.width = pct(fr[c]); bar.append(s); }
  return h("div", {class: "fractions"}, `IN ${pct(fr.in)} · OUT ${pct(fr.out)} · MIXED ${pct(fr.mixed)}`, bar);
}

function thumb(src, size, alt, onclick, lazy) {
  if (!src) return h("div", {class: "muted"}, "no picture");
  return h("img", {class: "thumb", src, width: size, height: size, alt, title: onclick ? "query by this part" : null,
                   loading: lazy ? "lazy" : null, onclick, dataset: {testid: "thumbnail"}});
}

// Four panels, ALL IN / OUT MIXED: each histogram's probability against distance / mean.
function overlay(curves, panelW, panelH) {
  const gap = 12, label = 14, width = 2 * panelW + gap, height = 2 * (panelH + label) + gap;
  const root = svg("svg", {width, height, viewBox: `0 0 ${width} ${height}`, class: "overlay", role: "img"});
  HISTOGRAMS.forEach((name, k) => {
    const x0 = (k % 2) * (panelW + gap), y0 = Math.floor(k / 2) * (panelH + label + gap) + label;
    let peak = 0;
    for (const c of curves) for (const v of c.histograms[name].p) peak = Math.max(peak, v);
    peak = peak * 1.05 || 1;
    const title = svg("text", {x: x0, y: y0 - 3}); title.textContent = name.toUpperCase(); root.append(title);
    root.append(svg("rect", {x: x0, y: y0, width: panelW, height: panelH, fill: "#fafafa", stroke: "#ddd"}));
    for (const c of curves) {
      const p = c.histograms[name].p, points = [];
      for (let i = 0; i < p.length; i++) {
        const x = (i + 0.5) / BINS_PER_MEAN;
        if (x > XMAX) break;
        points.push(`${(x0 + x / XMAX * panelW).toFixed(1)},${(y0 + panelH - p[i] / peak * panelH).toFixed(1)}`);
      }
      root.append(svg("polyline", {points: points.join(" "), fill: "none", stroke: c.colour, "stroke-width": 1.3}));
    }
  });
  return root;
}

function queryCard(q, extra) {
  return h("section", {class: "query", dataset: {testid: "query-card"}},
    thumb(q.thumbnail, 180, q.name, null, false),
    h("div", {}, h("h2", {text: q.name}), q.path ? h("div", {class: "path", text: q.path}) : null,
      subPartLine(q), metadataLine(q.metadata), fractions(q.fractions), extra || null));
}

function renderQuery(result) {
  const view = document.getElementById("view");
  const q = result.query;
  const what = result.parts ? "sub-parts" : "parts";
  const samePart = (result.filters || []).includes("--same-part");
  const kept = (result.filters || []).filter(f => f !== "--same-part");  // an order, not a filter
  const filtered = kept.length ? ` (${kept.join(", ")}: ${result.considered.toLocaleString()} ${what} left)` : "";
  const order = samePart ? "in the same-part order (the distance, then the gap of the exact measures: size, proportions, area, handedness), " : "";
  const counted = result.uses
    ? `${metricLabel(result.metric)}, the files holding a sub-part like it (of its size), nearest first: ${result.hits.length} shown, of ${result.entries.toLocaleString()} files. `
    : `${metricLabel(result.metric)}, ${order}top ${result.hits.length} of ${result.entries.toLocaleString()} ${what}${filtered}. `;
  const info = h("div", {class: "muted"}, counted,
    result.reason ? h("div", {class: "reason", dataset: {testid: "no-answer"}, text: `No hit: ${result.reason}.`}) : null,
    h("details", {}, h("summary", {text: "How the similarity words are calibrated"}), result.calibration));
  const hits = h("div", {class: "hits", dataset: {testid: "hits"}});
  result.hits.forEach((hit, k) => {
    const far = hit.words === "weakly similar" || hit.words === "not similar";
    const share = hit.closer_than ? ` (${hit.closer_than})` : "";
    hits.append(h("article", {class: "hit", dataset: {testid: "hit", rank: hit.rank, id: hit.id}},
      h("div", {class: "top"}, h("span", {class: "rank", text: `#${hit.rank}`}), h("span", {class: "distance", text: `distance ${hit.distance === 0 ? "0" : hit.distance.toPrecision(4)}`}),
        hit.shape_gap === undefined || hit.shape_gap === null ? null : h("span", {class: "gap", dataset: {testid: "shape-gap"},
          title: "the gap of the exact measures (size modulo a unit, proportions, area, handedness): 0 for the same part",
          text: `gap ${hit.shape_gap === 0 ? "0" : hit.shape_gap.toPrecision(2)}`})),
      h("div", {class: far ? "words far" : "words", text: hit.words + share}),
      thumb(hit.thumbnail, 160, hit.id, () => go("query", {id: hit.id, metric: result.metric, top: result.top}), k >= 12),
      h("div", {class: "path", text: hit.id}),
      subPartLine(hit),
      metadataLine(hit.metadata),
      fractions(hit.fractions),
      h("div", {class: "actions"},
        h("button", {class: "plain", dataset: {testid: "compare"}, onclick: () => go("compare", {a: q.id, b: hit.id}), text: "compare"}))));
  });
  view.replaceChildren(queryCard(q, info), hits);
}

function renderCompare(result) {
  const view = document.getElementById("view");
  const side = (part, cls, colour) => h("div", {class: `side ${cls}`},
    h("h3", {text: part.name}), thumb(part.thumbnail, 220, part.name, part.id.startsWith("upload:") ? null : () => go("query", {id: part.id, metric: metricValue(), top: topValue()}), false),
    part.path ? h("div", {class: "path", text: part.path}) : null, fractions(part.fractions));
  const rows = Object.entries(result.distances).map(([m, d]) => h("tr", {dataset: {metric: m}}, h("td", {text: result.labels[m] || m}), h("td", {text: d.toPrecision(5)})));
  view.replaceChildren(h("section", {class: "compare", dataset: {testid: "compare-view"}},
    h("div", {class: "pair"}, side(result.a, "a"), side(result.b, "b")),
    h("p", {class: "muted"}, "Histograms: probability against distance / mean of each set; ",
      h("b", {text: "blue"}), " the first part, ", h("b", {text: "red"}), " the second."),
    h("div", {class: "figures"},
      overlay([{histograms: result.a.histograms, colour: QUERY_COLOUR}, {histograms: result.b.histograms, colour: HIT_COLOUR}], 300, 120),
      h("table", {dataset: {testid: "distances"}}, h("tr", {}, h("th", {text: "distance"}), h("th", {text: "value"})), rows)),
    h("div", {class: "actions"}, h("button", {class: "plain", onclick: () => history.back(), text: "back"}))));
}

function renderBrowse(data, p) {
  const view = document.getElementById("view");
  const limit = 50, offset = Number(p.get("offset") || 0), status = p.get("status") || "all", filter = p.get("q") || "";
  const input = h("input", {type: "search", placeholder: "path contains…", value: filter});
  const select = h("select", {id: "status-filter"}, ...["all", "ok", "failed"].map(s => h("option", {value: s, text: s, selected: s === status ? "" : null})));
  const apply = () => go("browse", {status: select.value, q: input.value, offset: 0});
  input.addEventListener("change", apply); select.addEventListener("change", apply);
  const table = h("table", {dataset: {testid: "entries"}},
    h("tr", {}, ["", "path", "status", "triangles", "IN / OUT / MIXED or reason"].map(t => h("th", {text: t}))));
  for (const e of data.entries) {
    const ok = e.status === "ok";
    table.append(h("tr", {dataset: {id: e.id, status: e.status}},
      h("td", {}, ok ? thumb(`/api/thumbnail?id=${encodeURIComponent(e.id)}`, 56, e.id, () => go("query", {id: e.id, metric: metricValue(), top: topValue()}), true) : ""),
      h("td", {}, ok ? h("a", {href: "#/query?" + new URLSearchParams({id: e.id, metric: metricValue(), top: topValue()}), text: e.id}) : e.id),
      h("td", {text: e.status}), h("td", {text: e.triangles >= 0 ? e.triangles.toLocaleString() : ""}),
      ok ? h("td", {text: `${pct(e.fractions.in)} / ${pct(e.fractions.out)} / ${pct(e.fractions.mixed)}`}) : h("td", {class: "reason", text: e.reason})));
  }
  const pager = h("div", {class: "pager"},
    h("button", {class: "plain", disabled: offset <= 0 ? "" : null, onclick: () => go("browse", {status, q: filter, offset: Math.max(0, offset - limit)}), text: "previous"}),
    h("span", {text: data.total ? `${offset + 1}-${Math.min(offset + limit, data.total)} of ${data.total.toLocaleString()}` : "no entries"}),
    h("button", {class: "plain", disabled: offset + limit >= data.total ? "" : null, onclick: () => go("browse", {status, q: filter, offset: offset + limit}), text: "next"}));
  view.replaceChildren(h("div", {class: "filters"}, "Show", select, input), pager, table);
}

function renderIntro() {
  const i = state.info;
  document.getElementById("view").replaceChildren(h("section", {class: "intro"},
    h("p", {}, `Choose or drop a part file above to find the parts of the store that look like it, or `,
      h("a", {href: "#/browse", text: "browse the store"}), " and click any thumbnail to query by that part."),
    i ? h("p", {class: "muted", text: `${i.ok.toLocaleString()} parts indexed, ${i.failed.toLocaleString()} failed, under ${i.root}.`}) : null));
}

// each route() call's number: an answer that arrives after a newer route() began is dropped
// (a box ticked, then another address: the older answer must not overwrite the newer)
let routed = 0;
async function route() {
  const mine = ++routed;
  const latest = () => mine === routed;
  clearError();
  const view = (location.hash.split("?")[0] || "#/").slice(2);
  const p = params();
  if (p.get("metric")) document.getElementById("metric").value = p.get("metric");
  if (p.get("top")) document.getElementById("top").value = p.get("top");
  if (view === "query") document.getElementById("parts").checked = p.get("parts") === "1";
  if (view === "query") document.getElementById("uses").checked = p.get("uses") === "1";
  if (view === "query") document.getElementById("same-part").checked = p.get("same_part") === "1";
  const key = location.hash;
  busy(true);
  try {
    if (view === "query") {
      document.getElementById("where").value = p.getAll("where").join("; ");
      showWhereUsed();
      const url = "/api/query?" + withWhere({id: p.get("id") || "", metric: metricValue(), top: topValue()});
      const result = state.cache.get(key) || await api(url);
      if (latest()) renderQuery(result);
    } else if (view === "compare") {
      const result = await api("/api/compare?" + new URLSearchParams({a: p.get("a") || "", b: p.get("b") || ""}));
      if (latest()) renderCompare(result);
    } else if (view === "browse") {
      const url = "/api/entries?" + new URLSearchParams({offset: p.get("offset") || 0, limit: 50, status: p.get("status") || "all", q: p.get("q") || ""});
      const result = await api(url);
      if (latest()) renderBrowse(result, p);
    } else {
      renderIntro();
    }
  } catch (e) {
    if (latest()) showError(e.message);
  } finally {
    if (latest()) busy(false);
  }
}

async function upload(file) {
  clearError();
  if (!file) { showError("choose a part file first"); return; }
  if (state.info && file.size > state.info.max_upload) {
    showError(`${file.name}: ${file.size.toLocaleString()} bytes is over the upload limit of ${state.info.max_upload.toLocaleString()} bytes`);
    return;
  }
  const form = new FormData();
  form.append("file", file, file.name);
  form.append("top", topValue());
  form.append("metric", metricValue());
  form.append("parts", partsValue() || "0");
  form.append("uses", usesValue() || "0");
  form.append("same_part", samePartValue() || "0");
  if (!usesValue()) for (const w of whereValue()) form.append("where", w);
  busy(true);
  try {
    const result = await api("/api/query", {method: "POST", body: form});
    const key = "#/query?" + withWhere({id: result.query.id, metric: result.metric, top: result.top});
    state.cache.clear();
    state.cache.set(key, result);
    if (location.hash === key) renderQuery(result); else location.hash = key;
  } catch (e) {
    showError(e.message);
  } finally {
    busy(false);
  }
}

function requery() {
  const p = params();
  const view = (location.hash.split("?")[0] || "#/").slice(2);
  if (view === "query" && p.get("id")) location.hash = "#/query?" + withWhere({id: p.get("id"), metric: metricValue(), top: topValue()});
}

async function start() {
  const select = document.getElementById("metric");
  try {
    state.info = await api("/api/store");
    for (const m of state.info.metrics) select.append(h("option", {value: m.name, text: m.label, title: m.summary}));
    select.value = state.info.query_metric;
    const names = Object.keys(state.info.formats).map(f => f.toUpperCase()).join(", ");
    document.getElementById("drop").textContent = `…or drop a part file here (${names}; gzipped too)`;
    document.getElementById("file").setAttribute("accept", state.info.suffixes.concat(state.info.suffixes.map(s => s + ".gz"), [".gz"]).join(","));
    document.getElementById("where").title = "metadata conditions, separated by ';' (keys: " + state.info.metadata_keys.join(", ") + ")";
    document.getElementById("store-info").textContent =
      `${state.info.store}: ${state.info.ok.toLocaleString()} parts, ${state.info.failed.toLocaleString()} failed` +
      (state.info.parts ? `, ${state.info.sub_parts.toLocaleString()} sub-parts` : "");
    document.getElementById("parts-label").hidden = !state.info.parts;
    document.getElementById("uses-label").hidden = !state.info.parts;
  } catch (e) {
    showError(`cannot read the store: ${e.message}`);
  }
  document.getElementById("upload-form").addEventListener("submit", (ev) => { ev.preventDefault(); upload(document.getElementById("file").files[0]); });
  select.addEventListener("change", requery);
  document.getElementById("top").addEventListener("change", requery);
  document.getElementById("where").addEventListener("change", requery);
  document.getElementById("parts").addEventListener("change", chooseRanking);
  document.getElementById("uses").addEventListener("change", chooseRanking);
  document.getElementById("same-part").addEventListener("change", requery);
  const drop = document.getElementById("drop");
  drop.addEventListener("dragover", (ev) => { ev.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (ev) => { ev.preventDefault(); drop.classList.remove("over"); upload(ev.dataTransfer.files[0]); });
  window.addEventListener("hashchange", route);
  route();
}

start();
