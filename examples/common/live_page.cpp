// The live view's page: self-contained (no script, style or font from anywhere else), it polls
// /state.json twice a second and reloads /render.bmp when the frame changes (and /slice.bmp,
// the distance field's slice, when the field or the camera's height changes).

#include "live_server.hpp"

namespace octofuse::examples {

const char* live_page_html() {
  return R"html(<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>octofuse live</title>
<style>
body { font: 14px sans-serif; margin: 12px; background: #f4f4f4; color: #222; }
.row { display: flex; gap: 12px; flex-wrap: wrap; align-items: flex-start; }
.panel { background: #fff; padding: 8px; border: 1px solid #ccc; }
.panel h2 { font-size: 13px; margin: 0 0 6px 0; }
#status { font: 15px monospace; margin: 8px 0; }
#state.lost { color: #b00; font-weight: bold; }
img { image-rendering: pixelated; min-width: 320px; min-height: 240px; background: #000; }
.key span { display: inline-block; width: 10px; height: 10px; margin: 0 3px 0 10px; }
</style>
</head>
<body>
<h1>octofuse live</h1>
<div id="status">tracking <span id="state">(waiting)</span> · frame <span id="frame">-</span> ·
<span id="fps">-</span> fps · map <span id="memory">-</span>
<button id="mesh" onclick="getMesh()">Mesh (PLY)</button></div>
<div class="row">
<div class="panel"><h2>Ray-cast, coloured by scale</h2><img id="render" alt="ray-cast">
<div class="key"><span style="background:#d33"></span>0<span style="background:#3a3"></span>1
<span style="background:#36c"></span>2<span style="background:#cc3"></span>3</div></div>
<div class="panel" id="slicePanel" hidden><h2>Distance field at the camera's height
(<span id="sliceZ">-</span> m), from above, x right, y up</h2><img id="slice" alt="distance field slice">
<div class="key"><span style="background:#f00"></span>0 m<span style="background:#7fff80"></span><span id="sliceMid">-</span>
<span style="background:#00f"></span><span id="sliceMax">-</span> or more<span style="background:#808080"></span>unknown</div></div>
<div class="panel"><h2>Trajectory from above</h2>
<canvas id="trajectory" width="320" height="320"></canvas></div>
</div>
<div class="row">
<div class="panel"><h2>Stage times of the last frames (ms)</h2>
<canvas id="stages" width="664" height="200"></canvas>
<div class="key"><span style="background:#888"></span>pre-process<span style="background:#1f77b4"></span>track
<span style="background:#2ca02c"></span>integrate<span style="background:#d62728"></span>ray-cast</div></div>
</div>
<script>
"use strict";
const colours = ["#888", "#1f77b4", "#2ca02c", "#d62728"];
let shownFrame = -1, shownSlice = "";
function drawTrajectory(p) {
  // From above: the two world axes the camera moved along most (height varies least).
  const c = document.getElementById("trajectory"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (p.length < 3) return;
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < p.length; i += 3) {
    for (let k = 0; k < 3; k++) { lo[k] = Math.min(lo[k], p[i + k]); hi[k] = Math.max(hi[k], p[i + k]); }
  }
  const ext = k => hi[k] - lo[k];
  const up = [0, 1, 2].reduce((a, b) => (ext(b) < ext(a) ? b : a));
  const a = up === 0 ? 1 : 0, b = up === 2 ? 1 : 2;
  const span = Math.max(ext(a), ext(b), 0.1), s = (c.width - 20) / span;
  const X = v => 10 + (v - lo[a]) * s, Y = v => c.height - 10 - (v - lo[b]) * s;
  g.strokeStyle = "#1f77b4"; g.lineWidth = 1.5; g.beginPath();
  for (let i = 0; i < p.length; i += 3) (i ? g.lineTo : g.moveTo).call(g, X(p[i + a]), Y(p[i + b]));
  g.stroke();
  g.fillStyle = "#d62728"; g.beginPath();
  g.arc(X(p[p.length - 3 + a]), Y(p[p.length - 3 + b]), 4, 0, 7); g.fill();
  g.fillStyle = "#222";
  g.fillText("xyz"[a] + " right, " + "xyz"[b] + " up, " + span.toFixed(2) + " m across", 10, 14);
}
function drawStages(ms) {
  const c = document.getElementById("stages"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  const n = ms.length / 4;
  if (n < 1) return;
  let top = 1;
  for (let f = 0; f < n; f++) top = Math.max(top, ms[4 * f] + ms[4 * f + 1] + ms[4 * f + 2] + ms[4 * f + 3]);
  const w = c.width / 120, s = (c.height - 16) / top;
  for (let f = 0; f < n; f++) {
    let y = c.height;
    for (let k = 0; k < 4; k++) {
      const h = ms[4 * f + k] * s;
      g.fillStyle = colours[k]; g.fillRect(f * w, y - h, Math.max(w - 1, 1), h); y -= h;
    }
  }
  g.fillStyle = "#222"; g.fillText("max " + top.toFixed(1) + " ms", 4, 12);
}
async function tick() {
  try {
    const r = await fetch("/state.json", {cache: "no-store"});
    const s = await r.json();
    const state = document.getElementById("state");
    state.textContent = s.tracking || "(waiting)";
    state.className = s.tracking === "lost" ? "lost" : "";
    document.getElementById("frame").textContent = s.frame;
    document.getElementById("fps").textContent = s.fps.toFixed(1);
    document.getElementById("memory").textContent = (s.map_bytes_used / 1048576).toFixed(1) +
        " of " + (s.map_bytes_reserved / 1048576).toFixed(1) + " MB, blocks " + s.blocks_used +
        "/" + s.block_capacity;
    document.body.dataset.frame = s.frame;
    if (s.width > 0 && s.frame !== shownFrame) {
      shownFrame = s.frame;
      document.getElementById("render").src = "/render.bmp?frame=" + s.frame;
    }
    if (s.slice_width > 0) {
      const key = s.slice_version + "@" + s.slice_z_m;
      document.getElementById("slicePanel").hidden = false;
      document.getElementById("sliceZ").textContent = s.slice_z_m.toFixed(2);
      document.getElementById("sliceMid").textContent = (s.slice_max_m / 2).toFixed(2) + " m";
      document.getElementById("sliceMax").textContent = s.slice_max_m.toFixed(2) + " m";
      if (key !== shownSlice) {
        shownSlice = key;
        document.getElementById("slice").src = "/slice.bmp?v=" + encodeURIComponent(key);
      }
    }
    drawTrajectory(s.trajectory_p_W);
    drawStages(s.stage_ms);
  } catch (e) {
    document.getElementById("state").textContent = "(no answer from the run)";
  }
  setTimeout(tick, 500);
}
async function getMesh() {
  // The first request asks the run to mesh the map (202); the PLY comes with a later one.
  const button = document.getElementById("mesh");
  button.disabled = true;
  button.textContent = "meshing...";
  for (let i = 0; i < 600; i++) {
    const r = await fetch("/mesh.ply", {cache: "no-store"});
    if (r.status === 200) {
      const blob = await r.blob();
      const link = document.createElement("a");
      link.href = URL.createObjectURL(blob);
      link.download = "mesh.ply";
      link.click();
      button.textContent = "Mesh (PLY, last " + (blob.size / 1048576).toFixed(1) + " MB)";
      button.disabled = false;
      return;
    }
    await new Promise(done => setTimeout(done, 500));
  }
  button.textContent = "Mesh (PLY): no answer";
  button.disabled = false;
}
document.getElementById("render").onload = function () {
  document.body.dataset.renderWidth = this.naturalWidth;
  document.body.dataset.renderFrame = shownFrame;
};
tick();
</script>
</body>
</html>
)html";
}

}  // namespace octofuse::examples
