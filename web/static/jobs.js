// The job page: upload a scan, watch the jobs, open results in the viewer. Plain JavaScript,
// no build step. Every call goes to the /v1 API with the saved API key (if any) as a Bearer
// token; user-supplied text (file names, errors) is only ever set as textContent.
//
// Each status line says one thing and is cleared when that stops being true: #list-status is the
// job list's (cleared by the next successful refresh), #action-status a download's or delete's
// (replaced by the next action), #upload-status the last upload's (cleared once its job has
// left the queue, or when another file is picked), #key-status the key's (its 401 note cleared
// once the list loads).
"use strict";

const KEY_STORAGE = "jointseg.apiKey";
const POLL_MS = 1500;
const $ = (id) => document.getElementById(id);
const rows = new Map(); // job id -> <tr>
let viewerPort = 8080;
let queuedJob = null; // the job #upload-status says is queued, until it leaves the queue

function note(id, text, isError = false) {
  $(id).textContent = text;
  $(id).className = isError ? "note error" : "note";
}

function apiKey() {
  return localStorage.getItem(KEY_STORAGE) || "";
}

function authHeaders() {
  const key = apiKey();
  return key ? { Authorization: `Bearer ${key}` } : {};
}

async function api(path, options = {}) {
  const response = await fetch(path, {
    ...options,
    headers: { ...authHeaders(), ...(options.headers || {}) },
  });
  if (response.status === 401) {
    note("key-status", apiKey() ? "this API key was refused" : "this service needs an API key", true);
  }
  return response;
}

async function errorText(response) {
  try {
    const body = await response.json();
    return body.detail || JSON.stringify(body);
  } catch (_) {
    return `${response.status} ${response.statusText}`;
  }
}

// The viewer's address for one job: its websocket URL names the job, never the key (a link
// shares a view, not a credential: the viewer asks for a key itself, once per sign-in); the
// whole websocket URL is itself percent-encoded in the page URL's `websocket` parameter.
function viewerLink(jobId) {
  const base = `${location.protocol}//${location.hostname}:${viewerPort}`;
  const ws = base.replace(/^http/, "ws") + "/job/" + encodeURIComponent(jobId);
  return `${base}/?websocket=${encodeURIComponent(ws)}`;
}

// ------------------------------------------------------------------ API key
function setupKey() {
  $("api-key").value = apiKey();
  $("save-key").addEventListener("click", () => {
    const key = $("api-key").value.trim();
    if (key) localStorage.setItem(KEY_STORAGE, key);
    else localStorage.removeItem(KEY_STORAGE);
    note("key-status", key ? "saved in this browser" : "no key");
    for (const row of rows.values()) delete row.dataset.actionsFor; // redraw the links
    poll();
    frameFromAddress();
  });
}

// ------------------------------------------------------------------- upload
function setupUpload() {
  $("scan-file").addEventListener("change", () => {
    queuedJob = null;
    note("upload-status", ""); // the last upload's outcome is not about this file
  });
  $("upload-form").addEventListener("submit", (event) => {
    event.preventDefault();
    const file = $("scan-file").files[0];
    if (!file) return;
    const form = new FormData();
    form.append("file", file, file.name);
    form.append("config", JSON.stringify({
      quality: $("quality").value,
      network: { name: $("network").value },
      frame: { up: $("up").value, units: $("units").value },
    }));
    const request = new XMLHttpRequest(); // XHR, not fetch: it reports upload progress
    request.open("POST", "/v1/jobs");
    for (const [name, value] of Object.entries(authHeaders())) request.setRequestHeader(name, value);
    const bar = $("upload-progress");
    bar.hidden = false;
    bar.value = 0;
    $("upload").disabled = true;
    queuedJob = null;
    note("upload-status", `uploading ${file.name}...`);
    request.upload.onprogress = (e) => {
      if (e.lengthComputable) bar.value = e.loaded / e.total;
    };
    request.onloadend = () => {
      bar.hidden = true;
      $("upload").disabled = $("network").options.length === 0;
      let body = {};
      try {
        body = JSON.parse(request.responseText);
      } catch (_) {}
      if (request.status === 201) {
        queuedJob = body.id;
        note("upload-status", `job ${body.id} queued`);
        const network = $("network").value;
        $("upload-form").reset();
        $("network").value = network; // the next scan most likely wants the same network
        poll();
      } else {
        note(
          "upload-status",
          `upload refused (${request.status || "no answer"}): ${body.detail || request.statusText}`,
          true,
        );
      }
    };
    request.send(form);
  });
}

