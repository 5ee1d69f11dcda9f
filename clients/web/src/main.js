// The review page: joins a review room on a served model through the gateway's WebSocket
// (gateway.js), loads the model around the viewer progressively (FetchRegion, nearest piece
// first), shows every member's avatar live, moves its own with mouse drag and keys, and colours
// the daemon's answers: colliding triangles red, triangles within the tolerance amber, the nearest
// pair as a blue segment labelled with its distance. Clicking a triangle shows its object,
// triangle id and the daemon's closest pair between that object and this member's avatar.
// Edits (move, add, delete an object) go to the room and are applied when the daemon confirms
// them (edit_applied), for every member alike. Every number shown is the daemon's.
//
// The page state is exposed as window.__proxima for tests (tests/web).
import * as THREE from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import { startWatch } from './watch.js';

const GREY = new THREE.Color(0x9aa0a8);
const RED = new THREE.Color(0xe02020);
const AMBER = new THREE.Color(0xffb000);
const PALE_RED = new THREE.Color(0xc89090);
const PALE_AMBER = new THREE.Color(0xc8b48c);
const AVATAR_SIZE = 0.5;

const $ = (id) => document.getElementById(id);
const state = {
  phase: 'form', error: null, member: null, room: null, model: null, modelInfo: null,
  members: {},          // name -> {transform: [12], summary, sequence}
  objects: {},          // object index -> {name, pieces: [{mesh, triangleIds}], loadedT, deleted}
  region: { pieces: 0, triangles: 0, total: 0, trianglesTotal: 0, done: false },
  lastResult: null, pending: 0, sequence: 0, editSequence: 0, edits: [],
  coloured: { red: [], amber: [] },   // [{object, triangle}] currently coloured
  pick: null, modelVersion: 0,
};
window.__proxima = state;

// --- transforms ----------------------------------------------------------------------------

const toMatrix4 = (m) => new THREE.Matrix4().set(m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7],
                                                 m[8], m[9], m[10], m[11], 0, 0, 0, 1);
const translation = (x, y, z) => [1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, z];
const IDENTITY = translation(0, 0, 0);

// --- base64 <-> typed arrays ----------------------------------------------------------------

function b64ToBytes(s) {
  const bin = atob(s);
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}
function bytesToB64(bytes) {
  let s = '';
  const u = new Uint8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  for (let i = 0; i < u.length; i += 0x8000) s += String.fromCharCode(...u.subarray(i, i + 0x8000));
  return btoa(s);
}

// A box mesh in the daemon's form (12 triangles, outward), centred on the origin.
function boxMesh(name, half) {
  const p = [];
  for (let i = 0; i < 8; i++) p.push(i & 1 ? half : -half, i & 2 ? half : -half, i & 4 ? half : -half);
  const idx = [0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
               2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5];
  return { name, positions: bytesToB64(new Float32Array(p)), indices: bytesToB64(new Uint32Array(idx)) };
}

// --- three.js scene --------------------------------------------------------------------------

let renderer, scene, camera, controls, modelGroup, segment;
const avatars = {};   // member -> THREE.Mesh
const labels = {};    // key -> {el, position}

function initScene() {
  const canvas = $('canvas');
  renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  scene = new THREE.Scene();
  scene.background = new THREE.Color(0x20242a);
  camera = new THREE.PerspectiveCamera(45, 1, 0.01, 10000);
  camera.up.set(0, 0, 1);
  scene.add(new THREE.AmbientLight(0xffffff, 0.45));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  sun.position.set(0.4, -0.7, 1);
  scene.add(sun);
  modelGroup = new THREE.Group();
  scene.add(modelGroup);
  controls = new OrbitControls(camera, canvas);
  controls.enableDamping = false;
  controls.addEventListener('change', redraw);
  const lineGeom = new THREE.BufferGeometry().setAttribute('position',
    new THREE.Float32BufferAttribute([0, 0, 0, 0, 0, 0], 3));
  segment = new THREE.Line(lineGeom, new THREE.LineBasicMaterial({ color: 0x2060ff, depthTest: false }));
  segment.renderOrder = 10;
  segment.visible = false;
  scene.add(segment);
  window.addEventListener('resize', resize);
  resize();
  renderer.setAnimationLoop(render);
}

function resize() {
  const w = window.innerWidth;
  const h = window.innerHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  redraw();
}

