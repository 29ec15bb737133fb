// dronesim web ground station: the world floor by floor (row = x, column = y, (0,0) top-left), an
// isometric view, every drone with its status, trail and target, the turn, the event log; targets by
// click or typed coordinates. Live state comes by Server-Sent Events (/api/events): the full state at
// once, then every change. Replay mode plays /api/replay's frames. No external library.
"use strict";

const PALETTE = ["#e8590c", "#1c7ed6", "#2f9e44", "#ae3ec9", "#f08c00", "#0c8599",
                 "#e03131", "#5f3dc4", "#66a80f", "#c2255c", "#1098ad", "#862e9c"];
const STATUS_TEXT = {alive: "alive", reached: "reached", unreachable: "unreachable", dead: "dead", lost: "lost"};

const S = {
  world: null,        // {size, floors, mode, title}
  mode: "live",
  view: null,         // what is shown: {turn, phase, drones, log, over, control}
  floor: 0,
  followFloor: true,  // the floor follows the selected drone until the human picks one
  selected: null,     // selected drone id
  rotation: 0,
  colors: {},
  cells: [],          // cells[x][y] -> element
  cellKeys: [],       // last rendered signature of each cell
  replay: null,       // {frames, over, journal}
  frame: 0,
  timer: null,
  es: null,
};

const $ = (sel) => document.querySelector(sel);

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k === "style") e.style.cssText = v;
    else if (k.startsWith("data-")) e.setAttribute(k, v);
    else e[k] = v;
  }
  for (const c of children) e.append(c);
  return e;
}

function fmt(c) { return c ? `(${c.join(", ")})` : "–"; }
function same(a, b) { return !!a && !!b && a[0] === b[0] && a[1] === b[1] && a[2] === b[2]; }
function inside(c) {
  const [nx, ny, nz] = S.world.size;
  return c[0] >= 0 && c[0] < nx && c[1] >= 0 && c[1] < ny && c[2] >= 0 && c[2] < nz;
}
function isBuilding(x, y, z) {
  const [nx, ny, nz] = S.world.size;
  if (x < 0 || y < 0 || z < 0 || x >= nx || y >= ny || z >= nz) return false;
  return S.world.floors[z][x].charCodeAt(y) === 35; // '#'
}
function colorOf(id) {
  if (!(id in S.colors)) S.colors[id] = PALETTE[Object.keys(S.colors).length % PALETTE.length];
  return S.colors[id];
}

// ------------------------------------------------------------------------------------------ messages

function say(text, kind = "ok") {
  const m = $("#message");
  m.textContent = text;
  m.className = `message ${kind}`;
}

async function post(path, body) {
  let r;
  try {
    r = await fetch(path, {method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(body)});
  } catch (e) {
    throw new Error("the ground station cannot be reached");
  }
  let data = {};
  try { data = await r.json(); } catch (e) { /* not JSON */ }
  if (!r.ok) throw new Error(data.error || `HTTP ${r.status}`);
  return data;
}

// ------------------------------------------------------------------------------------------ targets

function parseCell(text) {
  const m = /^\s*\(?\s*(-?\d+)\s*[, ]\s*(-?\d+)\s*[, ]\s*(-?\d+)\s*\)?\s*$/.exec(text);
  if (!m) return {error: `"${text.trim()}" is not x,y,z (three integers)`};
  return {cell: [Number(m[1]), Number(m[2]), Number(m[3])]};
}

function checkTarget(drone, cell) {
  const [nx, ny, nz] = S.world.size;
  if (S.mode !== "live") return "this is a replay: it takes no targets";
  if (S.view && S.view.over) return "the game is over: no more targets";
  if (!drone) return "pick a drone first";
  const d = S.view && S.view.drones.find((v) => v.id === drone);
  if (!d) return `unknown drone ${drone}`;
  if (d.status === "dead" || d.status === "lost") return `${drone} is ${d.status}: it takes no more targets`;
  if (!inside(cell)) return `${fmt(cell)} is outside the world: 0 <= x < ${nx}, 0 <= y < ${ny}, 0 <= z < ${nz}`;
  if (isBuilding(...cell)) return `${fmt(cell)} is inside a building: no drone can get there`;
  return null;
}

