// colslam viewer page: receives the state through Server-Sent Events
// (/events: a full state, then deltas) and draws it with WebGL. Plain
// JavaScript, no dependencies. Counts of what is drawn are mirrored into
// #stats data attributes so tests can read them.
'use strict';

const $ = (id) => document.getElementById(id);

// ---------------------------------------------------------------- state
const model = {
  epoch: -1, version: 0, updates: 0,
  points: new Map(),   // id -> {x, y, z, r, g, b, track: number[]}
  cameras: new Map(),  // image id -> camera JSON (c, r, w, h, fx, fy, cx, cy, order, name)
  frame: null, keyframe: null, summary: null, source: '', hasController: false,
  run: { state: 'idle', message: '' }, status: '',
  images: null,        // {available, note} for a loaded model; null for a live map
  gt: null,            // ground-truth layer: {ate_rmse, matched, scale, path, ids, errors}
};
const view = {
  selected: -1, clipStart: 0, clipEnd: 0, clipFollow: true,
  showPath: true, showCams: true, showGrid: true, showGt: true, frustumScale: 1, pointSize: 3, bg: [0.08, 0.09, 0.11],
  target: [0, 0, 0], dist: 10, yaw: 0, pitch: 0.3, up: [0, -1, 0], fwd: [0, 0, 1], radius: 1,
  fitted: false,
  // Until the user moves the view, it is refitted as the map grows (live runs).
  userMoved: false,
  frustumBase: 0.04,
};
// What the last rebuild drew (CPU side, also used for picking).
let drawn = { pts: new Float32Array(0), ids: [], tracks: [], nPts: 0, nCams: 0, nPath: 0, nTrack: 0, camsSorted: [], clipped: [] };

function applyUpdate(msg) {
  if (msg.full) {
    const newModel = msg.epoch !== model.epoch;
    model.points.clear();
    model.cameras.clear();
    model.hasController = !!msg.has_controller;
    if (newModel) { view.fitted = false; view.userMoved = false; resetCameraSelection(); }
  }
  model.epoch = msg.epoch;
  model.version = msg.version;
  model.updates += 1;
  for (const id of msg.removed_points || []) model.points.delete(id);
  for (const id of msg.removed_cameras || []) model.cameras.delete(id);
  const p = msg.points;
  if (p) {
    let t = 0;
    for (let i = 0; i < p.ids.length; i++) {
      const n = p.tlen[i];
      model.points.set(p.ids[i], {
        x: p.xyz[3 * i], y: p.xyz[3 * i + 1], z: p.xyz[3 * i + 2],
        r: p.rgb[3 * i], g: p.rgb[3 * i + 1], b: p.rgb[3 * i + 2],
        track: p.track.slice(t, t + n),
      });
      t += n;
    }
  }
  for (const c of msg.cameras || []) model.cameras.set(c.id, c);
  // A full state without a frame/keyframe (after a reset) clears the panels.
  if ('frame' in msg) showFrame(msg.frame); else if (msg.full) clearFrame();
  if ('keyframe' in msg) showKeyframe(msg.keyframe); else if (msg.full) clearKeyframe();
  if ('summary' in msg) showSummary(msg.summary);
  if ('status' in msg) model.status = msg.status || '';
  if ('run' in msg) model.run = msg.run;
  if ('status' in msg || 'run' in msg || 'summary' in msg) showRunStatus();
  if ('source' in msg) { model.source = msg.source; $('source').textContent = msg.source || '–'; }
  if ('images' in msg) model.images = msg.images;
  if ('gt' in msg) showGroundTruth(msg.gt);
  updateRunButtons();
  if (p || msg.cameras || msg.removed_points || msg.removed_cameras || msg.full || 'gt' in msg) scheduleRebuild();
  if ('images' in msg || 'frame' in msg || 'keyframe' in msg || msg.full) updatePanels();
  setStat('epoch', model.epoch);
  setStat('version', model.version);
  setStat('updates', model.updates);
}

function setStat(key, v) { $('stats').setAttribute('data-' + key, String(v)); }

// ---------------------------------------------------------------- events
function connect() {
  const es = new EventSource('/events');
  es.addEventListener('update', (e) => {
    try { applyUpdate(JSON.parse(e.data)); } catch (err) { console.error('bad update', err); }
  });
  es.onopen = () => { $('conn').textContent = 'connected'; setStat('connected', 1); };
  // EventSource reconnects by itself; the server then sends the full state.
  es.onerror = () => { $('conn').textContent = 'connection lost, reconnecting…'; setStat('connected', 0); };
}

// ---------------------------------------------------------------- frame view
let frameLoading = false, framePending = null, frameLines = null;
function showFrame(f) {
  if (!f) return;
  $('frame-index').textContent = f.index;
  $('kf-badge').hidden = !f.is_keyframe;
  const okFlow = f.flow_score > f.flow_threshold, okMatch = f.num_matches >= f.min_matches;
  const fs = $('flow-score');
  fs.textContent = fmt(f.flow_score, 4); fs.className = okFlow ? 'ok' : 'bad';
  $('flow-threshold').textContent = fmt(f.flow_threshold, 4);
  const nm = $('num-matches');
  nm.textContent = f.num_matches; nm.className = okMatch ? 'ok' : 'bad';
  $('min-matches').textContent = f.min_matches;
  $('num-inliers').textContent = f.num_inliers;
  const fv = $('frame-view');
  fv.setAttribute('data-frame-index', f.index);
  fv.setAttribute('data-flow-lines', f.lines.length / 4);
  frameLines = f;
  if (f.picture != null) loadFramePicture('/api/frame.png?v=' + f.picture);
  else drawFlow();
}
function loadFramePicture(url) {
  // Only one picture in flight: frames may arrive faster than they load.
  if (frameLoading) { framePending = url; return; }
  frameLoading = true;
  $('frame-img').src = url;
}
$('frame-img').addEventListener('load', () => { frameLoading = false; drawFlow(); if (framePending) { const u = framePending; framePending = null; loadFramePicture(u); } });
$('frame-img').addEventListener('error', () => { frameLoading = false; });
function drawFlow() {
  const img = $('frame-img'), cv = $('flow'), f = frameLines;
  // The picture is drawn with object-fit: contain; the overlay covers
  // exactly the drawn content box.
  const bw = img.clientWidth, bh = img.clientHeight;
  const nw = img.naturalWidth || (f && f.width) || 1, nh = img.naturalHeight || (f && f.height) || 1;
  const k = Math.min(bw / nw, bh / nh);
  const w = Math.round(nw * k), h = Math.round(nh * k);
  cv.width = w; cv.height = h;
  cv.style.left = (img.offsetLeft + (bw - w) / 2) + 'px'; cv.style.top = (img.offsetTop + (bh - h) / 2) + 'px';
  const ctx = cv.getContext('2d');
  ctx.clearRect(0, 0, w, h);
  let nIn = 0, nOut = 0;
  if (f && f.width && w) {
    const sx = w / f.width, sy = h / f.height;
    const stroke = (lines, color) => {
      ctx.strokeStyle = color; ctx.lineWidth = 1.2; ctx.beginPath();
      let n = 0;
      for (let i = 0; i + 3 < lines.length; i += 4, n++) {
        ctx.moveTo(lines[i] * sx, lines[i + 1] * sy);
        ctx.lineTo(lines[i + 2] * sx, lines[i + 3] * sy);
      }
      ctx.stroke();
      return n;
    };
    // Rejected matches (on request) under the verified ones.
    if ($('show-outliers').checked) nOut = stroke(f.outlier_lines || [], '#e5484d');
    nIn = stroke(f.lines, '#39f');
  }
  // What was drawn, for the frame it was drawn for (tests compare the
  // line count with the frame's verified matches).
  setStat('flow-frame', f ? f.index : -1);
  setStat('flow-lines', nIn);
  setStat('outlier-lines', nOut);
  setStat('frame-matches', f ? f.num_matches : 0);
  setStat('frame-inliers', f ? f.num_inliers : 0);
}
$('show-outliers').addEventListener('change', () => drawFlow());
function clearFrame() {
  frameLines = null; framePending = null;
  $('frame-img').removeAttribute('src');
  for (const id of ['frame-index', 'flow-score', 'flow-threshold', 'num-matches', 'min-matches', 'num-inliers']) $(id).textContent = '–';
  $('kf-badge').hidden = true;
  $('frame-view').removeAttribute('data-frame-index');
  drawFlow();
}
function clearKeyframe() {
  $('kf-img').removeAttribute('src');
  $('kf-id').textContent = '–'; $('kf-caption').textContent = '';
  $('frame-view').removeAttribute('data-keyframe-id');
}
function showKeyframe(k) {
  if (!k) return;
  $('kf-id').textContent = '#' + k.image_id;
  $('kf-caption').textContent = (k.name || '') + ' (frame ' + k.frame_index + ')';
  $('frame-view').setAttribute('data-keyframe-id', k.image_id);
  if (k.picture != null) $('kf-img').src = '/api/keyframe.png?v=' + k.picture;
}
function showSummary(s) {
  if (!s) return;
  model.summary = s;
  $('sum-keyframes').textContent = s.keyframes;
  $('sum-points').textContent = s.points;
  $('sum-observations').textContent = s.observations;
  $('sum-error').textContent = s.mean_reproj_error == null ? '–' : fmt(s.mean_reproj_error, 3) + ' px';
  $('sum-fps').textContent = s.fps ? fmt(s.fps, 2) : '–';
}
function fmt(v, d) { return (v == null || !isFinite(v)) ? '–' : Number(v).toFixed(d); }

