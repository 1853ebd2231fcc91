// tactus memory browser: plain ES module, no build step, no external origin.
// Talks to the service's own API (same origin); every data request carries the bearer token
// the user typed (kept in sessionStorage only).

import { drawMap, pickTrajectory } from "./map.js";

const $ = (sel, root = document) => root.querySelector(sel);

const state = {
  token: sessionStorage.getItem("tactus-token") || "",
  senses: [], // GET /senses
  sessions: [], // GET /sessions
  // what the server offers, from its OpenAPI schema: grouped search (GET /moments or
  // GET /search?group=moment), GET /sessions/{id}/timeline, GET /items?session=
  caps: { group: null, timeline: false, itemsList: false },
  touchSenses: new Set(), // names of senses whose items are touch windows
  timelinePoints: [],
};

// ------------------------------------------------------------------------------ DOM helpers
function h(tag, attrs = {}, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === "class") el.className = v;
    else if (k === "dataset") Object.assign(el.dataset, v);
    else if (k.startsWith("on") && typeof v === "function") el.addEventListener(k.slice(2), v);
    else if (k === "style" && typeof v === "object") Object.assign(el.style, v);
    else el.setAttribute(k, v === true ? "" : String(v));
  }
  for (const c of children.flat()) {
    if (c === undefined || c === null || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return el;
}

function setStatus(el, text, kind = "") {
  el.textContent = text;
  el.dataset.kind = kind;
}

// ------------------------------------------------------------------------------ API
class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.status = status;
  }
}

function authHeaders(extra = {}) {
  return state.token ? { ...extra, Authorization: `Bearer ${state.token}` } : extra;
}

// While the server starts (socket open, models loading) data routes answer 503 + Retry-After
// with a detail starting "starting:"; the page waits that long and asks again (bounded).
const STARTING_RETRIES = 120;
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

async function api(path, options = {}, attempt = 0) {
  try {
    return await apiOnce(path, options);
  } catch (err) {
    if (err.status === 503 && err.retryAfter && attempt < STARTING_RETRIES && /^starting/.test(err.message)) {
      setStatus($("#search-status"), `The server is ${err.message.split(";")[0]}…`, "busy");
      await sleep(err.retryAfter * 1000);
      return api(path, options, attempt + 1);
    }
    throw err;
  }
}

async function apiOnce(path, { method = "GET", body, raw = false } = {}) {
  const init = { method, headers: authHeaders() };
  if (body instanceof FormData) {
    init.body = body; // multipart: the browser sets the boundary header
  } else if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers["Content-Type"] = "application/json";
  }
  let res;
  try {
    res = await fetch(path, init);
  } catch (err) {
    throw new ApiError(0, `the server did not answer (${err.message})`);
  }
  if (!res.ok) {
    let detail = res.statusText;
    try {
      const j = await res.json();
      detail = j.detail ? (typeof j.detail === "string" ? j.detail : JSON.stringify(j.detail)) : detail;
    } catch {
      /* not JSON */
    }
    if (res.status === 401) detail += " (set the access token at the top right)";
    const error = new ApiError(res.status, detail);
    error.retryAfter = Number(res.headers.get("Retry-After")) || 0;
    throw error;
  }
  return raw ? res : res.json();
}

// ------------------------------------------------------------------------------ formatting
function fmtT(t) {
  if (typeof t !== "number" || !Number.isFinite(t)) return "?";
  if (Math.abs(t) > 1e8) {
    // Unix seconds
    return new Date(t * 1000).toISOString().replace("T", " ").slice(0, 19) + " UTC";
  }
  return `${t.toFixed(2)} s`;
}

function fmtSpan(t, tEnd) {
  if (tEnd === undefined || tEnd === null || tEnd === t) return fmtT(t);
  return `${fmtT(t)} – ${fmtT(tEnd)}`;
}

function isTouch(hit) {
  return state.touchSenses.has(hit.sense) || hit.sense === "touch";
}

function senseBadge(sense) {
  const info = state.senses.find((s) => s.name === sense);
  const modality = info ? info.modality : sense;
  return h("span", { class: `badge badge-${cssIdent(modality)}`, title: `sense: ${sense}` }, sense);
}

function cssIdent(s) {
  return String(s).toLowerCase().replace(/[^a-z0-9_-]/g, "-");
}

// A stored value as text: strings as they are, anything else as JSON.
function fmtValue(v) {
  return typeof v === "string" ? v : JSON.stringify(v);
}

// <dl class="cls"> with one dt/dd per [label, value] pair; null pairs are left out.
function defList(cls, pairs) {
  return h(
    "dl",
    { class: cls },
    pairs.filter(Boolean).flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, v)]),
  );
}

// An item's meta as [key, text] pairs.
function metaEntries(meta) {
  return Object.entries(meta || {}).map(([k, v]) => [k, fmtValue(v)]);
}

function metaList(meta) {
  const entries = metaEntries(meta);
  return entries.length ? defList("meta", entries) : null;
}

// Touch facets (tactus_memory/touch/facets.py) beside the heat map: force, area, peak, grip,
// the active regions with their share of the load; a grasp adds its duration, squeeze, slip
// and caption.
function facetsList(f) {
  if (!f) return null;
  const pct = (x) => `${(100 * x).toFixed(0)} %`;
  const entries = [["force", Number(f.force).toFixed(1)], ["area", pct(f.area)]];
  entries.push(["peak", Number(f.peak).toFixed(2)]);
  if (f.grip) entries.push(["grip", f.grip]);
  const regions = Object.entries(f.regions || {})
    .filter(([, share]) => share >= 0.1)
    .sort((a, b) => b[1] - a[1])
    .map(([name, share]) => `${name} ${pct(share)}`);
  if (regions.length) entries.push(["regions", regions.join(", ")]);
  if (typeof f.duration === "number") {
    entries.push(["duration", `${f.duration.toFixed(1)} s`]);
    entries.push(["squeeze", `${Number(f.ramp).toFixed(1)} /s`]);
    entries.push(["slip", `${Number(f.slip).toFixed(1)} taxels/s`]);
  }
  if (f.caption) entries.push(["in words", f.caption]);
  return defList("meta facets", entries);
}

