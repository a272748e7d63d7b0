// Browser tests of the colslam viewer page, driven through headless Chromium
// by playwright-core. Started by crates/viewer/tests/browser.rs:
//   node e2e/test.mjs <config.json>
// The config names the page URL, the screenshot folder, the model folder the
// Rust test wrote, a scratch folder and the counts the page must show. Steps
// that need the server to do something (feed a simulated live run) are asked
// for on stdout ("STEP <name>") and acknowledged on stdin ("DONE <name>").
import { chromium } from 'playwright-core';
import { readFileSync } from 'node:fs';
import { createInterface } from 'node:readline';
import path from 'node:path';

const cfg = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const TIMEOUT_MS = 20000;

const acks = [];
const waiters = [];
createInterface({ input: process.stdin }).on('line', (line) => {
  const w = waiters.shift();
  if (w) w(line.trim()); else acks.push(line.trim());
});
function rust(step) {
  process.stdout.write(`STEP ${step}\n`);
  return new Promise((resolve, reject) => {
    const check = (line) => (line === `DONE ${step}` ? resolve() : reject(new Error(`expected DONE ${step}, got ${line}`)));
    if (acks.length) check(acks.shift()); else waiters.push(check);
  });
}

let failures = 0;
function log(...a) { process.stderr.write(a.join(' ') + '\n'); }
async function scenario(name, fn) {
  try { await fn(); log(`ok   ${name}`); } catch (e) { failures++; log(`FAIL ${name}: ${e.stack || e}`); }
}

const browser = await chromium.launch({
  executablePath: cfg.chromium,
  headless: true,
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-component-update',
    '--disable-sync', '--no-first-run', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
});
const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
const pageErrors = [];
page.on('pageerror', (e) => pageErrors.push(String(e)));
// Refused requests (the bad-model and bad-settings scenarios) log 4xx
// resource errors by design; anything else logged as an error fails.
page.on('console', (m) => {
  if (m.type() === 'error' && !/Failed to load resource: the server responded with a status of 4\d\d/.test(m.text())) pageErrors.push(m.text());
});

const stat = (key) => page.getAttribute('#stats', 'data-' + key);
async function stats() {
  return page.evaluate(() => Object.fromEntries(Object.entries(document.getElementById('stats').dataset)));
}
// Waits until #stats shows all the given values (keys in dataset camelCase).
async function waitStats(expect, what) {
  try {
    await page.waitForFunction((exp) => {
      const d = document.getElementById('stats').dataset;
      return Object.entries(exp).every(([k, v]) => d[k] === String(v));
    }, expect, { timeout: TIMEOUT_MS });
  } catch (e) {
    throw new Error(`${what}: wanted ${JSON.stringify(expect)}, page shows ${JSON.stringify(await stats())}`);
  }
}
async function waitText(sel, re, what) {
  try {
    await page.waitForFunction(([s, src]) => new RegExp(src).test(document.querySelector(s)?.textContent || ''), [sel, re.source], { timeout: TIMEOUT_MS });
  } catch (e) {
    throw new Error(`${what}: ${sel} should match ${re}, shows ${JSON.stringify(await page.textContent(sel))}`);
  }
}
// Sets a range input and fires its input event (fill() does not do ranges).
async function setRange(sel, value) {
  await page.evaluate(([s, v]) => { const e = document.querySelector(s); e.value = String(v); e.dispatchEvent(new Event('input')); }, [sel, value]);
}
async function setTrack(id) { await page.fill('#track', String(id)); }
const shot = (name) => path.join(cfg.shots, name);

await page.goto(cfg.url);
await scenario('page connects and WebGL runs', async () => {
  await waitStats({ connected: 1 }, 'connected');
  if ((await stat('webgl')) !== '1') throw new Error('WebGL context not available');
});

await scenario('bad model folder shows an error', async () => {
  await page.fill('#load-path', cfg.bad_model_dir);
  await page.click('#load-btn');
  await waitText('#model-msg', /no COLMAP model found/, 'error message');
  const cls = await page.getAttribute('#model-msg', 'class');
  if (!cls.includes('error')) throw new Error('message not marked as error: ' + cls);
  await page.fill('#load-path', '');
  await page.click('#load-btn');
  await waitText('#model-msg', /Enter the folder/, 'empty path refused');
});

