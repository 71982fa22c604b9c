// fogcast browser client: opens /ws, shows the newest frame, flies the camera(s).
// Protocol: docs/protocol.md. URL parameters (all optional): w, h (frame size),
// layout (mono|stereo|split), views (split: 2-4), quality (1-100), eye (stereo eye
// distance, metres), codec (h264|jpeg; default: h264 where WebCodecs decodes it),
// kbps (bitrate ceiling), token.
'use strict';

(() => {
  const FRAME_MAGIC = 0x31464346; // "FCF1" read as a little-endian u32
  const LAYOUTS = ['mono', 'stereo', 'split'];
  const CODECS = ['jpeg', 'h264', 'raw']; // the header's codec byte
  const V1_HEADER_BYTES = 32; // a header without the codec fields (a JPEG key frame)
  const FLAG_KEY = 1;
  // Constrained baseline, level 3.1; no `description`: the stream is Annex B, SPS and PPS
  // arrive in band with every key frame.
  const H264_CONFIG = { codec: 'avc1.42E01F', optimizeForLatency: true };
  const KEYFRAME_RETRY_MS = 500; // while waiting for a requested key frame
  const MAX_ERRORS_IN_A_ROW = 3; // then the decoder is broken, not the stream: use JPEG
  const MOVE_MPS = 2.0;
  const TURN_RAD_PER_S = 1.6;
  const LOOK_RAD_PER_PX = 0.005;
  const POSE_HZ = 60; // while moving
  const KEEPALIVE_MS = 250; // pose resend while still and visible, so latency stays measured

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
    maxKbps: params.has('kbps') ? num('kbps', undefined) : undefined,
    codec: 'jpeg', // asked for in the hello (chooseCodec)
    streamCodec: null, // the welcome's codec: what the server sends
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
    shownAt: [], // times of the frames shown in the last second
    latencyMs: null,
    header: null, // of the frame on the canvas
    pending: null, // JPEG: the newest frame not yet decoded
    decoding: false,
    decoder: null, // H.264: one VideoDecoder per stream
    needKey: true, // H.264: deltas are dropped until a key frame
    inDecoder: new Map(), // H.264: chunk timestamp -> header, for frames being decoded
    lastKeyRequest: -Infinity,
    corruptNext: false, // test hook: feed the next H.264 frame as garbage
    lastAcked: -1,
    framesDecoded: 0,
    keyFrames: 0,
    decodeErrors: 0,
    errorsInARow: 0, // H.264 decode errors since the last frame decoded
    clientDrops: 0, // frames received but never shown
    acks: 0,
    keyframeRequests: 0,
    idleClosed: false, // the server closed the session as idle: reconnect on user input
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

  // ---- codec choice ----
  async function h264Decodable() {
    if (!window.VideoDecoder) return false;
    try {
      return (await VideoDecoder.isConfigSupported(H264_CONFIG)).supported === true;
    } catch (e) {
      return false;
    }
  }

  // H.264 where this browser decodes it (WebCodecs), else JPEG; `?codec=` overrides, except
  // that H.264 without WebCodecs cannot be shown at all.
  async function chooseCodec() {
    const asked = params.get('codec');
    const h264 = await h264Decodable();
    $('codec').querySelector('option[value=h264]').disabled = !h264;
    if (asked === 'jpeg') return 'jpeg';
    if (asked === 'h264' && !h264) showMessage('this browser cannot decode H.264 (WebCodecs): using JPEG');
    return h264 ? 'h264' : 'jpeg';
  }

  // H.264 frames have even sizes (4:2:0); round an odd size from the URL down.
  const evenFor = (codec, n) => (codec === 'h264' ? n - (n % 2) : n);

  function hello() {
    return {
      type: 'hello',
      version: 1,
      width: evenFor(state.codec, state.width),
      height: evenFor(state.codec, state.height),
      layout: state.layout,
      views: state.layout === 'split' ? state.views : undefined,
      quality: state.quality,
      eye_distance_m: state.layout === 'stereo' ? state.eye : undefined,
      codec: state.codec,
      max_kbps: state.maxKbps,
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
    state.lastAcked = -1; // a restarted server numbers its frames from 0 again
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
      // Closed for sending no pose for a long time: come back when the user does something.
      if (ev.code === 4408 && ev.reason.startsWith('idle')) {
        state.idleClosed = true;
        setStatus('closed while idle: press a key or click to reconnect', true);
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
      // A bandwidth welcome shrinks the frames for a while, not what the user asked for
      // (which a reconnect asks for again).
      if (msg.reason !== 'bandwidth') {
        state.width = msg.width;
        state.height = msg.height;
      }
      state.quality = msg.quality;
      if (msg.layout === 'split') state.views = msg.views;
      state.dirty = true; // a reconnect keeps the camera where the user left it
      startStream(msg.codec || 'jpeg');
      if (msg.reason === 'bandwidth') showMessage(`slow link: the server now sends ${msg.width}×${msg.height}`);
      syncControls();
      setStatus(`connected · ${msg.scene} · session ${msg.session}`);
    } else if (msg.type === 'error') {
      state.errors.push(msg);
      if (state.errors.length > 20) state.errors.shift();
      console.warn(`fogcast: ${msg.code}: ${msg.message}`);
      showMessage(`${msg.code}: ${msg.message}`);
    }
  }

  // The fixed frame header (docs/protocol.md, "frames (binary)"); null if it is not one.
  function parseHeader(buf) {
    if (buf.byteLength < V1_HEADER_BYTES) return null;
    const dv = new DataView(buf);
    if (dv.getUint32(0, true) !== FRAME_MAGIC) return null;
    const headerLen = dv.getUint16(4, true);
    if (headerLen < V1_HEADER_BYTES || headerLen > buf.byteLength) return null;
    const extended = headerLen >= 40;
    return {
      headerLen,
      layout: LAYOUTS[dv.getUint8(6)],
      views: dv.getUint8(7),
      width: dv.getUint16(8, true),
      height: dv.getUint16(10, true),
      frame: dv.getUint32(12, true),
      seq: dv.getUint32(16, true),
      renderUs: dv.getUint32(20, true),
      encodeUs: dv.getUint32(24, true),
      dropped: dv.getUint32(28, true),
      codec: extended ? CODECS[dv.getUint8(32)] : 'jpeg',
      key: extended ? (dv.getUint8(33) & FLAG_KEY) !== 0 : true,
      quality: extended ? dv.getUint8(34) : state.quality,
      targetKbps: extended ? dv.getUint32(36, true) : null,
    };
  }

  function onFrame(buf) {
    const h = parseHeader(buf);
    // Raw frames are a debugging aid (raw_every) this client never asks for.
    if (!h || h.codec === undefined || h.codec === 'raw') return;
    const now = performance.now();
    state.received++;
    if (h.key) state.keyFrames++;
    state.arrivals.push([now, buf.byteLength]);
    const sent = state.sentAt.get(h.seq);
    if (sent !== undefined) {
      const ms = now - sent;
      state.latencyMs = state.latencyMs === null ? ms : 0.8 * state.latencyMs + 0.2 * ms;
    }
    for (const s of state.sentAt.keys()) if (s <= h.seq) state.sentAt.delete(s);
    const payload = new Uint8Array(buf, h.headerLen);
    if (h.codec === 'h264') decodeH264(h, payload);
    else queueJpeg(h, payload);
  }

  // Sizes the canvas to the frame and draws `image` (an ImageBitmap or a VideoFrame).
  function drawFrame(image, h) {
    if (canvas.width !== h.width || canvas.height !== h.height) {
      canvas.width = h.width;
      canvas.height = h.height;
    }
    ctx.drawImage(image, 0, 0, h.width, h.height);
    if (h.layout === 'split') outlineActiveTile(h);
    state.header = h;
    state.shown++;
    state.framesDecoded++;
    state.shownAt.push(performance.now());
    ack(h.frame);
  }

  // Flow control (docs/protocol.md, "ack"): acks are cumulative, so one per frame shown
  // covers the frames skipped before it. A frame dropped here is acked too: it was
  // delivered, and the server must not wait for an ack that would never come.
  function ack(frame) {
    if (frame <= state.lastAcked) return;
    if (send({ type: 'ack', frame })) {
      state.lastAcked = frame;
      state.acks++;
    }
  }

  function dropFrame(h) {
    state.clientDrops++;
    ack(h.frame);
  }

  // ---- JPEG: latest frame wins here too, decode one at a time, always the newest ----
  function queueJpeg(h, payload) {
    if (state.pending) state.clientDrops++; // replaced before it was decoded
    state.pending = { h, blob: new Blob([payload], { type: 'image/jpeg' }) };
    if (!state.decoding) drawPending();
  }

  async function drawPending() {
    state.decoding = true;
    while (state.pending) {
      const { h, blob } = state.pending;
      state.pending = null;
      try {
        const bmp = await createImageBitmap(blob);
        drawFrame(bmp, h);
        bmp.close();
      } catch (e) {
        state.decodeErrors++;
        dropFrame(h);
        console.warn('fogcast: frame decode failed', e);
      }
    }
    state.decoding = false;
  }

  // ---- H.264 through WebCodecs ----
  // A new stream starts with every welcome (the server sends a key frame after it).
  function startStream(codec) {
    state.streamCodec = codec;
    state.errorsInARow = 0;
    closeDecoder();
    if (codec !== 'h264') return;
    if (window.VideoDecoder) startDecoder();
    else fallBackToJpeg('the server sends H.264 and this browser has no WebCodecs');
  }

  // Until the welcome for it arrives, H.264 frames are dropped (there is no decoder).
  function fallBackToJpeg(why) {
    showMessage(`${why}: switching to JPEG`);
    state.codec = 'jpeg';
    configure({ codec: 'jpeg' });
  }

  function closeDecoder() {
    const dec = state.decoder;
    state.decoder = null;
    if (dec && dec.state !== 'closed') dec.close();
    state.clientDrops += state.inDecoder.size; // lost with the decoder
    state.inDecoder.clear();
  }

  // A fresh decoder, which needs a key frame first.
  function startDecoder() {
    closeDecoder();
    state.needKey = true;
    const dec = new VideoDecoder({
      output: (frame) => onDecoded(dec, frame),
      // Errors of a decoder already replaced (closed on purpose) are not news.
      error: (e) => { if (dec === state.decoder) decodeFailed(e); },
    });
    dec.configure(H264_CONFIG);
    state.decoder = dec;
  }

  function decodeH264(h, payload) {
    if (!state.decoder) {
      dropFrame(h);
      return;
    }
    // A delta frame refers to frames this decoder never saw: drop it, ask for a key frame.
    if (state.needKey && !h.key) {
      dropFrame(h);
      requestKeyframe();
      return;
    }
    state.needKey = false;
    let data = payload;
    if (state.corruptNext) {
      state.corruptNext = false;
      data = notH264(payload.length);
    }
    const timestamp = h.frame * 1000; // µs; server frame numbers only grow within a stream
    state.inDecoder.set(timestamp, h);
    try {
      state.decoder.decode(new EncodedVideoChunk({ type: h.key ? 'key' : 'delta', timestamp, data }));
    } catch (e) {
      decodeFailed(e);
    }
  }

  function onDecoded(dec, frame) {
    if (dec === state.decoder) {
      const h = state.inDecoder.get(frame.timestamp);
      // Frames come out in decode order: older ones still listed were never output.
      for (const t of state.inDecoder.keys()) {
        if (t > frame.timestamp) break;
        if (t < frame.timestamp) state.clientDrops++;
        state.inDecoder.delete(t);
      }
      if (h) {
        state.errorsInARow = 0;
        drawFrame(frame, h);
      }
    }
    frame.close();
  }

  // Start over from the next key frame, which the server sends at once when asked.
  // A decoder that fails again and again (without a frame between) is given up for JPEG.
  function decodeFailed(e) {
    state.decodeErrors++;
    state.errorsInARow++;
    const newest = Math.max(-1, ...[...state.inDecoder.values()].map((h) => h.frame));
    closeDecoder();
    if (newest >= 0) ack(newest);
    if (state.errorsInARow >= MAX_ERRORS_IN_A_ROW) {
      fallBackToJpeg(`H.264 decoding keeps failing (${e.message})`);
      return;
    }
    console.warn('fogcast: H.264 decode failed; asking for a key frame', e);
    startDecoder();
    requestKeyframe();
  }

  function requestKeyframe() {
    const now = performance.now();
    if (now - state.lastKeyRequest < KEYFRAME_RETRY_MS) return;
    if (send({ type: 'keyframe' })) {
      state.lastKeyRequest = now;
      state.keyframeRequests++;
    }
  }

  // Bytes no H.264 decoder accepts (no start code): the test hook's "corrupt frame".
  function notH264(length) {
    const data = new Uint8Array(Math.max(16, length));
    for (let i = 0; i < data.length; i++) data[i] = (i * 7919 + 13) & 0xff;
    return data;
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
    // No keepalive from a hidden page: a tab left in the background goes idle on the
    // server (closed after idle_timeout_s) instead of holding its views forever.
    const keepalive = since >= KEEPALIVE_MS && !document.hidden;
    if ((state.dirty && since >= 1000 / POSE_HZ) || keepalive) sendPose(now);
  }

  function look(dx, dy) {
    const c = state.cams[state.active];
    if (!c) return;
    c.yaw -= dx * LOOK_RAD_PER_PX;
    c.pitch = Math.max(-1.5, Math.min(1.5, c.pitch - dy * LOOK_RAD_PER_PX));
    state.dirty = true;
  }

  function wakeFromIdle() {
    if (!state.idleClosed) return;
    state.idleClosed = false;
    connect();
  }

  const CONTROL_KEYS = new Set(['ArrowUp', 'ArrowDown', 'ArrowLeft', 'ArrowRight', 'PageUp', 'PageDown', 'Space']);
  window.addEventListener('keydown', (e) => {
    wakeFromIdle();
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
  document.addEventListener('visibilitychange', () => { if (!document.hidden) wakeFromIdle(); });

  // Pointer events cover mouse, pen and touch: one pointer looks, two move.
  canvas.addEventListener('pointerdown', (e) => {
    wakeFromIdle();
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
    $('codec').value = state.streamCodec || state.codec;
    $('quality').disabled = $('codec').value !== 'jpeg'; // JPEG quality: H.264 has a bitrate
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
        codec: change.codec ?? state.codec,
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
  $('codec').addEventListener('change', (e) => {
    const codec = e.target.value;
    state.codec = codec; // a reconnect asks for it too
    configure({ codec, width: evenFor(codec, state.width), height: evenFor(codec, state.height) });
    e.target.blur();
  });
  $('quality').addEventListener('input', (e) => { $('quality-value').textContent = e.target.value; });
  $('quality').addEventListener('change', (e) => {
    configure({ quality: +e.target.value });
    e.target.blur();
  });

  // ---- overlay ----
  // Drops entries older than a second from a list whose entries start with a time.
  function lastSecond(list, timeOf) {
    const now = performance.now();
    while (list.length && now - timeOf(list[0]) > 1000) list.shift();
    return list;
  }
  const fps = () => lastSecond(state.shownAt, (t) => t).length;
  // Bitrate received over the last second (headers included), kbit/s.
  const kbps = () => lastSecond(state.arrivals, ([t]) => t).reduce((sum, [, bytes]) => sum + bytes, 0) * 8 / 1000;
  const serverDropped = () => (state.header ? state.header.dropped : 0);

  function updateOverlay() {
    const h = state.header;
    const latency = state.latencyMs === null ? '–' : `${state.latencyMs.toFixed(0)} ms`;
    const codec = state.streamCodec || state.codec;
    const lines = [`${codec}  fps ${fps().toString().padStart(3)}  latency ${latency}`];
    if (h) {
      const jpegQuality = h.codec === 'jpeg' ? `  JPEG quality ${h.quality}` : '';
      const target = h.targetKbps ? ` (target ${h.targetKbps})` : '';
      lines.push(
        `${h.width}×${h.height} ${h.layout}${h.views > 1 ? ' ×' + h.views : ''}${jpegQuality}`,
        `${kbps().toFixed(0)} kbit/s received${target}`,
        `render ${(h.renderUs / 1000).toFixed(1)} ms  encode ${(h.encodeUs / 1000).toFixed(1)} ms`,
        `dropped ${serverDropped() + state.clientDrops} (server ${serverDropped()}, here ${state.clientDrops})  decode errors ${state.decodeErrors}`,
      );
    } else {
      lines.push('waiting for frames…');
    }
    if (state.cams.length > 1) lines.push(`controlling view ${state.active + 1}/${state.cams.length} (keys 1–${state.cams.length})`);
    $('overlay').textContent = lines.join('\n');
  }

  // Hooks for tests and the console: the overlay's numbers, and more.
  window.fogcast = {
    stats: () => ({
      connected: state.connected,
      codec: state.streamCodec, // what the server sends (the welcome's)
      askedCodec: state.codec, // what the hello asked for
      received: state.received,
      shown: state.shown,
      framesDecoded: state.framesDecoded,
      keyFrames: state.keyFrames,
      decodeErrors: state.decodeErrors,
      clientDrops: state.clientDrops,
      serverDropped: serverDropped(),
      acks: state.acks,
      lastAcked: state.lastAcked,
      keyframeRequests: state.keyframeRequests,
      lastFrame: state.header ? state.header.frame : null,
      frameCodec: state.header ? state.header.codec : null,
      quality: state.header ? state.header.quality : null,
      targetKbps: state.header ? state.header.targetKbps : null,
      kbps: kbps(),
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
    // Feeds the next H.264 frame to the decoder as garbage: a decode error to recover from.
    corruptNextFrame: () => { state.corruptNext = true; },
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

  setInterval(tick, 1000 / POSE_HZ);
  setInterval(updateOverlay, 250);
  chooseCodec().then((codec) => {
    state.codec = codec;
    syncControls();
    connect();
  });
})();
