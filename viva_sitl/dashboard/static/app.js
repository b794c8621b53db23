// viva-sitl dashboard: plain ES module, no build step. Talks to /ws (JSON) and /ws/vac (binary JPEG frames).
const $ = (id) => document.getElementById(id);
const fmt = (v, nd = 1, unit = "") => (v === null || v === undefined ? "–" : `${Number(v).toFixed(nd)}${unit}`);

const S = {
  info: null, state: null, ws: null, role: "read-only", trail: [], keys: new Set(), lastSticks: null,
  view: null, follow: false, bg: null, bgLoading: false, bgWanted: 0, cmdId: 1, killTimer: null,
};

// ---------------------------------------------------------------- JSON socket
function wsUrl(path) { return `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${path}`; }

function connect() {
  const ws = new WebSocket(wsUrl("/ws"));
  S.ws = ws;
  ws.onopen = () => { $("conn").textContent = "connected"; $("conn").className = "ok"; };
  ws.onclose = () => {
    $("conn").textContent = "disconnected: retrying"; $("conn").className = "bad"; setRole("read-only");
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    let m; try { m = JSON.parse(ev.data); } catch { return; }
    if (m.t === "state") onState(m);
    else if (m.t === "statustext") addStatus(m);
    else if (m.t === "ack") onAck(m);
    else if (m.t === "role" || m.t === "hello") setRole(m.role, m.reason);
    else if (m.t === "error") $("last-result").textContent = `ignored: ${m.reason}`;
  };
}
function send(obj) { if (S.ws && S.ws.readyState === WebSocket.OPEN) S.ws.send(JSON.stringify(obj)); }
function setRole(role, reason) {
  S.role = role || "read-only";
  $("role").textContent = S.role + (reason ? ` (${reason})` : "");
  $("role").dataset.role = S.role;
  for (const b of document.querySelectorAll("#fly button, #mode-select")) b.disabled = S.role !== "pilot";
}
function command(cmd, extra = {}) {
  const id = S.cmdId++;
  send({ t: "cmd", id, cmd, ...extra });
}
function onAck(m) {
  const el = $("last-result");
  el.textContent = m.ok ? `${m.cmd}: accepted` : `${m.cmd}: ${m.result} — ${m.reason}`;
  el.className = m.ok ? "ok" : "bad";
  el.dataset.ok = String(m.ok);
}
function addStatus(m) {
  const li = document.createElement("li");
  li.className = `sev${m.severity}`;
  li.textContent = `[${fmt(m.sim_time_s, 1)} s] ${m.text}`;
  const ol = $("statustext"); ol.appendChild(li);
  while (ol.children.length > 100) ol.removeChild(ol.firstChild);
  ol.scrollTop = ol.scrollHeight;
}

