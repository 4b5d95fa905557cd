// Browser test of the Telextiles map page, driven by daemon/map/tests/browser.rs.
//
// Protocol (one JSON object per line): the Rust test passes the scenario in
// argv[2] as JSON; this script prints {"need": "..."} when it wants the test
// to act (send touch events, restart the server) and waits for one line on
// stdin; it prints {"ok": true, ...} at the end, or exits non-zero with the
// reason on stderr.
//
// Chromium is the system one (/usr/bin/chromium); playwright-core never
// downloads a browser.
import { chromium } from 'playwright-core';
import { createInterface } from 'node:readline';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

const sc = JSON.parse(process.argv[2]);
const STEP_MS = sc.step_ms || 20000;
const lines = createInterface({ input: process.stdin });
const iter = lines[Symbol.asyncIterator]();

function log(...a) { console.error('[map.test]', ...a); }
function need(what, extra = {}) {
  process.stdout.write(JSON.stringify(Object.assign({ need: what }, extra)) + '\n');
}
async function ack() {
  const r = await iter.next();
  if (r.done) throw new Error('the Rust test closed stdin');
  return r.value;
}

const profile = mkdtempSync(join(tmpdir(), 'telextiles-chromium-'));
// A fresh profile directory (--user-data-dir) per run.
const browser = await chromium.launchPersistentContext(profile, {
  executablePath: sc.chromium,
  headless: true,
  viewport: { width: 1280, height: 800 },
  args: [
    '--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
    '--disable-component-update', '--disable-sync', '--no-first-run', '--disable-quic',
    '--disable-dev-shm-usage',
  ],
}).catch((e) => {
  rmSync(profile, { recursive: true, force: true });
  console.error('[map.test] cannot start Chromium:', e.message);
  process.exit(1);
});