async function sendTarget(drone, cell) {
  const problem = checkTarget(drone, cell);
  if (problem) { say(problem, "error"); return; }
  try {
    const r = await post("/api/target", {drone, cell});
    say(r.text || `target of ${drone} set to ${fmt(cell)}`, "ok");
  } catch (e) {
    say(e.message, "error");
  }
}

async function control(action, value) {
  try {
    const r = await post("/api/control", value === undefined ? {action} : {action, value});
    say(r.text, "ok");
  } catch (e) {
    say(e.message, "error");
  }
}

// ------------------------------------------------------------------------------------------ floor map

function buildGrid() {
  const [nx, ny, nz] = S.world.size;
  const grid = $("#grid");
  const avail = Math.max(240, $(".floor-panel").clientWidth - 40);
  const cell = Math.max(14, Math.min(40, Math.floor(avail / (ny + 1)) - 1));
  document.documentElement.style.setProperty("--cell", `${cell}px`);
  grid.style.gridTemplateColumns = `18px repeat(${ny}, ${cell}px)`;
  grid.replaceChildren(el("div", {class: "axis"}, ""));
  const every = ny > 24 ? 5 : 1;
  for (let y = 0; y < ny; y++) grid.append(el("div", {class: "axis", title: `y = ${y}`}, y % every ? "" : String(y)));
  S.cells = [];
  S.cellKeys = [];
  for (let x = 0; x < nx; x++) {
    grid.append(el("div", {class: "axis", title: `x = ${x}`}, x % every ? "" : String(x)));
    S.cells.push([]);
    S.cellKeys.push([]);
    for (let y = 0; y < ny; y++) {
      const c = el("div", {class: "cell", "data-x": x, "data-y": y});
      c.addEventListener("click", () => onCellClick(x, y));
      grid.append(c);
      S.cells[x].push(c);
      S.cellKeys[x].push("");
    }
  }
  const floors = $("#floors");
  floors.replaceChildren();
  for (let z = 0; z < nz; z++) {
    const b = el("button", {type: "button", "data-z": z, title: `floor z = ${z}`}, String(z));
    b.addEventListener("click", () => { S.followFloor = false; setFloor(z); });
    floors.append(b);
  }
}

function onCellClick(x, y) {
  if (S.mode !== "live") { say("this is a replay: it takes no targets", "error"); return; }
  const drone = $("#target-drone").value;
  const cell = [x, y, S.floor];
  $("#target-input").value = cell.join(",");
  sendTarget(drone, cell);
}

function setFloor(z) {
  S.floor = z;
  render();
}

function renderFloor(view) {
  const [nx, ny] = S.world.size;
  const z = S.floor;
  $("#floor-label").textContent = `z = ${z}`;
  const here = {}, targets = {}, trails = {};
  const key = (x, y) => x * ny + y;
  for (const d of view.drones) {
    const c = colorOf(d.id);
    if (d.pos[2] === z && inside(d.pos)) (here[key(d.pos[0], d.pos[1])] ||= []).push(d);
    const t = d.wanted || d.target;
    if (t && t[2] === z && d.status !== "dead" && d.status !== "lost") {
      targets[key(t[0], t[1])] ||= {id: d.id, color: c, pending: !!d.wanted && !same(d.wanted, d.target)};
    }
    for (const p of d.trail || []) if (p[2] === z && inside(p)) trails[key(p[0], p[1])] ||= c;
  }
  for (let x = 0; x < nx; x++) {
    const row = S.world.floors[z][x];
    for (let y = 0; y < ny; y++) {
      const k = key(x, y);
      const ds = here[k] || [];
      const t = targets[k];
      const tr = trails[k];
      const b = row.charCodeAt(y) === 35;
      const sig = `${b}|${ds.map((d) => d.id + d.status).join(",")}|${t ? t.id + t.pending : ""}|${tr || ""}`;
      if (S.cellKeys[x][y] === sig) continue;
      S.cellKeys[x][y] = sig;
      const c = S.cells[x][y];
      const cls = ["cell"];
      if (b) cls.push("b");
      if (tr) { cls.push("trail"); c.style.setProperty("--trc", tr); }
      if (t) { cls.push("target"); if (t.pending) cls.push("pending"); c.style.setProperty("--tc", t.color); }
      if (ds.length) cls.push("has-drone");
      c.className = cls.join(" ");
      let title = `${x},${y},${z}${b ? " building" : ""}`;
      if (t) title += ` · target of ${t.id}`;
      if (ds.length) title += ` · ${ds.map((d) => `${d.id} (${d.status})`).join(", ")}`;
      c.title = title;
      c.replaceChildren();
      if (ds.length === 1) {
        const d = ds[0];
        const dead = d.status === "dead" || d.status === "lost";
        c.append(el("span", {class: `chip${dead ? " dead" : ""}`, style: `--c:${colorOf(d.id)}`}, d.id));
      } else if (ds.length > 1) {
        c.append(el("span", {class: "chip crowd"}, `${ds.length}×`));
      }
    }
  }
  for (const b of $("#floors").children) {
    const fz = Number(b.dataset.z);
    b.classList.toggle("active", fz === z);
    const d = view.drones.find((v) => v.pos[2] === fz && v.status !== "dead" && v.status !== "lost");
    b.classList.toggle("has-drone", !!d);
    if (d) b.style.setProperty("--dc", colorOf(d.id));
  }
}

