// Reads the float32 TIFFs that the native CLI writes, for the tests that compare with it.

import assert from 'node:assert/strict';

/** Width, height and float32 heights (row-major) of a TIFF as `terrain world` writes it
 * (little-endian, strips). */
export function readTiff(buf) {
  assert.equal(buf.toString('latin1', 0, 2), 'II', 'a little-endian TIFF');
  const ifd = buf.readUInt32LE(4);
  const tags = {};
  for (let k = 0; k < buf.readUInt16LE(ifd); k++) {
    const e = ifd + 2 + 12 * k;
    const [tag, type, count] = [buf.readUInt16LE(e), buf.readUInt16LE(e + 2), buf.readUInt32LE(e + 4)];
    if (![256, 257, 258, 273, 279, 339].includes(tag)) continue;
    const size = type === 3 ? 2 : 4;
    const at = count * size > 4 ? buf.readUInt32LE(e + 8) : e + 8;
    tags[tag] = Array.from({ length: count }, (_, i) => (size === 2 ? buf.readUInt16LE(at + 2 * i) : buf.readUInt32LE(at + 4 * i)));
  }
  const [width, height] = [tags[256][0], tags[257][0]];
  assert.equal(tags[258][0], 32);
  assert.equal(tags[339][0], 3, 'float samples');
  const data = [];
  tags[273].forEach((off, i) => { for (let b = 0; b < tags[279][i]; b += 4) data.push(buf.readFloatLE(off + b)); });
  assert.equal(data.length, width * height);
  return { width, height, data };
}

/** The float32 heights of such a TIFF. */
export const readTiffF32 = (buf) => readTiff(buf).data;