const m = cfg.model;
await scenario('load a saved model: counts', async () => {
  await page.fill('#load-path', cfg.model_dir);
  await page.click('#load-btn');
  await waitText('#model-msg', new RegExp(`Loaded ${m.points} points, ${m.cameras} cameras`), 'load message');
  await waitStats({ points: m.points, cameras: m.cameras, drawnPoints: m.points, drawnCameras: m.cameras, drawnPath: m.cameras - 1 }, 'loaded model');
  await waitText('#sum-points', new RegExp(`^${m.points}$`), 'summary points');
  await page.waitForTimeout(300);
  await page.locator('#recon-view').screenshot({ path: shot('viewer-reconstruction.png') });
  // A reloaded page (a new connection) gets the whole state again.
  await page.reload();
  await waitStats({ connected: 1, points: m.points, cameras: m.cameras, drawnPoints: m.points }, 'after reload');
});

// ---------------------------------------------------------------- cameras (frame panel, selection, timeline, grid, ground truth)
const fm = cfg.frames;
// Waits until the camera panel shows camera `id` with its picture and the
// keypoints drawn by state.
async function waitCameraPanel(id, what) {
  try {
    await page.waitForFunction((want) => {
      const p = document.getElementById('cam-panel');
      return !p.hidden && p.dataset.cameraId === String(want) && p.dataset.imageId === String(want)
        && document.getElementById('cam-img').naturalWidth > 0;
    }, id, { timeout: TIMEOUT_MS });
  } catch (e) {
    const d = await page.evaluate(() => ({ ...document.getElementById('cam-panel').dataset, note: document.getElementById('cam-note').textContent }));
    throw new Error(`${what}: camera panel should show camera ${id}, shows ${JSON.stringify(d)}`);
  }
}
const panelCounts = () => page.evaluate(() => {
  const d = document.getElementById('cam-panel').dataset;
  return { triangulated: Number(d.kpTriangulated), outlier: Number(d.kpOutlier), unmatched: Number(d.kpUnmatched) };
});
// Screen position of camera `id`'s centre, from the page's own projection.
const cameraOnScreen = (id) => page.evaluate((cid) => {
  const r = document.getElementById('gl').getBoundingClientRect(), mm = viewProj(r.width / r.height), c = model.cameras.get(cid);
  const [x, y, z] = c.c;
  const w = mm[3] * x + mm[7] * y + mm[11] * z + mm[15];
  return { x: r.left + ((mm[0] * x + mm[4] * y + mm[8] * z + mm[12]) / w * 0.5 + 0.5) * r.width,
    y: r.top + (0.5 - (mm[1] * x + mm[5] * y + mm[9] * z + mm[13]) / w * 0.5) * r.height };
}, id);

await scenario('a loaded model shows the latest camera: its image and keypoints by state', async () => {
  await waitCameraPanel(fm.latest.id, 'latest camera');
  const counts = await panelCounts();
  const want = fm.latest.counts;
  if (['triangulated', 'outlier', 'unmatched'].some((k) => counts[k] !== want[k])) throw new Error(`keypoints drawn ${JSON.stringify(counts)}, model has ${JSON.stringify(want)}`);
  if (!(await page.isHidden('#kf-panel')) || !(await page.isHidden('#cur-panel'))) throw new Error('empty live panels still shown for a loaded model');
  // The picture is the one on disk (its blue channel encodes the camera).
  const blue = await page.evaluate(() => {
    const img = document.getElementById('cam-img'), c = document.createElement('canvas');
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    const g = c.getContext('2d'); g.drawImage(img, 0, 0);
    return g.getImageData(2, 2, 1, 1).data[2];
  });
  if (blue !== fm.latest.blue) throw new Error(`picture pixel blue ${blue}, file has ${fm.latest.blue}`);
  await waitText('#hint', /drag: rotate/, 'mouse hint');
  await page.locator('#frame-view').screenshot({ path: shot('viewer-camera-panel.png') });
});