// ------------------------------------------------------------------------------ heat maps
// The PNG comes from the service (tactus_memory.touch.render.draw_window_png, the renderer
// the evaluation report uses too): frames 4 per row at 5 px per taxel, a colour bar under
// them. With a token, <img src> cannot send the header: fetch it. Hovering a taxel shows its
// calibrated value, from GET /items/{id}/touch.json (same query, fetched on first hover).
const HEATMAP_QUERY = "scale=5&columns=4&outline=true"; // the hand regions outlined

// Point img at src; with a token the image is fetched with it (an <img> sends no header).
function loadImage(img, src, label) {
  if (state.token) {
    api(src, { raw: true })
      .then((res) => res.blob())
      .then((blob) => {
        img.src = URL.createObjectURL(blob);
      })
      .catch((err) => {
        img.alt = `${label} (could not load: ${err.message})`;
      });
  } else {
    img.src = src;
  }
}

function heatmap(itemId, label) {
  const base = `/items/${encodeURIComponent(itemId)}`;
  const src = `${base}/touch.png?${HEATMAP_QUERY}`;
  const img = h("img", {
    class: "heatmap",
    alt: label,
    loading: "lazy",
    decoding: "async",
  });
  loadImage(img, src, label);
  const readout = h("output", { class: "taxel-value", "aria-live": "off" }, "");
  let values = null; // the touch.json answer, once fetched
  let loading = null;
  img.addEventListener("mousemove", (ev) => {
    if (!values) {
      loading = loading || api(`${base}/touch.json?${HEATMAP_QUERY}`).then((v) => (values = v));
      loading.catch(() => {});
      return;
    }
    const text = taxelAt(values, img, ev);
    readout.textContent = text;
    img.title = text;
  });
  img.addEventListener("mouseleave", () => {
    readout.textContent = "";
  });
  return h(
    "figure",
    { class: "heatmap-figure" },
    img,
    h(
      "figcaption",
      { class: "muted" },
      "pressure per frame, left to right then down; colour bar below (dark: no contact); " +
        "point at a taxel for its value ",
      readout,
    ),
  );
}

// The taxel under the pointer: the image is drawn at layout.scale px per taxel, each frame
// the sensor's frame_rows x frame_cols taxels, frames gap taxels apart, layout.columns per
// row; the colour bar sits below the frames.
function taxelAt(v, img, ev) {
  const L = v.layout;
  const k = img.naturalWidth / img.clientWidth; // CSS may shrink the image
  const x = ev.offsetX * k;
  const y = ev.offsetY * k;
  if (x >= L.width || y >= L.height) return "";
  const pitchX = (L.frame_cols + L.gap) * L.scale;
  const pitchY = (L.frame_rows + L.gap) * L.scale;
  const col = Math.floor(x / pitchX);
  const row = Math.floor(y / pitchY);
  const c = Math.floor((x - col * pitchX) / L.scale);
  const r = Math.floor((y - row * pitchY) / L.scale);
  const f = row * L.columns + col;
  if (c >= L.frame_cols || r >= L.frame_rows || f >= v.values.length) return "";
  const where = `frame ${v.frames[f] + 1}, row ${r}, column ${c}`;
  if (!v.taxels[r][c]) return `${where}: not a taxel of the sensor`;
  const value = v.values[f][r][c];
  const contact = value > v.scale.lo ? "contact" : "no contact";
  return `${where}: ${value.toFixed(3)} calibrated (${contact})`;
}

// ------------------------------------------------------------------------------ image thumbnails
// An image item keeps a thumbnail; GET /items/{id}/image.png draws it (fetched with the token).
function isImage(hit) {
  const info = state.senses.find((s) => s.name === hit.sense);
  return info ? info.modality === "image" : hit.sense === "image";
}

function thumbnail(itemId, label) {
  const src = `/items/${encodeURIComponent(itemId)}/image.png?size=160`;
  const img = h("img", { class: "thumb", alt: label, loading: "lazy", decoding: "async" });
  loadImage(img, src, label);
  return h("figure", { class: "thumb-figure" }, img);
}

function imageLabel(hit) {
  return `Image in session ${hit.session} at ${fmtSpan(hit.t, hit.t_end)}`;
}

function touchLabel(hit) {
  return `Pressure heat map of the touch window in session ${hit.session} at ${fmtSpan(hit.t, hit.t_end)}`;
}

// ------------------------------------------------------------------------------ tabs
const TABS = ["search", "sessions", "senses"];

function showTab(name, { focus = false, push = true } = {}) {
  for (const t of TABS) {
    const tab = $(`#tab-${t}`);
    const on = t === name;
    tab.setAttribute("aria-selected", String(on));
    tab.tabIndex = on ? 0 : -1;
    $(`#view-${t}`).hidden = !on;
    if (on && focus) tab.focus();
  }
  if (push && !location.hash.startsWith(`#${name}`)) history.replaceState(null, "", `#${name}`);
  if (name === "sessions") loadSessions();
  if (name === "senses") loadSenses();
}

function setupTabs() {
  const list = $(".tabs");
  list.addEventListener("click", (e) => {
    const tab = e.target.closest("[role=tab]");
    if (tab) showTab(tab.id.slice(4));
  });
  list.addEventListener("keydown", (e) => {
    const i = TABS.indexOf(document.activeElement.id.slice(4));
    if (i < 0) return;
    let j = null;
    if (e.key === "ArrowRight") j = (i + 1) % TABS.length;
    else if (e.key === "ArrowLeft") j = (i - 1 + TABS.length) % TABS.length;
    else if (e.key === "Home") j = 0;
    else if (e.key === "End") j = TABS.length - 1;
    if (j !== null) {
      e.preventDefault();
      showTab(TABS[j], { focus: true });
    }
  });
}

// ------------------------------------------------------------------------------ health, caps
async function loadHealth() {
  const el = $("#health");
  try {
    const res = await fetch("/health");
    const hl = await res.json();
    const space = hl.space || {};
    const parts = [
      `space ${space.name || "?"}${space.dim ? ` (${space.dim}-d)` : ""}`,
      `senses: ${(hl.senses || []).join(", ") || "none"}`,
    ];
    if (!hl.touch) parts.push(`touch off: ${hl.touch_unavailable || "no touch sense"}`);
    setStatus(el, parts.join(" · "), "ok");
  } catch (err) {
    setStatus(el, `server unreachable: ${err.message}`, "error");
  }
}