// ---------------------------------------------------------------- HUD
function setHud(id, text, value) { const el = $(id); el.textContent = text; if (value !== undefined) el.dataset.value = String(value); }
function onState(s) {
  S.state = s;
  const vx = s.vehicle_px;
  const last = S.trail[S.trail.length - 1];
  if (!last || Math.hypot(vx[0] - last[0], vx[1] - last[1]) > 0.5) { S.trail.push(vx); if (S.trail.length > 4000) S.trail.shift(); }
  setHud("hud-mode", s.mode, s.mode);
  setHud("hud-armed", s.armed ? "ARMED" : "disarmed", s.armed);
  setHud("hud-alt", fmt(s.alt_agl_m, 2, " m"), s.alt_agl_m);
  setHud("hud-alt-home", fmt(s.alt_rel_home_m, 2, " m"), s.alt_rel_home_m);
  setHud("hud-gs", fmt(s.ground_speed_m_s, 2, " m/s"), s.ground_speed_m_s);
  setHud("hud-vs", fmt(s.vertical_speed_m_s, 2, " m/s"), s.vertical_speed_m_s);
  setHud("hud-rp", `${fmt(s.att_deg[0], 1)}° / ${fmt(s.att_deg[1], 1)}°`);
  setHud("hud-hdg", fmt(s.heading_deg, 1, "°"), s.heading_deg);
  setHud("hud-bat", `${fmt(s.battery_pct, 0, " %")} ${fmt(s.battery_v, 2, " V")}`, s.battery_pct);
  setHud("hud-landed", s.landed_state, s.landed_state);
  setHud("hud-time", fmt(s.sim_time_s, 1, " s"), s.sim_time_s);
  setHud("hud-speed", `×${fmt(s.speed, 1)} (measured ${fmt(s.measured_speed, 2)})`, s.speed);
  setHud("hud-frame", `${s.footage_frame} / ${s.footage_frames}`, s.footage_frame);
  const d = s.dropped;
  setHud("hud-dropped", `render ${d.render_late} · video ${d.video_dropped} · page ${d.vac_page_drops}`);
  const st = s.rc.sticks;
  setHud("hud-sticks", s.rc.feeding ? `x ${st.x.toFixed(2)} y ${st.y.toFixed(2)} z ${st.z.toFixed(2)} r ${st.r.toFixed(2)} (page ${s.rc.pilot_page ?? "none: centred"})` : "off (no page has taken control)");
  setHud("hud-links", s.links.length ? s.links.map((l) => `${l.link} ${l.peer} ${l.ok ? "ok" : "LOST"} (${l.age_s} s)`).join(" · ") : "no peer");
  if (S.follow && S.view) { S.view.cx = vx[0]; S.view.cy = vx[1]; }
}

// ---------------------------------------------------------------- VAC
function connectVac() {
  const ws = new WebSocket(wsUrl("/ws/vac"));
  ws.binaryType = "arraybuffer";
  const canvas = $("vac"), ctx = canvas.getContext("2d");
  let busy = false, next = null;
  const draw = async (buf) => {
    busy = true;
    try {
      const n = new DataView(buf).getUint32(0, true);
      const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
      const bmp = await createImageBitmap(new Blob([new Uint8Array(buf, 4 + n)], { type: "image/jpeg" }));
      if (canvas.width !== bmp.width || canvas.height !== bmp.height) { canvas.width = bmp.width; canvas.height = bmp.height; }
      ctx.drawImage(bmp, 0, 0); bmp.close();
      canvas.dataset.frameCounter = String(head.frame_counter);
      canvas.dataset.simTime = String(head.sim_time_s);
      canvas.dataset.latencyMs = String(Math.round(Date.now() - head.wall_time_s * 1000));
      $("vac-info").textContent = `frame ${head.frame_counter} · t ${head.sim_time_s.toFixed(2)} s · ${canvas.dataset.latencyMs} ms`;
    } catch (e) { /* a bad frame is skipped */ }
    busy = false;
    if (next) { const b = next; next = null; draw(b); }
  };
  ws.onmessage = (ev) => { if (busy) next = ev.data; else draw(ev.data); }; // latest frame wins
  ws.onclose = () => setTimeout(connectVac, 1000);
}

