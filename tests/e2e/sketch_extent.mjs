// The same sketch at 8 km and at 0.5 km in 3-D (not a test; run by hand): opens the sketch
// world (the page's first example sketch, seed 1), frames it ("Frame the sketch"), waits for
// the learned world around it and the learned detail to settle and takes a screenshot; then
// sets the sketch panel's extent slider to its least (0.5 km) with the mouse, waits again and
// takes a second. Prints the links, timings and eye positions.
//   node sketch_extent.mjs DIST OUT
import fs from 'node:fs';
import path from 'node:path';
import { chromium } from 'playwright-core';
import { serve, SWIFTSHADER_ARGS as args } from './by_hand.mjs';

const [dist, out] = process.argv.slice(2);
fs.mkdirSync(out, { recursive: true });
const [server, base] = await serve(path.resolve(dist));
const browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium', headless: false, args });
const page = await browser.newPage({ viewport: { width: 1280, height: 720 } });
const t0 = Date.now();
await page.goto(`${base}#v=2&seed=1&src=sketch`);
const stats = () => page.evaluate(() => (window.wasmBindings?.terrain_stats ? JSON.parse(window.wasmBindings.terrain_stats()) : null));
// Rectangles come as [x, y, width, height].
const centre = (r) => [r[0] + r[2] / 2, r[1] + r[3] / 2];
// Waits until the learned world around the sketch is made and the learned detail has made no
// new quad for 10 s, for at most `ms`.
async function settled(what, pred, ms) {
  let s = null;
  let quads = -1;
  let still = 0;
  const t = Date.now();
  while (Date.now() - t < ms) {
    s = await stats();
    const st = s?.stats;
    if (st && pred(s) && /^sketch in the learned world/.test(s.source) && st.tiles_pending === 0 && st.tiles_stale === 0) {
      still = st.quads_made === quads ? still + 1 : 0;
      quads = st.quads_made;
      if (still >= 20) return s;
    }
    await page.waitForTimeout(500);
  }
  console.log(`${what}: not settled after ${ms / 1000} s`);
  return s;
}
let s = await settled('8 km', (q) => q.sketch_buttons?.frame, 600_000);
await page.mouse.click(...centre(s.sketch_buttons.frame));
s = await settled('8 km framed', () => true, 300_000);
await page.screenshot({ path: path.join(out, 'sketch_extent_8192m.png') });
console.log(JSON.stringify({ extent: '8 km', s: (Date.now() - t0) / 1000, link: s.link, eye_m: s.stats.eye_m, quads_made: s.stats.quads_made, max_depth_drawn: s.stats.max_depth_drawn }));
const slider = s.sketch_buttons.extent;
await page.mouse.click(slider[0] + 2, slider[1] + slider[3] / 2);
const t1 = Date.now();
s = await settled('0.5 km', (q) => /extent=512&|extent=512$/.test(q.link) && q.stats.sketch_shown > 0, 600_000);
await page.screenshot({ path: path.join(out, 'sketch_extent_512m.png') });
console.log(JSON.stringify({ extent: '0.5 km', s: (Date.now() - t1) / 1000, link: s.link, eye_m: s.stats.eye_m, quads_made: s.stats.quads_made, max_depth_drawn: s.stats.max_depth_drawn }));
await browser.close();
server.close();
