// Browser scenario of the colslam viewer with the real pipeline, started by
// crates/cli/tests/view.rs against `colslam view --port 0`:
//   node e2e_run.mjs <config.json>
// Fills the settings panel with the synthetic sequence, presses Run, and
// checks that keyframes arrive live (the keyframe shown changes while the
// run goes on) and that the run ends with its map drawn. Prints "ALL OK" on
// stdout when every check passed. With `shot` in the config, saves a
// screenshot of the finished run there.
import { readFileSync } from 'node:fs';

const cfg = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const { chromium } = await import(cfg.playwright);
const TIMEOUT_MS = 90000;
const log = (...a) => process.stderr.write(a.join(' ') + '\n');

const browser = await chromium.launch({
  executablePath: cfg.chromium,
  headless: true,
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-component-update',
    '--disable-sync', '--no-first-run', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
});
let ok = false;
try {
  const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  await page.goto(cfg.url);
  await page.waitForFunction(() => !document.getElementById('run-btn').disabled, null, { timeout: TIMEOUT_MS });
  await page.fill('#input-path', cfg.input);
  await page.fill('#output-path', cfg.output);
  // The max-frames bound comes from the server's probe of the input.
  await page.waitForFunction((n) => document.getElementById('max-bound').dataset.bound === String(n), cfg.frames, { timeout: TIMEOUT_MS });
  await page.click('#run-btn');
  await page.waitForFunction(() => /Started/.test(document.getElementById('run-msg').textContent), null, { timeout: TIMEOUT_MS });
  const seen = new Set();
  let frames = new Set();
  const deadline = Date.now() + TIMEOUT_MS;
  let state = '';
  while (Date.now() < deadline) {
    const id = await page.getAttribute('#frame-view', 'data-keyframe-id');
    const fi = await page.getAttribute('#frame-view', 'data-frame-index');
    state = await page.textContent('#run-note');
    if (/finished|failed/.test(state)) break;
    if (id) seen.add(id);
    if (fi) frames.add(fi);
    await page.waitForTimeout(30);
  }
  log(`keyframes seen while running: ${[...seen].join(',')}; frames seen: ${frames.size}; ${state}`);
  if (!/finished/.test(state)) throw new Error(`run did not finish: ${state}`);
  if (seen.size < 2) throw new Error(`fewer than 2 keyframes seen live: ${[...seen]}`);
  if (frames.size < 2) throw new Error(`fewer than 2 frames seen live`);
  const kf = parseInt(await page.textContent('#sum-keyframes'), 10);
  const cams = await page.getAttribute('#stats', 'data-cameras');
  const pts = parseInt(await page.getAttribute('#stats', 'data-points'), 10);
  if (!(kf >= 2) || String(kf) !== cams || !(pts > 0)) throw new Error(`final map: ${kf} keyframes, ${cams} cameras, ${pts} points`);
  if (cfg.shot) await page.screenshot({ path: cfg.shot });
  if (errors.length) throw new Error(errors.join('\n'));
  ok = true;
} catch (e) {
  log(`FAIL ${e.stack || e}`);
}
await browser.close();
process.stdout.write(ok ? 'ALL OK\n' : 'FAILED\n');
process.exit(ok ? 0 : 1);