// ---------------------------------------------------------------- geometry
let rebuildQueued = false;
function scheduleRebuild() {
  if (rebuildQueued) return;
  rebuildQueued = true;
  // setTimeout, not requestAnimationFrame: hidden tabs must keep state current.
  setTimeout(() => { rebuildQueued = false; rebuild(); }, 0);
}

// Recency colour: green for the first camera, red for the last.
function recency(rank, n) { const t = n > 1 ? rank / (n - 1) : 1; return [t, 1 - t, 0]; }

// Rebuilds the drawn geometry. `withPoints` false keeps the point arrays
// (frustum scale, visibility toggles and track selection do not change them),
// which keeps those controls smooth on large maps.
function rebuild(withPoints = true) {
  const cams = [...model.cameras.values()].sort((a, b) => a.order - b.order || a.id - b.id);
  const nCam = cams.length;
  // Clip sliders index cameras by rank in registration order.
  const cs = $('clip-start'), ce = $('clip-end');
  const maxRank = Math.max(0, nCam - 1);
  cs.max = ce.max = maxRank;
  if (view.clipFollow) view.clipEnd = maxRank;
  view.clipStart = Math.min(view.clipStart, maxRank);
  view.clipEnd = Math.min(Math.max(view.clipEnd, view.clipStart), maxRank);
  cs.value = view.clipStart; ce.value = view.clipEnd;
  $('clip-start-label').textContent = nCam ? label(cams[view.clipStart]) : '–';
  $('clip-end-label').textContent = nCam ? label(cams[view.clipEnd]) : '–';
  const loOrder = nCam ? cams[view.clipStart].order : -Infinity;
  const hiOrder = nCam ? cams[view.clipEnd].order : Infinity;
  const fullRange = !nCam || (view.clipStart === 0 && view.clipEnd === maxRank);
  const inClip = (o) => o >= loOrder && o <= hiOrder;

  let pos = null, col = null;
  if (withPoints) {
    ({ pos, col } = buildPoints(fullRange, inClip));
    if ((!view.fitted || !view.userMoved) && (model.points.size || nCam)) { fitView(); view.fitted = true; buildGrid(); }
  }
  drawn.camsSorted = cams;
  const clipped = [];
  cams.forEach((c, rank) => { if (inClip(c.order)) clipped.push([c, rank]); });

  // Frustums: 8 segments each (4 edges from the centre, 4 around the image).
  const s = view.frustumScale * view.frustumBase;
  const fr = new Float32Array(clipped.length * 16 * 3), fc = new Float32Array(clipped.length * 16 * 3);
  let v = 0;
  const push = (arr, carr, p, c) => { arr[3 * v] = p[0]; arr[3 * v + 1] = p[1]; arr[3 * v + 2] = p[2]; carr[3 * v] = c[0]; carr[3 * v + 1] = c[1]; carr[3 * v + 2] = c[2]; v++; };
  for (const [c, rank] of clipped) {
    const color = recency(rank, nCam);
    const corners = [[0, 0], [c.w, 0], [c.w, c.h], [0, c.h]].map(([u, w]) => {
      // Camera ray through the image corner, depth 1, scaled.
      const x = (u - c.cx) / c.fx * s, y = (w - c.cy) / c.fy * s, z = s;
      const r = c.r;
      return [c.c[0] + r[0] * x + r[1] * y + r[2] * z, c.c[1] + r[3] * x + r[4] * y + r[5] * z, c.c[2] + r[6] * x + r[7] * y + r[8] * z];
    });
    for (let i = 0; i < 4; i++) {
      push(fr, fc, c.c, color); push(fr, fc, corners[i], color);
      push(fr, fc, corners[i], color); push(fr, fc, corners[(i + 1) % 4], color);
    }
  }
  drawn.nCams = view.showCams ? clipped.length : 0;
  // Camera path through the clipped cameras, coloured like them.
  const pathN = Math.max(0, clipped.length - 1);
  const pp = new Float32Array(pathN * 6), pc = new Float32Array(pathN * 6);
  v = 0;
  for (let i = 0; i < pathN; i++) {
    const [a, ra] = clipped[i], [b, rb] = clipped[i + 1];
    push(pp, pc, a.c, pathColor(a, ra, nCam)); push(pp, pc, b.c, pathColor(b, rb, nCam));
  }
  drawn.nPath = view.showPath ? pathN : 0;
  // Track lines: selected point to every observing camera inside the clip.
  const tp = [], tc = [];
  const sel = model.points.get(view.selected);
  let selectedShown = false;
  if (sel) {
    let intro = Infinity;
    for (const im of sel.track) { const c = model.cameras.get(im); if (c && c.order < intro) intro = c.order; }
    selectedShown = intro === Infinity ? fullRange : inClip(intro);
    if (selectedShown) for (const im of sel.track) {
      const c = model.cameras.get(im);
      if (!c || !inClip(c.order)) continue;
      tp.push(sel.x, sel.y, sel.z, c.c[0], c.c[1], c.c[2]);
      tc.push(1, 0.85, 0.1, 1, 0.85, 0.1);
    }
  }
  drawn.nTrack = tp.length / 6;
  gpu.upload(pos, col, fr, fc, pp, pc, new Float32Array(tp), new Float32Array(tc));
  drawn.clipped = clipped;
  rebuildCameraLayers();

  setStat('points', model.points.size);
  setStat('cameras', nCam);
  setStat('drawn-points', drawn.nPts);
  setStat('drawn-cameras', drawn.nCams);
  setStat('drawn-path', drawn.nPath);
  setStat('drawn-track-lines', drawn.nTrack);
  setStat('selected-point', view.selected);
  requestDraw();
}
// Points, clipped by the order at which they were introduced (the smallest
// registration order among their observers; points without a registered
// observer only show when nothing is clipped).
function buildPoints(fullRange, inClip) {
  const n = model.points.size;
  const pos = new Float32Array(3 * n), col = new Uint8Array(3 * n), ids = new Array(n), tracks = new Array(n);
  let k = 0, maxId = -1;
  for (const [id, p] of model.points) {
    if (id > maxId) maxId = id;
    let intro = Infinity;
    for (const im of p.track) { const c = model.cameras.get(im); if (c && c.order < intro) intro = c.order; }
    if (intro === Infinity ? !fullRange : !inClip(intro)) continue;
    pos[3 * k] = p.x; pos[3 * k + 1] = p.y; pos[3 * k + 2] = p.z;
    col[3 * k] = p.r; col[3 * k + 1] = p.g; col[3 * k + 2] = p.b;
    ids[k] = id; tracks[k] = p.track; k++;
  }
  drawn.pts = pos.subarray(0, 3 * k); drawn.ids = ids.slice(0, k); drawn.tracks = tracks.slice(0, k); drawn.nPts = k;
  $('track-range').max = Math.max(0, maxId);
  return { pos: drawn.pts, col: col.subarray(0, 3 * k) };
}
function label(c) { return '#' + c.order + ' ' + (c.name || c.id); }