async function detectCaps() {
  // What the server supports, read from its own OpenAPI schema (degrade gracefully).
  try {
    const spec = await (await fetch("/openapi.json")).json();
    const paths = spec.paths || {};
    const params = ((paths["/search"] || {}).get || {}).parameters || [];
    if (paths["/moments"]?.get) state.caps.group = "/moments";
    else if (params.some((p) => p.name === "group")) state.caps.group = "/search?group=moment";
    state.caps.timeline = Boolean(paths["/sessions/{session}/timeline"]);
    const itemsGet = (paths["/items"] || {}).get;
    state.caps.itemsList = Boolean(
      itemsGet && (itemsGet.parameters || []).some((p) => p.name === "session"),
    );
  } catch {
    /* keep the defaults: plain search, timeline from a filtered search */
  }
  const group = $("#f-group");
  group.disabled = !state.caps.group;
  $("#group-note").hidden = state.caps.group;
  if (state.caps.group) {
    group.checked = true;
    group.title = `uses ${state.caps.group}`;
  }
}

// ------------------------------------------------------------------------------ senses
async function loadSenses() {
  const status = $("#senses-status");
  try {
    const { senses } = await api("/senses");
    state.senses = senses;
    state.touchSenses = new Set(senses.filter((s) => s.modality === "touch").map((s) => s.name));
    renderSenseFilter();
    renderSenses();
    setStatus(status, `${senses.length} sense${senses.length === 1 ? "" : "s"} registered.`);
  } catch (err) {
    setStatus(status, `Could not load senses: ${err.message}`, "error");
    const fs = $("#sense-filter");
    fs.replaceChildren(h("legend", {}, "Senses"), h("span", { class: "error" }, err.message));
  }
}

function renderSenseFilter() {
  const fs = $("#sense-filter");
  const previous = new Map(
    [...fs.querySelectorAll("input[type=checkbox]")].map((c) => [c.value, c.checked]),
  );
  fs.replaceChildren(h("legend", {}, "Senses"));
  for (const s of state.senses) {
    const id = `sense-${cssIdent(s.name)}`;
    const box = h("input", { type: "checkbox", id, name: "sense", value: s.name });
    box.checked = previous.has(s.name) ? previous.get(s.name) : true;
    fs.append(
      h(
        "span",
        { class: "sense-check" },
        box,
        h("label", { for: id }, s.name, h("span", { class: "muted" }, ` (${s.rows})`)),
      ),
    );
  }
  if (!state.senses.length) fs.append(h("span", { class: "muted" }, "none yet"));
}

// {a: {b: 1}, c: ""} -> [["a.b", "1"], ["c", "—"]]
function flatEntries(obj, prefix = "") {
  return Object.entries(obj || {}).flatMap(([k, v]) =>
    v && typeof v === "object" && !Array.isArray(v)
      ? flatEntries(v, `${prefix}${k}.`)
      : [[`${prefix}${k}`, v === "" || v === null ? "—" : fmtValue(v)]],
  );
}

function renderSenses() {
  const list = $("#senses-list");
  list.replaceChildren();
  for (const s of state.senses) {
    const prov = flatEntries(s.provenance);
    list.append(
      h(
        "article",
        { class: "sense-card" },
        h("h3", {}, senseBadge(s.name), " ", s.modality),
        defList("meta", [
          ["dimension", s.dim],
          ["stored items", s.rows],
          ["live", s.live ? "yes: can embed new items" : "no: known from the store only"],
          Array.isArray(s.shape) ? ["frame shape", `${s.shape[0]} × ${s.shape[1]} taxels`] : null,
          s.classes && s.classes.length ? ["recognises", s.classes.join(", ")] : null,
          s.taught && s.taught.length ? ["taught", s.taught.join(", ")] : null,
          s.mu !== null && s.mu !== undefined
            ? ["score calibration", `μ ${s.mu.toFixed(3)}, σ ${s.sigma.toFixed(3)}`]
            : null,
        ]),
        h("h4", {}, "Provenance"),
        prov.length ? defList("meta provenance", prov) : h("p", { class: "muted" }, "none recorded"),
      ),
    );
  }
}

// ------------------------------------------------------------------------------ search
function readFilters() {
  const out = {};
  const session = $("#f-session").value.trim();
  if (session) out.session = session;
  const after = $("#f-after").value;
  if (after !== "") out.after = Number(after);
  const before = $("#f-before").value;
  if (before !== "") out.before = Number(before);
  const k = Number($("#f-k").value) || 10;
  out.k = Math.min(Math.max(Math.round(k), 1), 1000);
  const boxes = [...document.querySelectorAll("#sense-filter input[type=checkbox]")];
  const chosen = boxes.filter((b) => b.checked).map((b) => b.value);
  out.senses = chosen.length === boxes.length ? null : chosen; // null: every sense
  return out;
}

async function onSearch(e) {
  e.preventDefault();
  const status = $("#search-status");
  const q = $("#q").value.trim();
  if (!q) {
    setStatus(status, "Type what you are looking for.", "error");
    $("#q").focus();
    return;
  }
  const f = readFilters();
  if (f.senses && !f.senses.length) {
    setStatus(status, "Choose at least one sense.", "error");
    return;
  }
  const params = new URLSearchParams({ q, k: String(f.k) });
  for (const s of f.senses || []) params.append("sense", s);
  if (f.session) params.set("session", f.session);
  if (f.after !== undefined) params.set("after", String(f.after));
  if (f.before !== undefined) params.set("before", String(f.before));
  const grouped = Boolean(state.caps.group) && $("#f-group").checked;
  let path = "/search";
  if (grouped && state.caps.group === "/moments") path = "/moments";
  else if (grouped) params.set("group", "moment");
  // touch answers are grasps by default (group=auto); single windows are one box away
  if (!grouped && $("#f-windows").checked) params.set("group", "window");
  setStatus(status, "Searching…", "busy");
  $("#results").setAttribute("aria-busy", "true");
  try {
    const res = await api(`${path}?${params}`);
    renderResults(res, `“${q}”`);
    const shown = Array.isArray(res.moments) ? res.moments.flatMap((m) => m.hits || []) : res.hits || [];
    await noteHiddenTouch(shown, params, grouped);
  } catch (err) {
    $("#results").replaceChildren();
    setStatus(status, `Search failed: ${err.message}`, "error");
  } finally {
    $("#results").removeAttribute("aria-busy");
  }
}

