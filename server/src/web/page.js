// edgepoint browser viewer (issue 16). Plain JavaScript served by the renderer itself
// (server/src/web): no build step, no CDN. One WebSocket to /live carries JSON messages both
// ways and the frames as changed 32x32 tiles, deflated (server/src/web/tiles.rs).
'use strict';

const $ = (id) => document.getElementById(id);
const canvas = $('frame');
const ctx = canvas.getContext('2d');
const TILE = 32;

// What the tests (tests/tests/browser.rs) and the stats overlay read.
const state = window.edgepoint = {
  status: 'connecting', refused: null, lost: null, frames: 0, lastSeq: -1, lastTiles: 0,
  bytes: [], latency: null, started: null, camera: null, picked: null, moves: 0, rejected: [],
  frameStamps: [], header: null,
};

// ---- vectors and the camera (the window viewer's FreeCamera, viewer/src/camera_control.rs)
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const len = (a) => Math.sqrt(dot(a, a));
const norm = (a) => mul(a, 1 / len(a));
const finite = (c) => [c.eye, c.target, c.up].every((v) => v.every(Number.isFinite)) && len(sub(c.target, c.eye)) > 1e-9;

function frameOf(c, w, h) {
  const forward = norm(sub(c.target, c.eye));
  const right = norm(cross(forward, c.up));
  return { eye: c.eye, forward, right, up: cross(right, forward), tanHalfY: Math.tan(c.fov * Math.PI / 360), aspect: w / h, w, h };
}
// Ray through continuous pixel position (x, y), origin top-left (scene/src/camera.rs).
function ray(f, x, y) {
  const nx = (2 * x / f.w - 1) * f.tanHalfY * f.aspect;
  const ny = (1 - 2 * y / f.h) * f.tanHalfY;
  return norm(add(add(f.forward, mul(f.right, nx)), mul(f.up, ny)));
}
const MIN_POLE = 5 * Math.PI / 180;
let home = null, cam = null, scale = 1;
function accept(c) { if (finite(c)) { cam = c; cameraDirty = true; } }
function orbit(yaw, pitch) {
  const off = sub(cam.eye, cam.target), r = len(off);
  const elev = Math.asin(Math.max(-1, Math.min(1, off[1] / r)));
  const e = Math.max(-(Math.PI / 2 - MIN_POLE), Math.min(Math.PI / 2 - MIN_POLE, elev + pitch));
  const az = Math.atan2(off[0], off[2]) + yaw;
  const dir = [Math.cos(e) * Math.sin(az), Math.sin(e), Math.cos(e) * Math.cos(az)];
  accept({ ...cam, eye: add(cam.target, mul(dir, r)), up: [0, 1, 0] });
}
function pan(dx, dy, h) {
  const f = frameOf(cam, h, h);
  const perPixel = 2 * len(sub(cam.target, cam.eye)) * f.tanHalfY / h;
  const shift = mul(add(mul(f.right, -dx), mul(f.up, dy)), perPixel);
  accept({ ...cam, eye: add(cam.eye, shift), target: add(cam.target, shift) });
}
function dolly(notches) {
  const off = sub(cam.eye, cam.target), d = len(off);
  const nd = Math.max(d * Math.pow(0.85, notches), 0.01 * scale);
  accept({ ...cam, eye: add(cam.target, mul(off, nd / d)) });
}

// ---- connection
let ws = null, info = null, image = null, chain = Promise.resolve(), cameraDirty = false, leaving = false;
const token = new URLSearchParams(location.hash.slice(1)).get('token') || '';

function show(text, error) {
  const s = $('status');
  s.hidden = !text;
  s.textContent = text || '';
  s.classList.toggle('error', !!error);
}
function notice(text) { $('notice').textContent = text; }
function send(obj) { if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj)); }

async function loadInfo() {
  try {
    const r = await fetch('info', { cache: 'no-store' });
    info = await r.json();
  } catch (e) {
    show('cannot reach the renderer: ' + e, true);
    state.status = 'lost';
    state.lost = String(e);
    return false;
  }
  const fill = (sel, items, pick) => {
    sel.innerHTML = '';
    for (const it of items) {
      const o = document.createElement('option');
      o.value = o.textContent = it.name;
      o.title = it.help;
      sel.appendChild(o);
    }
    const want = new URLSearchParams(location.search).get(pick);
    if (want && items.some((i) => i.name === want)) sel.value = want;
  };
  fill($('scene'), info.scenes, 'scene');
  fill($('shader'), info.shaders, 'shader');
  const size = new URLSearchParams(location.search).get('size');
  if (size) { const o = document.createElement('option'); o.textContent = size; $('size').appendChild(o); $('size').value = size; }
  return true;
}

