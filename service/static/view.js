// The live view of one omnisonar session: reads GET /sessions/{id}/events (server-sent events)
// with fetch, so that the API key travels in the Authorization header; the key comes from the
// URL fragment (#key=...), which the browser never sends to the server. Plain canvas drawing,
// nothing loaded from elsewhere.
"use strict";

const view = {
  map: null,        // the "map" event: extent_m [x0, x1, y0, y1], walls_m, g_png
  image: null,      // G as a loaded <img>
  state: null,      // the last "state" event
  frames: 0,
};

const $ = (id) => document.getElementById(id);
const sessionId = decodeURIComponent(location.pathname.split("/").slice(-2)[0]);
const key = new URLSearchParams(location.hash.slice(1)).get("key");

function setState(state, message) {
  document.body.dataset.state = state;
  $("message").textContent = message || "";
  if (state !== "live") {
    const badge = $("status");
    if (!document.body.dataset.status) { badge.textContent = state; }
  }
}

// ---- the event stream ------------------------------------------------------------------
async function connect() {
  const headers = { Accept: "text/event-stream" };
  if (key) { headers.Authorization = "Bearer " + key; }
  let response;
  try {
    response = await fetch("events", { headers, cache: "no-store" });
  } catch (err) {
    return retry("connection failed: " + err);
  }
  if (!response.ok) {
    let detail = response.statusText;
    try { detail = (await response.json()).detail || detail; } catch (e) { /* not JSON */ }
    if ([401, 403, 404].includes(response.status)) {
      const hint = response.status === 401 ? " (open this page as .../view#key=YOUR_KEY)" : "";
      return setState("error", `${response.status}: ${detail}${hint}`);
    }
    return retry(`${response.status}: ${detail}`);
  }
  setState("live");
  const reader = response.body.getReader();
  const decoder = new TextDecoder();
  let buffer = "";
  for (;;) {
    let chunk;
    try {
      chunk = await reader.read();
    } catch (err) {
      return retry("stream interrupted");
    }
    if (chunk.done) { break; }
    buffer += decoder.decode(chunk.value, { stream: true });
    let cut;
    while ((cut = buffer.indexOf("\n\n")) >= 0) {
      const block = buffer.slice(0, cut);
      buffer = buffer.slice(cut + 2);
      if (dispatch(block) === "end") { return; }
    }
  }
  retry("stream closed");
}

function retry(message) {
  setState("reconnecting", message);
  setTimeout(connect, 2000);
}

function dispatch(block) {
  let event = "message";
  const data = [];
  for (const line of block.split("\n")) {
    if (line.startsWith(":")) { continue; }              // keep-alive comment
    if (line.startsWith("event:")) { event = line.slice(6).trim(); }
    if (line.startsWith("data:")) { data.push(line.slice(5).trim()); }
  }
  if (!data.length) { return event; }
  const payload = JSON.parse(data.join("\n"));
  if (event === "map") { onMap(payload); }
  if (event === "state") { onState(payload); }
  if (event === "end") { setState("ended", "the session was deleted or expired"); }
  return event;
}

function onMap(map) {
  view.map = map;
  $("f-map").textContent = map.map_id + (map.pinned ? "" : " (replaced since!)");
  const img = new Image();
  img.onload = () => { view.image = img; drawMap(); };
  img.src = map.g_png;
}

function onState(state) {
  view.state = state;
  view.frames += 1;
  const est = state.estimate;
  const body = document.body.dataset;
  body.seq = state.seq === null ? "" : String(state.seq);
  body.updates = String(state.n_updates);
  body.status = est ? est.status : "";
  body.frames = String(view.frames);
  $("f-seq").textContent = state.seq === null ? "-" : state.seq;
  $("f-updates").textContent = state.n_updates;
  const badge = $("status");
  badge.className = "badge " + (est ? est.status : "");
  badge.textContent = est ? est.status : "no block yet";
  if (est) {
    const sx = Math.sqrt(est.cov_xy[0][0]), sy = Math.sqrt(est.cov_xy[1][1]);
    $("f-pose").textContent = `${est.x.toFixed(3)}, ${est.y.toFixed(3)} m`;
    $("f-yaw").textContent = `${(est.yaw * 180 / Math.PI).toFixed(1)}\u00b0`;
    $("f-std").textContent = `${(100 * sx).toFixed(1)}, ${(100 * sy).toFixed(1)} cm, ` +
      `${est.std_yaw_deg.toFixed(1)}\u00b0`;
    $("f-fit").textContent = est.fit === null ? "-" : est.fit.toFixed(3);
    $("f-ess").textContent = est.ess.toFixed(0);
    $("f-ms").textContent = `${est.processing_ms.toFixed(1)} ms`;
  }
  drawMap();
  drawHeat(state.heatmap);
}

// ---- drawing ---------------------------------------------------------------------------
function frameOf(canvas) {
  const [x0, x1, y0, y1] = view.map.extent_m;
  const pad = 10;
  const scale = Math.min((canvas.width - 2 * pad) / (x1 - x0),
                         (canvas.height - 2 * pad) / (y1 - y0));
  const ox = (canvas.width - scale * (x1 - x0)) / 2, oy = (canvas.height - scale * (y1 - y0)) / 2;
  return {
    scale,
    px: (x) => ox + scale * (x - x0),
    py: (y) => oy + scale * (y1 - y),   // y up in the map, down on the canvas
  };
}