function renderResults(res, what) {
  const list = $("#results");
  const status = $("#search-status");
  list.replaceChildren();
  const moments = Array.isArray(res.moments) ? res.moments : null;
  if (moments) {
    moments.forEach((m, i) => list.append(momentCard(m, i + 1)));
    const n = moments.length;
    const none = `No moment clears the match bar for ${what}; untick “Group into moments” to see the nearest hits.`;
    setStatus(status, n ? `${n} moment${n === 1 ? "" : "s"} for ${what}.` : none);
    return;
  }
  const hits = res.hits || [];
  hits.forEach((hit, i) => list.append(hitCard(hit, i + 1)));
  const n = hits.length;
  const matching = hits.filter((x) => x.match).length;
  const bar = n && hits.some((x) => typeof x.bar === "number") ? `; ${matching} clear the match bar` : "";
  setStatus(status, n ? `${n} hit${n === 1 ? "" : "s"} for ${what}, best first${bar}.` : `Nothing found for ${what}.`);
}

// Say when grouping or the match bar hides touch: the shown results hold no touch window that
// matches, yet touch windows exist in scope. `shown`: the hits on the page (moment members
// included); `params`: the search's own parameters (query, scope).
async function noteHiddenTouch(shown, params, grouped) {
  const note = $("#touch-note");
  note.hidden = true;
  note.textContent = "";
  const touch = state.senses.filter((s) => state.touchSenses.has(s.name) && s.rows > 0).map((s) => s.name);
  const chosen = params.getAll("sense");
  const inScope = touch.filter((name) => !chosen.length || chosen.includes(name));
  if (!inScope.length || shown.some((x) => isTouch(x) && x.match)) return;
  const probe = new URLSearchParams(params);
  probe.delete("sense");
  probe.delete("group");
  probe.delete("gap");
  probe.set("k", "3");
  for (const name of inScope) probe.append("sense", name);
  let nearest;
  try {
    nearest = (await api(`/search?${probe}`)).hits || [];
  } catch {
    return; // the note is a hint; the search itself already answered
  }
  if (!nearest.length) return;
  const best = nearest[0];
  const score = `the nearest touch window scores ${best.score.toFixed(2)}`;
  const bar = typeof best.bar === "number" ? ` (match bar ${best.bar.toFixed(2)})` : "";
  const why = best.match
    ? grouped
      ? "grouping into moments left it out of the moments shown; untick “Group into moments” to list it"
      : "it ranks below the hits shown; raise Results or choose the touch sense to list it"
    : grouped
      ? "below the match bar, so no moment shows it; untick “Group into moments” to see it"
      : shown.some(isTouch)
        ? "the touch hits listed are below the match bar"
        : "below the match bar and below the hits shown; choose the touch sense to list it";
  note.textContent = `Touch: ${score}${bar}: ${why}.`;
  note.hidden = false;
}

function hitCard(hit, rank, inMoment = false) {
  const body = [];
  if (hit.text) body.push(h("p", { class: "hit-text" }, hit.text));
  if (isTouch(hit)) body.push(heatmap(hit.id, touchLabel(hit)), facetsList(hit.facets));
  if (isImage(hit)) body.push(thumbnail(hit.id, imageLabel(hit)));
  body.push(metaList(hit.meta));
  const cls = hit.match === false ? "hit nomatch" : "hit";
  return h(
    "li",
    { class: cls, dataset: { id: hit.id, sense: hit.sense } },
    h(
      "div",
      { class: "hit-head" },
      h("span", { class: "rank", "aria-label": `rank ${rank}` }, `#${rank}`),
      senseBadge(hit.sense),
      h(
        "span",
        { class: "score", title: hit.cosine != null ? `cosine ${hit.cosine.toFixed(3)}` : "" },
        `score ${Number(hit.score).toFixed(2)}`,
      ),
      typeof hit.bar === "number"
        ? h(
            "span",
            {
              class: hit.match ? "bar bar-match" : "bar",
              title: "the score this sense needed to match this query (last/first/count use the same bar)",
            },
            hit.match ? `match (bar ${hit.bar.toFixed(2)})` : `bar ${hit.bar.toFixed(2)}`,
          )
        : null,
      h(
        "button",
        {
          type: "button",
          class: "link session-link",
          onclick: () => openSession(hit.session, hit.id),
          title: `Open the timeline of session ${hit.session} at this item`,
        },
        inMoment ? "show in timeline" : `session ${hit.session}`,
      ),
      typeof hit.n === "number"
        ? h(
            "span",
            { class: "grasp", title: "a grasp: the contiguous windows of one hold, scored together" },
            `grasp of ${hit.n} window${hit.n === 1 ? "" : "s"}`,
          )
        : null,
      h("span", { class: "time" }, fmtSpan(hit.t, hit.t_end)),
    ),
    body,
  );
}

function momentCard(m, rank) {
  const members = m.hits || m.items || m.members || m.evidence || [];
  const sessions = m.session || [...new Set(members.map((x) => x.session))].join(", ");
  const t = m.t ?? (members.length ? Math.min(...members.map((x) => x.t)) : undefined);
  const tEnd = m.t_end ?? (members.length ? Math.max(...members.map((x) => x.t_end ?? x.t)) : undefined);
  const score = m.score ?? (members.length ? Math.max(...members.map((x) => x.score)) : NaN);
  const senses = [...new Set(members.map((x) => x.sense))];
  const matched = members.some((x) => x.match);
  return h(
    "li",
    { class: matched ? "hit moment" : "hit moment nomatch", dataset: { session: sessions } },
    h(
      "div",
      { class: "hit-head" },
      h("span", { class: "rank", "aria-label": `rank ${rank}` }, `#${rank}`),
      h("span", { class: "badge badge-moment" }, "moment"),
      senses.map(senseBadge),
      h("span", { class: "score" }, `score ${Number(score).toFixed(2)}`),
      typeof m.session === "string"
        ? h(
            "button",
            { type: "button", class: "link session-link", onclick: () => openSession(m.session) },
            `session ${m.session}`,
          )
        : h("span", {}, `session ${sessions}`),
      h("span", { class: "time" }, fmtSpan(t, tEnd)),
    ),
    h("ol", { class: "members" }, members.map((x, i) => hitCard(x, `${rank}.${i + 1}`, true))),
  );
}

