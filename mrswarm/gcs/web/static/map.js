// mrswarm live map: draws what the server pushes over /ws (the swarm frame: metres east, north from
// the swarm origin) and sends the operator's commands back. No external asset, no library.
// window.mrswarm holds the state the page draws (tests read it; so can a user in the console).
"use strict";
(() => {
  const TRAIL = 4000;          // points kept per UAV trail, a metre apart (the server sends the trails from the run's start)
  const TRAIL_STEP = 1.0;      // m between two trail points
  const HIT_PX = 14;           // a click this close to a UAV selects it
  const COLORS = { virtual: "#4a90e2", physical: "#f08c2a", stale: "#5b6570", override: "#e6c35c", failsafe: "#ff5b4b" };
  const canvas = document.getElementById("map");
  const ctx = canvas.getContext("2d");
  const $ = (id) => document.getElementById(id);

  const S = window.mrswarm = {
    swarm: "", connected: false, t: 0, uavs: {}, trails: {}, scene: {}, selected: [], commands: [], lastReply: null,
    view: { scale: 3, cx: 0, cy: 0, fitted: false }, gotoMode: false,
    // where UAV `id` is drawn, in page coordinates (CSS px): what a click on it needs
    screenOf(id) {
      const u = S.uavs[id];
      if (!u) return null;
      const p = toScreen(u.x, u.y), r = canvas.getBoundingClientRect();
      return { x: r.left + p.x, y: r.top + p.y };
    },
    select(ids) { S.selected = [...new Set(ids)].filter((id) => id in S.uavs).sort((a, b) => a - b); render(); },
    send(verb, args) {
      if (!S.selected.length || !ws || ws.readyState !== WebSocket.OPEN) return false;
      ws.send(JSON.stringify({ op: "command", verb, uavs: S.selected.slice(), args: args || {} }));
      return true;
    },
    fit,
  };

  // ---- view: world (m, y north) <-> canvas (CSS px, y down) -------------------------------------
  function size() { const r = canvas.getBoundingClientRect(); return { w: r.width, h: r.height }; }
  function toScreen(x, y) {
    const { w, h } = size();
    return { x: w / 2 + (x - S.view.cx) * S.view.scale, y: h / 2 - (y - S.view.cy) * S.view.scale };
  }
  function toWorld(px, py) {
    const { w, h } = size();
    return { x: S.view.cx + (px - w / 2) / S.view.scale, y: S.view.cy - (py - h / 2) / S.view.scale };
  }
  function fit() {
    const us = Object.values(S.uavs);
    const pts = us.map((u) => [u.x, u.y]), sc = S.scene;
    if (sc.area) pts.push([sc.area[0], sc.area[2]], [sc.area[1], sc.area[3]]);
    for (const z of sc.zones || []) pts.push(...z.polygon);
    if (sc.hub) pts.push([sc.hub[0] - sc.hub[2], sc.hub[1] - sc.hub[2]], [sc.hub[0] + sc.hub[2], sc.hub[1] + sc.hub[2]]);
    for (const tr of Object.values(S.trails)) pts.push(...tr);
    if (!pts.length) return;
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (const [x, y] of pts) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
    const { w, h } = size();
    S.view.cx = (x0 + x1) / 2; S.view.cy = (y0 + y1) / 2;
    S.view.scale = Math.max(0.02, Math.min(40, Math.min(w / (x1 - x0 + 60), h / (y1 - y0 + 60))));
    S.view.fitted = true;
    draw();
  }
  function resize() {
    const dpr = window.devicePixelRatio || 1, { w, h } = size();
    canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    draw();
  }

  // ---- drawing ----------------------------------------------------------------------------------
  function niceStep(minPx) {
    const raw = minPx / S.view.scale, p = Math.pow(10, Math.floor(Math.log10(raw)));
    for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
    return 10 * p;
  }
  function colorOf(u) {
    if (u.stale) return COLORS.stale;
    if (u.failsafe) return COLORS.failsafe;
    if (u.override) return COLORS.override;
    return COLORS[u.realm] || COLORS.virtual;
  }
  function draw() {
    const { w, h } = size();
    ctx.clearRect(0, 0, w, h);
    const step = niceStep(70), a = toWorld(0, h), b = toWorld(w, 0);
    ctx.lineWidth = 1; ctx.strokeStyle = "#1f262e"; ctx.beginPath();
    for (let x = Math.ceil(a.x / step) * step; x <= b.x; x += step) { const s = toScreen(x, 0).x; ctx.moveTo(s, 0); ctx.lineTo(s, h); }
    for (let y = Math.ceil(a.y / step) * step; y <= b.y; y += step) { const s = toScreen(0, y).y; ctx.moveTo(0, s); ctx.lineTo(w, s); }
    ctx.stroke();
    const o = toScreen(0, 0);
    ctx.strokeStyle = "#56616c"; ctx.beginPath(); ctx.moveTo(o.x - 8, o.y); ctx.lineTo(o.x + 8, o.y); ctx.moveTo(o.x, o.y - 8); ctx.lineTo(o.x, o.y + 8); ctx.stroke();
    $("scale").textContent = `grid ${step} m · origin +`;
    drawScene();
    for (const [id, pts] of Object.entries(S.trails)) {
      const u = S.uavs[id];
      if (pts.length < 2) continue;
      ctx.strokeStyle = u ? colorOf(u) : COLORS.stale; ctx.globalAlpha = 0.45; ctx.lineWidth = 1.5; ctx.beginPath();
      pts.forEach((p, i) => { const s = toScreen(p[0], p[1]); if (i) ctx.lineTo(s.x, s.y); else ctx.moveTo(s.x, s.y); });
      ctx.stroke(); ctx.globalAlpha = 1;
    }
    ctx.font = "11px system-ui, sans-serif";
    for (const u of Object.values(S.uavs)) {
      const s = toScreen(u.x, u.y), c = colorOf(u);
      ctx.save(); ctx.translate(s.x, s.y); ctx.rotate(-u.yaw);  // yaw: ENU, 0 = east, counter-clockwise
      ctx.fillStyle = c; ctx.beginPath(); ctx.moveTo(11, 0); ctx.lineTo(-7, 6); ctx.lineTo(-4, 0); ctx.lineTo(-7, -6); ctx.closePath(); ctx.fill();
      ctx.restore();
      if (S.selected.includes(u.id)) { ctx.strokeStyle = "#ffffff"; ctx.lineWidth = 2; ctx.beginPath(); ctx.arc(s.x, s.y, 15, 0, 2 * Math.PI); ctx.stroke(); }
      ctx.fillStyle = u.stale ? COLORS.stale : "#dde3ea";
      ctx.fillText(`${u.id} ${u.phase}${u.override ? " (" + u.override + ")" : ""}`, s.x + 13, s.y - 9);
    }
  }

  // the run's fixed layer: mission area (dashed), no-fly zones and obstacles (hatched red), the hub (circle)
  function drawScene() {
    const sc = S.scene;
    ctx.save();
    if (sc.area) {
      const a = toScreen(sc.area[0], sc.area[3]), b = toScreen(sc.area[1], sc.area[2]);
      ctx.setLineDash([6, 4]); ctx.strokeStyle = "#8fa3b8"; ctx.lineWidth = 1.2;
      ctx.strokeRect(a.x, a.y, b.x - a.x, b.y - a.y); ctx.setLineDash([]);
      ctx.fillStyle = "#8fa3b8"; ctx.font = "11px system-ui, sans-serif"; ctx.fillText(sc.area_label || "mission area", a.x + 4, a.y + 13);
    }
    for (const z of sc.zones || []) {
      if (!z.polygon.length) continue;
      ctx.beginPath();
      z.polygon.forEach(([x, y], i) => { const s = toScreen(x, y); if (i) ctx.lineTo(s.x, s.y); else ctx.moveTo(s.x, s.y); });
      ctx.closePath();
      ctx.fillStyle = "rgba(255, 91, 75, 0.18)"; ctx.fill();
      ctx.strokeStyle = "#ff5b4b"; ctx.lineWidth = 1.5; ctx.stroke();
      const c = z.polygon.reduce((m, p) => [m[0] + p[0] / z.polygon.length, m[1] + p[1] / z.polygon.length], [0, 0]), s = toScreen(c[0], c[1]);
      ctx.fillStyle = "#ff8a7d"; ctx.font = "11px system-ui, sans-serif"; ctx.textAlign = "center";
      ctx.fillText(z.name || z.kind.replace("_", "-"), s.x, s.y); ctx.textAlign = "start";
    }
    if (sc.hub) {
      const s = toScreen(sc.hub[0], sc.hub[1]);
      ctx.strokeStyle = "#5fb3f0"; ctx.lineWidth = 1.5; ctx.beginPath(); ctx.arc(s.x, s.y, sc.hub[2] * S.view.scale, 0, 2 * Math.PI); ctx.stroke();
      ctx.fillStyle = "#5fb3f0"; ctx.font = "11px system-ui, sans-serif"; ctx.textAlign = "center"; ctx.fillText("hub", s.x, s.y + 4); ctx.textAlign = "start";
    }
    ctx.restore();
  }

  // ---- side panel -------------------------------------------------------------------------------
  const fmt = (v, d) => (v === null || v === undefined ? "-" : Number(v).toFixed(d));
  function render() {
    const us = Object.values(S.uavs).sort((a, b) => a.id - b.id);
    const stale = us.filter((u) => u.stale).length, over = us.filter((u) => u.override).length;
    $("counts").textContent = `${us.length} UAVs · ${stale} stale · ${over} overridden`;
    const body = document.querySelector("#uavs tbody");
    body.replaceChildren(...us.map((u) => {
      const tr = document.createElement("tr");
      tr.dataset.uav = u.id; tr.dataset.x = u.x; tr.dataset.y = u.y; tr.dataset.phase = u.phase;
      tr.className = [S.selected.includes(u.id) && "selected", u.stale && "stale", u.override && "override", u.failsafe && "failsafe"].filter(Boolean).join(" ");
      const cells = [u.id, u.realm === "physical" ? "P" : "V", u.phase + (u.override ? ` (${u.override})` : ""), u.mode, fmt(u.z, 1),
        fmt(u.speed, 1), u.battery === null ? "-" : fmt(u.battery * 100, 0), fmt(u.age_ms, 0), fmt(u.seen_s, 1)];
      for (const c of cells) { const td = document.createElement("td"); td.textContent = c; tr.appendChild(td); }
      tr.addEventListener("click", (e) => S.select(e.shiftKey ? toggle(u.id) : [u.id]));
      return tr;
    }));
    $("selcount").textContent = S.selected.length;
    $("selection").textContent = S.selected.length ? "UAV " + S.selected.join(", ") : "click a UAV on the map or in the table";
    for (const b of document.querySelectorAll("#buttons button")) b.disabled = !S.selected.length || !S.connected;
    const list = $("commands");
    list.replaceChildren(...S.commands.flatMap((c) => c.targets.map((t) => {
      const li = document.createElement("li");
      li.dataset.cmd = c.id; li.dataset.uav = t.uav; li.dataset.verb = c.verb; li.dataset.status = t.status; li.className = t.status;
      const ms = t.latency_ms === null ? "" : ` ${Math.round(t.latency_ms)} ms`;
      li.textContent = `#${c.id} ${c.verb} → UAV ${t.uav}: ${t.status}${ms}${t.message ? ": " + t.message : ""}`;
      return li;
    })));
    draw();
  }
  const toggle = (id) => (S.selected.includes(id) ? S.selected.filter((x) => x !== id) : [...S.selected, id]);

  // ---- the server -------------------------------------------------------------------------------
  let ws = null;
  function connect() {
    ws = new WebSocket(`ws://${location.host}/ws`);
    ws.onopen = () => { S.connected = true; $("status").textContent = "live"; $("status").className = "status on"; render(); };
    ws.onclose = () => {
      S.connected = false; $("status").textContent = "disconnected: retrying"; $("status").className = "status off"; render();
      setTimeout(connect, 1000);
    };
    ws.onmessage = (ev) => {
      const m = JSON.parse(ev.data);
      if (m.type === "hello") {
        S.swarm = m.swarm; $("swarm").textContent = "swarm " + m.swarm; document.title = `mrswarm ${m.swarm}`;
        S.scene = m.scene || {};
        for (const [id, pts] of Object.entries(m.trails || {})) S.trails[id] = pts.slice(-TRAIL);  // from the run's start
        S.view.fitted = false;
      }
      else if (m.type === "state") update(m);
      else if (m.type === "sent" || m.type === "error") { S.lastReply = m; if (m.type === "error") $("selection").textContent = "error: " + m.message; }
    };
  }
  function update(m) {
    S.t = m.t;
    const now = {};
    for (const u of m.uavs) {
      now[u.id] = u;
      const tr = S.trails[u.id] || (S.trails[u.id] = []), last = tr[tr.length - 1];
      if (!last || Math.hypot(last[0] - u.x, last[1] - u.y) >= TRAIL_STEP) { tr.push([u.x, u.y]); if (tr.length > TRAIL) tr.shift(); }
    }
    S.uavs = now;  // a UAV gone from the swarm keeps its trail (where it flew), drawn grey
    S.selected = S.selected.filter((id) => id in now);
    S.commands = m.commands;
    if (!S.view.fitted) fit();
    render();
  }

  // ---- input ------------------------------------------------------------------------------------
  let drag = null;
  canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, y: e.clientY, cx: S.view.cx, cy: S.view.cy, moved: false }; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 3) drag.moved = true;
    if (drag.moved) { S.view.cx = drag.cx - dx / S.view.scale; S.view.cy = drag.cy + dy / S.view.scale; draw(); }
  });
  window.addEventListener("mouseup", (e) => {
    const d = drag; drag = null;
    if (!d || d.moved || e.target !== canvas) return;
    const r = canvas.getBoundingClientRect(), px = e.clientX - r.left, py = e.clientY - r.top;
    if (S.gotoMode) {
      const w = toWorld(px, py), z = Number($("gotoalt").value);
      S.send("goto", { x: Math.round(w.x * 10) / 10, y: Math.round(w.y * 10) / 10, z });
      setGoto(false);
      return;
    }
    let best = null, bestD = HIT_PX;
    for (const u of Object.values(S.uavs)) { const s = toScreen(u.x, u.y), dd = Math.hypot(s.x - px, s.y - py); if (dd <= bestD) { best = u.id; bestD = dd; } }
    if (best !== null) S.select(e.shiftKey ? toggle(best) : [best]);
    else if (!e.shiftKey) S.select([]);
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const r = canvas.getBoundingClientRect(), px = e.clientX - r.left, py = e.clientY - r.top, before = toWorld(px, py);
    S.view.scale = Math.max(0.02, Math.min(200, S.view.scale * Math.exp(-e.deltaY * 0.0015)));
    const after = toWorld(px, py);
    S.view.cx += before.x - after.x; S.view.cy += before.y - after.y;
    draw();
  }, { passive: false });
  function setGoto(on) { S.gotoMode = on; canvas.classList.toggle("goto", on); $("gotohint").hidden = !on; }
  for (const b of document.querySelectorAll("#buttons button")) {
    b.addEventListener("click", () => { if (b.dataset.verb === "goto") setGoto(true); else S.send(b.dataset.verb); });
  }
  window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement) return;
    if (e.key === "Escape") setGoto(false);
    if (e.key === "f") fit();
  });
  window.addEventListener("resize", resize);
  resize();
  connect();
})();