function drawMap() {
  const canvas = $("map"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!view.map) { return; }
  const f = frameOf(canvas);
  const [x0, x1, y0, y1] = view.map.extent_m;
  if (view.image) {
    ctx.globalAlpha = 0.55;
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(view.image, f.px(x0), f.py(y1), f.scale * (x1 - x0), f.scale * (y1 - y0));
    ctx.globalAlpha = 1;
  }
  ctx.strokeStyle = "#1565c0";
  ctx.lineWidth = 2;
  for (const [xa, ya, xb, yb] of view.map.walls_m) {
    ctx.beginPath(); ctx.moveTo(f.px(xa), f.py(ya)); ctx.lineTo(f.px(xb), f.py(yb)); ctx.stroke();
  }
  drawScale(ctx, f);
  const state = view.state;
  if (!state) { return; }
  if (state.particles) {
    const p = state.particles;
    for (let i = 0; i < p.x.length; i++) {
      ctx.fillStyle = `rgba(239, 108, 0, ${0.15 + 0.85 * p.w[i]})`;
      ctx.fillRect(f.px(p.x[i]) - 1.5, f.py(p.y[i]) - 1.5, 3, 3);
    }
  }
  const est = state.estimate;
  if (est) { drawPose(ctx, f, est); }
}

function drawPose(ctx, f, est) {
  const [[a, b], [, c]] = est.cov_xy;
  const mid = (a + c) / 2, rad = Math.sqrt(((a - c) / 2) ** 2 + b * b);
  const l1 = Math.max(mid + rad, 0), l2 = Math.max(mid - rad, 0);
  const angle = 0.5 * Math.atan2(2 * b, a - c);
  const x = f.px(est.x), y = f.py(est.y);
  ctx.strokeStyle = "#c62828";
  ctx.fillStyle = "rgba(198, 40, 40, 0.15)";
  ctx.lineWidth = 2;
  ctx.beginPath();   // 2-sigma ellipse; canvas y is flipped, so the angle is negated
  ctx.ellipse(x, y, Math.max(2 * Math.sqrt(l1) * f.scale, 2),
              Math.max(2 * Math.sqrt(l2) * f.scale, 2), -angle, 0, 2 * Math.PI);
  ctx.fill(); ctx.stroke();
  const len = 18;
  const tx = x + len * Math.cos(est.yaw), ty = y - len * Math.sin(est.yaw);
  ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(tx, ty); ctx.stroke();
  const head = 6, back = est.yaw + Math.PI;
  ctx.beginPath();
  ctx.moveTo(tx, ty);
  ctx.lineTo(tx + head * Math.cos(back - 0.5), ty - head * Math.sin(back - 0.5));
  ctx.lineTo(tx + head * Math.cos(back + 0.5), ty - head * Math.sin(back + 0.5));
  ctx.closePath(); ctx.fillStyle = "#c62828"; ctx.fill();
}

function drawScale(ctx, f) {
  const metres = f.scale > 60 ? 1 : 5;
  const x = 14, y = ctx.canvas.height - 14;
  ctx.strokeStyle = "#333"; ctx.lineWidth = 2;
  ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x + metres * f.scale, y); ctx.stroke();
  ctx.fillStyle = "#333"; ctx.font = "12px sans-serif";
  ctx.fillText(`${metres} m`, x, y - 5);
}

function colour(v) {   // 0..255 -> a dark-blue to yellow ramp
  const t = v / 255;
  return [Math.round(255 * Math.min(1, 1.8 * t)), Math.round(230 * t * t),
          Math.round(90 + 80 * (1 - t) - 90 * t)];
}

function drawHeat(hm) {
  const canvas = $("heat"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!hm) {
    ctx.fillStyle = "#777"; ctx.font = "13px sans-serif";
    ctx.fillText("no heat map yet (a block arrives while this page is open)", 12, 24);
    return;
  }
  const raw = atob(hm.data_b64);
  const image = new ImageData(hm.cols, hm.rows);
  for (let i = 0; i < raw.length; i++) {
    const [r, g, b] = colour(raw.charCodeAt(i));
    image.data.set([r, g, b, 255], 4 * i);
  }
  const off = document.createElement("canvas");
  off.width = hm.cols; off.height = hm.rows;
  off.getContext("2d").putImageData(image, 0, 0);
  const left = 40, bottom = 22, w = canvas.width - left - 8, h = canvas.height - bottom - 8;
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(off, left, 8, w, h);
  ctx.fillStyle = "#333"; ctx.font = "11px sans-serif";
  ctx.fillText(`${hm.angle_min_deg}\u00b0`, 4, 18);
  ctx.fillText(`${hm.angle_max_deg}\u00b0`, 4, 8 + h);
  ctx.fillText("0 m", left, canvas.height - 6);
  ctx.fillText(`${hm.range_max_m.toFixed(1)} m`, left + w - 36, canvas.height - 6);
  const note = hm.direction_observable ? "" : " (too slow: no bearing)";
  ctx.fillText(`speed ${hm.speed_m_s.toFixed(2)} m/s${note}`, left + w / 2 - 50,
               canvas.height - 6);
}

$("sid").textContent = sessionId;
connect();