await scenario('clicking a camera selects it: image, info box, highlighted points', async () => {
  const pos = await cameraOnScreen(fm.click.id);
  await page.mouse.click(pos.x, pos.y);
  await waitCameraPanel(fm.click.id, 'clicked camera');
  await page.waitForFunction((id) => document.getElementById('cam-info').dataset.cameraId === String(id), fm.click.id, { timeout: TIMEOUT_MS });
  await waitText('#info-id', new RegExp(`^${fm.click.id}$`), 'info box id');
  await waitText('#info-obs', new RegExp(`^${fm.click.observations}$`), 'info box observations');
  await waitText('#info-err', /px$/, 'info box error');
  await waitStats({ currentCamera: fm.click.id, highlightedPoints: fm.click.observations }, 'observed points highlighted');
  const counts = await panelCounts();
  if (counts.triangulated + counts.outlier !== fm.click.observations) throw new Error(`keypoints with 3D points ${JSON.stringify(counts)}`);
});

await scenario('the timeline moves the current camera', async () => {
  await setRange('#timeline', fm.timeline.rank);
  await waitStats({ currentCamera: fm.timeline.id, timeline: fm.timeline.rank }, 'timeline');
  await waitCameraPanel(fm.timeline.id, 'timeline camera');
  // Play advances through registration order.
  await page.click('#play-btn');
  await page.waitForFunction((id) => Number(document.getElementById('stats').dataset.currentCamera) > id, fm.timeline.id, { timeout: TIMEOUT_MS });
  await page.click('#play-btn');
  const after = Number(await stat('current-camera'));
  await page.waitForTimeout(600);
  if (Number(await stat('current-camera')) !== after) throw new Error('pause did not stop the timeline');
});

await scenario('ground grid and axes with a scale, toggleable', async () => {
  const step = Number(await stat('grid-step'));
  const digits = step / Math.pow(10, Math.floor(Math.log10(step)));
  if (!(step > 0) || ![1, 2, 5].some((d) => Math.abs(digits - d) < 1e-6)) throw new Error(`grid step ${step} is not 1-2-5`);
  if (!(Number(await stat('drawn-grid-lines')) > 4)) throw new Error('no grid lines');
  await waitText('#grid-label', /grid .* model units/, 'scale label');
  await page.uncheck('#show-grid');
  await waitStats({ drawnGridLines: 0 }, 'grid hidden');
  await page.check('#show-grid');
});

await scenario('ground truth: aligned path, error colours and the ATE of colslam eval', async () => {
  await rust('gt');
  await page.waitForFunction(() => !document.getElementById('ate-row').hidden, null, { timeout: TIMEOUT_MS });
  const ate = Number(await page.getAttribute('#sum-ate', 'data-ate'));
  if (!(Math.abs(ate - fm.gt.ate) <= 1e-9 * Math.max(1, fm.gt.ate))) throw new Error(`page ATE ${ate}, colslam eval ${fm.gt.ate}`);
  await waitStats({ gtSegments: fm.gt.segments }, 'ground-truth path');
  await page.locator('#recon-view').screenshot({ path: shot('viewer-ground-truth.png') });
});

await scenario('track selector draws lines to observing cameras', async () => {
  await setTrack(m.track.id);
  await waitStats({ selectedPoint: m.track.id, drawnTrackLines: m.track.lines }, 'track selected');
  await setTrack(-1);
  await waitStats({ selectedPoint: -1, drawnTrackLines: 0 }, 'track cleared');
  await page.fill('#track', '999999');
  await waitStats({ selectedPoint: 999999, drawnTrackLines: 0 }, 'unknown point id draws nothing');
});