// Frames are drawn only when something changed (software WebGL is expensive).
let dirty = true;
const redraw = () => { dirty = true; };

function render() {
  if (!dirty) return;
  dirty = false;
  renderer.render(scene, camera);
  for (const l of Object.values(labels)) {
    const v = l.position.clone().project(camera);
    l.el.style.left = `${((v.x + 1) / 2) * window.innerWidth}px`;
    l.el.style.top = `${((1 - v.y) / 2) * window.innerHeight}px`;
    l.el.style.display = v.z < 1 ? '' : 'none';
  }
}

function setLabel(key, text, position, cls = '') {
  if (!text) {
    if (labels[key]) labels[key].el.remove();
    delete labels[key];
    return;
  }
  if (!labels[key]) {
    const el = document.createElement('div');
    el.className = `label ${cls}`;
    $('labels').appendChild(el);
    labels[key] = { el, position: new THREE.Vector3() };
  }
  labels[key].el.textContent = text;
  labels[key].position.copy(position);
}

function fitCamera(box, scale = 0.8) {
  redraw();
  const lo = new THREE.Vector3(box.lo.x, box.lo.y, box.lo.z);
  const hi = new THREE.Vector3(box.hi.x, box.hi.y, box.hi.z);
  const centre = lo.clone().add(hi).multiplyScalar(0.5);
  const size = hi.clone().sub(lo).length();
  camera.position.copy(centre).add(new THREE.Vector3(0.15, -1.0, 0.75).multiplyScalar(size * scale));
  controls.target.copy(centre);
  camera.near = size / 1000;
  camera.far = size * 20;
  camera.updateProjectionMatrix();
  controls.update();
}

// --- model geometry: one THREE.Mesh per piece, non-indexed, a colour per triangle -----------

const loadedPieces = new Set();   // object:first triangle id, so that refetches skip them

function addPiece(piece) {
  redraw();
  const key = `${piece.object}:${piece.triangle_ids[0]}:${piece.triangle_ids.length}`;
  if (loadedPieces.has(key) || state.objects[piece.object]?.deleted) return;
  loadedPieces.add(key);
  const pos = new Float32Array(b64ToBytes(piece.mesh.positions).buffer);
  const idx = new Uint32Array(b64ToBytes(piece.mesh.indices).buffer);
  const n = idx.length / 3;
  const flat = new Float32Array(n * 9);
  for (let t = 0; t < n; t++) {
    for (let k = 0; k < 3; k++) {
      const v = idx[3 * t + k];
      flat.set(pos.subarray(3 * v, 3 * v + 3), 9 * t + 3 * k);
    }
  }
  const colours = new Float32Array(n * 9);
  for (let i = 0; i < n * 3; i++) GREY.toArray(colours, 3 * i);
  const geom = new THREE.BufferGeometry();
  geom.setAttribute('position', new THREE.BufferAttribute(flat, 3));
  geom.setAttribute('color', new THREE.BufferAttribute(colours, 3));
  geom.computeVertexNormals();
  const mesh = new THREE.Mesh(geom, new THREE.MeshLambertMaterial({ vertexColors: true, flatShading: true }));
  mesh.matrixAutoUpdate = false;
  const o = state.objects[piece.object] ||= { name: piece.name, pieces: [], loadedT: IDENTITY,
                                              currentT: IDENTITY, deleted: false };
  const triangleIds = piece.triangle_ids;
  const byId = new Map(triangleIds.map((id, i) => [id, i]));
  mesh.userData = { object: piece.object, triangleIds };
  o.pieces.push({ mesh, triangleIds, byId });
  applyObjectTransform(piece.object);
  modelGroup.add(mesh);
}

// A moved object's loaded geometry already has loadedT applied: show it under currentT.
function applyObjectTransform(object) {
  redraw();
  const o = state.objects[object];
  const m = toMatrix4(o.currentT).multiply(toMatrix4(o.loadedT).invert());
  for (const p of o.pieces) {
    p.mesh.matrix.copy(m);
    p.mesh.matrixWorldNeedsUpdate = true;
  }
}

function setTriangleColour(object, triangle, colour) {
  redraw();
  const o = state.objects[object];
  if (!o) return false;
  for (const p of o.pieces) {
    const i = p.byId.get(triangle);
    if (i === undefined) continue;
    const attr = p.mesh.geometry.getAttribute('color');
    for (let k = 0; k < 3; k++) colour.toArray(attr.array, 9 * i + 3 * k);
    attr.needsUpdate = true;
    return true;
  }
  return false;
}

