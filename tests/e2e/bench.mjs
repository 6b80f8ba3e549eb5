// The page's speed on this machine (a benchmark, not a test: machines differ, so the test suite
// asserts none of it). Prints each figure as JSON and checks it against its goal; exits 1 when a
// goal is missed. Run by hand after a page build:
//   node bench.mjs [DIST] [NAME…]    # default ../../dist; NAME: sustained, gpu_world_frames, screens
// Measured:
// - sustained flight: the learned world at the default radius (4 tiles) flown by the autopilot
//   at 250, 500 and 1000 m/s, each on its own heading from the same start (90° apart, so each
//   flies over tiles not made yet), tiles from the CPU worker. Per speed, the view's own tiles
//   pending sampled every 250 ms over 20 s: the share with none pending, the most at once and
//   at the end, the tiles made a second. The view stays complete at a speed where the worker
//   keeps up: the backlog never grows past two rows of tiles across the view (2 × (2·4 + 1))
//   and every tile of the view is made again in the flight's last 5 s. Goal: 250 m/s.
// - frames while the learned world's networks run on WebGPU (?world=gpu, SwiftShader): a batch
//   goes to the GPU a few items a call (about half a median frame's work each; on SwiftShader
//   one item, a ×4 window in two halves), so a frame waits behind one piece at most. Goal:
//   worst / median ≤ 4 until the first tile (0, 2) is made (1.80–2.12 on the machine where it
//   was written; a whole 40-tile batch a call held the frames for 21–26 s, ratio 123–144).
// - screens: frames of one procedural view flown forward for 15 s (SwiftShader) at device pixel
//   ratio 1 and 2 (960×600 CSS px), at ratio 2 with the render scale at 100 % and 50 % (the
//   link's scale=), and drawn with WebGL2 (WebGPU off) beside WebGPU at ratio 1: median and worst
//   frame, and the 3-D view's pixels. Goal: each the page chooses by itself (ratio 1 and 2 at
//   the Auto scale, WebGL2) draws at least 10 frames in the flight; the forced scales only
//   report (at 100 % on a software adapter a ratio-2 frame took ~3 s where this was written).
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';
import { serve, SWIFTSHADER_ARGS as args } from './by_hand.mjs';

const here = path.dirname(fileURLToPath(import.meta.url));
const dist = path.resolve(process.argv[2] ?? path.join(here, '../../dist'));
const only = process.argv.slice(3);

const SUSTAINED_SPEEDS_MPS = [250, 500, 1000];
const SUSTAINED_GOAL_MPS = 250;
const SUSTAINED_FLIGHT_S = 20;
const SUSTAINED_BACKLOG_TILES = 18;
const SUSTAINED_CAUGHT_UP_S = 5;
const GPU_WORLD_FRAME_RATIO_MAX = 4;

const stats = (page) => page.evaluate(() => (window.wasmBindings?.terrain_stats ? JSON.parse(window.wasmBindings.terrain_stats()) : null));

async function waitFor(page, pred, what, timeoutMs) {
  const t0 = Date.now();
  for (;;) {
    const s = await stats(page);
    if (s && s.stats && pred(s)) return s;
    if (Date.now() - t0 > timeoutMs) throw new Error(`timed out waiting for ${what}`);
    await page.waitForTimeout(250);
  }
}

/** Opens `hash` (and `query`) in a fresh browser (with `launchArgs`, a page with `pageOptions`);
 * returns [browser, page]. */
async function open(base, hash, query = '', pageOptions = {}, launchArgs = args) {
  const browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium', headless: false, args: launchArgs });
  const page = await browser.newPage({ viewport: { width: 960, height: 600 }, ...pageOptions });
  await page.goto(base + query + '#' + hash);
  return [browser, page];
}

async function sustained(base) {
  const at = (v, k) => `v=2&seed=11&src=tcm&cam=3000,2500,9000,${(0.9 + k * Math.PI / 2).toFixed(4)},-0.3&lod=6&auto=${v}`;
  const [browser, page] = await open(base, at(0, 0));
  const t0 = Date.now();
  await waitFor(page, (s) => s.stats.source === 'learned' && s.stats.tiles_pending === 0 && s.stats.frames > 20, 'the learned view at the default radius', 900_000);
  const out = { first_complete_view_s: (Date.now() - t0) / 1000, radius_tiles: 4, flight_s: SUSTAINED_FLIGHT_S, speeds: {} };
  for (const [k, v] of SUSTAINED_SPEEDS_MPS.entries()) {
    await page.evaluate((f) => { window.location.hash = f; }, at(v, k));
    const before = await stats(page);
    const samples = [];
    const start = Date.now();
    while (Date.now() - start < SUSTAINED_FLIGHT_S * 1000) {
      await page.waitForTimeout(250);
      samples.push((await stats(page)).stats.tiles_pending);
    }
    const after = await stats(page);
    const secs = (Date.now() - start) / 1000;
    const lastComplete = samples.lastIndexOf(0);
    const lastCompleteS = lastComplete < 0 ? null : (lastComplete + 1) * 0.25;
    out.speeds[v] = {
      complete_share: samples.filter((p) => p === 0).length / samples.length,
      pending_max: Math.max(...samples), pending_end: samples[samples.length - 1],
      last_complete_s: lastCompleteS,
      tiles_made_per_s: (after.stats.tiles_generated - before.stats.tiles_generated) / secs,
      ms_per_tile: after.stats.ms_per_tile,
      stays_complete: Math.max(...samples) <= SUSTAINED_BACKLOG_TILES && lastCompleteS !== null && lastCompleteS >= SUSTAINED_FLIGHT_S - SUSTAINED_CAUGHT_UP_S,
    };
  }
  await browser.close();
  const kept = SUSTAINED_SPEEDS_MPS.filter((v) => out.speeds[v].stays_complete);
  out.fastest_complete_mps = kept.length ? Math.max(...kept) : null;
  out.goal_mps = SUSTAINED_GOAL_MPS;
  out.goal_met = out.fastest_complete_mps !== null && out.fastest_complete_mps >= SUSTAINED_GOAL_MPS;
  return out;
}

