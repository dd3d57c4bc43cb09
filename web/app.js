// The live page of the lhmpp node: each person's compact avatar (received once per revision
// over the WebSocket) rendered by Spark and skinned on the GPU by the pose stream.
//
// URL parameters: token (the node's --web-token, when it has one); camera=ex,ey,ez,tx,ty,tz
// and fov=degrees fix the camera (otherwise it frames the first avatar); bare=1 hides the list.
// window.lhmppState tells what was last drawn (tests read it). latency=1 records, for each
// pose, when the first frame showing it was drawn (window.lhmppTakeDraws(): [person, pose
// stamp ns, drawn ms since the epoch] rows, at most DRAWS_KEPT; `lhmpp bench latency` reads them).

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { SparkRenderer, SplatMesh, PackedSplats, SplatSkinning } from "@sparkjsdev/spark";

const params = new URLSearchParams(location.search);
const SH_C0 = 0.28209479177387814;
const COLOR_SCALE = 0.15;

let socket = null; // the WebSocket to the node
const persons = new Map(); // id -> { mesh, skinning, skeleton, header, status, pose, poseAt, el }
window.lhmppState = { frames: 0, persons: {} };
const latency = params.get("latency") === "1";
const DRAWS_KEPT = 10000;
const draws = [];
window.lhmppTakeDraws = () => draws.splice(0);

if (params.get("bare") === "1") document.body.classList.add("bare");

// ---- scene -------------------------------------------------------------------------------
const view = document.getElementById("view");
const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.setClearColor(0xffffff, 1);
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(1, 1, 1);
const spark = new SparkRenderer({
  renderer,
  // The node's CPU rasteriser (3DGS): Gaussians cut at 3σ, a 0.3 px² screen low-pass
  // without opacity compensation, alpha below 1/255 dropped.
  maxStdDev: 3.0,
  preBlurAmount: 0.3,
  blurAmount: 0.0,
  minAlpha: 1 / 255,
});
scene.add(spark);
const fov = Number(params.get("fov") || 45);
const camera = new THREE.PerspectiveCamera(fov, 1, 0.05, 100);
camera.position.set(0, 1, 3.5);
const controls = new OrbitControls(camera, renderer.domElement);
controls.target.set(0, 0.9, 0);
let framed = false;
const fixed = params.get("camera");
if (fixed) {
  const v = fixed.split(",").map(Number);
  camera.position.set(v[0], v[1], v[2]);
  controls.target.set(v[3], v[4], v[5]);
  framed = true;
}
controls.update();

function resize() {
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(1, h);
  camera.updateProjectionMatrix();
}
window.addEventListener("resize", resize);
resize();

renderer.setAnimationLoop(() => {
  for (const p of persons.values()) {
    if (p.posePending && p.skinning) { p.posePending = false; applyPose(p); }
  }
  controls.update();
  renderer.render(scene, camera);
  if (latency) noteDraws();
  // Asks the node for the poses that came since (it sends only each person's newest).
  if (socket && socket.readyState === WebSocket.OPEN) socket.send("drawn");
  const state = window.lhmppState;
  state.frames += 1;
  for (const [id, p] of persons) {
    state.persons[id] = {
      revision: p.header ? p.header.revision : 0,
      pose_stamp_ns: p.drawnStamp ?? null,
      splats: p.count ?? 0,
    };
  }
});
setInterval(refreshList, 250);

// Waits for the frame just rendered to be drawn (reading a pixel back finishes it), then
// records each person's pose drawn for the first time.
function noteDraws() {
  const gl = renderer.getContext();
  gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
  const at = performance.timeOrigin + performance.now();
  for (const [id, p] of persons) {
    if (p.drawnStamp == null || p.drawnStamp === p.reportedStamp) continue;
    p.reportedStamp = p.drawnStamp;
    draws.push([id, p.drawnStamp, at]);
  }
  if (draws.length > DRAWS_KEPT) draws.splice(0, draws.length - DRAWS_KEPT);
}