function tintObject(object, colour) {
  redraw();
  for (const p of state.objects[object]?.pieces || []) {
    const attr = p.mesh.geometry.getAttribute('color');
    for (let i = 0; i < attr.count; i++) colour.toArray(attr.array, 3 * i);
    attr.needsUpdate = true;
  }
}

// --- the gateway connection ----------------------------------------------------------------

let ws;
const regionHandlers = new Map();
let regionIds = 0;

function send(msg) { ws.send(JSON.stringify(msg)); }

function connect(token) {
  return new Promise((resolve, reject) => {
    const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
    ws = new WebSocket(`${proto}//${location.host}/ws`);
    ws.onopen = () => send({ type: 'hello', token });
    ws.onerror = () => reject(new Error('cannot reach the gateway'));
    ws.onclose = () => { if (state.phase !== 'form') status('disconnected from the gateway'); };
    ws.onmessage = (ev) => {
      const msg = JSON.parse(ev.data);
      if (msg.type === 'hello') resolve(msg);
      else if (msg.type === 'error' && msg.call === 'hello') reject(new Error(`${msg.code}: ${msg.message}`));
      else onMessage(msg);
    };
  });
}

function onMessage(msg) {
  if (msg.type === 'review') onReviewEvent(msg.event);
  else if (msg.type === 'watch') watcher?.onWatch(msg);
  else if (msg.type === 'frame') watcher?.onFrame(msg);
  else if (msg.type === 'region') regionHandlers.get(msg.id)?.(msg);
  else if (msg.type === 'error') {
    if (msg.call === 'region') regionHandlers.get(msg.id)?.(msg);
    state.error = `${msg.call}: ${msg.code}: ${msg.message}`;
    status(state.error);
    if (state.phase === 'joining' && (msg.call === 'review' || msg.call === 'watch')) showJoinError(state.error);
  }
}

function fetchRegion(req, onPiece) {
  const id = ++regionIds;
  return new Promise((resolve, reject) => {
    regionHandlers.set(id, (msg) => {
      if (msg.piece) onPiece(msg.piece);
      else if (msg.progress) onPiece(null, msg.progress);
      else if (msg.summary) { regionHandlers.delete(id); resolve(msg.summary); }
      else if (msg.type === 'error') { regionHandlers.delete(id); reject(new Error(`${msg.code}: ${msg.message}`)); }
    });
    send({ type: 'region', id, ...req });
  });
}

async function loadRegion(center, radius) {
  regionCentre = new THREE.Vector3(...center);
  regionRadius = radius;
  const r = state.region;
  const showProgress = () => {
    const frac = r.trianglesTotal ? r.triangles / r.trianglesTotal : 0;
    $('progress-bar').style.width = `${(r.done ? 1 : frac) * 100}%`;
    $('progress-text').textContent = r.done
      ? `model loaded: ${r.pieces} pieces, ${r.triangles} triangles`
      : `loading ${r.triangles} / ${r.trianglesTotal || '?'} triangles (${r.pieces} pieces)`;
  };
  showProgress();
  const summary = await fetchRegion({ model: state.model, room: state.room, center, radius },
    (piece, progress) => {
      if (piece) addPiece(piece);
      if (progress) {
        r.pieces = progress.pieces_sent;
        r.triangles = progress.triangles_sent;
        r.total = progress.pieces_total;
        r.trianglesTotal = progress.triangles_total;
      }
      showProgress();
    });
  r.pieces = summary.pieces;
  r.triangles = summary.triangles;
  r.done = true;
  showProgress();
  recolour();
}

// --- review events -------------------------------------------------------------------------

function avatarFor(member) {
  if (!avatars[member]) {
    const own = member === state.member;
    const g = new THREE.BoxGeometry(2 * AVATAR_SIZE, 2 * AVATAR_SIZE, 2 * AVATAR_SIZE);
    const mesh = new THREE.Mesh(g, new THREE.MeshLambertMaterial({ color: own ? 0x3070ff : 0x30c060 }));
    mesh.matrixAutoUpdate = false;
    mesh.userData = { member };
    scene.add(mesh);
    avatars[member] = mesh;
  }
  return avatars[member];
}