// Fits the orbit camera to the data: robust centre (median) and radius
// (90th percentile distance), looking along the mean camera direction with
// the mean camera "up" (-y axis, COLMAP's y points down) as up.
function fitView() {
  const xs = [], ys = [], zs = [];
  const step = Math.max(1, Math.floor(model.points.size / 20000));
  let i = 0;
  for (const p of model.points.values()) { if (i++ % step === 0) { xs.push(p.x); ys.push(p.y); zs.push(p.z); } }
  for (const c of model.cameras.values()) { xs.push(c.c[0]); ys.push(c.c[1]); zs.push(c.c[2]); }
  if (!xs.length) return;
  const med = (a) => { const b = Float64Array.from(a).sort(); return b[b.length >> 1]; };
  const ctr = [med(xs), med(ys), med(zs)];
  const d = xs.map((x, j) => Math.hypot(x - ctr[0], ys[j] - ctr[1], zs[j] - ctr[2])).sort((a, b) => a - b);
  // Robust for points (90th percentile) but keeping every camera in view.
  let radius = Math.max(d[Math.floor(0.9 * (d.length - 1))], 1e-6);
  for (const c of model.cameras.values()) radius = Math.max(radius, Math.hypot(c.c[0] - ctr[0], c.c[1] - ctr[1], c.c[2] - ctr[2]));
  // Frustum size: a fraction of the typical step between consecutive cameras.
  const cs = [...model.cameras.values()].sort((a, b) => a.order - b.order);
  const steps = [];
  for (let j = 1; j < cs.length; j++) steps.push(Math.hypot(cs[j].c[0] - cs[j - 1].c[0], cs[j].c[1] - cs[j - 1].c[1], cs[j].c[2] - cs[j - 1].c[2]));
  const stepMed = steps.length ? med(steps) : 0.04 * radius;
  view.frustumBase = Math.min(Math.max(0.8 * stepMed, 0.01 * radius), 0.08 * radius);
  let up = [0, 0, 0], fwd = [0, 0, 0];
  for (const c of model.cameras.values()) {
    up = add(up, [-c.r[1], -c.r[4], -c.r[7]]); fwd = add(fwd, [c.r[2], c.r[5], c.r[8]]);
  }
  if (norm(up) < 1e-9) up = [0, -1, 0];
  up = normalize(up);
  fwd = sub(fwd, scale(up, dot(fwd, up)));
  if (norm(fwd) < 1e-9) fwd = Math.abs(up[2]) < 0.9 ? normalize(cross(up, [0, 0, 1])) : normalize(cross(up, [1, 0, 0]));
  view.up = up; view.fwd = normalize(fwd);
  // Distance at which a sphere of this radius fits the 50-degree field of view.
  view.target = ctr; view.radius = radius; view.yaw = 0; view.pitch = 0.35;
  // Distance at which the data fills the view: each sample needs the eye far
  // enough back to fall inside both fields of view; take every camera and
  // 95 % of the points (outliers would shrink the cloud to a dot).
  const { dir, right, up: vup } = eyeBasis();
  const cv = $('gl'), aspect = (cv.clientWidth || 4) / (cv.clientHeight || 3);
  const tv = Math.tan(HALF_FOV), th = tv * aspect;
  const need = (x, y, z) => {
    const d = [x - ctr[0], y - ctr[1], z - ctr[2]];
    return Math.max(Math.abs(dot(d, right)) / th, Math.abs(dot(d, vup)) / tv) - dot(d, dir);
  };
  const np = xs.length - model.cameras.size;
  const pn = [];
  for (let j = 0; j < np; j++) pn.push(need(xs[j], ys[j], zs[j]));
  pn.sort((a, b) => a - b);
  let dist = pn.length ? pn[Math.floor(0.95 * (pn.length - 1))] : 0;
  for (const c of model.cameras.values()) dist = Math.max(dist, need(c.c[0], c.c[1], c.c[2]));
  view.dist = Math.max(1.1 * dist, 0.05 * radius, 1e-6);
}

// ---------------------------------------------------------------- math
const HALF_FOV = 25 * Math.PI / 180; // vertical field of view: 50 degrees
function add(a, b) { return [a[0] + b[0], a[1] + b[1], a[2] + b[2]]; }
function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
function scale(a, s) { return [a[0] * s, a[1] * s, a[2] * s]; }
function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
function norm(a) { return Math.hypot(a[0], a[1], a[2]); }
function normalize(a) { const n = norm(a) || 1; return scale(a, 1 / n); }

// Eye basis from the orbit parameters: yaw about `up`, pitch towards it.
function eyeBasis() {
  const right0 = normalize(cross(view.fwd, view.up));
  const cy = Math.cos(view.yaw), sy = Math.sin(view.yaw), cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
  const horiz = add(scale(view.fwd, cy), scale(right0, sy));
  const dir = add(scale(horiz, cp), scale(view.up, -sp)); // looking direction (down when pitch > 0)
  const eye = sub(view.target, scale(dir, view.dist));
  const right = normalize(cross(dir, view.up));
  const up = cross(right, dir);
  return { eye, dir, right, up };
}
// Column-major 4x4 view-projection matrix.
function viewProj(aspect) {
  const { eye, dir, right, up } = eyeBasis();
  const f = 1 / Math.tan(HALF_FOV);
  const near = view.dist * 0.01, far = view.dist + view.radius * 50;
  const a = (far + near) / (near - far), b = 2 * far * near / (near - far);
  // view rows: right, up, -dir ; projection then applied.
  const V = [right, up, scale(dir, -1)];
  const t = V.map((r) => -dot(r, eye));
  const m = new Float32Array(16);
  for (let c = 0; c < 3; c++) {
    m[4 * c + 0] = f / aspect * V[0][c];
    m[4 * c + 1] = f * V[1][c];
    m[4 * c + 2] = a * V[2][c];
    m[4 * c + 3] = -V[2][c];
  }
  m[12] = f / aspect * t[0]; m[13] = f * t[1]; m[14] = a * t[2] + b; m[15] = -t[2];
  return m;
}