// ---- decoding ----------------------------------------------------------------------------
async function gunzip(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

// msg/msg/CompactAvatar.msg: the LHCA Gaussians blob.
function decodeGaussians(raw) {
  const magic = String.fromCharCode(raw[0], raw[1], raw[2], raw[3]);
  if (magic !== "LHCA" || raw[4] !== 1) throw new Error(`not an LHCA v1 blob (${magic})`);
  const fb = raw[5], n = new DataView(raw.buffer, raw.byteOffset).getUint32(8, true);
  let at = 12;
  const pos = new Float32Array(3 * n);
  const unit = 1 / (1 << fb);
  for (let axis = 0; axis < 3; axis++) {
    let v = 0;
    for (let i = 0; i < n; i++) {
      const z = raw[at + i] | (raw[at + n + i] << 8) | (raw[at + 2 * n + i] << 16);
      const d = (z >>> 1) ^ -(z & 1);
      v = (((v + d) & 0xffffff) << 8) >> 8;
      pos[3 * i + axis] = v * unit;
    }
    at += 3 * n;
  }
  const alpha = raw.subarray(at, at + n); at += n;
  const color = raw.subarray(at, at + 3 * n); at += 3 * n;
  const scale = raw.subarray(at, at + 3 * n); at += 3 * n;
  const rot = new DataView(raw.buffer, raw.byteOffset + at, 4 * n);
  return { n, pos, alpha, color, scale, rot };
}

function unpackRotation(word, out) {
  const largest = word >>> 30;
  const q = [0, 0, 0, 0];
  let sum = 0;
  for (let i = 3; i >= 0; i--) {
    if (i === largest) continue;
    const mag = word & 511, neg = (word >>> 9) & 1;
    word >>>= 10;
    const v = Math.SQRT1_2 * mag / 511;
    q[i] = neg ? -v : v;
    sum += v * v;
  }
  q[largest] = Math.sqrt(Math.max(0, 1 - sum));
  return out.set(q[0], q[1], q[2], q[3]).normalize();
}

// The LHSK skin blob: bone indices and weights per Gaussian.
function decodeSkin(raw, n) {
  const magic = String.fromCharCode(raw[0], raw[1], raw[2], raw[3]);
  if (magic !== "LHSK" || raw[4] !== 1) throw new Error(`not an LHSK v1 blob (${magic})`);
  const ib = raw[5], levels = raw[6];
  if (new DataView(raw.buffer, raw.byteOffset).getUint32(8, true) !== n) throw new Error("skin rows differ from the Gaussians");
  const bones = new Uint16Array(4 * n), weights = new Float32Array(4 * n);
  const bAt = 12, wAt = 12 + 4 * n * ib;
  for (let i = 0; i < n; i++) {
    let sum = 0;
    for (let k = 0; k < 4; k++) {
      const o = bAt + (k * n + i) * ib;
      bones[4 * i + k] = ib === 1 ? raw[o] : raw[o] | (raw[o + 1] << 8);
      if (k < 3) { const w = raw[wAt + k * n + i]; weights[4 * i + k] = w / levels; sum += w; }
    }
    weights[4 * i + 3] = (levels - sum) / levels;
  }
  return { bones, weights };
}

async function onAvatar(buffer) {
  const bytes = new Uint8Array(buffer);
  const headerLength = new DataView(buffer).getUint32(4, true);
  const header = JSON.parse(new TextDecoder().decode(bytes.subarray(8, 8 + headerLength)));
  let at = 8 + headerLength;
  const g = decodeGaussians(await gunzip(bytes.subarray(at, at + header.gaussians_bytes)));
  at += header.gaussians_bytes;
  const skin = decodeSkin(await gunzip(bytes.subarray(at, at + header.skin_bytes)), g.n);

  const packed = new PackedSplats({ maxSplats: g.n });
  const c = new THREE.Vector3(), s = new THREE.Vector3(), q = new THREE.Quaternion();
  const col = new THREE.Color();
  for (let i = 0; i < g.n; i++) {
    c.set(g.pos[3 * i], g.pos[3 * i + 1], g.pos[3 * i + 2]);
    s.set(...[0, 1, 2].map((k) => Math.exp(g.scale[3 * i + k] / 16 - 10)));
    unpackRotation(g.rot.getUint32(4 * i, true), q);
    const rgb = [0, 1, 2].map((k) => 0.5 + SH_C0 * ((g.color[3 * i + k] / 255 - 0.5) / COLOR_SCALE));
    col.setRGB(...rgb.map((v) => Math.min(1, Math.max(0, v))));
    packed.pushSplat(c, s, q, g.alpha[i] / 255, col);
  }
  const mesh = new SplatMesh({ packedSplats: packed });
  const numBones = header.bone_names.length;
  const skinning = new SplatSkinning({ mesh, numSplats: g.n, numBones });
  // Every bone rests at the origin, unrotated, so that a bone's posed rotation and position
  // (applyPose) are its skinning transform itself (Spark's dual-quaternion skinning blends
  // rest-relative rotations and position offsets).
  const origin = new THREE.Vector3(), ident = new THREE.Quaternion();
  for (let b = 0; b < numBones; b++) skinning.setRestQuatPos(b, ident, origin);
  const bi = new THREE.Vector4(), bw = new THREE.Vector4();
  for (let i = 0; i < g.n; i++) {
    bi.fromArray(skin.bones, 4 * i);
    bw.fromArray(skin.weights, 4 * i);
    skinning.setSplatBones(i, bi, bw);
  }
  skinning.skinTexture.needsUpdate = true;
  mesh.skinning = skinning;
  mesh.updateGenerator();

  const p = person(header.person);
  if (p.mesh) { scene.remove(p.mesh); p.mesh.dispose?.(); }
  p.mesh = mesh; p.skinning = skinning; p.header = header; p.count = g.n;
  p.index = new Map(header.bone_names.map((name, i) => [name, i]));
  scene.add(mesh);
  if (!framed) frame(g);
  applyPose(p);
}

function frame(g) {
  const box = new THREE.Box3();
  for (let i = 0; i < g.n; i++) box.expandByPoint(new THREE.Vector3(g.pos[3 * i], g.pos[3 * i + 1], g.pos[3 * i + 2]));
  const centre = box.getCenter(new THREE.Vector3());
  const height = box.getSize(new THREE.Vector3()).y;
  controls.target.copy(centre);
  camera.position.set(centre.x, centre.y, centre.z + 1.2 * height / Math.tan(THREE.MathUtils.degToRad(fov) / 2) / 2 + 0.5);
  controls.update();
  framed = true;
}

// ---- poses -------------------------------------------------------------------------------
// Forward kinematics as the node's (body::Skeleton::skinning_matrices): local rotations about
// each joint in canonical axes, parents first; the root transform last, about the first joint.
function applyPose(p) {
  if (!p.skinning || !p.pose) return;
  const { bone_parents: parents, bone_rest: rest } = p.header;
  const n = parents.length;
  const local = Array.from({ length: n }, () => new THREE.Quaternion());
  p.pose.bones.forEach((name, k) => {
    const i = p.index.get(name);
    if (i !== undefined) local[i].fromArray(p.pose.rotations[k]).normalize();
  });
  const gq = [], gt = [];
  const joint = (i) => new THREE.Vector3().fromArray(rest, 3 * i);
  for (let j = 0; j < n; j++) {
    const par = parents[j];
    if (par >= 0) {
      gq[j] = gq[par].clone().multiply(local[j]);
      gt[j] = joint(j).sub(joint(par)).applyQuaternion(gq[par]).add(gt[par]);
    } else {
      gq[j] = local[j].clone();
      gt[j] = joint(j);
    }
  }
  const rr = new THREE.Quaternion().fromArray(p.pose.root_rotation).normalize();
  const rt = new THREE.Vector3().fromArray(p.pose.root_translation);
  const pivot = n > 0 ? joint(0) : new THREE.Vector3();
  for (let j = 0; j < n; j++) {
    // World transform W_j = (q, t) of the bone; its skinning transform W_j · T(−joint_j).
    const q = rr.clone().multiply(gq[j]);
    const t = gt[j].clone().sub(pivot).applyQuaternion(rr).add(pivot).add(rt);
    t.sub(joint(j).applyQuaternion(q));
    p.skinning.setBoneQuatPos(j, q, t);
  }
  p.skinning.updateBones();
  p.drawnStamp = p.pose.stamp_ns;
}

// ---- the list ----------------------------------------------------------------------------
function person(id) {
  let p = persons.get(id);
  if (!p) {
    const el = document.createElement("div");
    el.className = "person";
    el.onclick = () => {
      for (const q of persons.values()) q.el.classList.toggle("selected", q === p);
      if (p.mesh) {
        const box = new THREE.Box3().setFromObject(p.mesh);
        if (!box.isEmpty()) controls.target.copy(box.getCenter(new THREE.Vector3()));
      }
    };
    document.getElementById("persons").appendChild(el);
    p = { el };
    persons.set(id, p);
    refreshList();
  }
  return p;
}

const STATES = ["idle", "waiting", "reconstructing", "error"];

function refreshList() {
  const now = performance.now();
  for (const [id, p] of persons) {
    const s = p.status || {};
    const age = p.poseAt === undefined ? "—" : `${Math.round(now - p.poseAt)} ms`;
    const rows = [
      ["revision", p.header ? p.header.revision : "—"],
      ["views", s.views_held ?? (p.header ? p.header.views_used : "—")],
      ["pose age", age],
      ["state", s.state !== undefined ? STATES[s.state] ?? s.state : "—"],
      ["Gaussians", p.count ?? "—"],
    ];
    p.el.innerHTML = `<b></b><table>${rows.map(() => "<tr><td></td><td></td></tr>").join("")}</table>`;
    p.el.querySelector("b").textContent = id;
    p.el.querySelectorAll("tr").forEach((tr, k) => {
      tr.children[0].textContent = rows[k][0];
      tr.children[1].textContent = String(rows[k][1]);
    });
    if (s.state === 3) p.el.querySelector("table").classList.add("error");
  }
}

// ---- the link ----------------------------------------------------------------------------
function connect() {
  const link = document.getElementById("link");
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const token = params.get("token");
  const url = `${scheme}://${location.host}/ws${token ? `?token=${encodeURIComponent(token)}` : ""}`;
  const ws = new WebSocket(url);
  socket = ws;
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { link.textContent = `live: ${location.host}`; };
  ws.onclose = () => { link.textContent = "disconnected; retrying…"; setTimeout(connect, 1000); };
  ws.onmessage = (event) => {
    if (typeof event.data !== "string") {
      queueAvatar(event.data);
      return;
    }
    // Poses and statuses never wait for an avatar being decoded: the newest pose is applied
    // once per drawn frame (and to an avatar when it is ready).
    const msg = JSON.parse(event.data);
    const p = person(msg.person);
    if (msg.type === "pose") { p.pose = msg; p.poseAt = performance.now(); p.posePending = true; }
    else if (msg.type === "status") { p.status = msg; }
  };
}

// Avatars are decoded one at a time; while one is decoded, only each person's newest waits.
const avatarsWaiting = new Map(); // person -> ArrayBuffer
let decodingAvatar = false;
function queueAvatar(buffer) {
  const headerLength = new DataView(buffer).getUint32(4, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8, headerLength)));
  avatarsWaiting.delete(header.person);
  avatarsWaiting.set(header.person, buffer);
  if (!decodingAvatar) decodeAvatars();
}
async function decodeAvatars() {
  decodingAvatar = true;
  while (avatarsWaiting.size > 0) {
    const [id, buffer] = avatarsWaiting.entries().next().value;
    avatarsWaiting.delete(id);
    try { await onAvatar(buffer); } catch (e) { link.textContent = `avatar: ${e.message}`; console.error(e); }
  }
  decodingAvatar = false;
}
connect();