// ------------------------------------------------------------------------------------------ 3D view

function renderIso(view) {
  const cv = $("#iso");
  const dpr = window.devicePixelRatio || 1;
  const [nx, ny, nz] = S.world.size;
  const R = S.rotation;
  const U = R % 2 === 0 ? nx : ny, V = R % 2 === 0 ? ny : nx;
  const k = 0.85, m = 26;
  const W = cv.clientWidth;
  if (!W) return;
  // as tall as the world needs at this width (a flat world gets a short canvas)
  const byWidth = (W - 2 * m) / (U + V);
  const H = Math.round(Math.min(640, Math.max(300, byWidth * ((U + V) / 2 + nz * k) + 2 * m + 14)));
  if (cv.style.height !== `${H}px`) cv.style.height = `${H}px`;
  if (cv.width !== Math.round(W * dpr) || cv.height !== Math.round(H * dpr)) {
    cv.width = Math.round(W * dpr);
    cv.height = Math.round(H * dpr);
  }
  const ctx = cv.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, W, H);
  const toUV = (x, y) => [[x, y], [y, nx - 1 - x], [nx - 1 - x, ny - 1 - y], [ny - 1 - y, x]][R];
  const fromUV = (u, v) => [[u, v], [nx - 1 - v, u], [nx - 1 - u, ny - 1 - v], [v, ny - 1 - u]][R];
  const hw = Math.max(2, Math.min((W - 2 * m) / (U + V), (H - 2 * m - 14) / ((U + V) / 2 + nz * k)));
  const hh = hw / 2, hz = hw * k;
  const ox = (W - (U + V) * hw) / 2 + U * hw;
  const oy = (H - ((U + V) * hh + nz * hz)) / 2 + nz * hz + 7;
  const P = (u, v, z) => [ox + (v - u) * hw, oy + (u + v) * hh - z * hz];
  const poly = (pts, fill, stroke) => {
    ctx.beginPath();
    pts.forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
    ctx.closePath();
    if (fill) { ctx.fillStyle = fill; ctx.fill(); }
    if (stroke) { ctx.strokeStyle = stroke; ctx.stroke(); }
  };
  const B = (u, v, z) => { const [x, y] = fromUV(u, v); return isBuilding(x, y, z); };
  const center = (c) => { const [u, v] = toUV(c[0], c[1]); return P(u + 0.5, v + 0.5, c[2] + 0.5); };

  // ground, with its grid
  poly([P(0, 0, 0), P(0, V, 0), P(U, V, 0), P(U, 0, 0)], "#dfe6f0", "#b8c3d3");
  ctx.lineWidth = 0.5;
  ctx.strokeStyle = "rgba(120,135,160,.35)";
  ctx.beginPath();
  for (let u = 1; u < U; u++) { const a = P(u, 0, 0), b = P(u, V, 0); ctx.moveTo(...a); ctx.lineTo(...b); }
  for (let v = 1; v < V; v++) { const a = P(0, v, 0), b = P(U, v, 0); ctx.moveTo(...a); ctx.lineTo(...b); }
  ctx.stroke();
  // the world's back edges
  ctx.setLineDash([3, 4]);
  ctx.strokeStyle = "rgba(100,115,140,.45)";
  ctx.beginPath();
  for (const [u, v] of [[0, 0], [0, V], [U, 0]]) { ctx.moveTo(...P(u, v, 0)); ctx.lineTo(...P(u, v, nz)); }
  ctx.moveTo(...P(0, V, nz)); ctx.lineTo(...P(0, 0, nz)); ctx.lineTo(...P(U, 0, nz));
  ctx.stroke();
  ctx.setLineDash([]);
  ctx.lineWidth = 1;
  // three ground corners with their (x, y), so the rotation stays readable
  ctx.font = "11px DejaVu Sans, sans-serif";
  ctx.textAlign = "center";
  ctx.fillStyle = "#56627a";
  const mid = P(U / 2, V / 2, 0);
  for (const [x, y] of [[0, 0], [nx - 1, 0], [0, ny - 1]]) {
    const [u, v] = toUV(x, y);
    const c = P(u + 0.5, v + 0.5, 0);
    const dx = c[0] - mid[0], dy = c[1] - mid[1], n = Math.hypot(dx, dy) || 1;
    ctx.fillText(`${x},${y}`, c[0] + (dx / n) * hw * 1.3, c[1] + (dy / n) * hw * 1.3 + 4);
  }

  // buildings: exposed faces only, back to front
  const cubes = [];
  for (let u = 0; u < U; u++) for (let v = 0; v < V; v++) for (let z = 0; z < nz; z++) {
    if (B(u, v, z)) cubes.push([u, v, z]);
  }
  cubes.sort((a, b) => (a[0] + a[1] + a[2]) - (b[0] + b[1] + b[2]) || a[2] - b[2]);
  ctx.lineWidth = 0.6;
  for (const [u, v, z] of cubes) {
    const shade = 0.82 + 0.18 * (z / Math.max(1, nz - 1));
    const c = (r, g, b) => `rgb(${Math.round(r * shade)},${Math.round(g * shade)},${Math.round(b * shade)})`;
    if (!B(u + 1, v, z)) poly([P(u + 1, v, z + 1), P(u + 1, v + 1, z + 1), P(u + 1, v + 1, z), P(u + 1, v, z)], c(126, 142, 166), "rgba(40,50,70,.35)");
    if (!B(u, v + 1, z)) poly([P(u, v + 1, z + 1), P(u + 1, v + 1, z + 1), P(u + 1, v + 1, z), P(u, v + 1, z)], c(96, 111, 136), "rgba(40,50,70,.35)");
    if (!B(u, v, z + 1)) poly([P(u, v, z + 1), P(u, v + 1, z + 1), P(u + 1, v + 1, z + 1), P(u + 1, v, z + 1)], c(190, 202, 220), "rgba(40,50,70,.35)");
  }
  ctx.lineWidth = 1;

  // the selected floor
  const f = S.floor;
  poly([P(0, 0, f), P(0, V, f), P(U, V, f), P(U, 0, f)], "rgba(47,111,222,.08)", "rgba(47,111,222,.65)");
  ctx.fillStyle = "rgba(47,111,222,.9)";
  ctx.textAlign = "left";
  ctx.fillText(`blue plane: the floor shown, z = ${f}`, 10, 18);

  // trails
  ctx.lineJoin = "round";
  for (const d of view.drones) {
    const pts = (d.trail || []).filter(inside);
    if (pts.length < 2) continue;
    ctx.strokeStyle = colorOf(d.id);
    ctx.globalAlpha = 0.75;
    ctx.lineWidth = Math.max(1.5, hw * 0.12);
    ctx.beginPath();
    pts.forEach((p, i) => { const [x, y] = center(p); i ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
    ctx.stroke();
  }
  ctx.globalAlpha = 1;
  ctx.lineWidth = 1;

  // targets: a ring with a line down to the ground
  for (const d of view.drones) {
    const t = d.wanted || d.target;
    if (!t || d.status === "dead" || d.status === "lost" || !inside(t)) continue;
    const [x, y] = center(t);
    const [u, v] = toUV(t[0], t[1]);
    const g = P(u + 0.5, v + 0.5, 0);
    ctx.strokeStyle = colorOf(d.id);
    ctx.setLineDash([2, 3]);
    ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(g[0], g[1]); ctx.stroke();
    ctx.setLineDash(d.wanted && !same(d.wanted, d.target) ? [3, 3] : []);
    ctx.lineWidth = 2.5;
    ctx.beginPath(); ctx.ellipse(x, y, hw * 0.55, hw * 0.3, 0, 0, 2 * Math.PI); ctx.stroke();
    ctx.setLineDash([]);
    ctx.lineWidth = 1;
  }

  // drones: a shadow on the ground, a ball, the id
  const order = [...view.drones].filter((d) => inside(d.pos))
    .sort((a, b) => { const [ua, va] = toUV(a.pos[0], a.pos[1]), [ub, vb] = toUV(b.pos[0], b.pos[1]); return ua + va + a.pos[2] - (ub + vb + b.pos[2]); });
  for (const d of order) {
    const [x, y] = center(d.pos);
    const [u, v] = toUV(d.pos[0], d.pos[1]);
    const g = P(u + 0.5, v + 0.5, 0);
    const dead = d.status === "dead" || d.status === "lost";
    const r = Math.max(4, hw * 0.42);
    ctx.fillStyle = "rgba(20,30,50,.18)";
    ctx.beginPath(); ctx.ellipse(g[0], g[1], r, r * 0.5, 0, 0, 2 * Math.PI); ctx.fill();
    if (d.pos[2] > 0) {
      ctx.strokeStyle = "rgba(20,30,50,.25)";
      ctx.beginPath(); ctx.moveTo(g[0], g[1]); ctx.lineTo(x, y); ctx.stroke();
    }
    const grad = ctx.createRadialGradient(x - r * 0.35, y - r * 0.35, r * 0.1, x, y, r);
    grad.addColorStop(0, "#ffffff");
    grad.addColorStop(0.35, dead ? "#9aa0aa" : colorOf(d.id));
    grad.addColorStop(1, dead ? "#5c626c" : colorOf(d.id));
    ctx.fillStyle = grad;
    ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.fill();
    ctx.strokeStyle = "#fff"; ctx.lineWidth = 1.5; ctx.stroke(); ctx.lineWidth = 1;
    if (dead) {
      ctx.strokeStyle = "#fff"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(x - r * .5, y - r * .5); ctx.lineTo(x + r * .5, y + r * .5);
      ctx.moveTo(x + r * .5, y - r * .5); ctx.lineTo(x - r * .5, y + r * .5); ctx.stroke(); ctx.lineWidth = 1;
    }
    ctx.font = "bold 11px DejaVu Sans, sans-serif";
    ctx.textAlign = "center";
    const tw = ctx.measureText(d.id).width + 8;
    ctx.fillStyle = "rgba(255,255,255,.9)";
    ctx.fillRect(x - tw / 2, y - r - 17, tw, 14);
    ctx.fillStyle = dead ? "#5c626c" : "#1d2433";
    ctx.fillText(d.id, x, y - r - 6);
  }
}

// ------------------------------------------------------------------------------------------ side panels

function renderDrones(view) {
  const body = $("#drones tbody");
  const rows = view.drones.map((d) => {
    const pending = d.wanted && !same(d.wanted, d.target);
    const tgt = d.wanted || d.target;
    const st = el("span", {class: `st st-${d.status}`, "data-status": d.status}, STATUS_TEXT[d.status] || d.status);
    if (d.cause_text) st.title = d.cause_text;
    const tr = el("tr", {id: `drone-${d.id}`, "data-drone": d.id, class: d.id === S.selected ? "selected" : ""},
      el("td", {}, el("span", {class: "swatch", style: `--c:${colorOf(d.id)}`})),
      el("td", {class: "id"}, el("strong", {}, d.id)),
      el("td", {class: "pos"}, fmt(d.pos)),
      el("td", {class: "status"}, st),
      el("td", {class: "target"}, fmt(tgt), pending ? el("span", {class: "pending-tag", title: "sent at the next GCS phase"}, "pending") : ""));
    tr.addEventListener("click", () => selectDrone(d.id, true));
    return tr;
  });
  body.replaceChildren(...rows);
  const sel = $("#target-drone");
  const ids = view.drones.map((d) => d.id).join(",");
  if (sel.dataset.ids !== ids) {
    sel.replaceChildren(...view.drones.map((d) => el("option", {value: d.id}, d.id)));
    sel.dataset.ids = ids;
  }
  for (const o of sel.options) {
    const d = view.drones.find((v) => v.id === o.value);
    o.disabled = !d || d.status === "dead" || d.status === "lost";
    o.textContent = d && o.disabled ? `${d.id} (${d.status})` : o.value;
  }
  if (S.selected) sel.value = S.selected;
}

function selectDrone(id, jump) {
  S.selected = id;
  $("#target-drone").value = id;
  if (jump) S.followFloor = true;
  render();
}

function renderLog(view) {
  const log = $("#log");
  const items = view.log || [];
  const sig = `${items.length}|${items.length ? items[items.length - 1].text : ""}`;
  if (log.dataset.sig === sig) return;
  log.dataset.sig = sig;
  log.replaceChildren(...items.slice().reverse().map((e) =>
    el("li", {class: `k-${e.kind}`}, el("span", {class: "t"}, `t${e.turn}`), e.text)));
}

function renderHeader(view) {
  $("#turn").textContent = String(view.turn);
  $("#phase").textContent = view.phase && !view.over ? `${view.phase} phase` : "";
  $("#gamestate").textContent = view.control ? view.control.text : "";
  const over = $("#over");
  if (view.over) {
    over.hidden = false;
    over.textContent = `GAME OVER at turn ${view.over.turn}: ${view.over.reason}${view.over.text ? " — " + view.over.text : ""}`;
    over.classList.toggle("bad", view.over.reason === "NO_DRONE_ALIVE" || view.over.reason === "ABORTED");
  } else {
    over.hidden = true;
  }
  if (S.mode === "live") {
    const ended = !!view.over;
    for (const id of ["#pause", "#step", "#pace", "#quit", "#target-set", "#target-input", "#target-drone"]) $(id).disabled = ended;
    if (ended) $("#quit-confirm").hidden = true;
    const c = view.control || {};
    $("#pause").textContent = c.paused ? "Resume" : "Pause";
    const pace = $("#pace");
    if (document.activeElement !== pace) {
      const v = String(c.pace);
      if (![...pace.options].some((o) => o.value === v)) pace.append(el("option", {value: v}, `${v} s / turn`));
      pace.value = v;
    }
  }
}

function render() {
  const view = S.view;
  if (!view || !S.world) return;
  if (!S.selected || !view.drones.some((d) => d.id === S.selected)) {
    const first = view.drones.find((d) => d.status !== "dead" && d.status !== "lost") || view.drones[0];
    S.selected = first ? first.id : null;
  }
  if (S.followFloor && S.selected) {
    const d = view.drones.find((v) => v.id === S.selected);
    if (d && inside(d.pos)) S.floor = d.pos[2];
  }
  renderHeader(view);
  renderDrones(view);
  renderFloor(view);
  renderIso(view);
  renderLog(view);
}

// ------------------------------------------------------------------------------------------ live mode

function setConn(state, text) {
  const c = $("#conn");
  c.dataset.state = state;
  c.textContent = text || state;
}

function connectLive() {
  const es = new EventSource("/api/events");
  S.es = es;
  es.addEventListener("state", (ev) => {
    S.view = JSON.parse(ev.data);
    setConn("live");
    render();
    if (S.view.over) { es.close(); setConn("ended", "game over"); }
  });
  es.addEventListener("end", () => { es.close(); setConn("ended", "ended"); });
  es.onopen = () => setConn("live");
  es.onerror = () => {
    if (es.readyState === EventSource.CLOSED) setConn("ended", "disconnected");
    else setConn("reconnecting", "reconnecting…");
  };
}

function setupLive() {
  $("#target-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    const text = $("#target-input").value;
    const p = parseCell(text);
    if (p.error) { say(p.error, "error"); return; }
    S.followFloor = false;
    if (inside(p.cell)) S.floor = p.cell[2];
    sendTarget($("#target-drone").value, p.cell);
  });
  $("#target-drone").addEventListener("change", (ev) => selectDrone(ev.target.value, true));
  $("#pause").addEventListener("click", () => control(S.view && S.view.control.paused ? "resume" : "pause"));
  $("#step").addEventListener("click", () => control("step"));
  $("#pace").addEventListener("change", (ev) => control("pace", Number(ev.target.value)));
  $("#quit").addEventListener("click", () => { $("#quit-confirm").hidden = false; });
  $("#quit-no").addEventListener("click", () => { $("#quit-confirm").hidden = true; });
  $("#quit-yes").addEventListener("click", () => { $("#quit-confirm").hidden = true; control("quit"); });
  connectLive();
}

