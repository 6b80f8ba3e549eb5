// The native CLI's exports read by other people's tools: the Khronos glTF validator and
// trimesh (a Python mesh library that reads .glb the way Blender-style importers do). Needs the
// native debug binary (as page.test.mjs does) and the Python environment tests/setup.sh makes.
// Adds its numbers to out/export_report.json.

import { test, after } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { execFileSync } from 'node:child_process';
import validator from 'gltf-validator';
import { readTiff } from './tiff.mjs';

const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, '../..');
const out = path.join(here, 'out');
fs.mkdirSync(out, { recursive: true });
const home = process.env.HOME;
const nativeBin = process.env.TERRAIN_BIN ?? path.join(process.env.CARGO_TARGET_DIR ?? path.join(home, '.cache/terrain-target'), 'debug/terrain');
const python = process.env.TERRAIN_PY ?? path.join(home, '.cache/terrain-py/bin/python');
const report = {};

after(() => {
  fs.writeFileSync(path.join(out, 'export_report.json'), JSON.stringify(report, null, 1));
  console.log(`# EXPORT REPORT ${JSON.stringify(report)}`);
});

const terrain = (...args) => execFileSync(nativeBin, args, { stdio: ['ignore', 'pipe', 'pipe'] });

/** What trimesh reads from a .glb, unprocessed (no vertex merging): vertex and face counts,
 * the heights' range and whether every face's normal points up. */
function trimeshRead(file) {
  const script = [
    'import json, sys, trimesh',
    'm = trimesh.load(sys.argv[1], force="mesh", process=False)',
    'v = m.vertices',
    'print(json.dumps({"vertices": len(v), "faces": len(m.faces), "y_min": float(v[:, 1].min()), "y_max": float(v[:, 1].max()),',
    '  "x_span": float(v[:, 0].max() - v[:, 0].min()), "z_span": float(v[:, 2].max() - v[:, 2].min()),',
    '  "faces_up": int((m.face_normals[:, 1] > 0).sum())}))',
  ].join('\n');
  return JSON.parse(execFileSync(python, ['-c', script, file]).toString());
}

test('a .glb of the learned world at 32, 16 and 8 m passes the Khronos glTF validator with no errors or warnings, and trimesh reads one vertex per sample, two upward faces per cell and the exported heights', async () => {
  const weights = path.join(repo, 'weights');
  const tif32 = path.join(out, 'export_32m.tif');
  terrain('world', '--seed', '9', '--tiles', '0', '0', '1', '1', '--source', 'tcm', '--weights', weights, '--out', tif32);
  report.glb = {};
  for (const spacing of [32, 16, 8]) {
    const tif = spacing === 32 ? tif32 : path.join(out, `export_${spacing}m.tif`);
    const glb = path.join(out, `export_${spacing}m.glb`);
    if (spacing === 32) {
      terrain('world', '--seed', '9', '--tiles', '0', '0', '1', '1', '--source', 'tcm', '--weights', weights, '--out', glb);
    } else {
      // Learned detail (the TEM) from the 32 m tile: the same heights as a GeoTIFF and a mesh.
      terrain('enhance', '--input', tif32, '--output-res', String(spacing), '--weights', weights, '--out', tif);
      terrain('enhance', '--input', tif32, '--output-res', String(spacing), '--weights', weights, '--out', glb);
    }
    const { width, height, data } = readTiff(fs.readFileSync(tif));
    const bytes = fs.readFileSync(glb);
    const v = await validator.validateBytes(new Uint8Array(bytes), { maxIssues: 20 });
    const issues = v.issues;
    assert.equal(issues.numErrors, 0, `validator errors at ${spacing} m: ${JSON.stringify(issues.messages)}`);
    assert.equal(issues.numWarnings, 0, `validator warnings at ${spacing} m: ${JSON.stringify(issues.messages)}`);
    const m = trimeshRead(glb);
    const [lo, hi] = data.reduce(([a, b], x) => [Math.min(a, x), Math.max(b, x)], [Infinity, -Infinity]);
    assert.equal(m.vertices, width * height, `vertices at ${spacing} m`);
    assert.equal(m.faces, 2 * (width - 1) * (height - 1), `faces at ${spacing} m`);
    assert.equal(m.faces_up, m.faces, `faces whose normal points up at ${spacing} m`);
    assert.ok(Math.abs(m.y_min - lo) < 1e-3 && Math.abs(m.y_max - hi) < 1e-3, `heights ${m.y_min}..${m.y_max} vs ${lo}..${hi}`);
    assert.ok(Math.abs(m.x_span - (width - 1) * spacing) < 1e-2 && Math.abs(m.z_span - (height - 1) * spacing) < 1e-2, `spans ${m.x_span}, ${m.z_span}`);
    report.glb[`${spacing}m`] = { samples: [width, height], vertices: m.vertices, faces: m.faces, bytes: bytes.length, validator_infos: issues.numInfos, validator_hints: issues.numHints, relief_m: hi - lo };
  }
});
