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
  await page.waitForFunction(() => /running|finished/.test(document.getElementById('stats').dataset.runState), null, { timeout: TIMEOUT_MS });
  const seen = new Set();
  let frames = new Set();
  const deadline = Date.now() + TIMEOUT_MS;
  let state = '';
  // What the frame panel drew, sampled while the run goes on: one flow line
  // per verified match of the frame drawn.
  const drawn = new Map();
  const running = new Set();
  while (Date.now() < deadline) {
    const id = await page.getAttribute('#frame-view', 'data-keyframe-id');
    const fi = await page.getAttribute('#frame-view', 'data-frame-index');
    const d = await page.evaluate(() => ({ ...document.getElementById('stats').dataset }));
    state = await page.textContent('#run-note');
    if (/^running/.test(state)) running.add(await page.textContent('#status-line'));
    if (/finished|failed/.test(state)) break;
    if (id) seen.add(id);
    if (fi) frames.add(fi);
    if (d.flowFrame && d.flowFrame !== '-1') drawn.set(d.flowFrame, d);
    await page.waitForTimeout(30);
  }
  log(`keyframes seen while running: ${[...seen].join(',')}; frames seen: ${frames.size}; frames drawn: ${drawn.size}; ${state}`);
  if (!/finished/.test(state)) throw new Error(`run did not finish: ${state}`);
  if (seen.size < 2) throw new Error(`fewer than 2 keyframes seen live: ${[...seen]}`);
  if (frames.size < 2) throw new Error(`fewer than 2 frames seen live`);
  if (drawn.size < 2) throw new Error(`fewer than 2 frames drawn with flow`);
  for (const [f, d] of drawn) {
    if (d.flowLines !== d.frameInliers) throw new Error(`frame ${f}: ${d.flowLines} lines drawn for ${d.frameInliers} verified matches`);
    if (Number(d.outlierLines) !== 0) throw new Error(`frame ${f}: rejected matches drawn without asking`);
  }
  const withOutliers = [...drawn.values()].filter((d) => Number(d.frameInliers) < Number(d.frameMatches));
  if (!withOutliers.length) throw new Error('no frame had rejected matches: the test shows nothing');
  log(`verified / matches of the frames drawn: ${[...drawn.values()].map((d) => d.frameInliers + '/' + d.frameMatches).join(' ')}`);
  // The status followed the run: "running: frame i/N" while it went on.
  if (![...running].some((t) => new RegExp(`^running: frame \\d+/${cfg.frames}`).test(t))) throw new Error(`running status: ${[...running]}`);
  // The rejected matches on request, in another colour.
  await page.check('#show-outliers');
  const out = await page.evaluate(() => ({ ...document.getElementById('stats').dataset }));
  if (!(Number(out.outlierLines) > 0) && Number(out.frameInliers) < Number(out.frameMatches)) throw new Error(`rejected matches not drawn: ${JSON.stringify(out)}`);
  await page.uncheck('#show-outliers');
  // Finished: its line names the localised frames and the output folder;
  // nothing says "Started." any more.
  const status = await page.textContent('#status-line');
  const report = JSON.parse(readFileSync(cfg.output + '/report.json', 'utf8'));
  const want = `finished: ${report.localized} of ${cfg.frames} frames localised, ${report.keyframes} keyframes`;
  if (!status.startsWith(want) || !status.endsWith(`outputs in ${cfg.output}`)) throw new Error(`status ${JSON.stringify(status)}, wanted ${want} ... outputs in ${cfg.output}`);
  if (/Started/.test(await page.textContent('#sidebar'))) throw new Error('"Started." left after the run');
  const kf = parseInt(await page.textContent('#sum-keyframes'), 10);
  const cams = await page.getAttribute('#stats', 'data-cameras');
  const pts = parseInt(await page.getAttribute('#stats', 'data-points'), 10);
  if (!(kf >= 2) || String(kf) !== cams || !(pts > 0)) throw new Error(`final map: ${kf} keyframes, ${cams} cameras, ${pts} points`);
  if (cfg.shot) await page.screenshot({ path: cfg.shot });
  // A run that fails (frames that cannot be decoded pass the start checks):
  // the status says failed, with the pipeline's message.
  await page.fill('#input-path', cfg.broken_input);
  await page.fill('#output-path', cfg.broken_output);
  await page.click('#run-btn');
  await page.waitForFunction(() => document.getElementById('stats').dataset.runState === 'failed', null, { timeout: TIMEOUT_MS });
  const failed = await page.textContent('#status-line');
  if (!failed.startsWith('failed: ') || !failed.includes('no frame could be read') || !failed.includes('broken')) throw new Error(`failed status: ${JSON.stringify(failed)}`);
  if ((await page.textContent('#run-msg')).trim()) throw new Error('a run message was left: ' + await page.textContent('#run-msg'));
  if (errors.length) throw new Error(errors.join('\n'));
  ok = true;
} catch (e) {
  log(`FAIL ${e.stack || e}`);
}
await browser.close();
process.stdout.write(ok ? 'ALL OK\n' : 'FAILED\n');
process.exit(ok ? 0 : 1);