// ------------------------------------------------------------------------------------------ replay mode

function replayView(i) {
  const frames = S.replay.frames;
  const f = frames[i];
  const trails = {};
  const log = [];
  for (let j = 0; j <= i; j++) {
    for (const d of frames[j].drones) {
      const t = (trails[d.id] ||= []);
      const last = t[t.length - 1];
      if (!last || !same(last, d.pos)) t.push(d.pos);
    }
    log.push(...frames[j].events);
  }
  const lastTurn = frames[frames.length - 1].turn;
  const over = i === frames.length - 1 ? S.replay.over : null;
  return {
    mode: "replay", turn: f.turn, phase: null, over, log: log.slice(-300),
    drones: f.drones.map((d) => ({...d, wanted: null, trail: trails[d.id]})),
    control: {text: `replay: turn ${f.turn} of ${lastTurn}${S.timer ? " (playing)" : ""}`},
  };
}

function showFrame(i) {
  const n = S.replay.frames.length;
  S.frame = Math.max(0, Math.min(n - 1, i));
  $("#rp-slider").value = String(S.frame);
  S.view = replayView(S.frame);
  render();
}

function play(on) {
  if (S.timer) { clearInterval(S.timer); S.timer = null; }
  if (on) {
    if (S.frame >= S.replay.frames.length - 1) showFrame(0);
    S.timer = setInterval(() => {
      if (S.frame >= S.replay.frames.length - 1) { play(false); return; }
      showFrame(S.frame + 1);
    }, Number($("#rp-speed").value));
  }
  $("#rp-play").innerHTML = S.timer ? "&#x23F8; pause" : "&#x25B6; play";
  if (S.view) { S.view = replayView(S.frame); render(); }
}