// ---------------------------------------------------------------- downloads
// A finished job's six downloads, each from the API's own route:
// [button, path after the job's, what the file is for].
const DOWNLOADS = [
  ["PLY", "result?format=ply", "the points with every label field"],
  ["LAS", "result?format=las", "the points for survey and CAD software"],
  ["LAZ", "result?format=laz", "the same, compressed"],
  ["report", "report", "timings, scores and settings (JSON)"],
  ["objects", "objects", "objects, rooms and walls (JSON)"],
  ["IFC", "result?format=ifc", "an IFC4 model for BIM software"],
];

// The file name the API gives in Content-Disposition (RFC 6266: filename* first), else `fallback`.
function dispositionName(response, fallback) {
  const header = response.headers.get("Content-Disposition") || "";
  const extended = /filename\*=utf-8''([^;]+)/i.exec(header);
  if (extended) {
    try {
      return decodeURIComponent(extended[1]);
    } catch (_) {}
  }
  const plain = /filename="([^"]*)"/i.exec(header);
  return plain ? plain[1] : fallback;
}

// Fetch with the key (a header, never the address), then save the body as a blob.
async function download(path, label) {
  note("action-status", `downloading ${label}...`);
  const response = await api(path);
  if (!response.ok) {
    note("action-status", `download of ${label} failed: ${await errorText(response)}`, true);
    return;
  }
  const filename = dispositionName(response, label);
  const url = URL.createObjectURL(await response.blob());
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 60000);
  note("action-status", "");
}

async function removeJob(job) {
  const finished = ["succeeded", "failed", "cancelled"].includes(job.status);
  if (finished && !confirm(`Delete job ${job.filename} and its files?`)) return;
  const response = await api(`/v1/jobs/${job.id}`, { method: "DELETE" });
  if (response.ok) note("action-status", "");
  else note("action-status", `${finished ? "delete" : "cancel"} failed: ${await errorText(response)}`, true);
  poll();
}

// ---------------------------------------------------------------- job list
function cell(row, name) {
  return row.querySelector(`[data-col="${name}"]`);
}

function newRow(job) {
  const row = document.createElement("tr");
  row.dataset.jobId = job.id;
  for (const name of ["created", "file", "points", "network", "status", "progress", "actions"]) {
    const td = document.createElement("td");
    td.dataset.col = name;
    row.appendChild(td);
  }
  cell(row, "points").className = "num";
  cell(row, "actions").className = "actions";
  const bar = document.createElement("progress");
  bar.max = 1;
  const label = document.createElement("span");
  label.className = "note";
  label.addEventListener("click", () => {
    if (label.classList.contains("job-error")) label.classList.toggle("unfolded");
  });
  const tiles = document.createElement("span");
  tiles.className = "note tiles";
  tiles.hidden = true;
  cell(row, "progress").append(bar, " ", label, " ", tiles);
  return row;
}

// "tiles 3/8, 2 running" for a job whose scan was cut into tiles (the API's `tiles` object);
// null for any other job, and for a service whose jobs have no `tiles` field at all.
function tilesText(job) {
  const tiles = job.tiles;
  if (!tiles || typeof tiles !== "object") return null;
  const { total, done, running } = tiles;
  if (!Number.isFinite(total) || !Number.isFinite(done)) return null;
  const busy = job.status === "running" && Number.isFinite(running) && running > 0;
  return `tiles ${done}/${total}` + (busy ? `, ${running} running` : "");
}