// ---------------------------------------------------------------- overview
function fitView() {
  const c = $("overview"), f = S.info.footage;
  S.view = { cx: (f.width_px - 1) / 2, cy: (f.height_px - 1) / 2, scale: Math.max(f.width_px / c.width, f.height_px / c.height) * 1.02 };
  S.follow = false; requestBg();
}
function toCanvas(p) { const c = $("overview"), v = S.view; return [(p[0] - v.cx) / v.scale + c.width / 2, (p[1] - v.cy) / v.scale + c.height / 2]; }
function toFootage(x, y) { const c = $("overview"), v = S.view; return [(x - c.width / 2) * v.scale + v.cx, (y - c.height / 2) * v.scale + v.cy]; }
function visibleRect() {
  const c = $("overview"), f = S.info.footage;
  const [x0, y0] = toFootage(0, 0), [x1, y1] = toFootage(c.width, c.height);
  return [Math.max(0, x0), Math.max(0, y0), Math.min(f.width_px, x1), Math.min(f.height_px, y1)];
}
function requestBg() { S.bgWanted = Date.now(); }
async function loadBg() {
  if (S.bgLoading || !S.info) return;
  const [x0, y0, x1, y1] = visibleRect();
  if (x1 - x0 < 1 || y1 - y0 < 1) return;
  const dpr = window.devicePixelRatio || 1, max = S.info.overview_max_px;
  const w = Math.max(1, Math.min(max, Math.round((x1 - x0) / S.view.scale * dpr)));
  const h = Math.max(1, Math.min(max, Math.round((y1 - y0) / S.view.scale * dpr)));
  S.bgLoading = true; S.bgWanted = 0;
  try {
    const r = await fetch(`/api/overview.jpg?x0=${x0.toFixed(1)}&y0=${y0.toFixed(1)}&x1=${x1.toFixed(1)}&y1=${y1.toFixed(1)}&w=${w}&h=${h}`);
    if (r.ok) {
      const bmp = await createImageBitmap(await r.blob());
      if (S.bg) S.bg.img.close();
      S.bg = { img: bmp, rect: [x0, y0, x1, y1], frame: r.headers.get("X-Footage-Frame") };
      $("overview").dataset.bgFrame = S.bg.frame;
      $("overview").dataset.bgRect = S.bg.rect.map((v) => v.toFixed(0)).join(",");
    }
  } catch (e) { /* retried on the next refresh */ }
  S.bgLoading = false;
}
function poly(ctx, pts, close) { ctx.beginPath(); pts.forEach((p, i) => { const [x, y] = toCanvas(p); if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y); }); if (close) ctx.closePath(); }
function drawOverview() {
  requestAnimationFrame(drawOverview);
  const c = $("overview"), ctx = c.getContext("2d"), s = S.state;
  if (!S.view) return;
  ctx.fillStyle = "#0a0a0a"; ctx.fillRect(0, 0, c.width, c.height);
  if (S.bg) { const [x0, y0, x1, y1] = S.bg.rect; const [a, b] = toCanvas([x0 - 0.5, y0 - 0.5]), [e, f] = toCanvas([x1 - 0.5, y1 - 0.5]); ctx.drawImage(S.bg.img, a, b, e - a, f - b); }
  const F = S.info.footage;
  ctx.lineWidth = 2; ctx.strokeStyle = "#e33"; // geofence: the footage edge
  poly(ctx, [[-0.5, -0.5], [F.width_px - 0.5, -0.5], [F.width_px - 0.5, F.height_px - 0.5], [-0.5, F.height_px - 0.5]], true); ctx.stroke();
  if (!s) return;
  for (const name of S.info.layers) {
    const box = document.querySelector(`input[data-layer="${name}"]`);
    if (!box || !box.checked) continue;
    ctx.strokeStyle = "#f0f"; ctx.fillStyle = "#f0f"; ctx.lineWidth = 1.5; ctx.font = "11px sans-serif";
    for (const ft of s.layers[name] || []) {
      if (ft.color) { ctx.strokeStyle = ft.color; ctx.fillStyle = ft.color; }
      if (ft.kind === "box") { const [a, b] = toCanvas(ft.points[0]), [e, f] = toCanvas(ft.points[1]); ctx.strokeRect(a, b, e - a, f - b); ctx.fillText(ft.label || "", a, b - 2); }
      else if (ft.kind === "polygon") {
        poly(ctx, ft.points, true);
        if (ft.fill) { ctx.save(); ctx.fillStyle = ft.fill; ctx.fill(); ctx.restore(); }
        ctx.stroke();
      }
      else { const [a, b] = toCanvas(ft.points[0]); ctx.fillRect(a - 2, b - 2, 4, 4); }
    }
  }
  if ($("layer-trail").checked && S.trail.length > 1) { ctx.strokeStyle = "#2dd"; ctx.lineWidth = 1.5; poly(ctx, S.trail, false); ctx.stroke(); }
  if ($("layer-mission").checked && s.mission.length) {
    ctx.strokeStyle = "#fd4"; ctx.lineWidth = 1; poly(ctx, s.mission.map((m) => m.px), false); ctx.stroke();
    ctx.fillStyle = "#fd4"; ctx.font = "12px sans-serif";
    for (const m of s.mission) { const [x, y] = toCanvas(m.px); ctx.beginPath(); ctx.arc(x, y, 5, 0, 7); ctx.fill(); ctx.fillText(String(m.seq), x + 7, y - 7); }
  }
  { const [x, y] = toCanvas(s.home_px); ctx.fillStyle = "#4f4"; ctx.font = "bold 14px sans-serif"; ctx.fillText("H", x - 5, y + 5); }
  if ($("layer-footprint").checked && s.footprint_px) { ctx.strokeStyle = "#ff0"; ctx.lineWidth = 2; poly(ctx, s.footprint_px, true); ctx.stroke(); }
  const [vx, vy] = toCanvas(s.vehicle_px), [nx, ny] = toCanvas(s.nose_px), [wx, wy] = toCanvas(s.vel_px);
  ctx.strokeStyle = "#4af"; ctx.lineWidth = 2; ctx.beginPath(); ctx.moveTo(vx, vy); ctx.lineTo(wx, wy); ctx.stroke(); // velocity (2 s ahead)
  const ang = Math.atan2(ny - vy, nx - vx);
  ctx.fillStyle = s.armed ? "#f84" : "#ccc"; ctx.beginPath();
  ctx.moveTo(vx + 11 * Math.cos(ang), vy + 11 * Math.sin(ang));
  ctx.lineTo(vx + 7 * Math.cos(ang + 2.5), vy + 7 * Math.sin(ang + 2.5));
  ctx.lineTo(vx + 7 * Math.cos(ang - 2.5), vy + 7 * Math.sin(ang - 2.5)); ctx.closePath(); ctx.fill();
  c.dataset.footprint = s.footprint_px ? s.footprint_px.map((p) => p.map((v) => v.toFixed(1)).join(" ")).join(";") : "";
}
function setupOverviewInput() {
  const c = $("overview");
  c.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const r = c.getBoundingClientRect(), x = (ev.clientX - r.left) * c.width / r.width, y = (ev.clientY - r.top) * c.height / r.height;
    const before = toFootage(x, y), k = ev.deltaY > 0 ? 1.25 : 0.8;
    S.view.scale = Math.min(Math.max(S.view.scale * k, 0.05), 64);
    const after = toFootage(x, y); S.view.cx += before[0] - after[0]; S.view.cy += before[1] - after[1];
    requestBg();
  }, { passive: false });
  let drag = null;
  c.addEventListener("mousedown", (ev) => { drag = [ev.clientX, ev.clientY]; S.follow = false; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (ev) => {
    if (!drag) return;
    const r = c.getBoundingClientRect(), k = c.width / r.width;
    S.view.cx -= (ev.clientX - drag[0]) * k * S.view.scale; S.view.cy -= (ev.clientY - drag[1]) * k * S.view.scale;
    drag = [ev.clientX, ev.clientY]; requestBg();
  });
  $("btn-fit").onclick = fitView;
  $("btn-follow").onclick = () => { S.follow = true; requestBg(); };
}