async function setupReplay() {
  $("#replay-controls").hidden = false;
  $("#live-controls").hidden = true;
  $("#target-panel").hidden = true;
  $("#click-hint").textContent = "a replay: read only";
  const r = await fetch("/api/replay");
  if (!r.ok) { setConn("ended", "no replay"); return; }
  S.replay = await r.json();
  $("#replay-name").textContent = S.replay.journal;
  const slider = $("#rp-slider");
  slider.max = String(S.replay.frames.length - 1);
  slider.addEventListener("input", () => { play(false); showFrame(Number(slider.value)); });
  $("#rp-play").addEventListener("click", () => play(!S.timer));
  $("#rp-back").addEventListener("click", () => { play(false); showFrame(S.frame - 1); });
  $("#rp-fwd").addEventListener("click", () => { play(false); showFrame(S.frame + 1); });
  $("#rp-start").addEventListener("click", () => { play(false); showFrame(0); });
  $("#rp-end").addEventListener("click", () => { play(false); showFrame(S.replay.frames.length - 1); });
  $("#rp-speed").addEventListener("change", () => { if (S.timer) play(true); });
  setConn("ended", "journal");
  showFrame(0);
}

// ------------------------------------------------------------------------------------------ start

async function main() {
  $("#rot-left").addEventListener("click", () => { S.rotation = (S.rotation + 3) % 4; render(); });
  $("#rot-right").addEventListener("click", () => { S.rotation = (S.rotation + 1) % 4; render(); });
  document.addEventListener("keydown", (ev) => {
    if (ev.target && ["INPUT", "SELECT", "TEXTAREA"].includes(ev.target.tagName)) return;
    if (!S.world) return;
    if (ev.key === "PageUp" || ev.key === "]") { S.followFloor = false; setFloor(Math.min(S.world.size[2] - 1, S.floor + 1)); }
    if (ev.key === "PageDown" || ev.key === "[") { S.followFloor = false; setFloor(Math.max(0, S.floor - 1)); }
  });
  let world = null;
  for (let attempt = 0; !world; attempt++) {
    try {
      const r = await fetch("/api/world");
      if (r.ok) world = await r.json();
    } catch (e) { /* retried below */ }
    if (!world) { setConn("reconnecting", "waiting for the ground station…"); await new Promise((ok) => setTimeout(ok, 1000)); }
  }
  S.world = world;
  S.mode = world.mode;
  const badge = $("#mode");
  badge.textContent = world.mode === "replay" ? "REPLAY" : "LIVE";
  badge.classList.toggle("replay", world.mode === "replay");
  if (world.title) document.title = `dronesim ground station — ${world.title}`;
  buildGrid();
  window.addEventListener("resize", () => { buildGrid(); render(); });
  if (world.mode === "replay") await setupReplay(); else setupLive();
}

main();