// ------------------------------------------------------------------------------ by example
function f16(bits) {
  const s = bits & 0x8000 ? -1 : 1;
  const e = (bits >> 10) & 0x1f;
  const f = bits & 0x3ff;
  if (e === 0) return s * 2 ** -14 * (f / 1024);
  if (e === 31) return f ? NaN : s * Infinity;
  return s * 2 ** (e - 15) * (1 + f / 1024);
}

// Parse a NumPy .npy file (format versions 1-3; numeric dtypes) into {shape, data: number[]}.
export function parseNpy(buffer) {
  const bytes = new Uint8Array(buffer);
  const magic = [0x93, 0x4e, 0x55, 0x4d, 0x50, 0x59];
  if (bytes.length < 10 || magic.some((b, i) => bytes[i] !== b)) throw new Error("not an .npy file");
  const dv = new DataView(buffer);
  const major = bytes[6];
  const headerLen = major === 1 ? dv.getUint16(8, true) : dv.getUint32(8, true);
  const start = major === 1 ? 10 : 12;
  const header = new TextDecoder(major === 3 ? "utf-8" : "latin1").decode(
    bytes.subarray(start, start + headerLen),
  );
  const descr = /'descr':\s*'([^']+)'/.exec(header)?.[1];
  const fortran = /'fortran_order':\s*True/.test(header);
  const shapeText = /'shape':\s*\(([^)]*)\)/.exec(header)?.[1];
  if (!descr || shapeText === undefined) throw new Error("unreadable .npy header");
  const shape = shapeText.split(",").map((s) => s.trim()).filter(Boolean).map(Number);
  const little = descr[0] !== ">";
  const kind = descr.slice(1);
  const readers = {
    f2: [2, (o) => f16(dv.getUint16(o, little))],
    f4: [4, (o) => dv.getFloat32(o, little)],
    f8: [8, (o) => dv.getFloat64(o, little)],
    i1: [1, (o) => dv.getInt8(o)],
    u1: [1, (o) => dv.getUint8(o)],
    b1: [1, (o) => dv.getUint8(o)],
    i2: [2, (o) => dv.getInt16(o, little)],
    u2: [2, (o) => dv.getUint16(o, little)],
    i4: [4, (o) => dv.getInt32(o, little)],
    u4: [4, (o) => dv.getUint32(o, little)],
    i8: [8, (o) => Number(dv.getBigInt64(o, little))],
    u8: [8, (o) => Number(dv.getBigUint64(o, little))],
  };
  if (!readers[kind]) throw new Error(`unsupported .npy dtype ${descr}`);
  const [size, read] = readers[kind];
  const n = shape.reduce((a, b) => a * b, 1);
  const offset = start + headerLen;
  if (offset + n * size > bytes.length) throw new Error(".npy file is truncated");
  const flat = new Array(n);
  for (let i = 0; i < n; i++) flat[i] = read(offset + i * size);
  if (!fortran || shape.length < 2) return { shape, data: flat };
  // Fortran order: reorder to C order.
  const data = new Array(n);
  const cStrides = shape.map((_, i) => shape.slice(i + 1).reduce((a, b) => a * b, 1));
  const fStrides = shape.map((_, i) => shape.slice(0, i).reduce((a, b) => a * b, 1));
  for (let c = 0; c < n; c++) {
    let rem = c;
    let f = 0;
    for (let d = 0; d < shape.length; d++) {
      const idx = Math.floor(rem / cStrides[d]);
      rem %= cStrides[d];
      f += idx * fStrides[d];
    }
    data[c] = flat[f];
  }
  return { shape, data };
}

function nest(data, shape) {
  if (shape.length === 1) return data.slice(0, shape[0]);
  const step = shape.slice(1).reduce((a, b) => a * b, 1);
  const out = [];
  for (let i = 0; i < shape[0]; i++) out.push(nest(data.slice(i * step, (i + 1) * step), shape.slice(1)));
  return out;
}

function shapeOf(arr) {
  const shape = [];
  let x = arr;
  while (Array.isArray(x)) {
    shape.push(x.length);
    x = x[0];
  }
  return shape;
}

// -> {frames: K x H x W nested arrays, calibrated: bool|null}; H x W must be the frame shape
// of a touch sense of this memory (GET /senses: shape), which touchSenseFor picks
export async function readWindowFile(file) {
  let frames;
  let calibrated = null;
  if (/\.npy$/i.test(file.name)) {
    const { shape, data } = parseNpy(await file.arrayBuffer());
    frames = nest(data, shape);
  } else {
    let obj;
    try {
      obj = JSON.parse(await file.text());
    } catch (err) {
      throw new Error(`not valid JSON: ${err.message}`);
    }
    if (obj && !Array.isArray(obj)) {
      calibrated = typeof obj.calibrated === "boolean" ? obj.calibrated : null;
      obj = obj.frames ?? obj.window ?? obj.windows;
    }
    frames = obj;
  }
  let shape = shapeOf(frames);
  if (shape.length === 4 && shape[0] === 1) {
    frames = frames[0];
    shape = shape.slice(1);
  }
  if (shape.length === 2) {
    frames = [frames];
    shape = [1, ...shape];
  }
  if (shape.length !== 3 || shape[0] < 1 || shape[1] < 1 || shape[2] < 1) {
    throw new Error(`a touch window must have shape K×H×W; this file has ${shape.join("×") || "no array"}`);
  }
  if (shape[0] > 512) throw new Error(`at most 512 frames per window; this file has ${shape[0]}`);
  return { frames, calibrated };
}

async function onLike(e) {
  e.preventDefault();
  const status = $("#search-status");
  const file = $("#like-file").files[0];
  if (!file) {
    setStatus(status, "Choose a .npy or .json touch window first.", "error");
    $("#like-file").focus();
    return;
  }
  if (file.type.startsWith("image/")) {
    await likeImage(file, status);
    return;
  }
  setStatus(status, `Reading ${file.name}…`, "busy");
  try {
    const { frames, calibrated: fileCalibrated } = await readWindowFile(file);
    const sense = touchSenseFor(shapeOf(frames).slice(1));
    const calibrated = $("#like-calibrated").checked || fileCalibrated === true;
    showLikePreview(frames, calibrated, file.name, sense);
    const f = readFilters();
    const body = { sense, frames, calibrated, k: f.k };
    if (f.session) body.session = f.session;
    if (f.after !== undefined) body.after = f.after;
    if (f.before !== undefined) body.before = f.before;
    setStatus(status, "Searching by example…", "busy");
    const res = await api("/search/like", { method: "POST", body });
    renderResults(res, `the example ${file.name} (${frames.length} frame${frames.length === 1 ? "" : "s"})`);
  } catch (err) {
    $("#results").replaceChildren();
    setStatus(status, `Search by example failed: ${err.message}`, "error");
  }
}