function actionButton(text, onClick) {
  const button = document.createElement("button");
  button.type = "button";
  button.textContent = text;
  button.addEventListener("click", onClick);
  return button;
}

// "download" opens a menu of the six files (kept open across polls: the row is redrawn only when
// its status changes); choosing one closes it, as does a click anywhere else.
function downloadMenu(job) {
  const wrapper = document.createElement("span");
  wrapper.className = "downloads";
  const menu = document.createElement("div");
  menu.className = "download-menu";
  menu.hidden = true;
  const toggle = actionButton("download", () => {
    menu.hidden = !menu.hidden;
    toggle.setAttribute("aria-expanded", String(!menu.hidden));
  });
  toggle.setAttribute("aria-expanded", "false");
  for (const [label, route, what] of DOWNLOADS) {
    const button = actionButton(label, () => {
      menu.hidden = true;
      toggle.setAttribute("aria-expanded", "false");
      download(`/v1/jobs/${job.id}/${route}`, label);
    });
    const hint = document.createElement("span");
    hint.className = "note";
    hint.textContent = what;
    const item = document.createElement("div");
    item.append(button, hint);
    menu.append(item);
  }
  wrapper.append(toggle, menu);
  return wrapper;
}

document.addEventListener("click", (event) => {
  for (const wrapper of document.querySelectorAll(".downloads")) {
    const menu = wrapper.querySelector(".download-menu");
    if (!menu.hidden && !wrapper.contains(event.target)) {
      menu.hidden = true;
      wrapper.querySelector("button").setAttribute("aria-expanded", "false");
    }
  }
});

function renderActions(row, job) {
  if (row.dataset.actionsFor === job.status) return; // unchanged: keep the links under the mouse
  row.dataset.actionsFor = job.status;
  const td = cell(row, "actions");
  td.replaceChildren();
  if (job.status === "succeeded") {
    const view = document.createElement("a");
    view.href = viewerLink(job.id);
    view.target = "_blank";
    view.rel = "noopener";
    view.textContent = "view";
    view.className = "view-link";
    td.append(view, downloadMenu(job), actionButton("frame", () => openFrame(job.id)));
  }
  const finished = ["succeeded", "failed", "cancelled"].includes(job.status);
  td.append(actionButton(finished ? "delete" : "cancel", () => removeJob(job)));
}

function renderJob(job) {
  let row = rows.get(job.id);
  if (!row) {
    row = newRow(job);
    rows.set(job.id, row);
  }
  row.dataset.status = job.status;
  cell(row, "created").textContent = new Date(job.created_at).toLocaleString();
  cell(row, "file").textContent = job.rerun_of ? `${job.filename} (re-run)` : job.filename;
  cell(row, "file").title = job.rerun_of ? `re-run of job ${job.rerun_of} with another frame` : "";
  cell(row, "points").textContent = job.points == null ? "" : job.points.toLocaleString();
  cell(row, "network").textContent =
    job.quality && job.quality !== "standard" ? `${job.network}, ${job.quality}` : job.network;
  const status = cell(row, "status");
  status.textContent = job.status;
  status.className = `status status-${job.status}`;
  status.title = job.error || "";
  const [bar, , label, , tilesNote] = cell(row, "progress").childNodes;
  bar.value = job.progress;
  bar.hidden = job.status === "failed"; // its error takes the cell: the bar means nothing there
  const tiles = tilesText(job);
  // the tiles' own note replaces a stage that only repeats their count ("tiles 3/8")
  const repeats = tiles !== null && /^tiles\b/.test(job.stage || "");
  const stage = job.status === "running" && job.stage && !repeats ? `${job.stage} ` : "";
  // a failed job's error, however long, stays on one line (cut with an ellipsis, whole in the
  // tooltip, unfolded by a click) so it never squeezes the row's links into a column
  const failed = job.status === "failed";
  label.textContent = failed ? job.error || "" : `${stage}${Math.round(job.progress * 100)}%`;
  label.title = failed ? job.error || "" : "";
  label.classList.toggle("job-error", failed);
  if (!failed) label.classList.remove("unfolded");
  tilesNote.textContent = tiles || "";
  tilesNote.hidden = tiles === null;
  renderActions(row, job);
  return row;
}

