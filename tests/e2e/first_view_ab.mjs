// Before/after of the default view's start (not a test; run by hand): for each page folder
// given, opens the default learned world in a fresh SwiftShader browser and prints the seconds
// to the first terrain drawn, to 20 nodes drawn and to the complete view (every tile made).
//   node first_view_ab.mjs DIST_A DIST_B [rounds]
import path from 'node:path';
import { chromium } from 'playwright-core';
import { serve, SWIFTSHADER_ARGS as args } from './by_hand.mjs';

const [a, b, rounds = '2'] = process.argv.slice(2);
for (let k = 0; k < Number(rounds); k++) {
  for (const dist of [a, b]) {
    const [server, base] = await serve(path.resolve(dist));
    const browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium', headless: false, args });
    const page = await browser.newPage({ viewport: { width: 960, height: 600 } });
    const t0 = Date.now();
    await page.goto(base);
    const times = {};
    while (Date.now() - t0 < 240_000) {
      const s = await page.evaluate(() => (window.wasmBindings?.terrain_stats ? JSON.parse(window.wasmBindings.terrain_stats()) : null));
      const st = s?.stats;
      if (st && st.nodes_drawn > 0) times.first ??= (Date.now() - t0) / 1000;
      if (st && st.nodes_drawn >= 20) times.view20 ??= (Date.now() - t0) / 1000;
      if (st && st.nodes_drawn > 0 && st.tiles_pending === 0 && st.frames > 20) { times.complete = (Date.now() - t0) / 1000; break; }
      await page.waitForTimeout(100);
    }
    console.log(JSON.stringify({ dist, round: k + 1, ...times }));
    await browser.close();
    server.close();
  }
}