// ---------------------------------------------------------------- WebGL
const gpu = (() => {
  const canvas = $('gl');
  const gl = canvas.getContext('webgl', { antialias: true, preserveDrawingBuffer: true });
  if (!gl) {
    $('gl-note').hidden = false;
    $('gl-note').textContent = 'WebGL is not available in this browser: the 3D view is off, the rest works.';
    return { gl: null, upload() {}, uploadLayers() {}, draw() {} };
  }
  setStat('webgl', 1);
  const vs = `attribute vec3 pos; attribute vec3 col; uniform mat4 mvp; uniform float size; varying vec3 vcol;
    void main() { gl_Position = mvp * vec4(pos, 1.0); gl_PointSize = size; vcol = col; }`;
  const fsPts = `precision mediump float; varying vec3 vcol;
    void main() { vec2 d = gl_PointCoord - vec2(0.5); if (dot(d, d) > 0.25) discard; gl_FragColor = vec4(vcol, 1.0); }`;
  const fsLines = `precision mediump float; varying vec3 vcol; void main() { gl_FragColor = vec4(vcol, 1.0); }`;
  function program(fsrc) {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fsrc]]) {
      const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) console.error(gl.getShaderInfoLog(s));
      gl.attachShader(p, s);
    }
    gl.bindAttribLocation(p, 0, 'pos'); gl.bindAttribLocation(p, 1, 'col');
    gl.linkProgram(p);
    return { p, mvp: gl.getUniformLocation(p, 'mvp'), size: gl.getUniformLocation(p, 'size') };
  }
  const progPts = program(fsPts), progLines = program(fsLines);
  const mk = () => ({ pos: gl.createBuffer(), col: gl.createBuffer(), n: 0, norm: false });
  const bufs = { pts: mk(), cams: mk(), path: mk(), track: mk(), grid: mk(), gt: mk(), hl: mk(), cur: mk() };
  function set(b, pos, col, normalized) {
    gl.bindBuffer(gl.ARRAY_BUFFER, b.pos); gl.bufferData(gl.ARRAY_BUFFER, pos, gl.STATIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, b.col); gl.bufferData(gl.ARRAY_BUFFER, col, gl.STATIC_DRAW);
    b.n = pos.length / 3; b.norm = normalized;
  }
  function bind(b) {
    gl.bindBuffer(gl.ARRAY_BUFFER, b.pos); gl.enableVertexAttribArray(0); gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, b.col); gl.enableVertexAttribArray(1);
    if (b.norm) gl.vertexAttribPointer(1, 3, gl.UNSIGNED_BYTE, true, 0, 0); else gl.vertexAttribPointer(1, 3, gl.FLOAT, false, 0, 0);
  }
  return {
    gl,
    // Layers of the camera section (grid and axes, ground truth, the current
    // camera's frustum and observed points): [positions, colours] or null.
    uploadLayers(layers) {
      for (const k of ['grid', 'gt', 'hl', 'cur']) if (layers[k]) set(bufs[k], layers[k][0], layers[k][1], false);
    },
    upload(pp, pc, fp, fc, cp, cc, tp, tc) {
      if (pp) set(bufs.pts, pp, pc, true);
      set(bufs.cams, fp, fc, false); set(bufs.path, cp, cc, false); set(bufs.track, tp, tc, false);
    },
    draw() {
      const dpr = window.devicePixelRatio || 1;
      const w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
      if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
      gl.viewport(0, 0, w, h);
      gl.clearColor(view.bg[0], view.bg[1], view.bg[2], 1); gl.enable(gl.DEPTH_TEST);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      const m = viewProj(w / h);
      // One draw call per kind.
      gl.useProgram(progPts.p); gl.uniformMatrix4fv(progPts.mvp, false, m); gl.uniform1f(progPts.size, view.pointSize * dpr);
      if (bufs.pts.n) { bind(bufs.pts); gl.drawArrays(gl.POINTS, 0, bufs.pts.n); }
      if (bufs.hl.n) {
        // Observed points of the current camera, over the others.
        gl.disable(gl.DEPTH_TEST); gl.uniform1f(progPts.size, (view.pointSize + 2) * dpr);
        bind(bufs.hl); gl.drawArrays(gl.POINTS, 0, bufs.hl.n); gl.enable(gl.DEPTH_TEST);
      }
      gl.useProgram(progLines.p); gl.uniformMatrix4fv(progLines.mvp, false, m); gl.uniform1f(progLines.size, 1);
      if (view.showCams && bufs.cams.n) { bind(bufs.cams); gl.drawArrays(gl.LINES, 0, bufs.cams.n); }
      if (view.showPath && bufs.path.n) { bind(bufs.path); gl.drawArrays(gl.LINES, 0, bufs.path.n); }
      if (view.showGrid && bufs.grid.n) { bind(bufs.grid); gl.drawArrays(gl.LINES, 0, bufs.grid.n); }
      if (view.showGt && bufs.gt.n) { bind(bufs.gt); gl.drawArrays(gl.LINES, 0, bufs.gt.n); }
      if (bufs.cur.n) { gl.disable(gl.DEPTH_TEST); bind(bufs.cur); gl.drawArrays(gl.LINES, 0, bufs.cur.n); gl.enable(gl.DEPTH_TEST); }
      if (bufs.track.n) { gl.disable(gl.DEPTH_TEST); bind(bufs.track); gl.drawArrays(gl.LINES, 0, bufs.track.n); }
    },
  };
})();
let drawQueued = false;
function requestDraw() {
  if (drawQueued) return;
  drawQueued = true;
  requestAnimationFrame(() => { drawQueued = false; gpu.draw(); });
}
window.addEventListener('resize', () => { requestDraw(); drawFlow(); drawKeypoints(); });

// ---------------------------------------------------------------- mouse
(() => {
  const c = $('gl');
  let drag = null;
  c.addEventListener('contextmenu', (e) => e.preventDefault());
  c.addEventListener('mousedown', (e) => { drag = { x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, pan: e.button !== 0 || e.shiftKey }; });
  window.addEventListener('mouseup', (e) => {
    if (drag && Math.hypot(e.clientX - drag.x0, e.clientY - drag.y0) < 4 && !drag.pan) pick(e);
    drag = null;
  });
  window.addEventListener('mousemove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    view.userMoved = true;
    if (drag.pan) {
      const { right, up } = eyeBasis(), k = view.dist * 0.0015;
      view.target = add(view.target, add(scale(right, -dx * k), scale(up, dy * k)));
    } else {
      view.yaw -= dx * 0.006;
      view.pitch = Math.max(-1.5, Math.min(1.5, view.pitch + dy * 0.006));
    }
    requestDraw();
  });
  c.addEventListener('wheel', (e) => { e.preventDefault(); view.dist *= Math.exp(e.deltaY * 0.001); view.userMoved = true; requestDraw(); }, { passive: false });
})();