function showMember(name, transform, summary) {
  redraw();
  const m = state.members[name] ||= { transform: null, summary: null, sequence: 0 };
  if (transform) m.transform = transform;
  if (summary) m.summary = summary;
  if (!m.transform) return;
  const a = avatarFor(name);
  a.matrix.copy(toMatrix4(m.transform));
  a.matrixWorldNeedsUpdate = true;
  if (name !== state.member) {
    const s = m.summary;
    const colour = s && s.collisions > 0 ? 0xe02020 : s && s.within > 0 ? 0xffb000 : 0x30c060;
    a.material.color.setHex(colour);
    m.colour = s && s.collisions > 0 ? 'red' : s && s.within > 0 ? 'amber' : 'green';
  }
  const p = new THREE.Vector3(m.transform[3], m.transform[7], m.transform[11] + AVATAR_SIZE);
  setLabel(`member:${name}`, name, p, 'member-label');
  renderMembers();
}

function renderMembers() {
  $('members').textContent = `room ${state.room}: ` + Object.entries(state.members).map(([n, m]) =>
    `${n}${n === state.member ? ' (you)' : ''}${m.summary && m.summary.collisions ? ' [collides]' : ''}`).join(', ');
}

function onReviewEvent(e) {
  redraw();
  switch (e.kind) {
    case 'joined':
      state.phase = 'joined';
      state.modelVersion = e.model_version;
      for (const m of e.members) {
        if (m.has_pose) showMember(m.name, m.transform, m.summary);
        else state.members[m.name] ||= { transform: null, summary: null, sequence: 0 };
      }
      joinedResolve?.(e);
      break;
    case 'result':
      state.pending = 0;
      state.lastResult = e;
      // A pose may have been computed on the version before an edit already shown.
      state.modelVersion = Math.max(state.modelVersion, e.model_version);
      recolour();
      showResult(e);
      if (poseDirty) sendPose();
      break;
    case 'peer':
      showMember(e.member, e.transform, e.summary);
      break;
    case 'member_joined':
      state.members[e.member] ||= { transform: null, summary: null, sequence: 0 };
      renderMembers();
      break;
    case 'member_left':
      delete state.members[e.member];
      if (avatars[e.member]) scene.remove(avatars[e.member]);
      delete avatars[e.member];
      setLabel(`member:${e.member}`, null);
      renderMembers();
      break;
    case 'edit_applied':
      onEditApplied(e);
      break;
    case 'end':
      status('the daemon ended the review stream');
      break;
    default:
  }
}

async function onEditApplied(e) {
  redraw();
  state.edits.push(e);
  state.modelVersion = e.model_version;
  status(`${e.member} ${e.what === 'EDIT_MOVE' ? 'moved' : e.what === 'EDIT_ADD' ? 'added' : 'deleted'} ` +
         `object ${e.object} (${e.object_name}); model version ${e.model_version}`);
  if (e.what === 'EDIT_MOVE') {
    const o = state.objects[e.object];
    if (o && e.transform && e.transform.length === 12) {
      o.currentT = e.transform;
      applyObjectTransform(e.object);
    } else if (o) {
      // A daemon that does not say where the object went: fetch its room's view again.
      for (const p of o.pieces) modelGroup.remove(p.mesh);
      delete state.objects[e.object];
      for (const k of [...loadedPieces]) if (k.startsWith(`${e.object}:`)) loadedPieces.delete(k);
      await fetchRegion({ model: state.model, room: state.room, center: [0, 0, 0], radius: 0,
                          objects: [e.object] }, (piece) => { if (piece) addPiece(piece); });
    }
  } else if (e.what === 'EDIT_DELETE') {
    const o = state.objects[e.object];
    if (o) {
      o.deleted = true;
      for (const p of o.pieces) modelGroup.remove(p.mesh);
    }
  } else if (e.what === 'EDIT_ADD') {
    await fetchRegion({ model: state.model, room: state.room, center: [0, 0, 0], radius: 0,
                        objects: [e.object] }, (piece) => { if (piece) addPiece(piece); });
  }
  // The room changed: the avatar's answer may too.
  poseDirty = true;
  if (!state.pending) sendPose();
}