// ---------------------------------------------------------------- sticks: keyboard and gamepad
const STICK_KEYS = new Set(["w", "a", "s", "d", "q", "e", "r", "f", "arrowup", "arrowdown", "arrowleft", "arrowright"]);
function keySticks() {
  const k = S.keys, g = Number($("stick-gain").value) / 100, on = (...names) => names.some((n) => k.has(n)) ? 1 : 0;
  return {
    x: g * (on("w", "arrowup") - on("s", "arrowdown")), y: g * (on("d", "arrowright") - on("a", "arrowleft")),
    r: g * (on("e") - on("q")), z: 0.5 + 0.5 * g * (on("r") - on("f")),
  };
}
function gamepadSticks() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const p of pads) {
    if (!p || p.axes.length < 4) continue;
    const dz = (v) => (Math.abs(v) < 0.05 ? 0 : Math.max(-1, Math.min(1, v)));
    const a = p.axes.map(dz);
    if (a.every((v) => v === 0)) continue;
    return { x: -a[3], y: a[2], r: a[0], z: Math.max(0, Math.min(1, 0.5 - 0.5 * a[1])) };
  }
  return null;
}
function stickLoop() {
  if (S.role === "pilot") {
    const st = gamepadSticks() || keySticks();
    send({ t: "sticks", ...st });
    S.lastSticks = st;
  }
}
function centre() { S.keys.clear(); if (S.role === "pilot") send({ t: "sticks", x: 0, y: 0, z: 0.5, r: 0 }); }
const KEY_COMMANDS = {
  c: () => send({ t: "take_control" }), m: () => command("arm"), t: () => command("takeoff"), l: () => command("land"),
  h: () => command("hold"), b: () => command("rtl"), k: () => askKill(),
  1: () => command("mode", { mode: "POSCTL" }), 2: () => command("mode", { mode: "ALTCTL" }),
  3: () => command("mode", { mode: "STABILIZED" }), 4: () => command("mode", { mode: "DIRECT" }),
};
function setupKeys() {
  window.addEventListener("keydown", (ev) => {
    if (ev.target.closest && ev.target.closest("input, select, textarea")) return;
    if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
    const k = ev.key.toLowerCase();
    if (STICK_KEYS.has(k)) { ev.preventDefault(); if (!S.keys.has(k)) { S.keys.add(k); stickLoop(); } return; }
    if (!ev.repeat && KEY_COMMANDS[k]) { ev.preventDefault(); KEY_COMMANDS[k](); }
  });
  window.addEventListener("keyup", (ev) => { const k = ev.key.toLowerCase(); if (S.keys.delete(k)) stickLoop(); });
  window.addEventListener("blur", centre);
  document.addEventListener("visibilitychange", () => { if (document.hidden) centre(); });
}
function askKill() {
  $("btn-kill-confirm").hidden = false;
  clearTimeout(S.killTimer);
  S.killTimer = setTimeout(() => { $("btn-kill-confirm").hidden = true; }, 4000);
}

