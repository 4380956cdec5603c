// The job page: upload a scan, watch the jobs, open results in the viewer. Plain JavaScript,
// no build step. Every call goes to the /v1 API with the saved API key (if any) as a Bearer
// token; user-supplied text (file names, errors) is only ever set as textContent.
"use strict";

const KEY_STORAGE = "jointseg.apiKey";
const POLL_MS = 1500;
const $ = (id) => document.getElementById(id);
const rows = new Map(); // job id -> <tr>
let viewerPort = 8080;

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
    $("key-status").textContent = apiKey() ? "this API key was refused" : "this service needs an API key";
    $("key-status").className = "note error";
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
    $("key-status").textContent = key ? "saved in this browser" : "no key";
    $("key-status").className = "note";
    poll();
  });
}

// ------------------------------------------------------------------- upload
function setupUpload() {
  $("upload-form").addEventListener("submit", (event) => {
    event.preventDefault();
    const file = $("scan-file").files[0];
    if (!file) return;
    const form = new FormData();
    form.append("file", file, file.name);
    form.append("config", JSON.stringify({
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
    $("upload-status").className = "note";
    $("upload-status").textContent = `uploading ${file.name}...`;
    request.upload.onprogress = (e) => {
      if (e.lengthComputable) bar.value = e.loaded / e.total;
    };
    request.onloadend = () => {
      bar.hidden = true;
      $("upload").disabled = false;
      let body = {};
      try {
        body = JSON.parse(request.responseText);
      } catch (_) {}
      if (request.status === 201) {
        $("upload-status").textContent = `job ${body.id} queued`;
        $("upload-form").reset();
        poll();
      } else {
        $("upload-status").className = "note error";
        $("upload-status").textContent =
          `upload refused (${request.status || "no answer"}): ${body.detail || request.statusText}`;
      }
    };
    request.send(form);
  });
}

// ---------------------------------------------------------------- downloads
async function download(path, filename) {
  const response = await api(path);
  if (!response.ok) {
    $("list-status").className = "note error";
    $("list-status").textContent = `download failed: ${await errorText(response)}`;
    return;
  }
  const url = URL.createObjectURL(await response.blob());
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 60000);
}

async function removeJob(job) {
  const finished = ["succeeded", "failed", "cancelled"].includes(job.status);
  if (finished && !confirm(`Delete job ${job.filename} and its files?`)) return;
  const response = await api(`/v1/jobs/${job.id}`, { method: "DELETE" });
  if (!response.ok) {
    $("list-status").className = "note error";
    $("list-status").textContent = await errorText(response);
  }
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

function renderActions(row, job) {
  if (row.dataset.actionsFor === job.status) return; // unchanged: keep the links under the mouse
  row.dataset.actionsFor = job.status;
  const td = cell(row, "actions");
  td.replaceChildren();
  const stem = job.filename.replace(/\.[^.]*$/, "");
  if (job.status === "succeeded") {
    const view = document.createElement("a");
    view.href = viewerLink(job.id);
    view.target = "_blank";
    view.rel = "noopener";
    view.textContent = "view";
    view.className = "view-link";
    td.append(
      view,
      actionButton("result", () => download(`/v1/jobs/${job.id}/result`, `${stem}_segmented.ply`)),
      actionButton("report", () => download(`/v1/jobs/${job.id}/report`, `${stem}_report.json`)),
    );
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
  cell(row, "file").textContent = job.filename;
  cell(row, "points").textContent = job.points == null ? "" : job.points.toLocaleString();
  cell(row, "network").textContent = job.network;
  const status = cell(row, "status");
  status.textContent = job.status;
  status.className = `status status-${job.status}`;
  status.title = job.error || "";
  const [bar, , label, , tilesNote] = cell(row, "progress").childNodes;
  bar.value = job.progress;
  const tiles = tilesText(job);
  // the tiles' own note replaces a stage that only repeats their count ("tiles 3/8")
  const repeats = tiles !== null && /^tiles\b/.test(job.stage || "");
  const stage = job.status === "running" && job.stage && !repeats ? `${job.stage} ` : "";
  label.textContent = job.status === "failed" ? job.error || "" : `${stage}${Math.round(job.progress * 100)}%`;
  tilesNote.textContent = tiles || "";
  tilesNote.hidden = tiles === null;
  renderActions(row, job);
  return row;
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
      $("list-status").textContent = "";
      $("list-status").className = "note";
    } else {
      $("list-status").className = "note error";
      $("list-status").textContent = `job list unavailable: ${await errorText(response)}`;
    }
  } catch (error) {
    $("list-status").className = "note error";
    $("list-status").textContent = `service unreachable: ${error}`;
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
  } catch (error) {
    $("list-status").textContent = `page configuration unavailable: ${error}`;
  }
}

document.addEventListener("DOMContentLoaded", async () => {
  setupKey();
  setupUpload();
  await loadConfig();
  poll();
});