// Picking: the drawn point nearest to the click in screen space (within
// PICK_RADIUS_PX) becomes the selected track.
const PICK_RADIUS_PX = 12;
function pick(e) {
  if (pickCamera(e)) return;
  const c = $('gl'), r = c.getBoundingClientRect();
  const m = viewProj(r.width / r.height);
  const mx = e.clientX - r.left, my = e.clientY - r.top;
  let best = -1, bestD = PICK_RADIUS_PX * PICK_RADIUS_PX;
  const P = drawn.pts;
  for (let i = 0; i < drawn.nPts; i++) {
    const x = P[3 * i], y = P[3 * i + 1], z = P[3 * i + 2];
    const w = m[3] * x + m[7] * y + m[11] * z + m[15];
    if (w <= 0) continue;
    const sx = ((m[0] * x + m[4] * y + m[8] * z + m[12]) / w * 0.5 + 0.5) * r.width;
    const sy = (0.5 - (m[1] * x + m[5] * y + m[9] * z + m[13]) / w * 0.5) * r.height;
    const d = (sx - mx) ** 2 + (sy - my) ** 2;
    if (d < bestD) { bestD = d; best = drawn.ids[i]; }
  }
  if (best >= 0) selectTrack(best);
}
function selectTrack(id) {
  view.selected = Number.isFinite(id) ? id : -1;
  $('track').value = view.selected; $('track-range').value = view.selected;
  rebuild(false);
}

// ---------------------------------------------------------------- controls
function pair(rangeId, numId, onChange) {
  const r = $(rangeId), n = $(numId);
  r.addEventListener('input', () => { n.value = r.value; onChange && onChange(); });
  n.addEventListener('input', () => { if (n.value !== '') r.value = n.value; onChange && onChange(); });
}
pair('track-range', 'track', () => selectTrack(parseInt($('track').value, 10)));
pair('skip-range', 'skip', () => queueMaxFrames());
pair('max-range', 'max-frames');
pair('init-range', 'init-frames');
pair('thr-range', 'flow-thr');
$('input-path').addEventListener('input', () => queueMaxFrames());
$('bg-color').addEventListener('input', (e) => {
  const h = e.target.value; view.bg = [1, 3, 5].map((i) => parseInt(h.slice(i, i + 2), 16) / 255); requestDraw();
});
$('show-path').addEventListener('change', (e) => { view.showPath = e.target.checked; rebuild(false); });
$('show-cams').addEventListener('change', (e) => { view.showCams = e.target.checked; rebuild(false); });
$('frustum-scale').addEventListener('input', (e) => { view.frustumScale = parseFloat(e.target.value); rebuild(false); });
$('point-size').addEventListener('input', (e) => { view.pointSize = parseFloat(e.target.value); requestDraw(); });
$('reset-cam').addEventListener('click', () => { view.userMoved = false; fitView(); rebuild(); });
$('clip-start').addEventListener('input', (e) => {
  view.clipStart = parseInt(e.target.value, 10);
  if (view.clipEnd < view.clipStart) { view.clipEnd = view.clipStart; view.clipFollow = false; }
  rebuild();
});
$('clip-end').addEventListener('input', (e) => {
  view.clipEnd = parseInt(e.target.value, 10);
  view.clipFollow = view.clipEnd === parseInt(e.target.max, 10);
  if (view.clipStart > view.clipEnd) view.clipStart = view.clipEnd;
  rebuild();
});

