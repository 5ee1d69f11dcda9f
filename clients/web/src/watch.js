// Watch mode: a recorded scene stream (gateway --recordings) played through the daemon, one Query
// per frame, with a timeline (step, play, pause). Colours: colliding triangles red; triangles of
// pairs within the tolerance by their distance, a colour map from deep amber (touching) to pale
// yellow (at the tolerance); each object's closest pair (separation) a blue segment labelled with
// its distance; penetration vectors as arrows. Every number is the daemon's.
import * as THREE from 'three';

const GREY = new THREE.Color(0x9aa0a8);
const RED = new THREE.Color(0xe02020);
const NEAR = new THREE.Color(0xff8c00);   // distance 0
const FAR = new THREE.Color(0xfff0a0);    // distance = tolerance

// The colour of a triangle at distance d within tolerance tol.
export function distanceColour(d, tol) {
  return NEAR.clone().lerp(FAR, tol > 0 ? Math.min(1, Math.max(0, d / tol)) : 0);
}

export function startWatch(ctx) {
  const { scene, state, send, b64ToBytes, setLabel, redraw, $ } = ctx;
  const w = state.watch = { frames: 0, index: -1, playing: false, result: null, tolerance: ctx.tolerance,
                            colours: {}, arrows: 0, segments: 0, pending: null };
  const group = ctx.group;
  const meshes = [];
  const extras = new THREE.Group();
  scene.add(extras);
  let timer = null;

  function onWatch(msg) {
    w.frames = msg.frames;
    msg.objects.forEach((o, k) => {
      const idx = new Uint32Array(b64ToBytes(o.indices).buffer);
      const geom = new THREE.BufferGeometry();
      const n = idx.length / 3;
      geom.setAttribute('position', new THREE.BufferAttribute(new Float32Array(n * 9), 3));
      geom.setAttribute('color', new THREE.BufferAttribute(new Float32Array(n * 9), 3));
      const mesh = new THREE.Mesh(geom, new THREE.MeshLambertMaterial({ vertexColors: true, flatShading: true }));
      mesh.userData = { object: k, triangleIds: Array.from({ length: n }, (_, i) => i), idx };
      meshes.push(mesh);
      group.add(mesh);
      state.objects[k] = { name: o.name, pieces: [{ mesh, triangleIds: mesh.userData.triangleIds,
        byId: new Map(mesh.userData.triangleIds.map((i) => [i, i])) }], loadedT: null, currentT: null, deleted: false };
    });
    $('timeline').hidden = false;
    $('tl-slider').max = String(w.frames - 1);
    show(0);
  }

  function show(index) {
    if (index < 0 || index >= w.frames) return;
    w.pending = index;
    send({ type: 'frame', index });
  }

  function onFrame(msg) {
    if (msg.index !== w.pending) return;
    w.pending = null;
    w.index = msg.index;
    w.result = msg.result;
    const r = msg.result;
    // Positions (non-indexed, a colour per triangle).
    msg.positions.forEach((b64, k) => {
      const pos = new Float32Array(b64ToBytes(b64).buffer);
      const { idx } = meshes[k].userData;
      const attr = meshes[k].geometry.getAttribute('position');
      for (let t = 0; t < idx.length; t++) attr.array.set(pos.subarray(3 * idx[t], 3 * idx[t] + 3), 3 * t);
      attr.needsUpdate = true;
      meshes[k].geometry.computeVertexNormals();
      meshes[k].geometry.computeBoundingSphere();
      meshes[k].geometry.computeBoundingBox();
    });
    // Per-triangle colours: the nearest pair within the tolerance, red for collisions.
    const dist = meshes.map(() => new Map());
    const note = (o, t, d) => { const m = dist[o]; if (!m.has(t) || m.get(t) > d) m.set(t, d); };
    for (const p of r.tolerance) { note(p.object, p.triangle, p.distance); note(p.other, p.other_triangle, p.distance); }
    for (const p of r.collisions) { note(p.object, p.triangle, -1); note(p.other, p.other_triangle, -1); }
    w.colours = {};
    meshes.forEach((mesh, k) => {
      const attr = mesh.geometry.getAttribute('color');
      const n = attr.count / 3;
      for (let t = 0; t < n; t++) {
        const d = dist[k].get(t);
        const c = d === undefined ? GREY : d < 0 ? RED : distanceColour(d, w.tolerance);
        for (let v = 0; v < 3; v++) c.toArray(attr.array, 9 * t + 3 * v);
        if (d !== undefined) w.colours[`${k}:${t}`] = d < 0 ? 'red' : 'map';
      }
      attr.needsUpdate = true;
    });
    // Closest pairs as segments with their distance; penetration vectors as arrows.
    extras.clear();
    for (const key of Object.keys(w.labels || {})) setLabel(key, null);
    w.labels = {};
    w.segments = 0;
    const seen = new Set();
    r.separation.forEach((s, k) => {
      if (!s.has_other || s.distance <= 0) return;
      const key = [Math.min(k, s.other), Math.max(k, s.other)].join('-');
      if (seen.has(key)) return;
      seen.add(key);
      const a = new THREE.Vector3(s.point.x, s.point.y, s.point.z);
      const b = new THREE.Vector3(s.other_point.x, s.other_point.y, s.other_point.z);
      const line = new THREE.Line(new THREE.BufferGeometry().setFromPoints([a, b]),
                                  new THREE.LineBasicMaterial({ color: 0x2060ff, depthTest: false }));
      line.renderOrder = 10;
      extras.add(line);
      const label = `sep:${key}`;
      setLabel(label, s.distance.toPrecision(4), a.clone().add(b).multiplyScalar(0.5));
      w.labels[label] = true;
      w.segments++;
    });
    w.arrows = 0;
    for (const p of r.penetrations) {
      const mesh = meshes[p.object];
      const attr = mesh.geometry.getAttribute('position');
      const c = new THREE.Vector3();
      for (let v = 0; v < 3; v++) c.add(new THREE.Vector3().fromBufferAttribute(attr, 3 * p.triangle + v));
      c.divideScalar(3);
      const dir = new THREE.Vector3(p.direction.x, p.direction.y, p.direction.z);
      if (dir.lengthSq() === 0) continue;
      const len = Math.max(p.depth, 0.05);
      const arrow = new THREE.ArrowHelper(dir.normalize(), c, len, 0xff00ff, Math.min(0.2, len / 3), Math.min(0.1, len / 6));
      for (const part of [arrow.line, arrow.cone]) {
        part.material.depthTest = false;   // drawn over the objects it points out of
        part.renderOrder = 11;
      }
      extras.add(arrow);
      w.arrows++;
    }
    $('tl-slider').value = String(w.index);
    $('tl-label').textContent = `frame ${w.index + 1} / ${w.frames}: ${r.collisions.length} colliding pairs, ` +
      `${r.tolerance.length} within ${w.tolerance}, ${w.arrows} penetration vectors`;
    redraw();
    if (w.playing) timer = setTimeout(() => step(1), 400);
  }

  function step(d) {
    const next = w.index + d;
    if (next < 0 || next >= w.frames) { pause(); return; }
    show(next);
  }
  function play() {
    if (w.index >= w.frames - 1) show(0);
    w.playing = true;
    $('tl-play').textContent = 'pause';
    if (w.pending === null) step(1);
  }
  function pause() {
    w.playing = false;
    clearTimeout(timer);
    $('tl-play').textContent = 'play';
  }
  $('tl-back').onclick = () => { pause(); step(-1); };
  $('tl-fwd').onclick = () => { pause(); step(1); };
  $('tl-play').onclick = () => (w.playing ? pause() : play());
  $('tl-slider').oninput = () => { pause(); show(Number($('tl-slider').value)); };
  window.addEventListener('keydown', (e) => {
    if (e.target.tagName === 'INPUT' && e.target.type !== 'range') return;
    if (e.key === ' ') { e.preventDefault(); (w.playing ? pause() : play()); }
    if (e.key === 'ArrowRight') { pause(); step(1); }
    if (e.key === 'ArrowLeft') { pause(); step(-1); }
  });
  return { onWatch, onFrame, group };
}