async function gpuWorldFrames(base) {
  const [browser, page] = await open(base, 'v=2&seed=7&src=tcm&cam=3000,2500,9000,0.9,-0.3&r=1&lod=6', '?world=gpu&tem=off');
  await waitFor(page, (s) => s.stats.frames > 0, 'the first frame', 300_000);
  await page.evaluate(() => window.wasmBindings.terrain_frame_intervals());
  await page.evaluate(() => window.wasmBindings.terrain_request_tile(0, 2));
  const t0 = Date.now();
  let heights = null;
  while (!heights && Date.now() - t0 < 900_000) {
    heights = JSON.parse(await page.evaluate(() => window.wasmBindings.terrain_tile_heights()));
    if (!heights) await page.waitForTimeout(1000);
  }
  const frames = (await page.evaluate(() => Array.from(window.wasmBindings.terrain_frame_intervals()))).sort((a, b) => a - b);
  await browser.close();
  const median = frames[Math.floor(frames.length / 2)];
  const ratio = frames[frames.length - 1] / median;
  return { first_tile_s: (Date.now() - t0) / 1000, frames: frames.length, frame_ms_median: median, frame_ms_worst: frames[frames.length - 1], worst_over_median: ratio, goal_max: GPU_WORLD_FRAME_RATIO_MAX, goal_met: heights !== null && ratio <= GPU_WORLD_FRAME_RATIO_MAX };
}

// Chromium with WebGPU off (WebGL2 through ANGLE on SwiftShader).
const WEBGL2_ARGS = args.filter((a) => a !== '--enable-unsafe-webgpu').concat(['--disable-features=WebGPU']);
const SCREENS_MIN_FRAMES = 10;
const SCREENS_FLIGHT_S = 15;

async function screens(base) {
  const view = (scale) => `v=2&seed=7&src=procedural&cam=3000,2500,9000,0.9,-0.3&r=3&lod=6${scale ? `&scale=${scale}` : ''}`;
  const runs = [
    ['ratio_1', view(), {}, args, true],
    ['ratio_2', view(), { deviceScaleFactor: 2 }, args, true],
    ['ratio_2_scale_100', view(1), { deviceScaleFactor: 2 }, args, false],
    ['ratio_2_scale_50', view(0.5), { deviceScaleFactor: 2 }, args, false],
    ['webgl2_ratio_1', view(), {}, WEBGL2_ARGS, true],
  ];
  const out = {};
  for (const [name, hash, options, launchArgs] of runs) {
    const [browser, page] = await open(base, hash, '', options, launchArgs);
    await waitFor(page, (s) => s.stats.tiles_pending === 0 && s.stats.frames > 20, `the view (${name})`, 600_000);
    await page.evaluate(() => window.wasmBindings.terrain_frame_intervals());
    await page.keyboard.down('KeyW');
    await page.waitForTimeout(SCREENS_FLIGHT_S * 1000);
    await page.keyboard.up('KeyW');
    const frames = (await page.evaluate(() => Array.from(window.wasmBindings.terrain_frame_intervals()))).sort((a, b) => a - b);
    const s = await stats(page);
    await browser.close();
    out[name] = { adapter: s.adapter, view_px: s.view_px, screen_px: s.screen_px, frames: frames.length, frame_ms_median: frames[Math.floor(frames.length / 2)], frame_ms_worst: frames[frames.length - 1] };
  }
  out.goal_min_frames = SCREENS_MIN_FRAMES;
  out.goal_met = runs.every(([name, , , , chosen]) => !chosen || out[name].frames >= SCREENS_MIN_FRAMES);
  return out;
}

const [server, base] = await serve(dist);
const benches = { sustained, gpu_world_frames: gpuWorldFrames, screens };
const results = {};
for (const [name, run] of Object.entries(benches)) {
  if (!only.length || only.includes(name)) results[name] = await run(base);
}
server.close();
console.log('BENCH ' + JSON.stringify(results));
const missed = Object.entries(results).filter(([, r]) => !r.goal_met).map(([k]) => k);
if (missed.length) {
  console.error(`goals missed: ${missed.join(', ')}`);
  process.exit(1);
}