// ---------------------------------------------------------------- frame box
// A finished job's frame (report.json's `frame` section: up axis, tilt, units, each with its
// confidence; a warning means the stage was unsure) and the one action that corrects it: re-run
// the job from its stored upload with another up axis or unit (POST /v1/jobs/{id}/rerun gives a
// NEW job; this one stays as it is). Opened by a row's "frame" button or by the address
// `#frame=<job id>&up=<axis>&units=<unit>`: the viewer's Frame folder links there, since the
// viewer holds no API key and the page does.
let frameJob = null; // the job the box shows, once its report is read

function flipped(axis) {
  return (axis[0] === "-" ? "+" : "-") + axis.slice(1);
}

// Set a <select> to `value` when it offers it, else to `fallback`.
function choose(select, value, fallback) {
  select.value = value || "";
  if (!value || select.value !== value) select.value = fallback;
}

function frameRow(field, value, confidence, how, unsure) {
  const row = document.querySelector(`#frame-decision tr[data-field="${field}"]`);
  const part = (name) => row.querySelector(`[data-part="${name}"]`);
  part("value").textContent = value;
  part("confidence").textContent = Number.isFinite(confidence)
    ? `confidence ${confidence.toFixed(2)}`
    : "";
  part("how").textContent = how || "";
  row.classList.toggle("unsure", unsure);
}

function showFrame(frame) {
  const warnings = frame.warnings || [];
  const up = frame.up || {};
  const units = frame.units || {};
  const upUnsure = warnings.some((w) => /^up axis/.test(w));
  const unitsUnsure = warnings.some((w) => /units|tall/.test(w));
  frameRow("up", up.axis || "?", up.confidence, up.how, upUnsure);
  const tilt = Number.isFinite(up.tilt_degrees) ? `${up.tilt_degrees.toFixed(1)}°` : "?";
  const levelled = up.levelled ? "levelled" : "not levelled (under the real-tilt rule)";
  frameRow("tilt", `${tilt}, ${levelled}`, up.confidence, "with the up axis", upUnsure);
  frameRow("units", units.unit || "?", units.confidence, units.how, unitsUnsure);
  $("frame-warnings").replaceChildren(
    ...warnings.map((text) => {
      const item = document.createElement("li");
      item.textContent = text;
      return item;
    }),
  );
  $("frame-unsure").hidden = warnings.length === 0;
  $("frame-box").dataset.unsure = String(warnings.length > 0);
}

async function openFrame(jobId, wanted = {}) {
  frameJob = null;
  $("frame-box").hidden = false;
  $("frame-rerun").disabled = true;
  note("frame-status", "reading the job's report...");
  const path = `/v1/jobs/${encodeURIComponent(jobId)}`;
  const [job, report] = await Promise.all([api(path), api(`${path}/report`)]);
  if (!job.ok || !report.ok) {
    note("frame-status", `no frame to show: ${await errorText(job.ok ? report : job)}`, true);
    return;
  }
  const [record, frame] = [await job.json(), (await report.json()).frame];
  $("frame-job").textContent = `${record.filename} [${record.id.slice(0, 8)}]`;
  if (!frame) {
    note("frame-status", "this job's report has no frame decision", true);
    return;
  }
  showFrame(frame);
  choose($("frame-up"), wanted.up, (frame.up || {}).axis || "+z");
  choose($("frame-units"), wanted.units, (frame.units || {}).unit || "m");
  frameJob = record.id;
  $("frame-rerun").disabled = false;
  note("frame-status", "");
  $("frame-box").scrollIntoView({ block: "nearest" });
}