function connect() {
  if (ws) { leaving = true; ws.close(); }
  leaving = false;
  const side = parseInt($('size').value, 10);
  canvas.width = canvas.height = side;
  image = ctx.createImageData(side, side);
  for (let i = 3; i < image.data.length; i += 4) image.data[i] = 255;
  Object.assign(state, { status: 'connecting', refused: null, lost: null, started: null, lastSeq: -1 });
  show('connecting…');
  const url = (location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/live';
  const sock = ws = new WebSocket(url);
  sock.binaryType = 'arraybuffer';
  sock.onopen = () => {
    show('starting the session…');
    sock.send(JSON.stringify({ type: 'hello', token, start: { scene: $('scene').value, shader: $('shader').value, width: side, height: side } }));
    sendSettings();
  };
  sock.onmessage = (ev) => {
    if (sock !== ws) return;
    if (typeof ev.data === 'string') onText(JSON.parse(ev.data));
    else { const buf = ev.data; chain = chain.then(() => onFrame(buf)).catch((e) => notice('bad frame: ' + e)); }
  };
  sock.onclose = (ev) => {
    if (sock !== ws || leaving) return;
    if (state.refused) return; // the refusal is already on screen
    state.status = 'lost';
    state.lost = `code ${ev.code}${ev.reason ? ': ' + ev.reason : ''}`;
    show(`Connection to the renderer lost (${state.lost}).\nReload the page to reconnect.`, true);
  };
}

function onText(m) {
  switch (m.type) {
    case 'started':
      state.started = m;
      state.status = 'started';
      home = { eye: m.camera.eye, target: m.camera.target, up: [0, 1, 0], fov: m.camera.fov };
      cam = { ...home };
      scale = Math.max(1e-3, len(sub(m.scene_max, m.scene_min)) * 0.5);
      show('waiting for the first samples…');
      break;
    case 'progress':
      if (state.frames === 0 || state.lastSeq < 0) show(`${m.stage}: ${m.message || `${m.done}/${m.total || '?'}`}`);
      break;
    case 'picked':
      state.picked = m;
      onPicked(m);
      break;
    case 'rejected':
      state.rejected.push(m.message);
      notice(`rejected (${m.code}): ${m.message}`);
      break;
    case 'refused':
      state.status = 'refused';
      state.refused = `${m.code}: ${m.message}`;
      show(`The renderer refused this viewer.\n${m.code}: ${m.message}`, true);
      break;
    case 'ended':
      state.status = 'ended';
      state.lost = m.message;
      show(m.message, true);
      break;
  }
}

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

async function onFrame(buf) {
  const n = new DataView(buf).getUint32(0, true);
  const h = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const rgb = await inflate(new Uint8Array(buf, 4 + n));
  if (h.width !== image.width || h.height !== image.height) {
    canvas.width = h.width; canvas.height = h.height;
    image = ctx.createImageData(h.width, h.height);
  }
  const W = h.width, tilesX = Math.ceil(W / TILE), px = image.data;
  let at = 0;
  for (const i of h.tiles) {
    const x0 = (i % tilesX) * TILE, y0 = Math.floor(i / tilesX) * TILE;
    const w = Math.min(TILE, W - x0), th = Math.min(TILE, h.height - y0);
    for (let y = y0; y < y0 + th; y++) {
      let o = (y * W + x0) * 4;
      for (let x = 0; x < w; x++, o += 4, at += 3) {
        px[o] = rgb[at]; px[o + 1] = rgb[at + 1]; px[o + 2] = rgb[at + 2]; px[o + 3] = 255;
      }
    }
  }
  ctx.putImageData(image, 0, 0);
  send({ type: 'shown', seq: h.seq, t: h.t });
  const now = performance.now();
  state.frames++;
  state.lastSeq = h.seq;
  state.lastTiles = h.tiles.length;
  state.header = h;
  state.camera = h.camera;
  state.latency = h.latency_ms;
  state.bytes.push(buf.byteLength);
  if (state.bytes.length > 600) state.bytes.shift();
  state.frameStamps.push(now);
  while (state.frameStamps.length && now - state.frameStamps[0] > 1000) state.frameStamps.shift();
  if (state.status === 'started') { state.status = 'live'; show(''); }
  drawStats();
}

function drawStats() {
  const el = $('stats');
  el.hidden = !$('showstats').checked;
  const h = state.header;
  if (!h || el.hidden) return;
  const recent = state.bytes.slice(-30);
  const avg = recent.reduce((a, b) => a + b, 0) / recent.length;
  const stages = h.stages.filter(([, ms]) => ms >= 0.05).map(([s, ms]) => `${s} ${ms.toFixed(1)}`).join('  ');
  el.textContent =
    `fps ${state.frameStamps.length}   frame ${h.seq}   ${h.width}x${h.height}   workers ${h.live_workers}\n` +
    `samples/frame ${h.samples_used} (requested ${h.samples_requested})   frame ${h.total_ms.toFixed(1)} ms\n` +
    `bytes/frame ${(avg / 1024).toFixed(1)} KiB (last ${(state.bytes[state.bytes.length - 1] / 1024).toFixed(1)}, tiles ${h.tiles.length})\n` +
    `latency ${h.latency_ms == null ? '–' : h.latency_ms.toFixed(1) + ' ms'}   dropped ${h.frames_dropped}\n` +
    `ms: ${stages}`;
}

function sendSettings() {
  send({ type: 'settings', overlay: $('overlay').value, reconstruction: $('reconstruction').value, paused: $('paused').checked });
}

// ---- mouse: orbit, pan, zoom, object drag
let drag = null; // {kind: 'orbit'|'pan'|'object', x, y, pick, grab}
let nextPick = 1;
function framePos(ev) {
  const r = canvas.getBoundingClientRect();
  return [(ev.clientX - r.left) * canvas.width / r.width, (ev.clientY - r.top) * canvas.height / r.height];
}
canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener('mousedown', (ev) => {
  if (!cam) return;
  ev.preventDefault();
  const [x, y] = framePos(ev);
  const grabbing = ev.button === 1 || (ev.button === 0 && (ev.ctrlKey || $('movemode').checked));
  if (grabbing) {
    const id = nextPick++;
    drag = { kind: 'object', x, y, pick: id, grab: null };
    send({ type: 'pick', id, x, y });
  } else {
    drag = { kind: ev.button === 2 ? 'pan' : 'orbit', x, y };
  }
});
window.addEventListener('mouseup', () => { drag = null; });
window.addEventListener('mousemove', (ev) => {
  if (!drag || !cam) return;
  const [x, y] = framePos(ev);
  const dx = x - drag.x, dy = y - drag.y;
  drag.x = x; drag.y = y;
  if (drag.kind === 'orbit') orbit(-dx / canvas.width * 2 * Math.PI, dy / canvas.height * Math.PI);
  else if (drag.kind === 'pan') pan(dx, dy, canvas.height);
  else if (drag.grab) moveObject(drag.grab, x, y);
});
canvas.addEventListener('wheel', (ev) => {
  if (!cam) return;
  ev.preventDefault();
  dolly(-Math.sign(ev.deltaY));
}, { passive: false });

// The grabbed point follows the cursor in the plane through it facing the camera
// (viewer/src/object_drag.rs): the object's transform is translated by the point's shift.
function onPicked(m) {
  if (!drag || drag.kind !== 'object' || drag.pick !== m.id) return;
  if (!m.hit) { notice('nothing under the cursor'); drag = null; return; }
  const c = m.camera;
  notice(`moving ${m.name || 'object ' + m.object}`);
  drag.grab = { object: m.object, point: m.position, normal: norm(sub(c.target, c.eye)), rows: m.transform };
  moveObject(drag.grab, drag.x, drag.y);
}
function moveObject(g, x, y) {
  const f = frameOf(cam, canvas.width, canvas.height);
  const d = ray(f, x, y);
  const denom = dot(d, g.normal);
  if (Math.abs(denom) < 1e-6) return;
  const t = dot(sub(g.point, cam.eye), g.normal) / denom;
  if (!(t > 0 && Number.isFinite(t))) return;
  const shift = sub(add(cam.eye, mul(d, t)), g.point);
  const rows = g.rows.slice();
  rows[3] += shift[0]; rows[7] += shift[1]; rows[11] += shift[2];
  send({ type: 'move', object: g.object, rows });
  state.moves++;
}

// Camera changes go out at most once per display refresh.
function tick() {
  if (cameraDirty && cam) {
    cameraDirty = false;
    send({ type: 'camera', eye: cam.eye, target: cam.target, up: cam.up, fov: cam.fov });
  }
  requestAnimationFrame(tick);
}

$('reset').onclick = () => { if (home) accept({ ...home }); };
for (const id of ['overlay', 'reconstruction', 'paused']) $(id).onchange = sendSettings;
for (const id of ['scene', 'shader', 'size']) $(id).onchange = connect;
$('showstats').onchange = drawStats;
setInterval(drawStats, 500);

// Test hooks (tests/tests/browser.rs drives real mouse events; these only read or steer the view).
state.orbitBy = (yaw, pitch) => orbit(yaw, pitch);

loadInfo().then((ok) => { if (ok) { connect(); requestAnimationFrame(tick); } });