// Colours the triangles of the latest result: collisions red (they win), within amber.
function recolour() {
  redraw();
  for (const c of [...state.coloured.red, ...state.coloured.amber]) tintObject(c.object, GREY);
  state.coloured = { red: [], amber: [] };
  const r = state.lastResult;
  segment.visible = false;
  setLabel('nearest', null);
  if (!r) return;
  // The objects of the pairs, lightly tinted so that a pair shows whichever side is in view.
  for (const h of r.within) tintObject(h.object, PALE_AMBER);
  for (const h of r.collisions) tintObject(h.object, PALE_RED);
  for (const h of r.within) {
    if (setTriangleColour(h.object, h.object_triangle, AMBER)) state.coloured.amber.push({ object: h.object, triangle: h.object_triangle });
  }
  for (const h of r.collisions) {
    if (setTriangleColour(h.object, h.object_triangle, RED)) state.coloured.red.push({ object: h.object, triangle: h.object_triangle });
  }
  const n = r.nearest;
  if (n && n.object_name !== '' && r.collisions.length === 0) {
    const a = new THREE.Vector3(n.object_point.x, n.object_point.y, n.object_point.z);
    const b = new THREE.Vector3(n.avatar_point.x, n.avatar_point.y, n.avatar_point.z);
    segment.geometry.getAttribute('position').setXYZ(0, a.x, a.y, a.z);
    segment.geometry.getAttribute('position').setXYZ(1, b.x, b.y, b.z);
    segment.geometry.getAttribute('position').needsUpdate = true;
    segment.visible = true;
    setLabel('nearest', `${n.distance.toPrecision(4)}`, a.clone().add(b).multiplyScalar(0.5));
  }
}

function showResult(r) {
  const f = (h) => `${h.object_name} (#${h.object}) tri ${h.object_triangle} d=${h.distance.toPrecision(4)}`;
  $('result').textContent = [
    `pose ${r.sequence}: ${r.collisions.length} colliding, ${r.within.length} within tolerance`,
    ...r.collisions.map((h) => `collides: ${f(h)}`),
    ...r.within.map((h) => `within: ${f(h)}`),
    r.nearest && r.nearest.object_name !== '' ? `nearest: ${f(r.nearest)}` : '',
  ].filter(Boolean).join('\n');
}

function status(text) { $('status').textContent = text; }

// --- the own avatar: keys and mouse drag ---------------------------------------------------

let poseDirty = false;
let position = new THREE.Vector3();

function sendPose() {
  poseDirty = false;
  state.pending = ++state.sequence;
  const t = translation(position.x, position.y, position.z);
  showMember(state.member, t, null);
  send({ type: 'pose', sequence: state.sequence, m: t });
}

// With a region radius, the region follows the avatar: moving more than half the radius from
// where the last region was fetched fetches the region around the new place (pieces already
// shown are skipped).
let regionCentre = null;
let regionRadius = 0;
let regionBusy = false;
function followRegion() {
  if (!regionRadius || regionBusy || !regionCentre) return;
  if (position.distanceTo(regionCentre) <= regionRadius / 2) return;
  regionBusy = true;
  state.region.done = false;
  loadRegion(position.toArray(), regionRadius).catch((e) => { state.error = e.message; })
    .finally(() => { regionBusy = false; followRegion(); });
}

function moveAvatarTo(p) {
  position.copy(p);
  followRegion();
  poseDirty = true;
  if (!state.pending) sendPose();
}

function initInput() {
  const canvas = $('canvas');
  const step = () => Math.max(0.05, AVATAR_SIZE / 2);
  window.addEventListener('keydown', (e) => {
    if (state.phase !== 'joined' || e.target.tagName === 'INPUT') return;
    const d = { ArrowLeft: [-1, 0, 0], ArrowRight: [1, 0, 0], ArrowUp: [0, 1, 0], ArrowDown: [0, -1, 0],
                a: [-1, 0, 0], d: [1, 0, 0], w: [0, 1, 0], s: [0, -1, 0], q: [0, 0, -1], e: [0, 0, 1] }[e.key];
    if (!d) return;
    e.preventDefault();
    moveAvatarTo(position.clone().add(new THREE.Vector3(...d).multiplyScalar(step())));
  });
  const ray = new THREE.Raycaster();
  const ndc = (e) => new THREE.Vector2((e.offsetX / canvas.clientWidth) * 2 - 1, -(e.offsetY / canvas.clientHeight) * 2 + 1);
  let drag = null;
  let down = null;
  canvas.addEventListener('pointerdown', (e) => {
    down = { x: e.clientX, y: e.clientY };
    const own = avatars[state.member];
    if (!own) return;
    ray.setFromCamera(ndc(e), camera);
    if (ray.intersectObject(own).length) {
      // Drag on the horizontal plane through the avatar's centre.
      drag = { plane: new THREE.Plane(new THREE.Vector3(0, 0, 1), -position.z) };
      controls.enabled = false;
      canvas.setPointerCapture(e.pointerId);
    }
  }, { capture: true });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    ray.setFromCamera(ndc(e), camera);
    const p = new THREE.Vector3();
    if (ray.ray.intersectPlane(drag.plane, p)) moveAvatarTo(p);
  });
  canvas.addEventListener('pointerup', (e) => {
    const moved = down && Math.hypot(e.clientX - down.x, e.clientY - down.y) > 3;
    if (drag) {
      drag = null;
      controls.enabled = true;
    } else if (!moved) {
      ray.setFromCamera(ndc(e), camera);
      pick(ray);
    }
    down = null;
  });
}

