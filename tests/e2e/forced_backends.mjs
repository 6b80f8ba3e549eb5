// The learned world's networks forced onto each backend (not a test; run by hand, it can take
// half an hour on SwiftShader): for each `?world=` choice given (default: cpu, then gpu), opens
// the default learned view in a fresh SwiftShader browser and prints the seconds to the first
// terrain and to the complete view (every tile made), and the frames meanwhile: their count,
// median and worst interval and worst / median, the slowest 8 frames (when, and the GPU's items
// a call then), from the first frame after start-up (the
// first 20 frames, while the models load, are left out).
//   node forced_backends.mjs DIST [cpu gpu ...]
import path from 'node:path';
import { chromium } from 'playwright-core';
import { serve, SWIFTSHADER_ARGS as args } from './by_hand.mjs';

const [dist, ...choices] = process.argv.slice(2);
const limitMs = 40 * 60_000;
for (const world of choices.length ? choices : ['cpu', 'gpu']) {
  const [server, base] = await serve(path.resolve(dist));
  const browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium', headless: false, args });
  const page = await browser.newPage({ viewport: { width: 960, height: 600 } });
  const t0 = Date.now();
  await page.goto(`${base}?world=${world}&tem=off`);
  const out = { world };
  const intervals = [];
  const slowest = [];
  let s = null;
  while (Date.now() - t0 < limitMs) {
    s = await page.evaluate(() => (window.wasmBindings?.terrain_stats ? JSON.parse(window.wasmBindings.terrain_stats()) : null));
    const st = s?.stats;
    if (st && st.frames > 0) {
      const got = await page.evaluate(() => Array.from(window.wasmBindings.terrain_frame_intervals()));
      if (st.frames > 20) {
        intervals.push(...got);
        // The longest frames, each with the seconds since the start and the GPU's items a call then.
        for (const ms of got) slowest.push({ s: (Date.now() - t0) / 1000, ms, gpu_call_items: s.world_gpu_call_items });
        slowest.sort((x, y) => y.ms - x.ms).splice(8);
      }
    }
    if (st && st.nodes_drawn > 0) out.first_terrain_s ??= (Date.now() - t0) / 1000;
    if (st && st.nodes_drawn > 0 && st.tiles_pending === 0 && st.frames > 20) { out.complete_s = (Date.now() - t0) / 1000; break; }
    await page.waitForTimeout(1000);
  }
  intervals.sort((x, y) => x - y);
  const median = intervals[Math.floor(intervals.length / 2)];
  Object.assign(out, {
    world_backend: s?.world_backend, tiles: s?.stats?.tiles_generated, pending: s?.stats?.tiles_pending, gpu_ms_per_tile: s?.world_gpu_ms_per_tile,
    gpu_call_items: s?.world_gpu_call_items, slowest, frames: intervals.length, frame_ms_median: median, frame_ms_worst: intervals.at(-1),
    worst_over_median: intervals.at(-1) / median, frame_ms_p99: intervals[Math.floor(intervals.length * 0.99)],
  });
  console.log(JSON.stringify(out));
  await browser.close();
  server.close();
}