function message(id, text, kind) { const m = $(id); m.textContent = text; m.className = 'msg ' + (kind || ''); }
async function post(url, body) {
  const r = await fetch(url, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
  let j = {};
  try { j = await r.json(); } catch (_) { j = { error: 'HTTP ' + r.status }; }
  if (!r.ok) throw new Error(j.error || ('HTTP ' + r.status));
  return j;
}

$('load-btn').addEventListener('click', async () => {
  const path = $('load-path').value.trim();
  if (!path) return message('model-msg', 'Enter the folder of a COLMAP model.', 'error');
  message('model-msg', 'loading…');
  try {
    const j = await post('/api/load', { path });
    message('model-msg', `Loaded ${j.points} points, ${j.cameras} cameras.`, 'info');
  } catch (e) { message('model-msg', e.message, 'error'); }
});
$('export-btn').addEventListener('click', async () => {
  const path = $('export-path').value.trim();
  if (!path) return message('model-msg', 'Enter a path to export to.', 'error');
  try {
    const j = await post('/api/export', { path, format: $('export-format').value });
    message('model-msg', 'Exported to ' + j.path, 'info');
  } catch (e) { message('model-msg', e.message, 'error'); }
});

// Settings validation (the server checks the same again).
function readSettings() {
  const input = $('input-path').value.trim(), output = $('output-path').value.trim();
  const int = (id) => { const s = $(id).value.trim(); return /^-?\d+$/.test(s) ? parseInt(s, 10) : NaN; };
  const skip = int('skip'), init = int('init-frames');
  const thr = parseFloat($('flow-thr').value);
  const maxS = $('max-frames').value.trim();
  const bound = parseInt($('max-range').max, 10);
  let maxFrames = null;
  if (maxS !== '') {
    maxFrames = /^-?\d+$/.test(maxS) ? parseInt(maxS, 10) : NaN;
    if (!(maxFrames >= 1)) throw new Error('Maximum frames must be a whole number of at least 1 (or empty for all).');
    if (!$('max-range').disabled && maxFrames >= bound) maxFrames = null;
  }
  if (!input) throw new Error('Input path is missing.');
  if (!output) throw new Error('Output path is missing.');
  if (!(skip >= 1)) throw new Error('Frame skip must be a whole number of at least 1.');
  if (!(init >= 2)) throw new Error('Initialisation frames must be a whole number of at least 2.');
  if (!(thr >= 0 && thr <= 1)) throw new Error('Flow threshold must be between 0 and 1.');
  return { input, output, skip, max_frames: maxFrames, init_frames: init, flow_threshold: thr,
    extractor: $('extractor').value, matcher: $('matcher').value };
}
$('run-btn').addEventListener('click', async () => {
  let s;
  try { s = readSettings(); } catch (e) { return message('run-msg', e.message, 'error'); }
  // The run's state follows in the status line (running, finished, failed).
  try { await post('/api/run', s); message('run-msg', ''); } catch (e) { message('run-msg', e.message, 'error'); }
});
$('stop-btn').addEventListener('click', async () => {
  try { await post('/api/stop', {}); message('run-msg', 'Stopping…', 'info'); } catch (e) { message('run-msg', e.message, 'error'); }
});
function updateRunButtons() {
  const running = model.run.state === 'running' || model.run.state === 'stopping';
  $('run-btn').disabled = !model.hasController || running;
  $('stop-btn').disabled = !model.hasController || !running;
  $('run-note').textContent = !model.hasController
    ? 'Run is off: no pipeline attached (start with `colslam run … --view`).'
    : (runLine() || 'idle');
}
// The run in one line: "running: frame 12/40", "finished: …", "failed: …",
// "stopped: …"; empty when no run was started (a loaded model).
function runLine() {
  const r = model.run, s = model.summary;
  switch (r.state) {
    case 'running': {
      const progress = s && s.frames ? ': frame ' + s.frames + (s.total_frames ? '/' + s.total_frames : '') : '';
      return 'running' + progress + (model.status ? ' · ' + model.status : '');
    }
    case 'stopping': return 'stopping after the current frame…';
    case 'finished': case 'stopped': case 'failed': return r.state + (r.message ? ': ' + r.message : '');
    default: return '';
  }
}
function showRunStatus() {
  const line = runLine();
  $('status-line').textContent = line || model.status;
  $('status-line').className = model.run.state === 'failed' ? 'bad' : '';
  setStat('run-state', model.run.state);
  updateRunButtons();
}

// Max-frames bound: asked from the server whenever input or skip change.
let maxTimer = null;
function queueMaxFrames() { clearTimeout(maxTimer); maxTimer = setTimeout(fetchMaxFrames, 300); }
async function fetchMaxFrames() {
  const input = $('input-path').value.trim(), skip = $('skip').value.trim();
  if (!input || !model.hasController) return;
  try {
    // A POST: asking opens the input on the server (GET requests have no effects).
    const j = await post('/api/max_frames', { input, skip });
    const rg = $('max-range');
    rg.disabled = false; rg.max = Math.max(1, j.max_frames);
    rg.value = rg.max; $('max-frames').value = rg.max;
    $('max-bound').textContent = 'bound: ' + j.max_frames + ' frames';
    $('max-bound').setAttribute('data-bound', j.max_frames);
  } catch (e) { $('max-bound').textContent = 'bound unknown: ' + e.message; $('max-bound').setAttribute('data-bound', '-1'); }
}

// ================================================================ cameras
// Selection, the camera frame panel, timeline, ground grid, ground-truth
// layer and screenshot mode. The current camera is the one clicked or set
// by the timeline, else the latest registered one; its image and keypoints
// (loaded models) fill the camera panel, its observed points are
// highlighted and its numbers fill the info box.
const SCREENSHOT = new URLSearchParams(location.search).get('screenshot') === '1';
const cur = {
  id: -1,            // the current camera's image id (-1: none)
  explicit: false,   // chosen by a click or the timeline (else: the latest)
  detail: null,      // /api/camera answer for `id`
  imageId: -1,       // camera whose picture is shown
  playing: null,     // timeline timer
  seq: 0,            // request counter: stale answers are dropped
};
const KP_COLORS = ['#4aa8ff', '#2ee66b', '#ff4040']; // unmatched, triangulated, outlier (server's states)
const PLAY_INTERVAL_MS = 250;

function resetCameraSelection() {
  cur.id = -1; cur.explicit = false; cur.detail = null; cur.imageId = -1;
  stopPlay();
  const img = $('cam-img');
  if (img.src && img.src.startsWith('blob:')) URL.revokeObjectURL(img.src);
  img.removeAttribute('src');
  $('cam-panel').removeAttribute('data-image-id');
}

// Panels: a loaded model shows the camera panel; the live panels (last
// keyframe, current frame) only show once a live run fed them.
function updatePanels() {
  const fv = $('frame-view');
  const live = fv.hasAttribute('data-frame-index') || fv.hasAttribute('data-keyframe-id');
  const camPanel = model.images != null || (cur.explicit && cur.id >= 0);
  $('cam-panel').hidden = !camPanel;
  $('kf-panel').hidden = camPanel && !live;
  $('cur-panel').hidden = camPanel && !live;
  drawKeypoints();
}

// The cameras changed (rebuild): keep the current camera valid, move the
// timeline, and rebuild the layers that depend on it.
function rebuildCameraLayers() {
  const cams = drawn.camsSorted;
  const tl = $('timeline');
  tl.max = Math.max(0, cams.length - 1);
  if (cur.explicit && !model.cameras.has(cur.id)) cur.explicit = false;
  const latest = cams.length ? cams[cams.length - 1].id : -1;
  const id = cur.explicit ? cur.id : latest;
  if (id !== cur.id) setCurrent(id, cur.explicit); else uploadCameraLayers();
  updatePanels();
}

function rankOf(id) { return drawn.camsSorted.findIndex((c) => c.id === id); }

// Makes camera `id` current (explicit: chosen by the user).
function setCurrent(id, explicit) {
  cur.id = model.cameras.has(id) ? id : -1;
  cur.explicit = explicit && cur.id >= 0;
  const rank = rankOf(cur.id);
  if (rank >= 0) $('timeline').value = rank;
  const c = model.cameras.get(cur.id);
  $('timeline-label').textContent = c ? label(c) : '–';
  setStat('current-camera', cur.id);
  setStat('timeline', rank);
  uploadCameraLayers();
  showCameraInfo();
  loadCameraDetail();
  updatePanels();
}

// The current frustum, and the observed points of a camera the user chose
// (the latest camera of a growing map is not highlighted: its points would
// hide the colours), drawn over the rest. O(drawn points) per change of the
// chosen camera, never per mouse move.
function uploadCameraLayers() {
  const c = model.cameras.get(cur.id);
  const hp = [], hc = [];
  if (c && cur.explicit) {
    const P = drawn.pts;
    for (let i = 0; i < drawn.nPts; i++) {
      if (!drawn.tracks[i].includes(cur.id)) continue;
      hp.push(P[3 * i], P[3 * i + 1], P[3 * i + 2]); hc.push(1, 0.2, 1);
    }
  }
  const fp = [], fc = [];
  if (c && view.showCams) {
    const s = 1.6 * view.frustumScale * view.frustumBase;
    const corners = [[0, 0], [c.w, 0], [c.w, c.h], [0, c.h]].map(([u, w]) => {
      const x = (u - c.cx) / c.fx * s, y = (w - c.cy) / c.fy * s, z = s, r = c.r;
      return [c.c[0] + r[0] * x + r[1] * y + r[2] * z, c.c[1] + r[3] * x + r[4] * y + r[5] * z, c.c[2] + r[6] * x + r[7] * y + r[8] * z];
    });
    for (let i = 0; i < 4; i++) {
      fp.push(...c.c, ...corners[i], ...corners[i], ...corners[(i + 1) % 4]);
      for (let j = 0; j < 4; j++) fc.push(1, 1, 1);
    }
  }
  gpu.uploadLayers({ hl: [new Float32Array(hp), new Float32Array(hc)], cur: [new Float32Array(fp), new Float32Array(fc)] });
  setStat('highlighted-points', hp.length / 3);
  requestDraw();
}

// Counts from the page's own tracks (live maps have no server-side detail).
function showCameraInfo() {
  const c = model.cameras.get(cur.id);
  const box = $('cam-info');
  box.hidden = !c;
  box.setAttribute('data-camera-id', c ? c.id : -1);
  if (!c) return;
  $('info-id').textContent = c.id;
  $('info-name').textContent = c.name || '';
  const d = cur.detail && cur.detail.id === c.id ? cur.detail : null;
  const stamp = d && d.timestamp != null ? d.timestamp : null;
  $('info-time').textContent = stamp != null ? 'time ' + stamp.toFixed(3) + ' s' : 'registration #' + c.order;
  $('info-obs').textContent = d ? d.observations : (cur.explicit ? $('stats').dataset.highlightedPoints : '–');
  $('info-err').textContent = d && d.mean_reproj_error != null ? fmt(d.mean_reproj_error, 3) + ' px' : '–';
}

// Keypoints and numbers of the current camera (loaded models), then its picture.
async function loadCameraDetail() {
  const id = cur.id, seq = ++cur.seq;
  $('cam-title').textContent = id >= 0 ? '#' + id + ' ' + ((model.cameras.get(id) || {}).name || '') : '–';
  if (id < 0 || model.images == null) { cur.detail = null; drawKeypoints(); return; }
  screenshotStage('camera ' + id);
  try {
    const r = await fetch('/api/camera?id=' + id);
    if (seq !== cur.seq) return;
    cur.detail = r.ok ? await r.json() : null;
  } catch (_) { cur.detail = null; }
  if (seq !== cur.seq) return;
  showCameraInfo();
  drawKeypoints();
  await loadCameraImage(id, seq);
}

async function loadCameraImage(id, seq) {
  const note = $('cam-note'), img = $('cam-img'), panel = $('cam-panel');
  if (!model.images || !model.images.available) {
    if (img.src && img.src.startsWith('blob:')) URL.revokeObjectURL(img.src);
    img.removeAttribute('src'); cur.imageId = -1;
    note.textContent = 'No image: ' + ((model.images && model.images.note) || 'no images folder');
    panel.setAttribute('data-image-id', -1);
    drawKeypoints(); markDrawn();
    return;
  }
  try {
    screenshotStage('image ' + id);
    // A POST: the server opens the file (or decodes the video frame).
    const r = await fetch('/api/image', { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify({ id }) });
    if (seq !== cur.seq) return;
    if (!r.ok) {
      let msg = 'HTTP ' + r.status;
      try { msg = (await r.json()).error || msg; } catch (_) { /* keep the status */ }
      throw new Error(msg);
    }
    const url = URL.createObjectURL(await r.blob());
    if (seq !== cur.seq) { URL.revokeObjectURL(url); return; }
    screenshotStage('picture ' + id);
    await new Promise((resolve) => {
      img.onload = resolve; img.onerror = resolve;
      if (img.src && img.src.startsWith('blob:')) URL.revokeObjectURL(img.src);
      img.src = url;
    });
    if (seq !== cur.seq) return;
    cur.imageId = id; note.textContent = '';
    panel.setAttribute('data-image-id', id);
  } catch (e) {
    if (seq !== cur.seq) return;
    img.removeAttribute('src'); cur.imageId = -1;
    note.textContent = 'No image: ' + e.message;
    panel.setAttribute('data-image-id', -1);
  }
  drawKeypoints();
  markDrawn();
}

// Keypoints over the picture (object-fit: contain), coloured by state. The
// drawn counts go to data attributes for the tests.
function drawKeypoints() {
  const img = $('cam-img'), cv = $('cam-kp'), panel = $('cam-panel'), d = cur.detail;
  const bw = img.clientWidth, bh = img.clientHeight;
  const nw = (d && d.width) || img.naturalWidth || 1, nh = (d && d.height) || img.naturalHeight || 1;
  const k = Math.min(bw / nw, bh / nh);
  const w = Math.max(0, Math.round(nw * k)), h = Math.max(0, Math.round(nh * k));
  cv.width = w; cv.height = h;
  cv.style.left = (img.offsetLeft + (bw - w) / 2) + 'px'; cv.style.top = (img.offsetTop + (bh - h) / 2) + 'px';
  const counts = [0, 0, 0];
  if (d && d.id === cur.id && w > 0) {
    const ctx = cv.getContext('2d');
    const xy = d.keypoints.xy, st = d.keypoints.state, sx = w / d.width, sy = h / d.height;
    const r = Math.max(1.5, Math.min(3, w / 300));
    // One path per state: unmatched first, so the others stay on top.
    for (const state of [0, 2, 1]) {
      ctx.fillStyle = KP_COLORS[state];
      ctx.beginPath();
      for (let i = 0; i < st.length; i++) {
        if (st[i] !== state) continue;
        const x = xy[2 * i] * sx, y = xy[2 * i + 1] * sy;
        ctx.moveTo(x + r, y); ctx.arc(x, y, r, 0, 2 * Math.PI);
        counts[state]++;
      }
      ctx.fill();
    }
  }
  const show = d && d.id === cur.id;
  $('kp-tri').textContent = show ? counts[1] : '–';
  $('kp-out').textContent = show ? counts[2] : '–';
  $('kp-un').textContent = show ? counts[0] : '–';
  panel.setAttribute('data-camera-id', show ? d.id : -1);
  panel.setAttribute('data-kp-triangulated', counts[1]);
  panel.setAttribute('data-kp-outlier', counts[2]);
  panel.setAttribute('data-kp-unmatched', counts[0]);
}

// Click picking of cameras: the frustum's axis (centre to image centre)
// nearest to the click in screen space, over the clipped cameras only.
function pickCamera(e) {
  if (!view.showCams) return false;
  const cv = $('gl'), r = cv.getBoundingClientRect();
  const m = viewProj(r.width / r.height);
  const mx = e.clientX - r.left, my = e.clientY - r.top;
  const toScreen = (x, y, z) => {
    const w = m[3] * x + m[7] * y + m[11] * z + m[15];
    if (w <= 0) return null;
    return [((m[0] * x + m[4] * y + m[8] * z + m[12]) / w * 0.5 + 0.5) * r.width, (0.5 - (m[1] * x + m[5] * y + m[9] * z + m[13]) / w * 0.5) * r.height];
  };
  const s = view.frustumScale * view.frustumBase;
  let best = -1, bestD = PICK_RADIUS_PX * PICK_RADIUS_PX;
  for (const [c] of drawn.clipped) {
    const a = toScreen(c.c[0], c.c[1], c.c[2]);
    const b = toScreen(c.c[0] + c.r[2] * s, c.c[1] + c.r[5] * s, c.c[2] + c.r[8] * s);
    if (!a || !b) continue;
    const dx = b[0] - a[0], dy = b[1] - a[1], len2 = dx * dx + dy * dy;
    const t = len2 > 0 ? Math.max(0, Math.min(1, ((mx - a[0]) * dx + (my - a[1]) * dy) / len2)) : 0;
    const d = (a[0] + t * dx - mx) ** 2 + (a[1] + t * dy - my) ** 2;
    if (d < bestD) { bestD = d; best = c.id; }
  }
  if (best < 0) return false;
  stopPlay();
  setCurrent(best, true);
  return true;
}

// ---------------------------------------------------------------- timeline
function stopPlay() {
  if (cur.playing) clearInterval(cur.playing);
  cur.playing = null;
  $('play-btn').textContent = '▶';
}
$('timeline').addEventListener('input', (e) => {
  const c = drawn.camsSorted[parseInt(e.target.value, 10)];
  if (c) setCurrent(c.id, true);
});
$('play-btn').addEventListener('click', () => {
  if (cur.playing) return stopPlay();
  const cams = drawn.camsSorted;
  if (!cams.length) return;
  if (rankOf(cur.id) >= cams.length - 1) setCurrent(cams[0].id, true);
  $('play-btn').textContent = '❚❚';
  cur.playing = setInterval(() => {
    const next = rankOf(cur.id) + 1;
    if (next >= drawn.camsSorted.length) return stopPlay();
    setCurrent(drawn.camsSorted[next].id, true);
  }, PLAY_INTERVAL_MS);
});

// ---------------------------------------------------------------- grid and axes
// A grid step of 1, 2 or 5 times a power of ten: about 8 cells across the scene.
function niceStep(x) {
  const p = Math.pow(10, Math.floor(Math.log10(x)));
  const f = x / p;
  return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * p;
}
// Ground grid perpendicular to the view's up direction, at the height of
// the lowest 5 % of the scene, and the world axes (x red, y green, z blue).
function buildGrid() {
  const up = view.up, fwd = view.fwd, right = normalize(cross(fwd, up));
  const hs = [];
  const step0 = Math.max(1, Math.floor(model.points.size / 20000));
  let i = 0;
  for (const p of model.points.values()) if (i++ % step0 === 0) hs.push(dot([p.x, p.y, p.z], up));
  for (const c of model.cameras.values()) hs.push(dot(c.c, up));
  if (!hs.length) { gpu.uploadLayers({ grid: [new Float32Array(0), new Float32Array(0)] }); return; }
  hs.sort((a, b) => a - b);
  const level = hs[Math.floor(0.05 * (hs.length - 1))];
  const step = niceStep(view.radius / 4);
  const n = Math.max(2, Math.ceil(1.5 * view.radius / step));
  const t = view.target;
  // The grid centre: the view target dropped to the ground, snapped to the grid.
  const cr = Math.round(dot(t, right) / step) * step, cf = Math.round(dot(t, fwd) / step) * step;
  const at = (a, b) => add(add(scale(right, a), scale(fwd, b)), scale(up, level));
  const gp = [], gc = [];
  const line = (p, q, col) => { gp.push(...p, ...q); gc.push(...col, ...col); };
  for (let k = -n; k <= n; k++) {
    const col = k === 0 ? [0.42, 0.44, 0.5] : [0.26, 0.27, 0.31];
    line(at(cr + k * step, cf - n * step), at(cr + k * step, cf + n * step), col);
    line(at(cr - n * step, cf + k * step), at(cr + n * step, cf + k * step), col);
  }
  const L = step;
  line([0, 0, 0], [L, 0, 0], [1, 0.2, 0.2]); line([0, 0, 0], [0, L, 0], [0.2, 1, 0.2]); line([0, 0, 0], [0, 0, L], [0.3, 0.5, 1]);
  gpu.uploadLayers({ grid: [new Float32Array(gp), new Float32Array(gc)] });
  view.gridStep = step; view.gridLines = gp.length / 6;
  setStat('grid-step', step);
  setStat('drawn-grid-lines', view.showGrid ? view.gridLines : 0);
  showGridLabel();
}
function showGridLabel() {
  const step = view.gridStep;
  if (!step || !view.showGrid) { $('grid-label').textContent = ''; return; }
  const metric = model.gt && model.gt.scale > 0 ? ' ≈ ' + fmtLength(step * model.gt.scale) : '';
  $('grid-label').textContent = ` · grid ${+step.toPrecision(3)} model units${metric} · axes x y z`;
}
function fmtLength(m) { return m >= 1 ? m.toPrecision(3) + ' m' : m >= 0.01 ? (100 * m).toPrecision(3) + ' cm' : (1000 * m).toPrecision(3) + ' mm'; }
$('show-grid').addEventListener('change', (e) => {
  view.showGrid = e.target.checked;
  setStat('drawn-grid-lines', view.showGrid ? (view.gridLines || 0) : 0);
  showGridLabel(); requestDraw();
});

// ---------------------------------------------------------------- ground truth
const ERR_LO = [0.16, 0.43, 0.94], ERR_HI = [0.94, 0.23, 0.16], NO_ERR = [0.5, 0.5, 0.5];
let gtErrors = new Map(), gtMax = 0;
function showGroundTruth(gt) {
  model.gt = gt || null;
  gtErrors = new Map();
  gtMax = 0;
  if (gt) gt.ids.forEach((id, i) => { gtErrors.set(id, gt.errors[i]); gtMax = Math.max(gtMax, gt.errors[i]); });
  $('ate-row').hidden = !gt;
  $('gt-legend').hidden = !gt;
  const ate = $('sum-ate');
  ate.textContent = gt ? fmtLength(gt.ate_rmse) + ' (' + gt.matched + ' poses)' : '–';
  ate.setAttribute('data-ate', gt ? gt.ate_rmse : '');
  $('gt-max').textContent = gt ? fmtLength(gtMax) : '–';
  const gp = [], gc = [];
  if (gt) for (let i = 0; i + 5 < gt.path.length; i += 3) { gp.push(...gt.path.slice(i, i + 6)); gc.push(0.85, 0.85, 0.85, 0.85, 0.85, 0.85); }
  gpu.uploadLayers({ gt: [new Float32Array(gp), new Float32Array(gc)] });
  setStat('gt-segments', gp.length / 6);
  showGridLabel();
}
// Path colour: the error against the ground truth when there is one, else recency.
function pathColor(c, rank, n) {
  if (!model.gt || !view.showGt) return recency(rank, n);
  const e = gtErrors.get(c.id);
  if (e == null) return NO_ERR;
  const t = gtMax > 0 ? e / gtMax : 0;
  return [ERR_LO[0] + t * (ERR_HI[0] - ERR_LO[0]), ERR_LO[1] + t * (ERR_HI[1] - ERR_LO[1]), ERR_LO[2] + t * (ERR_HI[2] - ERR_LO[2])];
}
$('show-gt').addEventListener('change', (e) => { view.showGt = e.target.checked; rebuild(false); });

// ---------------------------------------------------------------- screenshot mode
// `?screenshot=1`: one state from /api/state, no event stream (it would keep
// headless Chromium's virtual time from settling), everything drawn once,
// then <body data-screenshot="drawn"> for the screenshot to wait for.
// Chromium takes its picture when its virtual time is spent, so the mark
// only has to be set once everything is drawn; its stage says how far a
// page that never finishes got.
let drawnMarked = false;
function screenshotStage(stage) { if (SCREENSHOT) document.body.setAttribute('data-screenshot-stage', stage); }
function markDrawn() {
  if (!SCREENSHOT || drawnMarked) return;
  drawnMarked = true;
  gpu.draw();
  screenshotStage('drawn');
  document.body.setAttribute('data-screenshot', 'drawn');
}
async function screenshotMode() {
  document.body.classList.add('screenshot');
  screenshotStage('state');
  try {
    const r = await fetch('/api/state');
    applyUpdate(await r.json());
  } catch (e) { console.error('state', e); }
  screenshotStage('scene');
  rebuild();
  // A loaded model: wait for the camera panel; otherwise the scene is all.
  if (cur.id < 0 || model.images == null) markDrawn();
}

// Opened with the access token (a viewer bound off loopback): the server
// has set it as a cookie, so the URL shown need not keep it.
if (new URLSearchParams(location.search).has('token')) history.replaceState(null, '', location.pathname + (SCREENSHOT ? '?screenshot=1' : ''));

updateRunButtons();
rebuild();
if (SCREENSHOT) screenshotMode(); else connect();