// Search by an example image (PNG/JPEG/WebP): POST /search/like/image, image -> image.
async function likeImage(file, status) {
  const fig = $("#like-preview");
  const img = $("img", fig);
  img.src = URL.createObjectURL(file);
  img.alt = `Your example image ${file.name}`;
  $("figcaption", fig).textContent = `Your example: ${file.name}`;
  fig.hidden = false;
  const f = readFilters();
  const form = new FormData();
  form.append("file", file);
  form.append("k", String(f.k));
  if (f.session) form.append("session", f.session);
  if (f.after !== undefined) form.append("after", String(f.after));
  if (f.before !== undefined) form.append("before", String(f.before));
  setStatus(status, "Searching by example image…", "busy");
  try {
    const res = await api("/search/like/image", { method: "POST", body: form });
    renderResults(res, `the image ${file.name}`);
  } catch (err) {
    $("#results").replaceChildren();
    setStatus(status, `Search by image failed: ${err.message}`, "error");
  }
}

// The touch sense whose frames are H x W (the glove's "touch" first when it fits): each touch
// sense reads its own sensor's shape (GET /senses: shape). None fits: an error naming them.
export function touchSenseFor([rows, cols], senses = state.senses) {
  const touch = senses.filter((s) => s.modality === "touch" && Array.isArray(s.shape));
  const fits = touch.filter((s) => s.shape[0] === rows && s.shape[1] === cols);
  const pick = fits.find((s) => s.name === "touch") || fits[0];
  if (pick) return pick.name;
  if (!touch.length) return "touch"; // senses not loaded yet: the server names the problem
  const known = touch.map((s) => `${s.name} ${s.shape[0]}×${s.shape[1]}`).join(", ");
  throw new Error(`no touch sense reads ${rows}×${cols} frames (touch senses here: ${known})`);
}

async function showLikePreview(frames, calibrated, name, sense) {
  const fig = $("#like-preview");
  try {
    const res = await api(`/render/touch.png?${HEATMAP_QUERY}`, {
      method: "POST",
      body: { frames, calibrated, sense },
      raw: true,
    });
    const img = $("img", fig);
    img.src = URL.createObjectURL(await res.blob());
    img.alt = `Pressure heat map of the example ${name}`;
    $("figcaption", fig).textContent = `Your example: ${name}, ${frames.length} frame(s)`;
    fig.hidden = false;
  } catch {
    fig.hidden = true; // the preview is a nicety; the search still runs
  }
}

// ------------------------------------------------------------------------------ sessions
async function loadSessions() {
  const status = $("#sessions-status");
  try {
    const { sessions } = await api("/sessions");
    state.sessions = sessions;
    $("#session-ids").replaceChildren(...sessions.map((s) => h("option", { value: s.id })));
    renderSessionList();
    const searchStatus = $("#search-status");
    if (!sessions.length && !searchStatus.textContent) {
      setStatus(
        searchStatus,
        "This memory is empty. Store notes, touch windows, images or vectors through the API " +
          "(see API documentation below), then search them here.",
      );
    }
    setStatus(status, sessions.length ? `${sessions.length} session${sessions.length === 1 ? "" : "s"}.` : "No sessions stored yet.");
  } catch (err) {
    setStatus(status, `Could not load sessions: ${err.message}`, "error");
  }
}

function renderSessionList() {
  const list = $("#session-list");
  const current = list.dataset.current;
  list.replaceChildren(
    ...state.sessions.map((s) =>
      h(
        "li",
        {},
        h(
          "button",
          {
            type: "button",
            class: "session-button",
            "aria-pressed": String(s.id === current),
            dataset: { session: s.id },
            onclick: () => openSession(s.id),
          },
          h("strong", {}, s.id),
          h("span", { class: "muted" }, `${s.n} items · ${fmtSpan(s.t_min, s.t_max)}`),
          h(
            "span",
            { class: "counts" },
            Object.entries(s.counts).map(([name, n]) => h("span", { class: "count" }, senseBadge(name), ` ${n}`)),
          ),
        ),
      ),
    ),
  );
}

function normalisePoints(res, session) {
  let pts = res;
  if (!Array.isArray(pts)) {
    pts = res.items || res.points || res.events || res.hits || res.timeline || null;
    if (!pts && res.lanes && typeof res.lanes === "object") {
      pts = Array.isArray(res.lanes)
        ? res.lanes.flatMap((l) => (l.items || l.points || []).map((p) => ({ sense: l.sense, ...p })))
        : Object.entries(res.lanes).flatMap(([sense, list]) => list.map((p) => ({ sense, ...p })));
    }
    if (!pts && res.senses && typeof res.senses === "object" && !Array.isArray(res.senses)) {
      pts = Object.entries(res.senses).flatMap(([sense, list]) =>
        Array.isArray(list) ? list.map((p) => ({ sense, ...p })) : [],
      );
    }
  }
  return (pts || [])
    .filter((p) => p && typeof p.t === "number")
    .map((p) => ({
      session,
      ...p,
      // the session clock when the server aligns streams (t_aligned), else the stored t
      t: p.t_aligned ?? p.t,
      t_end: p.t_end_aligned ?? p.t_end ?? p.t,
      t_stored: p.t,
    }))
    .sort((a, b) => a.t - b.t);
}

const MAX_POINTS = 5000; // drawn per timeline; the status line says when a session has more

async function fetchTimeline(id) {
  const summary = state.sessions.find((s) => s.id === id);
  const n = summary ? summary.n : 1000;
  if (state.caps.timeline) {
    const limit = String(Math.min(Math.max(n, 1), MAX_POINTS));
    const res = await api(`/sessions/${encodeURIComponent(id)}/timeline?limit=${limit}`);
    return { points: normalisePoints(res, id), source: `GET /sessions/${id}/timeline`, n };
  }
  const k = Math.min(Math.max(n, 1), 1000);
  if (state.caps.itemsList) {
    const res = await api(`/items?${new URLSearchParams({ session: id, k: String(k) })}`);
    return { points: normalisePoints(res, id), source: "GET /items?session=", n };
  }
  // Fallback: every item of the session through a session-filtered search (any query
  // matches everything when k covers the session), sorted by time.
  const params = new URLSearchParams({ q: "moment", k: String(k), session: id });
  const res = await api(`/search?${params}`);
  // The filler query's scores mean nothing here: drop them.
  const points = normalisePoints(res, id).map(({ score, cosine, ...p }) => p);
  return {
    points,
    source: "a session-filtered search (this server has no timeline route)",
    n,
  };
}