async function rerunFrame(event) {
  event.preventDefault();
  if (!frameJob) return;
  const frame = { up: $("frame-up").value, units: $("frame-units").value };
  $("frame-rerun").disabled = true;
  note("frame-status", "starting the re-run...");
  try {
    const response = await api(`/v1/jobs/${frameJob}/rerun`, {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ frame }),
    });
    if (response.status !== 201) {
      note("frame-status", `re-run refused: ${await errorText(response)}`, true);
      return;
    }
    rerunStarted(await response.json(), frame);
  } catch (error) {
    note("frame-status", `service unreachable: ${error}`, true);
  } finally {
    $("frame-rerun").disabled = false;
  }
}

// The new job in the status line, linked to its row in the job list (where "view" follows).
function rerunStarted(job, frame) {
  const link = document.createElement("a");
  link.id = "frame-new-job";
  link.href = `#job-${job.id}`;
  link.dataset.jobId = job.id;
  link.textContent = `job ${job.id.slice(0, 8)}`;
  link.addEventListener("click", (event) => {
    event.preventDefault();
    const row = rows.get(job.id);
    if (row) row.scrollIntoView({ block: "center" });
  });
  const status = $("frame-status");
  status.className = "note";
  status.replaceChildren(
    `re-run with up ${frame.up} and units ${frame.units} as `,
    link,
    ` (${job.status}): it is in the job list`,
  );
  poll();
}

function frameFromAddress() {
  const params = new URLSearchParams(location.hash.slice(1));
  const jobId = params.get("frame");
  if (jobId) openFrame(jobId, { up: params.get("up"), units: params.get("units") });
}

function setupFrame() {
  $("frame-flip").addEventListener("click", () => {
    $("frame-up").value = flipped($("frame-up").value);
  });
  $("frame-form").addEventListener("submit", rerunFrame);
  $("frame-close").addEventListener("click", () => {
    $("frame-box").hidden = true;
    frameJob = null;
  });
  window.addEventListener("hashchange", frameFromAddress);
}

let polling = null;

async function poll() {
  clearTimeout(polling);
  try {
    const response = await api("/v1/jobs?limit=50");
    if (response.ok) {
      const page = await response.json();
      const tbody = $("jobs").querySelector("tbody");
      const seen = new Set();
      page.items.forEach((job, i) => {
        seen.add(job.id);
        const row = renderJob(job);
        if (tbody.children[i] !== row) tbody.insertBefore(row, tbody.children[i] || null);
      });
      for (const [id, row] of rows) {
        if (!seen.has(id)) {
          row.remove();
          rows.delete(id);
        }
      }
      $("job-count").textContent = `(${page.items.length} of ${page.total})`;
      $("no-jobs").hidden = page.total > 0;
      note("list-status", "");
      if ($("key-status").classList.contains("error")) note("key-status", "");
      const queued = page.items.find((job) => job.id === queuedJob);
      if (queuedJob && (!queued || queued.status !== "queued")) {
        queuedJob = null; // the row now tells where the job is
        note("upload-status", "");
      }
    } else {
      $("no-jobs").hidden = true;
      note("list-status", `job list unavailable: ${await errorText(response)}`, true);
    }
  } catch (error) {
    $("no-jobs").hidden = true;
    note("list-status", `service unreachable: ${error}`, true);
  }
  polling = setTimeout(poll, document.hidden ? POLL_MS * 4 : POLL_MS);
}

async function loadConfig() {
  try {
    const config = await (await fetch("/web/config.json")).json();
    viewerPort = config.viewer_port;
    for (const name of config.networks) {
      const option = document.createElement("option");
      option.value = option.textContent = name;
      $("network").appendChild(option);
    }
    if (config.networks.length === 0) {
      $("upload").disabled = true;
      note("upload-status", "no network has weights on this service: ask its operator", true);
    }
  } catch (error) {
    note("upload-status", `page configuration unavailable: ${error}`, true);
  }
}

document.addEventListener("DOMContentLoaded", async () => {
  setupKey();
  setupUpload();
  setupFrame();
  await loadConfig();
  poll();
  frameFromAddress();
});