await scenario('clicking a point selects its track', async () => {
  await setTrack(-1);
  // Cameras hidden: a click then picks points only.
  await page.uncheck('#show-cams');
  // Screen position of the first drawn point, from the page's own projection.
  const pos = await page.evaluate(() => {
    const r = document.getElementById('gl').getBoundingClientRect(), mm = viewProj(r.width / r.height), P = drawn.pts;
    for (let i = 0; i < drawn.nPts; i++) {
      const [x, y, z] = [P[3 * i], P[3 * i + 1], P[3 * i + 2]];
      const w = mm[3] * x + mm[7] * y + mm[11] * z + mm[15];
      const sx = ((mm[0] * x + mm[4] * y + mm[8] * z + mm[12]) / w * 0.5 + 0.5) * r.width;
      const sy = (0.5 - (mm[1] * x + mm[5] * y + mm[9] * z + mm[13]) / w * 0.5) * r.height;
      if (w > 0 && sx > 5 && sy > 5 && sx < r.width - 5 && sy < r.height - 5) return { x: r.left + sx, y: r.top + sy };
    }
    return null;
  });
  if (!pos) throw new Error('no point on screen');
  await page.mouse.click(pos.x, pos.y);
  await page.waitForFunction(() => document.getElementById('stats').dataset.selectedPoint !== '-1', null, { timeout: TIMEOUT_MS });
  await page.check('#show-cams');
  const lines = Number(await stat('drawn-track-lines'));
  if (!(lines >= 1)) throw new Error('picked point draws no track lines');
  await page.locator('#recon-view').screenshot({ path: shot('viewer-track.png') });
});

await scenario('orbit, zoom, reset camera and background colour', async () => {
  const eye = () => page.evaluate(() => eyeBasis().eye);
  const e0 = await eye();
  const box = await page.locator('#gl').boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  await page.mouse.move(cx + 120, cy + 40, { steps: 5 });
  await page.mouse.up();
  await page.mouse.wheel(0, 300);
  const e1 = await eye();
  if (Math.hypot(e1[0] - e0[0], e1[1] - e0[1], e1[2] - e0[2]) < 1e-6) throw new Error('drag/zoom did not move the view');
  await page.click('#reset-cam');
  const e2 = await eye();
  if (Math.hypot(e2[0] - e0[0], e2[1] - e0[1], e2[2] - e0[2]) > 1e-6) throw new Error(`reset camera: ${e2} vs ${e0}`);
  // Background colour reaches the canvas (a corner pixel, no data there).
  const corner = async () => page.evaluate(() => new Promise((res) => requestAnimationFrame(() => requestAnimationFrame(() => {
    const gl = gpu.gl, px = new Uint8Array(4); gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px); res([...px]);
  }))));
  await page.evaluate(() => { const e = document.getElementById('bg-color'); e.value = '#ffffff'; e.dispatchEvent(new Event('input')); });
  const white = await corner();
  if (white.slice(0, 3).some((c) => c < 250)) throw new Error('background not white: ' + white);
  await page.evaluate(() => { const e = document.getElementById('bg-color'); e.value = '#15171c'; e.dispatchEvent(new Event('input')); });
  const dark = await corner();
  if (dark.slice(0, 3).some((c) => c > 40)) throw new Error('background not dark: ' + dark);
});

await scenario('clip range limits points, cameras and tracks', async () => {
  await setTrack(m.track.id);
  await setRange('#clip-start', m.clip.start);
  await setRange('#clip-end', m.clip.end);
  await waitStats({ drawnPoints: m.clip.points, drawnCameras: m.clip.cameras, drawnPath: m.clip.cameras - 1, drawnTrackLines: m.clip.track_lines }, 'clipped');
  await setRange('#clip-start', 0);
  await setRange('#clip-end', m.cameras - 1);
  await waitStats({ drawnPoints: m.points, drawnCameras: m.cameras, drawnTrackLines: m.track.lines }, 'clip reset');
  // Hiding cameras and the path.
  await page.uncheck('#show-cams');
  await page.uncheck('#show-path');
  await waitStats({ drawnCameras: 0, drawnPath: 0 }, 'hidden');
  await page.check('#show-cams');
  await page.check('#show-path');
  await waitStats({ drawnCameras: m.cameras, drawnPath: m.cameras - 1 }, 'shown again');
  await setTrack(-1);
});

await scenario('export and reload', async () => {
  const out = path.join(cfg.work_dir, 'exported');
  await page.fill('#export-path', out);
  await page.selectOption('#export-format', 'colmap-txt');
  await page.click('#export-btn');
  await waitText('#model-msg', /Exported to/, 'export message');
  await page.fill('#export-path', path.join(cfg.work_dir, 'cloud.ply'));
  await page.selectOption('#export-format', 'ply');
  await page.click('#export-btn');
  await waitText('#model-msg', /cloud\.ply/, 'ply export');
  await page.fill('#load-path', out);
  await page.click('#load-btn');
  await waitText('#model-msg', new RegExp(`Loaded ${m.points} points, ${m.cameras} cameras`), 'reload message');
  await waitStats({ points: m.points, cameras: m.cameras }, 'reloaded');
});