// --- picking -------------------------------------------------------------------------------

function pick(ray) {
  const hits = ray.intersectObjects(modelGroup.children, false);
  const panel = $('pick');
  if (!hits.length) {
    state.pick = null;
    panel.hidden = true;
    $('edit-move').disabled = $('edit-delete').disabled = true;
    return;
  }
  const h = hits[0];
  const { object, triangleIds } = h.object.userData;
  const triangle = triangleIds[h.faceIndex];
  const o = state.objects[object];
  const r = state.lastResult;
  const all = r ? [...r.collisions, ...r.within, ...(r.nearest && r.nearest.object_name !== '' ? [r.nearest] : [])] : [];
  const pair = all.find((x) => x.object === object) || null;
  state.pick = { object, name: o.name, triangle, pair };
  const lines = [`object ${object} (${o.name})`, `triangle ${triangle}`];
  const sep = state.watch?.result?.separation?.[object];
  if (state.watch) {
    state.pick.pair = sep && sep.has_other ? sep : null;
    lines.push(sep && sep.has_other
      ? `closest pair: triangle ${sep.triangle} - object ${sep.other} triangle ${sep.other_triangle}`
      : 'no other object', ...(sep && sep.has_other ? [`distance ${sep.distance}`] : []));
  } else if (pair) {
    lines.push(`closest pair to your avatar: object triangle ${pair.object_triangle}, ` +
               `avatar triangle ${pair.avatar_triangle}`, `distance ${pair.distance}`);
  } else {
    lines.push('not within the tolerance of your avatar');
  }
  panel.textContent = lines.join('\n');
  panel.hidden = false;
  $('edit-move').disabled = $('edit-delete').disabled = false;
  redraw();
}

function initEdits() {
  $('edit-move').onclick = () => {
    if (!state.pick) return;
    const o = state.objects[state.pick.object];
    const t = o.currentT.slice();
    t[3] += 1;
    send({ type: 'edit', sequence: ++state.editSequence, move: { object: state.pick.object, m: t } });
  };
  $('edit-delete').onclick = () => {
    if (!state.pick) return;
    send({ type: 'edit', sequence: ++state.editSequence, remove: { object: state.pick.object } });
  };
  $('edit-add').onclick = () => {
    const m = boxMesh(`box-by-${state.member}-${state.editSequence + 1}`, 0.3);
    const p = new Float32Array(b64ToBytes(m.positions).buffer);
    for (let i = 0; i < p.length; i += 3) { p[i] += position.x + 1.2; p[i + 1] += position.y; p[i + 2] += position.z; }
    m.positions = bytesToB64(p);
    send({ type: 'edit', sequence: ++state.editSequence, add: m });
  };
}

// --- joining -------------------------------------------------------------------------------

let joinedResolve = null;
let watcher = null;

// Watch mode: a recording served by the gateway (--recordings), played through the daemon.
async function watchRecording(f, hello) {
  if (!hello.recordings.includes(f.recording)) {
    showJoinError(`no recording ${f.recording} (the gateway has: ${hello.recordings.join(', ') || 'none'})`);
    return;
  }
  $('join').hidden = true;
  $('view').hidden = false;
  $('edits').hidden = true;
  $('progress').hidden = true;
  state.phase = 'joining';
  if (!renderer) {
    initScene();
    initInput();
  }
  let fitted = false;
  watcher = startWatch({ scene, state, send, b64ToBytes, setLabel, $, tolerance: Number(f.tolerance),
    group: modelGroup,
    redraw: () => {
      if (!fitted) {
        fitted = true;
        const box = new THREE.Box3().setFromObject(modelGroup);
        fitCamera({ lo: box.min, hi: box.max }, 1.2);
        state.phase = 'watching';
        state.loaded = true;
      }
      redraw();
    } });
  send({ type: 'watch', recording: f.recording, tolerance: Number(f.tolerance) });
  status(`watching recording ${f.recording}`);
}

