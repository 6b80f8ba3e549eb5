// Before/after of the default view's start (not a test; run by hand): for each page folder
// given, opens the default learned world in a fresh SwiftShader browser and prints the seconds
// to the first terrain drawn, to 20 nodes drawn and to the complete view (every tile made).
//   node first_view_ab.mjs DIST_A DIST_B [rounds]
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { chromium } from 'playwright-core';

const MIME = { '.html': 'text/html', '.js': 'text/javascript', '.wasm': 'application/wasm', '.css': 'text/css', '.json': 'application/json' };
function serve(dist) {
  return new Promise((resolve) => {
    const server = http.createServer((req, res) => {
      let file = path.join(dist, decodeURIComponent(new URL(req.url, 'http://x').pathname));
      if (fs.existsSync(file) && fs.statSync(file).isDirectory()) file = path.join(file, 'index.html');
      if (!fs.existsSync(file)) { res.writeHead(404).end(); return; }
      res.writeHead(200, { 'content-type': MIME[path.extname(file)] ?? 'application/octet-stream' });
      fs.createReadStream(file).pipe(res);
    });
    server.listen(0, '127.0.0.1', () => resolve([server, `http://127.0.0.1:${server.address().port}/`]));
  });
}
const args = ['--headless=new', '--no-sandbox', '--enable-unsafe-webgpu', '--enable-features=Vulkan', '--use-vulkan=swiftshader', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--disable-background-networking', '--no-first-run'];
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