await scenario('invalid settings are refused in the page', async () => {
  const run = async () => { await page.click('#run-btn'); };
  await page.fill('#input-path', '');
  await page.fill('#output-path', path.join(cfg.work_dir, 'run-out'));
  await run();
  await waitText('#run-msg', /Input path is missing/, 'missing input');
  await page.fill('#input-path', cfg.run_input);
  await page.fill('#skip', '-2');
  await run();
  await waitText('#run-msg', /Frame skip must be/, 'negative skip');
  await page.fill('#skip', '2');
  await page.fill('#flow-thr', '1.5');
  await run();
  await waitText('#run-msg', /Flow threshold must be/, 'threshold out of range');
  await page.fill('#flow-thr', '0.05');
  // The max-frames bound follows input and skip (asked from the server).
  await page.waitForFunction((b) => document.getElementById('max-bound').dataset.bound === String(b), cfg.run_bound_skip2, { timeout: TIMEOUT_MS });
  await page.fill('#init-frames', '1');
  await run();
  await waitText('#run-msg', /Initialisation frames must be/, 'init frames');
  await page.fill('#init-frames', '20');
  await page.selectOption('#extractor', 'xfeat');
  await page.selectOption('#matcher', 'lighterglue');
});

await scenario('a simulated live run: frames and keyframes arrive', async () => {
  await page.click('#run-btn');
  await waitStats({ runState: 'running' }, 'run started');
  await rust('run-started');
  const seen = new Set();
  const live = cfg.live;
  const deadline = Date.now() + TIMEOUT_MS;
  const done = rust('live');
  let finished = false;
  done.then(() => { finished = true; });
  // Poll while the server feeds frames: keyframe ids must change over time.
  while (Date.now() < deadline) {
    const id = await page.getAttribute('#frame-view', 'data-keyframe-id');
    if (id) seen.add(id);
    if (finished && id === String(live.last_keyframe_id)) break;
    await page.waitForTimeout(40);
  }
  await done;
  if (seen.size < 2) throw new Error(`keyframes seen live: ${[...seen]}`);
  await waitStats({ cameras: live.cameras, points: live.points, drawnCameras: live.cameras }, 'live map');
  await waitText('#frame-index', new RegExp(`^${live.last_frame}$`), 'last frame');
  await waitText('#sum-keyframes', new RegExp(`^${live.cameras}$`), 'summary keyframes');
  await waitText('#run-note', /finished/, 'run finished');
  const lines = await page.getAttribute('#frame-view', 'data-flow-lines');
  if (lines !== String(live.flow_lines)) throw new Error(`flow lines ${lines}`);
  // One line drawn per verified match; the rejected ones only on request.
  await waitStats({ flowFrame: live.last_frame, flowLines: live.flow_lines, frameInliers: live.flow_lines, outlierLines: 0 }, 'verified flow lines');
  await page.check('#show-outliers');
  await waitStats({ flowLines: live.flow_lines, outlierLines: live.outlier_lines }, 'rejected matches shown');
  await page.uncheck('#show-outliers');
  await waitStats({ outlierLines: 0 }, 'rejected matches hidden');
  // The status follows the run: finished with its line, no "Started." left.
  await waitText('#status-line', new RegExp('^finished: ' + live.finished.replace(/[.*+?^${}()|[\]\\]/g, '\\$&') + '$'), 'finished status');
  if ((await page.textContent('#run-msg')).trim()) throw new Error('run message left: ' + await page.textContent('#run-msg'));
  await page.waitForFunction(() => document.getElementById('frame-img').complete && document.getElementById('kf-img').complete);
  await page.waitForTimeout(300);
  await page.locator('#frame-view').screenshot({ path: shot('viewer-frame-view.png') });
  // Stable paths in the sidebar so the picture does not change between runs.
  await page.fill('#load-path', 'sparse/0');
  await page.fill('#export-path', 'out/model');
  await page.fill('#output-path', 'out/run');
  await page.evaluate(() => { document.getElementById('model-msg').textContent = ''; document.activeElement?.blur(); });
  await page.mouse.move(1, 1);
  await page.screenshot({ path: shot('viewer-overview.png') });
});