let failed = null;
const errors = [];
try {
  const page = await browser.newPage();
  page.setDefaultTimeout(STEP_MS);
  let phase = 'load';
  page.on('pageerror', (e) => errors.push(`${phase}: page error: ${e.message}`));
  page.on('console', (m) => {
    // While the server is down the browser logs refused connections; those
    // are expected. Anything else (CSP violations, script errors) is not.
    if (m.type() === 'error' && phase !== 'restart') errors.push(`${phase}: console: ${m.text()}`);
  });

  // 1. The page loads, connects and draws every textile.
  await page.goto(sc.url);
  await page.waitForSelector('#status.connected');
  await page.waitForFunction((n) => document.getElementById('map').dataset.points === String(n), sc.points);
  const drawn = await page.evaluate(() => {
    const traces = document.querySelectorAll('#map .scatterlayer .trace');
    return [traces[0].querySelectorAll('.point').length, traces[1].querySelectorAll('.point').length,
            traces[2].querySelectorAll('.point').length];
  });
  log('drawn seen/unseen/slots', drawn);
  if (drawn[0] !== sc.seen || drawn[1] !== sc.points - sc.seen || drawn[2] !== sc.slots) {
    throw new Error(`expected ${sc.seen} seen, ${sc.points - sc.seen} unseen, ${sc.slots} slot markers; drew ${drawn}`);
  }
  const status1 = await page.textContent('#status');
  if (!status1.includes(`${sc.points} textiles`)) throw new Error(`status line: ${status1}`);

  // 2. Hovering a point shows its name, attributes and texture image.
  async function hover(id) {
    const p = await page.evaluate((id) => window.telextilesMap.pointPixel(id), id);
    if (!p) throw new Error(`no point for ${id}`);
    await page.mouse.move(p.x - 40, p.y - 40);
    await page.mouse.move(p.x, p.y, { steps: 4 });
    await page.waitForFunction((id) => {
      const tip = document.getElementById('tip');
      return !tip.hidden && tip.dataset.id === id;
    }, id);
  }
  await hover(sc.hover.id);
  const tipText = await page.textContent('#tip-text');
  log('tooltip:', tipText);
  for (const want of [sc.hover.name, sc.hover.id, 'roughness']) {
    if (!tipText.includes(want)) throw new Error(`tooltip lacks ${JSON.stringify(want)}: ${tipText}`);
  }
  await page.waitForFunction(() => {
    const img = document.getElementById('tip-img');
    return img.complete && img.naturalWidth === 240 && img.naturalHeight === 320;
  });

  // 3. Box zoom narrows the x range; Reset view restores it.
  const rangeOf = () => page.evaluate(() => document.getElementById('map')._fullLayout.xaxis.range.slice());
  const before = await rangeOf();
  const box = await page.locator('#map .nsewdrag').first().boundingBox();
  await page.mouse.move(box.x + box.width * 0.3, box.y + box.height * 0.3);
  await page.mouse.down();
  await page.mouse.move(box.x + box.width * 0.6, box.y + box.height * 0.6, { steps: 8 });
  await page.mouse.up();
  await page.waitForFunction((w) => {
    const r = document.getElementById('map')._fullLayout.xaxis.range;
    return r[1] - r[0] < 0.6 * w;
  }, before[1] - before[0]);
  await page.click('#reset');
  await page.waitForFunction((b) => {
    const r = document.getElementById('map')._fullLayout.xaxis.range;
    return Math.abs(r[0] - b[0]) < 1e-6 && Math.abs(r[1] - b[1]) < 1e-6;
  }, before);

  // 4. A simulated press moves the live point, leaves a trail and highlights
  //    its nearest textiles.
  phase = 'touch';
  const liveXY = () => page.evaluate(() => {
    const d = document.getElementById('map').dataset;
    return { n: Number(d.touches || 0), x: d.liveX, y: d.liveY };
  });
  const t0 = await liveXY();
  need('press');
  await ack();
  await page.waitForFunction((n) => Number(document.getElementById('map').dataset.touches || 0) >= n, t0.n + sc.press_touches);
  const t1 = await liveXY();
  log('live point', t0, '->', t1);
  if (t1.x === undefined || (t1.x === t0.x && t1.y === t0.y)) throw new Error('the live point did not move');
  if (Math.abs(Number(t1.x) - sc.press_end[0]) > 1e-4 || Math.abs(Number(t1.y) - sc.press_end[1]) > 1e-4) {
    throw new Error(`live point at ${t1.x},${t1.y}, the press ended at ${sc.press_end}`);
  }
  // Plotly redraws the layers asynchronously after an update: wait until
  // all seven traces are back before counting their points.
  await page.waitForFunction(() => document.querySelectorAll('#map .scatterlayer .trace').length >= 7);
  const layer = await page.evaluate(() => {
    const traces = document.querySelectorAll('#map .scatterlayer .trace');
    return { near: traces[3].querySelectorAll('.point').length, trail: traces[5].querySelectorAll('.point').length,
             live: traces[6].querySelectorAll('.point').length };
  });
  log('live layer', layer);
  if (layer.live !== 1 || layer.trail < 2 || layer.near !== 3) throw new Error(`live layer: ${JSON.stringify(layer)}`);
  await page.waitForFunction((name) => document.getElementById('nearest').textContent.includes(name), sc.press_nearest_name);
  await page.waitForFunction((name) => document.getElementById('decision').textContent.includes(name), sc.press_nearest_name);
  if ((await page.textContent('#decision')).includes('unknown')) throw new Error('a known fabric shown as unknown');
  await page.waitForFunction((slot) => document.getElementById('roller').textContent.includes('at slot ' + slot), sc.press_slot);
  // The wheel: every slot drawn, the target filled, the plate turned so
  // that the sample under the finger is at the top; the felt latency.
  const wheel = await page.evaluate(() => ({
    slots: document.querySelectorAll('#wheel [data-slot]').length,
    target: [...document.querySelectorAll('#wheel .slot.target')].map((c) => c.parentNode.dataset.slot),
    here: [...document.querySelectorAll('#wheel .slot.here')].map((c) => c.parentNode.dataset.slot),
    angle: document.getElementById('plate').dataset.angle,
  }));
  log('wheel', wheel);
  const wantAngle = (sc.press_slot * 360 / sc.slots).toFixed(1);
  if (wheel.slots !== sc.slots || wheel.target.join() !== String(sc.press_slot) ||
      wheel.here.join() !== String(sc.press_slot) || wheel.angle !== wantAngle) {
    throw new Error(`wheel: ${JSON.stringify(wheel)}, want slot ${sc.press_slot} of ${sc.slots} at ${wantAngle}`);
  }
  await page.waitForFunction(() => document.getElementById('felt').textContent.includes('felt 234 ms after contact'));
  await page.waitForFunction(() => document.getElementById('peers').textContent.includes('browser-test'));
  // Its path (direct or relay) and round trip are shown beside it.
  await page.waitForFunction(() => document.getElementById('peers').textContent.includes('relay · 23.4 ms'));
  // The rendered marker sits where the map puts the touch.
  const markerOk = await page.evaluate(([x, y]) => {
    const pt = document.querySelectorAll('#map .scatterlayer .trace')[6].querySelector('.point');
    const r = pt.getBoundingClientRect();
    const want = window.telextilesMap.pixelOf(x, y);
    return Math.hypot(r.left + r.width / 2 - want.x, r.top + r.height / 2 - want.y) < 3;
  }, sc.press_end);
  if (!markerOk) throw new Error('the live marker is not drawn at the touch position');

  if (sc.screenshot) {
    await hover(sc.hover.id);
    await page.waitForFunction(() => document.getElementById('tip-img').naturalWidth > 0);
    await page.screenshot({ path: sc.screenshot });
    log('screenshot', sc.screenshot);
  }

  // 5. The server restarts with another index: the page reconnects by
  //    itself and re-fetches the map because the fingerprint changed.
  phase = 'restart';
  const fp1 = await page.evaluate(() => document.getElementById('map').dataset.fingerprint);
  need('restart');
  await ack();
  await page.waitForFunction((fp) => document.getElementById('map').dataset.fingerprint !== fp, fp1);
  await page.waitForSelector('#status.connected');
  await page.waitForFunction((n) => document.getElementById('map').dataset.points === String(n), sc.points2);
  const drawn2 = await page.evaluate(() =>
    document.querySelectorAll('#map .scatterlayer .trace')[0].querySelectorAll('.point').length +
    document.querySelectorAll('#map .scatterlayer .trace')[1].querySelectorAll('.point').length);
  if (drawn2 !== sc.points2) throw new Error(`after restart drew ${drawn2} points, want ${sc.points2}`);
  // Hovering still works on the new map and describes the new textiles.
  await hover(sc.hover2.id);
  const tip2 = await page.textContent('#tip-text');
  if (!tip2.includes(sc.hover2.name)) throw new Error(`tooltip after restart: ${tip2}`);
  phase = 'after-restart';
  const n2 = (await liveXY()).n;
  need('press');
  await ack();
  await page.waitForFunction((n) => Number(document.getElementById('map').dataset.touches || 0) >= n, n2 + sc.press_touches);
  // That press was decided as a fabric the index does not have.
  await page.waitForFunction(() => document.getElementById('decision').textContent.startsWith('unknown fabric; nearest known: '));
  await page.waitForSelector('#decision.unknown');
  if (errors.length) throw new Error('browser errors:\n' + errors.join('\n'));
  process.stdout.write(JSON.stringify({ ok: true, drawn, tooltip: tipText, live: t1 }) + '\n');
} catch (e) {
  failed = e;
} finally {
  await browser.close().catch(() => {});
  rmSync(profile, { recursive: true, force: true });
  lines.close();
}
if (failed) {
  log('FAILED:', failed.stack || failed.message);
  if (errors.length) log('browser errors:\n' + errors.join('\n'));
  process.exit(1);
}