// A refused join (a hello or the daemon's answer to the join): back to the form, which says why.
function showJoinError(text) {
  $('join-error').textContent = text;
  state.phase = 'form';
  state.error = text;
  $('join').hidden = false;
  $('view').hidden = true;
  if (ws && ws.readyState <= WebSocket.OPEN) ws.close();
  joinedResolve?.(null);
}

async function join(form) {
  const f = Object.fromEntries(new FormData(form).entries());
  state.phase = 'joining';
  $('join-error').textContent = '';
  let hello;
  try {
    hello = await connect(f.token);
  } catch (e) {
    showJoinError(e.message);
    return;
  }
  if (f.recording) {
    await watchRecording(f, hello);
    return;
  }
  const info = hello.models.find((m) => m.name === f.model);
  if (!info) {
    showJoinError(`no model ${f.model} (served: ${hello.models.map((m) => m.name).join(', ')})`);
    ws.close();
    return;
  }
  Object.assign(state, { member: f.member, room: f.room, model: f.model, modelInfo: info });
  const start = f.start ? f.start.split(',').map(Number)
    : [info.box.lo.x - 1, info.box.lo.y - 1, (info.box.lo.z + info.box.hi.z) / 2];
  position = new THREE.Vector3(...start);
  form.hidden = true;
  $('view').hidden = false;
  if (!renderer) {
    initScene();
    initInput();
    initEdits();
  }
  fitCamera(info.box);
  const joined = new Promise((resolve) => { joinedResolve = resolve; });
  send({ type: 'join', room: f.room, model: f.model, member: f.member, tolerance: Number(f.tolerance),
         nearest: true, avatar: boxMesh('avatar', AVATAR_SIZE) });
  if (!(await joined)) return;   // refused: the form says why
  state.error = null;
  status(`joined room ${f.room} on ${f.model} as ${f.member}`);
  sendPose();
  try {
    await loadRegion(start, Number(f.radius));
  } catch (e) {
    status(`loading the model failed: ${e.message}`);
    state.error = e.message;
  }
  state.phase = 'joined';
  state.loaded = true;
}

// Settings that are not secret may come from the query string (?model=&room=&member=&start=);
// the token never does.
const params = new URLSearchParams(location.search);
for (const key of ['model', 'room', 'member', 'tolerance', 'start', 'radius', 'recording']) {
  if (params.has(key)) document.querySelector(`#join [name=${key}]`).value = params.get(key);
}
if (!document.querySelector('#join [name=member]').value) {
  document.querySelector('#join [name=member]').value = `reviewer-${Math.floor(Math.random() * 1000)}`;
}
$('join').addEventListener('submit', (e) => {
  e.preventDefault();
  join(e.target);
});
state.moveAvatarTo = (x, y, z) => moveAvatarTo(new THREE.Vector3(x, y, z));
state.project = (x, y, z) => {
  const v = new THREE.Vector3(x, y, z).project(camera);
  return { x: ((v.x + 1) / 2) * window.innerWidth, y: ((1 - v.y) / 2) * window.innerHeight };
};
state.triangleCentre = (object, triangle) => {
  for (const p of state.objects[object]?.pieces || []) {
    const i = p.byId.get(triangle);
    if (i === undefined) continue;
    const a = p.mesh.geometry.getAttribute('position');
    const c = new THREE.Vector3();
    for (let k = 0; k < 3; k++) c.add(new THREE.Vector3().fromBufferAttribute(a, 3 * i + k));
    return c.divideScalar(3).applyMatrix4(p.mesh.matrix).toArray();
  }
  return null;
};
state.pixel = (x, y) => {
  const gl = renderer.getContext();
  const out = new Uint8Array(4);
  gl.readPixels(Math.round(x), gl.drawingBufferHeight - 1 - Math.round(y), 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, out);
  return Array.from(out.slice(0, 3));
};
