// fogcast browser client: opens /ws, shows the newest frame, flies the camera(s).
// Protocol: docs/protocol.md. URL parameters (all optional): w, h (frame size),
// layout (mono|stereo|split), views (split: 2-4), quality (1-100), eye (stereo eye
// distance, metres), token.
'use strict';

(() => {
  const FRAME_MAGIC = 0x31464346; // "FCF1" read as a little-endian u32
  const LAYOUTS = ['mono', 'stereo', 'split'];
  const MOVE_MPS = 2.0;
  const TURN_RAD_PER_S = 1.6;
  const LOOK_RAD_PER_PX = 0.005;
  const POSE_HZ = 60; // while moving
  const KEEPALIVE_MS = 250; // pose resend while still, so latency stays measured

  const $ = (id) => document.getElementById(id);
  const canvas = $('view');
  const ctx = canvas.getContext('2d');
  const params = new URLSearchParams(location.search);
  const num = (name, fallback) => (params.has(name) && Number.isFinite(+params.get(name)) ? +params.get(name) : fallback);

  const state = {
    ws: null,
    connected: false,
    welcome: null,
    retryMs: 500,
    retryTimer: 0,
    layout: LAYOUTS.includes(params.get('layout')) ? params.get('layout') : 'mono',
    views: num('views', 2),
    width: num('w', 640),
    height: num('h', 360),
    quality: num('quality', 75),
    eye: params.has('eye') ? num('eye', 0.064) : undefined,
    token: params.get('token') || undefined,
    cams: [], // {pos: [x, y, z], yaw, pitch, fov} per pose of the session
    active: 0,
    seq: 0,
    sentAt: new Map(), // seq -> performance.now() when sent
    lastSend: 0,
    dirty: false,
    received: 0,
    shown: 0,
    arrivals: [], // [time, bytes] of the last second of frames
    latencyMs: null,
    header: null,
    pending: null,
    decoding: false,
    errors: [],
    keys: new Set(),
    pointers: new Map(),
  };

  // ---- camera math: yaw about +y, then pitch about the camera's x; forward is -z ----
  function forwardOf(c) {
    const cp = Math.cos(c.pitch);
    return [-Math.sin(c.yaw) * cp, Math.sin(c.pitch), -Math.cos(c.yaw) * cp];
  }
  function rightOf(c) {
    return [Math.cos(c.yaw), 0, -Math.sin(c.yaw)];
  }
  function quatOf(c) {
    const sy = Math.sin(c.yaw / 2), cy = Math.cos(c.yaw / 2);
    const sp = Math.sin(c.pitch / 2), cp = Math.cos(c.pitch / 2);
    return [cy * sp, sy * cp, -sy * sp, cy * cp];
  }
  function camFromPose(p) {
    const [x, y, z, w] = p.orientation;
    // Rotate (0, 0, -1) by q: v + w t + q×t with t = 2 q×v.
    const t = [2 * y * -1, -2 * x * -1, 0];
    const f = [
      0 + w * t[0] + (y * t[2] - z * t[1]),
      0 + w * t[1] + (z * t[0] - x * t[2]),
      -1 + w * t[2] + (x * t[1] - y * t[0]),
    ];
    return {
      pos: p.position.slice(),
      yaw: Math.atan2(-f[0], -f[2]),
      pitch: Math.asin(Math.max(-1, Math.min(1, f[1]))),
      fov: p.fov_y_deg,
    };
  }

  // ---- connection ----
  function setStatus(text, bad = false) {
    const s = $('status');
    s.textContent = text;
    s.classList.toggle('bad', bad);
  }
  let messageTimer = 0;
  function showMessage(text) {
    const m = $('message');
    m.textContent = text;
    m.hidden = false;
    clearTimeout(messageTimer);
    messageTimer = setTimeout(() => { m.hidden = true; }, 5000);
  }

  function hello() {
    return {
      type: 'hello',
      version: 1,
      width: state.width,
      height: state.height,
      layout: state.layout,
      views: state.layout === 'split' ? state.views : undefined,
      quality: state.quality,
      eye_distance_m: state.layout === 'stereo' ? state.eye : undefined,
      token: state.token,
    };
  }

  function connect() {
    clearTimeout(state.retryTimer);
    if (state.ws) {
      state.ws.onclose = null;
      state.ws.close(1000, 'reconnecting');
    }
    const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const ws = new WebSocket(`${proto}//${location.host}/ws`);
    ws.binaryType = 'arraybuffer';
    state.ws = ws;
    setStatus('connecting…');
    ws.onopen = () => ws.send(JSON.stringify(hello()));
    ws.onmessage = (ev) => (typeof ev.data === 'string' ? onText(ev.data) : onFrame(ev.data));
    ws.onclose = (ev) => {
      if (state.ws !== ws) return;
      state.ws = null;
      state.connected = false;
      const reason = ev.reason || `code ${ev.code}`;
      // A refused hello, token or size (over_budget: the reason offers a size that fits)
      // will be refused again: wait for the user to change something.
      if (ev.code === 4400 || ev.code === 4401 || ev.code === 4413) {
        setStatus(`closed: ${reason}`, true);
        showMessage(reason);
        return;
      }
      const wait = state.retryMs;
      state.retryMs = Math.min(state.retryMs * 2, 5000);
      setStatus(`disconnected (${reason}); retrying in ${(wait / 1000).toFixed(1)} s`, true);
      state.retryTimer = setTimeout(connect, wait);
    };
  }

  function send(msg) {
    if (state.ws && state.ws.readyState === WebSocket.OPEN) {
      state.ws.send(JSON.stringify(msg));
      return true;
    }
    return false;
  }

  function onText(text) {
    let msg;
    try {
      msg = JSON.parse(text);
    } catch (e) {
      console.warn('fogcast: unparsable server message', e);
      return;
    }
    if (msg.type === 'welcome') {
      const keep = state.cams.length === msg.poses.length;
      if (!keep) {
        state.cams = msg.poses.map(camFromPose);
        state.active = 0;
      }
      state.welcome = msg;
      state.connected = true;
      state.retryMs = 500;
      state.layout = msg.layout;
      state.width = msg.width;
      state.height = msg.height;
      state.quality = msg.quality;
      if (msg.layout === 'split') state.views = msg.views;
      state.dirty = true; // a reconnect keeps the camera where the user left it
      syncControls();
      setStatus(`connected · ${msg.scene} · session ${msg.session}`);
    } else if (msg.type === 'error') {
      state.errors.push(msg);
      if (state.errors.length > 20) state.errors.shift();
      console.warn(`fogcast: ${msg.code}: ${msg.message}`);
      showMessage(`${msg.code}: ${msg.message}`);
    }
  }

  function onFrame(buf) {
    if (buf.byteLength < 32) return;
    const dv = new DataView(buf);
    if (dv.getUint32(0, true) !== FRAME_MAGIC) return;
    const headerLen = dv.getUint16(4, true);
    const h = {
      layout: LAYOUTS[dv.getUint8(6)],
      views: dv.getUint8(7),
      width: dv.getUint16(8, true),
      height: dv.getUint16(10, true),
      frame: dv.getUint32(12, true),
      seq: dv.getUint32(16, true),
      renderUs: dv.getUint32(20, true),
      encodeUs: dv.getUint32(24, true),
      dropped: dv.getUint32(28, true),
    };
    const now = performance.now();
    state.received++;
    state.arrivals.push([now, buf.byteLength]);
    const sent = state.sentAt.get(h.seq);
    if (sent !== undefined) {
      const ms = now - sent;
      state.latencyMs = state.latencyMs === null ? ms : 0.8 * state.latencyMs + 0.2 * ms;
    }
    for (const s of state.sentAt.keys()) if (s <= h.seq) state.sentAt.delete(s);
    // Latest frame wins here too: decode one at a time, always the newest.
    state.pending = { h, blob: new Blob([new Uint8Array(buf, headerLen)], { type: 'image/jpeg' }) };
    if (!state.decoding) drawPending();
  }

  async function drawPending() {
    state.decoding = true;
    while (state.pending) {
      const { h, blob } = state.pending;
      state.pending = null;
      try {
        const bmp = await createImageBitmap(blob);
        if (canvas.width !== bmp.width || canvas.height !== bmp.height) {
          canvas.width = bmp.width;
          canvas.height = bmp.height;
        }
        ctx.drawImage(bmp, 0, 0);
        bmp.close();
        if (h.layout === 'split') outlineActiveTile(h);
        state.header = h;
        state.shown++;
      } catch (e) {
        console.warn('fogcast: frame decode failed', e);
      }
    }
    state.decoding = false;
  }

  function outlineActiveTile(h) {
    const vw = h.width / 2;
    const vh = h.views === 2 ? h.height : h.height / 2;
    const x = (state.active % 2) * vw;
    const y = Math.floor(state.active / 2) * vh;
    ctx.strokeStyle = 'rgba(255, 255, 255, 0.7)';
    ctx.lineWidth = 2;
    ctx.strokeRect(x + 1, y + 1, vw - 2, vh - 2);
  }

  // ---- camera input ----
  function sendPose(now) {
    if (!state.connected || state.cams.length === 0) return;
    state.seq = (state.seq + 1) >>> 0;
    const ok = send({
      type: 'pose',
      seq: state.seq,
      views: state.cams.map((c) => ({ position: c.pos, orientation: quatOf(c), fov_y_deg: c.fov })),
    });
    if (ok) {
      state.sentAt.set(state.seq, now);
      if (state.sentAt.size > 256) state.sentAt.delete(state.sentAt.keys().next().value);
      state.lastSend = now;
      state.dirty = false;
    }
  }

  function move(c, forward, strafe, up, dt) {
    const f = forwardOf(c), r = rightOf(c);
    const speed = (state.keys.has('ShiftLeft') || state.keys.has('ShiftRight') ? 4 : 1) * MOVE_MPS * dt;
    for (let i = 0; i < 3; i++) c.pos[i] += (f[i] * forward + r[i] * strafe + (i === 1 ? up : 0)) * speed;
  }

  let lastTick = performance.now();
  function tick() {
    const now = performance.now();
    const dt = Math.min(0.1, (now - lastTick) / 1000);
    lastTick = now;
    const c = state.cams[state.active];
    if (c) {
      const k = (...codes) => codes.some((code) => state.keys.has(code));
      const forward = (k('KeyW', 'ArrowUp') ? 1 : 0) - (k('KeyS', 'ArrowDown') ? 1 : 0);
      const strafe = (k('KeyD') ? 1 : 0) - (k('KeyA') ? 1 : 0);
      const up = (k('KeyE', 'PageUp') ? 1 : 0) - (k('KeyQ', 'PageDown') ? 1 : 0);
      const turn = (k('ArrowLeft') ? 1 : 0) - (k('ArrowRight') ? 1 : 0);
      if (forward || strafe || up) {
        move(c, forward, strafe, up, dt);
        state.dirty = true;
      }
      if (turn) {
        c.yaw += turn * TURN_RAD_PER_S * dt;
        state.dirty = true;
      }
    }
    const since = now - state.lastSend;
    if ((state.dirty && since >= 1000 / POSE_HZ) || since >= KEEPALIVE_MS) sendPose(now);
  }

  function look(dx, dy) {
    const c = state.cams[state.active];
    if (!c) return;
    c.yaw -= dx * LOOK_RAD_PER_PX;
    c.pitch = Math.max(-1.5, Math.min(1.5, c.pitch - dy * LOOK_RAD_PER_PX));
    state.dirty = true;
  }

  const CONTROL_KEYS = new Set(['ArrowUp', 'ArrowDown', 'ArrowLeft', 'ArrowRight', 'PageUp', 'PageDown', 'Space']);
  window.addEventListener('keydown', (e) => {
    if (e.target instanceof HTMLSelectElement || e.target instanceof HTMLInputElement) return;
    if (/^Digit[1-4]$/.test(e.code)) {
      const i = +e.code.slice(5) - 1;
      if (i < state.cams.length) state.active = i;
      return;
    }
    state.keys.add(e.code);
    if (CONTROL_KEYS.has(e.code)) e.preventDefault();
  });
  window.addEventListener('keyup', (e) => state.keys.delete(e.code));
  window.addEventListener('blur', () => state.keys.clear());

  // Pointer events cover mouse, pen and touch: one pointer looks, two move.
  canvas.addEventListener('pointerdown', (e) => {
    canvas.setPointerCapture(e.pointerId);
    state.pointers.set(e.pointerId, [e.clientX, e.clientY]);
    canvas.focus();
  });
  canvas.addEventListener('pointermove', (e) => {
    const prev = state.pointers.get(e.pointerId);
    if (!prev) return;
    const dx = e.clientX - prev[0], dy = e.clientY - prev[1];
    state.pointers.set(e.pointerId, [e.clientX, e.clientY]);
    if (state.pointers.size === 1) {
      look(dx, dy);
    } else {
      const c = state.cams[state.active];
      if (c) {
        // Each of the two pointers contributes half of the gesture.
        move(c, -dy * 0.01 / state.pointers.size, dx * 0.01 / state.pointers.size, 0, 1);
        state.dirty = true;
      }
    }
  });
  const release = (e) => state.pointers.delete(e.pointerId);
  canvas.addEventListener('pointerup', release);
  canvas.addEventListener('pointercancel', release);

  // ---- controls ----
  function syncControls() {
    $('layout').value = state.layout === 'split' ? `split${state.views}` : state.layout;
    const res = `${state.width}x${state.height}`;
    const sel = $('resolution');
    if (![...sel.options].some((o) => o.value === res)) sel.add(new Option(res.replace('x', '×'), res));
    sel.value = res;
    $('quality').value = state.quality;
    $('quality-value').textContent = state.quality;
  }

  function configure(change) {
    if (!send({ type: 'configure', ...change })) {
      // Not connected: apply locally and open a new session with it.
      Object.assign(state, {
        layout: change.layout ?? state.layout,
        views: change.views ?? state.views,
        width: change.width ?? state.width,
        height: change.height ?? state.height,
        quality: change.quality ?? state.quality,
      });
      connect();
    }
  }

  $('layout').addEventListener('change', (e) => {
    const v = e.target.value;
    const layout = v.startsWith('split') ? 'split' : v;
    configure({ layout, views: layout === 'split' ? +v.slice(5) : undefined });
    e.target.blur();
  });
  $('resolution').addEventListener('change', (e) => {
    const [width, height] = e.target.value.split('x').map(Number);
    configure({ width, height });
    e.target.blur();
  });
  $('quality').addEventListener('input', (e) => { $('quality-value').textContent = e.target.value; });
  $('quality').addEventListener('change', (e) => {
    configure({ quality: +e.target.value });
    e.target.blur();
  });

  // ---- overlay ----
  function fps() {
    const now = performance.now();
    while (state.arrivals.length && now - state.arrivals[0][0] > 1000) state.arrivals.shift();
    return state.arrivals.length;
  }
  function updateOverlay() {
    const h = state.header;
    const kbps = state.arrivals.reduce((a, [, b]) => a + b, 0) / 1024;
    const lines = [
      `fps ${fps().toString().padStart(3)}   latency ${state.latencyMs === null ? '–' : state.latencyMs.toFixed(0) + ' ms'}`,
      h ? `${h.width}×${h.height} ${h.layout}${h.views > 1 ? ' ×' + h.views : ''} q${state.quality}  ${kbps.toFixed(0)} KiB/s` : 'waiting for frames…',
      h ? `render ${(h.renderUs / 1000).toFixed(1)} ms  encode ${(h.encodeUs / 1000).toFixed(1)} ms  dropped ${h.dropped}` : '',
    ];
    if (state.cams.length > 1) lines.push(`controlling view ${state.active + 1}/${state.cams.length} (keys 1–${state.cams.length})`);
    $('overlay').textContent = lines.filter(Boolean).join('\n');
  }

  // Hooks for tests and the console.
  window.fogcast = {
    stats: () => ({
      connected: state.connected,
      received: state.received,
      shown: state.shown,
      seq: state.seq,
      frameSeq: state.header ? state.header.seq : null,
      latencyMs: state.latencyMs,
      fps: fps(),
      width: canvas.width,
      height: canvas.height,
      layout: state.layout,
      errors: state.errors.map((e) => e.code),
      camera: state.cams[state.active] || null,
    }),
    // Mean luma and an 8x8 grid of mean lumas of what the canvas shows (0-255).
    canvasStats: () => {
      const { width: w, height: h } = canvas;
      const d = ctx.getImageData(0, 0, w, h).data;
      const grid = new Array(64).fill(0), count = new Array(64).fill(0);
      let sum = 0;
      for (let y = 0; y < h; y++) {
        for (let x = 0; x < w; x++) {
          const i = (y * w + x) * 4;
          const l = 0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2];
          sum += l;
          const g = Math.min(7, Math.floor((y * 8) / h)) * 8 + Math.min(7, Math.floor((x * 8) / w));
          grid[g] += l;
          count[g]++;
        }
      }
      return { mean: sum / (w * h), grid: grid.map((s, i) => s / Math.max(1, count[i])) };
    },
  };

  syncControls();
  setInterval(tick, 1000 / POSE_HZ);
  setInterval(updateOverlay, 250);
  connect();
})();