export async function openSession(id, focusItem = null) {
  showTab("sessions", { push: false });
  history.replaceState(null, "", `#sessions/${encodeURIComponent(id)}`);
  const list = $("#session-list");
  list.dataset.current = id;
  if (!state.sessions.length) await loadSessions();
  for (const b of list.querySelectorAll(".session-button")) {
    b.setAttribute("aria-pressed", String(b.dataset.session === id));
  }
  const status = $("#timeline-status");
  $("#timeline-title").textContent = `Timeline of ${id}`;
  setStatus(status, "Loading timeline…", "busy");
  $("#evidence").hidden = true;
  try {
    const { points, source, n } = await fetchTimeline(id);
    state.timelinePoints = points;
    renderTimeline(points);
    const shown = points.length < n ? `${points.length} of ${n}` : `${points.length}`;
    setStatus(status, `${shown} items, from ${source}. Use the arrow keys to move between points.`);
    const target = focusItem && $(`#timeline .point[data-id="${CSS.escape(focusItem)}"]`);
    if (target) {
      selectPoint(target, { focus: true });
    }
  } catch (err) {
    $("#timeline").replaceChildren();
    setStatus(status, `Could not load the timeline: ${err.message}`, "error");
  }
  await loadMap(id);
}

// ------------------------------------------------------------------------------ the map
// The session's trajectory seen from above, with the hits of a search in that session.
async function loadMap(id) {
  const panel = $("#map-panel");
  const status = $("#map-status");
  state.map = { session: id, trajectory: null };
  $("#map").replaceChildren();
  $("#map-hits").replaceChildren();
  panel.hidden = false;
  let res;
  try {
    res = await api(`/sessions/${encodeURIComponent(id)}/poses`);
  } catch (err) {
    setStatus(status, err.status === 404 ? "This server has no poses route." : `Could not load the poses: ${err.message}`, "error");
    $("#map-form").hidden = true;
    return;
  }
  const trajectory = pickTrajectory(res.trajectories || []);
  $("#map-form").hidden = !trajectory;
  if (!trajectory) {
    setStatus(status, "No poses for this session: nothing to draw (POST /sessions/{id}/poses, or ingest an odometry topic).");
    return;
  }
  state.map.trajectory = trajectory;
  drawMap($("#map"), trajectory, [], null);
  const others = (res.trajectories || []).length - 1;
  setStatus(status, `${trajectory.position.length} poses in frame ${trajectory.frame}` + (others ? ` (${others} more frames not drawn)` : "") + ". Ask where something happened.");
}

async function onMapSearch(e) {
  e.preventDefault();
  const { session, trajectory } = state.map || {};
  const q = $("#map-q").value.trim();
  if (!session || !trajectory || !q) return;
  const status = $("#map-status");
  setStatus(status, "Searching…", "busy");
  try {
    const res = await api(`/search?${new URLSearchParams({ q, session, k: "10" })}`);
    const hits = res.hits || [];
    const { drawn, elsewhere } = drawMap($("#map"), trajectory, hits, (itemId) => {
      const btn = $(`#timeline .point[data-id="${CSS.escape(itemId)}"]`);
      if (btn) selectPoint(btn, { focus: true });
    });
    $("#map-hits").replaceChildren(
      ...hits.map((hit, i) => h("li", { dataset: { id: hit.id } },
        `#${i + 1} ${hit.sense}${hit.text ? `: ${hit.text}` : ""} — `,
        hit.position ? `at (${hit.position.map((v) => v.toFixed(2)).join(", ")}) in ${hit.frame}` : "no place",
      )),
    );
    setStatus(status, `${drawn} of ${hits.length} hits for “${q}” on the map` + (elsewhere ? ` (${elsewhere} without a place in frame ${trajectory.frame})` : "") + ".");
  } catch (err) {
    setStatus(status, `Search failed: ${err.message}`, "error");
  }
}

function renderTimeline(points) {
  const root = $("#timeline");
  root.replaceChildren();
  if (!points.length) return;
  const t0 = Math.min(...points.map((p) => p.t));
  const t1 = Math.max(...points.map((p) => p.t_end));
  const span = t1 - t0 || 1;
  const pct = (t) => ((t - t0) / span) * 100;
  const senses = [...new Set(points.map((p) => p.sense))].sort();
  root.append(
    h(
      "div",
      { class: "axis", "aria-hidden": "true" },
      h("span", { class: "lane-label" }),
      h(
        "div",
        { class: "ticks" },
        [0, 0.25, 0.5, 0.75, 1].map((f) =>
          h("span", { class: "tick", style: { left: `${f * 100}%` } }, fmtT(t0 + f * span)),
        ),
      ),
    ),
  );
  let first = true;
  for (const sense of senses) {
    const lanePts = points.filter((p) => p.sense === sense);
    const track = h("div", { class: "track", role: "group", "aria-label": `${sense}: ${lanePts.length} items` });
    for (const p of lanePts) {
      const width = Math.max(pct(p.t_end) - pct(p.t), 0);
      const btn = h(
        "button",
        {
          type: "button",
          class: `point point-${cssIdent(state.senses.find((s) => s.name === sense)?.modality || sense)}`,
          dataset: { id: p.id, sense },
          tabindex: first ? "0" : "-1",
          "aria-label": `${sense} at ${fmtSpan(p.t, p.t_end)}${p.text ? `: ${p.text}` : ""}`,
          title: `${sense} · ${fmtSpan(p.t, p.t_end)}${p.text ? ` · ${p.text}` : ""}`,
          style: { left: `${pct(p.t)}%`, width: `max(${width}%, 0.75rem)` },
          onclick: (e) => selectPoint(e.currentTarget),
        },
      );
      first = false;
      track.append(btn);
    }
    root.append(h("div", { class: "lane" }, h("span", { class: "lane-label" }, senseBadge(sense)), track));
    const strip = forceStrip(sense, lanePts, pct);
    if (strip) root.append(strip);
  }
  root.onkeydown = onTimelineKey;
}