await scenario('a failed run shows its message', async () => {
  await rust('live-failed');
  await waitStats({ runState: 'failed' }, 'failed state');
  await waitText('#status-line', new RegExp('^failed: ' + cfg.live.failed + '$'), 'failed status');
  await waitText('#run-note', /^failed: /, 'failed run note');
  if (!(await page.getAttribute('#status-line', 'class')).includes('bad')) throw new Error('failure not marked');
});

await scenario('large map: 100,000 points and 2,000 cameras', async () => {
  const big = cfg.large;
  const t0 = Date.now();
  await rust('large');
  await waitStats({ points: big.points, cameras: big.cameras, drawnPoints: big.points, drawnCameras: big.cameras }, 'large map');
  const arrive = Date.now() - t0;
  const t = await page.evaluate(() => {
    const r0 = performance.now(); rebuild(); const r1 = performance.now(); rebuild(false); const r2 = performance.now();
    const frames = [], px = new Uint8Array(4);
    for (let i = 0; i < 10; i++) { view.yaw += 0.05; const a = performance.now(); gpu.draw(); gpu.gl.readPixels(0, 0, 1, 1, gpu.gl.RGBA, gpu.gl.UNSIGNED_BYTE, px); frames.push(performance.now() - a); }
    frames.sort((x, y) => x - y);
    return { rebuild: r1 - r0, camerasOnly: r2 - r1, drawMedian: frames[5] };
  });
  log(`PERF large map: fed + delivered + rebuilt in ${arrive} ms; rebuild ${t.rebuild.toFixed(1)} ms (cameras and tracks only: ${t.camerasOnly.toFixed(1)} ms); draw (software GL) ${t.drawMedian.toFixed(1)} ms`);
  if (t.rebuild > big.max_rebuild_ms) throw new Error(`rebuild took ${t.rebuild} ms`);
  // Selecting a camera (highlight of its points) and picking by click stay
  // cheap on the large map: neither walks the points per mouse move.
  const sel = await page.evaluate(() => {
    const c = drawn.camsSorted[drawn.camsSorted.length >> 1];
    const a = performance.now(); setCurrent(c.id, true); const b = performance.now();
    const r = document.getElementById('gl').getBoundingClientRect();
    const p0 = performance.now(); pickCamera({ clientX: r.left + r.width / 2, clientY: r.top + r.height / 2 }); const p1 = performance.now();
    return { select: b - a, pick: p1 - p0, highlighted: Number(document.getElementById('stats').dataset.highlightedPoints) };
  });
  log(`PERF large map: select a camera ${sel.select.toFixed(1)} ms (${sel.highlighted} points highlighted), pick ${sel.pick.toFixed(2)} ms`);
  if (!(sel.highlighted > 0)) throw new Error('the selected camera highlights no points');
  if (sel.select > big.max_rebuild_ms || sel.pick > big.max_pick_ms) throw new Error(`selection ${sel.select} ms, pick ${sel.pick} ms`);
  await page.locator('#recon-view').screenshot({ path: shot('viewer-large-map.png') });
  // An increment on top of the large map: one new point.
  await rust('large-delta');
  await waitStats({ points: big.points + 1 }, 'increment on the large map');
});

await scenario('the page reconnects to a restarted server and gets its whole state', async () => {
  await rust('restart');
  await waitStats({ connected: 1, points: cfg.restart.points, cameras: cfg.restart.cameras, drawnPoints: cfg.restart.points }, 'after restart');
  await waitText('#frame-index', /^–$/, 'frame view cleared');
});

await scenario('no page errors', async () => {
  if (pageErrors.length) throw new Error(pageErrors.join('\n'));
});

await browser.close();
process.stdout.write(failures ? `FAILED ${failures}\n` : 'ALL OK\n');
process.exit(failures ? 1 : 0);