// ---------------------------------------------------------------- start
async function main() {
  S.info = await (await fetch("/api/info")).json();
  $("footage-name").textContent = `· ${S.info.footage.name} · sysid ${S.info.sysid}`;
  S.trail = S.info.trail.slice();
  for (const m of S.info.statustexts) addStatus(m);
  const sel = $("mode-select");
  sel.innerHTML = `<option value="">mode…</option>` + S.info.modes.map((m) => `<option>${m}</option>`).join("");
  sel.onchange = () => { if (sel.value) command("mode", { mode: sel.value }); sel.value = ""; };
  $("keys").innerHTML = S.info.keys.map(([k, d]) => `<tr><td>${k}</td><td>${d}</td></tr>`).join("");
  $("layer-toggles").innerHTML = S.info.layers.map((n) => `<label><input type="checkbox" data-layer="${n}" checked> ${n}</label>`).join(" ");
  const buttons = { "btn-arm": "arm", "btn-disarm": "disarm", "btn-takeoff": "takeoff", "btn-land": "land", "btn-hold": "hold", "btn-rtl": "rtl" };
  for (const [id, cmd] of Object.entries(buttons)) $(id).onclick = () => command(cmd);
  $("btn-kill").onclick = askKill;
  $("btn-kill-confirm").onclick = () => { $("btn-kill-confirm").hidden = true; command("kill", { confirm: true }); };
  $("btn-take").onclick = () => send({ t: "take_control" });
  $("btn-release").onclick = () => send({ t: "release_control" });
  $("stick-gain").oninput = () => { $("stick-gain-v").textContent = $("stick-gain").value; };
  if (!S.info.video) $("vac-info").textContent = "video disabled (--no-video)";
  setRole("read-only");
  fitView(); setupOverviewInput(); setupKeys();
  connect(); if (S.info.video) connectVac();
  setInterval(stickLoop, 50);
  setInterval(() => { if (S.bgWanted && Date.now() - S.bgWanted > 120) loadBg(); }, 100);
  setInterval(requestBg, 1000);
  requestAnimationFrame(drawOverview);
}
main();