// Touch facets on the timeline (tactus_memory/touch/facets.py): a strip under a touch lane
// drawing each window's force (the sum of its calibrated taxels, averaged over its frames)
// at the middle of its span, scaled to the lane's firmest; null when no item has a force.
// The strip's SVG is parsed from fixed markup: the HTML parser puts it in the SVG namespace, so
// the page names no origin (not even the namespace's), as tests/service/test_browser.py checks.
const FORCE_SVG =
  '<svg viewBox="0 0 100 24" preserveAspectRatio="none"><polyline vector-effect="non-scaling-stroke"></polyline></svg>';
function forceStrip(sense, lanePts, pct) {
  const pts = lanePts.filter((p) => typeof p.facets?.force === "number");
  if (!pts.length) return null;
  const top = Math.max(...pts.map((p) => p.facets.force)) || 1;
  const holder = document.createElement("div");
  holder.innerHTML = FORCE_SVG;
  const svg = holder.firstElementChild;
  const xy = pts.map((p) => `${((pct(p.t) + pct(p.t_end)) / 2).toFixed(3)},${(23 - (22 * p.facets.force) / top).toFixed(3)}`);
  svg.querySelector("polyline").setAttribute("points", xy.join(" "));
  const lo = Math.min(...pts.map((p) => p.facets.force));
  const label = `${sense} force over time: ${pts.length} windows, ${lo.toFixed(1)} to ${top.toFixed(1)}`;
  return h(
    "div",
    { class: "lane force-lane" },
    h("span", { class: "lane-label muted" }, "force"),
    h("div", { class: "force-strip", role: "img", "aria-label": label, title: label, dataset: { sense } }, svg),
  );
}

function onTimelineKey(e) {
  const cur = e.target.closest(".point");
  if (!cur) return;
  const lanes = [...$("#timeline").querySelectorAll(".track")];
  const lane = cur.parentElement;
  const inLane = [...lane.querySelectorAll(".point")];
  const i = inLane.indexOf(cur);
  let next = null;
  if (e.key === "ArrowRight") next = inLane[i + 1];
  else if (e.key === "ArrowLeft") next = inLane[i - 1];
  else if (e.key === "Home") next = inLane[0];
  else if (e.key === "End") next = inLane[inLane.length - 1];
  else if (e.key === "ArrowDown" || e.key === "ArrowUp") {
    const li = lanes.indexOf(lane) + (e.key === "ArrowDown" ? 1 : -1);
    const other = lanes[li];
    if (other) {
      const t = Number.parseFloat(cur.style.left);
      next = [...other.querySelectorAll(".point")].reduce((best, p) =>
        Math.abs(Number.parseFloat(p.style.left) - t) < Math.abs(Number.parseFloat(best.style.left) - t) ? p : best,
      );
    }
  }
  if (next) {
    e.preventDefault();
    for (const p of $("#timeline").querySelectorAll(".point")) p.tabIndex = -1;
    next.tabIndex = 0;
    next.focus();
  }
}

function selectPoint(btn, { focus = false } = {}) {
  for (const p of $("#timeline").querySelectorAll(".point")) {
    p.tabIndex = p === btn ? 0 : -1;
    p.classList.toggle("selected", p === btn);
    p.setAttribute("aria-pressed", String(p === btn));
  }
  if (focus) btn.focus();
  const point = state.timelinePoints.find((p) => p.id === btn.dataset.id);
  if (point) showEvidence(point);
}

function showEvidence(p) {
  const info = state.senses.find((s) => s.name === p.sense);
  const prov = info ? Object.entries(info.provenance || {}) : [];
  const body = $("#evidence-body");
  body.replaceChildren(
    h(
      "div",
      { class: "hit-head" },
      senseBadge(p.sense),
      h("span", { class: "time" }, fmtSpan(p.t, p.t_end)),
      typeof p.score === "number" ? h("span", { class: "score" }, `score ${p.score.toFixed(2)}`) : null,
    ),
    p.text ? h("blockquote", { class: "hit-text" }, p.text) : "",
    isTouch(p) ? heatmap(p.id, touchLabel(p)) : "",
    isImage(p) ? thumbnail(p.id, imageLabel(p)) : "",
    defList("meta", [
      ["item", p.id],
      ["session", p.session],
      p.source ? ["source", p.source] : null,
      p.position ? ["place", `(${p.position.map((v) => v.toFixed(2)).join(", ")}) in ${p.frame}`] : null,
      p.t_stored !== undefined && p.t_stored !== p.t ? ["stored t", fmtT(p.t_stored)] : null,
      ...metaEntries(p.meta),
      prov.length ? ["encoder", prov.map(([k, v]) => `${k}: ${fmtValue(v)}`).join("; ")] : null,
    ]),
  );
  $("#evidence-title").textContent = `Evidence: ${p.sense} at ${fmtSpan(p.t, p.t_end)}`;
  $("#evidence").hidden = false;
}

// ------------------------------------------------------------------------------ start
function setupToken() {
  $("#token").value = state.token;
  if (state.token) $(".token summary").textContent = "Access token (set)";
  $("#token-form").addEventListener("submit", (e) => {
    e.preventDefault();
    state.token = $("#token").value.trim();
    if (state.token) sessionStorage.setItem("tactus-token", state.token);
    else sessionStorage.removeItem("tactus-token");
    $(".token").open = false;
    $(".token summary").textContent = state.token ? "Access token (set)" : "Access token";
    refresh();
  });
}

async function refresh() {
  await Promise.all([loadHealth(), loadSenses(), loadSessions(), detectCaps()]);
}

async function start() {
  setupTabs();
  setupToken();
  $("#search-form").addEventListener("submit", onSearch);
  $("#like-form").addEventListener("submit", onLike);
  $("#map-form").addEventListener("submit", onMapSearch);
  await refresh();
  route();
  window.addEventListener("hashchange", route); // links like #sessions/<id> work in place
  document.body.dataset.ready = "true";
}

// #search, #sessions, #senses, #sessions/<session id>
function route() {
  const hash = decodeURIComponent(location.hash.slice(1));
  if (hash.startsWith("sessions/")) openSession(hash.slice("sessions/".length));
  else if (TABS.includes(hash)) showTab(hash, { push: false });
}

start();
