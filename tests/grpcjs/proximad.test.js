// proximad driven from Node's grpc-js (a second, independent gRPC implementation: no gRPC C core,
// no generated code) through the calls docs/api.md documents, with nothing but that page and
// proto/proxima/v1/proxima.proto: health, reflection, scenes, uploads, one-shot queries, frame
// streams (one scene per stream), message size limits, deadlines, tokens and error codes.
// Answers on random scenes are checked against a brute force written here in JavaScript.
//
//   PROXIMAD=build/release/server/proximad node --test tests/grpcjs/
//
// The packages come from tests/grpcjs/package-lock.json (deploy/setup.sh runs `npm ci` there).
'use strict';

const { test, before, after } = require('node:test');
const assert = require('node:assert/strict');
const { spawn } = require('node:child_process');
const crypto = require('node:crypto');
const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');

let grpc;
let protoLoader;
try {
  grpc = require('@grpc/grpc-js');
  protoLoader = require('@grpc/proto-loader');
} catch (e) {
  throw new Error(`tests/grpcjs: cannot load @grpc/grpc-js / @grpc/proto-loader (${e.message}); ` +
                  'run deploy/setup.sh (it runs `npm ci` in tests/grpcjs)');
}

const PROXIMAD = process.env.PROXIMAD;
if (!PROXIMAD || !fs.existsSync(PROXIMAD)) {
  throw new Error(`set PROXIMAD to the proximad binary (got ${JSON.stringify(PROXIMAD)})`);
}
const ROOT = path.resolve(__dirname, '..', '..');
const LOAD_OPTIONS = { keepCase: true, longs: String, enums: String, defaults: true, oneofs: true };
const load = (file) => grpc.loadPackageDefinition(protoLoader.loadSync(file, LOAD_OPTIONS));
const proxima = load(path.join(ROOT, 'proto', 'proxima', 'v1', 'proxima.proto')).proxima.v1;
// The standard services' definitions, as their npm packages (pinned in package-lock.json) ship them.
const MODULES = path.join(__dirname, 'node_modules');
const health = load(path.join(MODULES, 'grpc-health-check', 'proto', 'health', 'v1', 'health.proto'))
  .grpc.health.v1;
const reflection = load(path.join(MODULES, '@grpc', 'reflection', 'build', 'proto', 'grpc',
  'reflection', 'v1alpha', 'reflection.proto')).grpc.reflection.v1alpha;
const { status } = grpc;

// --- the daemon ----------------------------------------------------------------------------

// proximad on a free loopback port: its first stdout line is "listening on HOST:PORT".
function startDaemon(...flags) {
  return new Promise((resolve, reject) => {
    const proc = spawn(PROXIMAD, ['--listen', '127.0.0.1:0', ...flags],
                       { stdio: ['ignore', 'pipe', 'pipe'] });
    let out = '';
    let err = '';
    let done = false;
    const timer = setTimeout(() => fail(new Error('proximad printed no address in 30 s')), 30000);
    function fail(e) {
      if (done) return;
      done = true;
      clearTimeout(timer);
      proc.kill('SIGKILL');
      reject(new Error(`${e.message}; stderr:\n${err}`));
    }
    proc.stderr.on('data', (d) => { err += d; });
    proc.on('exit', (code) => fail(new Error(`proximad exited with ${code}`)));
    proc.stdout.on('data', (d) => {
      out += d;
      const nl = out.indexOf('\n');
      if (done || nl < 0) return;
      const m = /^listening on (\S+:\d+)$/.exec(out.slice(0, nl).trim());
      if (!m) return fail(new Error(`unexpected first line ${JSON.stringify(out.slice(0, nl))}`));
      done = true;
      clearTimeout(timer);
      resolve({
        proc,
        address: m[1],
        log: () => err,
        stop: () => new Promise((res) => {
          if (proc.exitCode !== null) return res(proc.exitCode);
          proc.removeAllListeners('exit');
          proc.on('exit', (code, signal) => res(code ?? signal));
          proc.kill('SIGTERM');
        }),
      });
    });
  });
}

function clientsFor(address, options = {}) {
  const creds = grpc.credentials.createInsecure();
  return {
    proximity: new proxima.Proximity(address, creds, options),
    health: new health.Health(address, creds),
    reflection: new reflection.ServerReflection(address, creds),
    close() {
      this.proximity.close();
      this.health.close();
      this.reflection.close();
    },
  };
}

// A unary call as a promise; opts: metadata, deadline (ms from now).
function unary(client, method, request, opts = {}) {
  const metadata = opts.metadata ?? new grpc.Metadata();
  const callOptions = opts.deadline ? { deadline: Date.now() + opts.deadline } : {};
  return new Promise((resolve, reject) => {
    client[method](request, metadata, callOptions, (err, res) => (err ? reject(err) : resolve(res)));
  });
}

async function expectCode(promise, code, pattern) {
  let result;
  try {
    result = await promise;
  } catch (e) {
    assert.equal(status[e.code], status[code], `expected ${status[code]}, got ${status[e.code]}: ${e.details}`);
    if (pattern) assert.match(e.details, pattern);
    return e;
  }
  assert.fail(`expected ${status[code]}, the call succeeded: ${JSON.stringify(result).slice(0, 200)}`);
}

// A bidirectional or client stream read one message at a time.
function openStream(call) {
  const queue = [];
  const waiters = [];
  let ended = null;
  const finished = new Promise((resolve) => call.on('status', resolve));
  call.on('data', (d) => (waiters.length ? waiters.shift().resolve(d) : queue.push(d)));
  const stop = (e) => {
    ended = e;
    while (waiters.length) waiters.shift().reject(e);
  };
  call.on('error', stop);
  call.on('end', () => stop(ended ?? new Error('the stream ended')));
  return {
    call,
    send: (m) => call.write(m),
    next: () => (queue.length ? Promise.resolve(queue.shift())
                 : ended ? Promise.reject(ended)
                 : new Promise((resolve, reject) => waiters.push({ resolve, reject }))),
    close() {
      call.end();
      return finished;
    },
    finished,
  };
}

// --- geometry on the wire (docs/api.md: packed little-endian buffers) ----------------------

function packVertices(vertices, type = 'SCALAR_TYPE_FLOAT64') {
  const size = type === 'SCALAR_TYPE_FLOAT32' ? 4 : 8;
  const b = Buffer.alloc(vertices.length * 3 * size);
  vertices.flat().forEach((x, k) => (size === 4 ? b.writeFloatLE(x, k * 4) : b.writeDoubleLE(x, k * 8)));
  return { type, data: b };
}

function packTriangles(triangles) {
  const b = Buffer.alloc(triangles.length * 12);
  triangles.flat().forEach((i, k) => b.writeUInt32LE(i, k * 4));
  return b;
}

const mesh = (name, m, type) => ({ name, vertices: packVertices(m.vertices, type), indices: packTriangles(m.triangles) });

// The box of docs/api.md's C++ example (12 triangles, outward).
function box(lo, hi) {
  const vertices = [];
  for (let k = 0; k < 8; ++k) vertices.push([k & 1 ? hi[0] : lo[0], k & 2 ? hi[1] : lo[1], k & 4 ? hi[2] : lo[2]]);
  const triangles = [[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                     [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]];
  return { vertices, triangles };
}

const shifted = (m, d) => ({ vertices: m.vertices.map(([x, y, z]) => [x + d[0], y + d[1], z + d[2]]), triangles: m.triangles });

// --- brute force: triangle-triangle distance (Ericson, Real-Time Collision Detection 5.1) ----

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const clamp01 = (x) => Math.min(1, Math.max(0, x));
const dist = (a, b) => Math.sqrt(dot(sub(a, b), sub(a, b)));

function closestPointTriangle(p, a, b, c) {
  const ab = sub(b, a), ac = sub(c, a), ap = sub(p, a);
  const d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const bp = sub(p, b), d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return add(a, mul(ab, d1 / (d1 - d3)));
  const cp = sub(p, c), d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return add(a, mul(ac, d2 / (d2 - d6)));
  const va = d3 * d6 - d5 * d4;
  if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) return add(b, mul(sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))));
  const denom = 1 / (va + vb + vc);
  return add(a, add(mul(ab, vb * denom), mul(ac, vc * denom)));
}

function segmentSegmentDistance(p1, q1, p2, q2) {
  const d1 = sub(q1, p1), d2 = sub(q2, p2), r = sub(p1, p2);
  const a = dot(d1, d1), e = dot(d2, d2), f = dot(d2, r), c = dot(d1, r), b = dot(d1, d2);
  const denom = a * e - b * b;
  let s = denom > 0 ? clamp01((b * f - c * e) / denom) : 0;
  let t = (b * s + f) / e;
  if (t < 0) {
    t = 0;
    s = clamp01(-c / a);
  } else if (t > 1) {
    t = 1;
    s = clamp01((b - c) / a);
  }
  return dist(add(p1, mul(d1, s)), add(p2, mul(d2, t)));
}

function segmentCrossesTriangle(p, q, a, b, c) {
  const n = cross(sub(b, a), sub(c, a));
  const dp = dot(n, sub(p, a)), dq = dot(n, sub(q, a));
  if ((dp > 0 && dq > 0) || (dp < 0 && dq < 0) || dp === dq) return false;
  const x = add(p, mul(sub(q, p), dp / (dp - dq)));
  const s1 = dot(cross(sub(b, a), sub(x, a)), n), s2 = dot(cross(sub(c, b), sub(x, b)), n);
  const s3 = dot(cross(sub(a, c), sub(x, c)), n);
  return (s1 >= 0 && s2 >= 0 && s3 >= 0) || (s1 <= 0 && s2 <= 0 && s3 <= 0);
}

// Distance between two triangles in general position (random ones): 0 when an edge of one
// crosses the other, else the least of the 6 vertex-triangle and 9 edge-edge distances.
function triangleDistance(t, u) {
  for (let i = 0; i < 3; ++i) {
    if (segmentCrossesTriangle(t[i], t[(i + 1) % 3], ...u)) return 0;
    if (segmentCrossesTriangle(u[i], u[(i + 1) % 3], ...t)) return 0;
  }
  let best = Infinity;
  for (let i = 0; i < 3; ++i) {
    best = Math.min(best, dist(t[i], closestPointTriangle(t[i], ...u)), dist(u[i], closestPointTriangle(u[i], ...t)));
    for (let j = 0; j < 3; ++j) best = Math.min(best, segmentSegmentDistance(t[i], t[(i + 1) % 3], u[j], u[(j + 1) % 3]));
  }
  return best;
}

const corners = (m, k) => m.triangles[k].map((i) => m.vertices[i]);

function mulberry32(seed) {
  return () => {
    seed = (seed + 0x6d2b79f5) | 0;
    let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t;
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

// Separate random triangles (no shared vertices) around a random centre.
function randomSoup(rand, triangles, spread, size) {
  const centre = [rand() * spread, rand() * spread, rand() * spread];
  const m = { vertices: [], triangles: [] };
  for (let k = 0; k < triangles; ++k) {
    const c = add(centre, [rand() - 0.5, rand() - 0.5, rand() - 0.5]);
    for (let i = 0; i < 3; ++i) m.vertices.push(add(c, [(rand() - 0.5) * size, (rand() - 0.5) * size, (rand() - 0.5) * size]));
    m.triangles.push([3 * k, 3 * k + 1, 3 * k + 2]);
  }
  return m;
}

const close = (a, b, what) => assert.ok(Math.abs(a - b) <= 1e-9 * Math.max(1, Math.abs(b)), `${what}: ${a} vs ${b}`);
const pairKey = (p) => `${p.object}/${p.triangle}/${p.other}/${p.other_triangle}`;

// --- the tests -------------------------------------------------------------------------------

let daemon;
let c;

before(async () => {
  daemon = await startDaemon();
  c = clientsFor(daemon.address);
});

after(async () => {
  c?.close();
  if (daemon) assert.equal(await daemon.stop(), 0, 'proximad exits 0 on SIGTERM');
});

test('GetServerInfo: api, version and the limits', async () => {
  const info = await unary(c.proximity, 'GetServerInfo', {});
  assert.equal(info.api, 'proxima.v1');
  assert.match(info.version, /^\d+\.\d+/);
  assert.equal(info.limits.max_message_bytes, String(256 * 1024 * 1024));
  assert.equal(info.limits.max_frames_in_flight, 4);
  assert.equal(info.limits.max_scenes, '64');
  assert.equal(info.principal, '');
});

test('health: grpc.health.v1 answers SERVING for "" and proxima.v1.Proximity', async () => {
  for (const service of ['', 'proxima.v1.Proximity']) {
    const r = await unary(c.health, 'Check', { service });
    assert.equal(r.status, 'SERVING', `service ${JSON.stringify(service)}`);
  }
  await expectCode(unary(c.health, 'Check', { service: 'no.such.Service' }), status.NOT_FOUND);
});

test('reflection: grpc.reflection.v1alpha lists the services and serves the proto', async () => {
  const s = openStream(c.reflection.ServerReflectionInfo());
  s.send({ list_services: '' });
  const listed = await s.next();
  assert.equal(listed.message_response, 'list_services_response');
  const names = listed.list_services_response.service.map((x) => x.name);
  for (const name of ['proxima.v1.Proximity', 'grpc.health.v1.Health', 'grpc.reflection.v1alpha.ServerReflection']) {
    assert.ok(names.includes(name), `${name} in ${names}`);
  }
  s.send({ file_containing_symbol: 'proxima.v1.Proximity' });
  const file = await s.next();
  assert.equal(file.message_response, 'file_descriptor_response');
  assert.ok(file.file_descriptor_response.file_descriptor_proto[0].includes('proxima/v1/proxima.proto'));
  assert.equal((await s.close()).code, status.OK);
  // Only v1alpha: the v1 service of newer gRPC releases is not there.
  const raw = new grpc.Client(daemon.address, grpc.credentials.createInsecure());
  const v1 = raw.makeBidiStreamRequest('/grpc.reflection.v1.ServerReflection/ServerReflectionInfo',
                                       () => Buffer.from([0x3a, 0]), (b) => b);  // list_services: ""
  const v1Status = new Promise((resolve) => v1.on('status', resolve));
  v1.on('error', () => {});
  v1.write({});
  v1.end();
  assert.equal((await v1Status).code, status.UNIMPLEMENTED);
  raw.close();
});

test('CreateScene, DescribeScene, Query: two unit boxes 0.5 apart, exact answers', async () => {
  const a = box([0, 0, 0], [1, 1, 1]);
  const b = box([1.5, 0, 0], [2.5, 1, 1]);
  const scene = await unary(c.proximity, 'CreateScene', { name: 'boxes', objects: [mesh('a', a), mesh('b', b)] });
  assert.match(scene.scene_id, /^[0-9a-f]{16}$/);
  assert.deepEqual(scene.objects.map((o) => [o.id, o.name, o.vertex_count, o.triangle_count]),
                   [['1', 'a', 8, 12], ['2', 'b', 8, 12]]);

  // Every query is off unless set: a Frame without queries answers no separation at all.
  const none = await unary(c.proximity, 'Query', { scene_id: scene.scene_id, frame: 7 });
  assert.equal(none.frame, '7');
  assert.deepEqual(none.object_ids, ['1', '2']);
  assert.equal(none.separation.length, 0);
  assert.equal(none.collisions.length, 0);

  const r = await unary(c.proximity, 'Query', { scene_id: scene.scene_id, queries: { separation: true, tolerance: 0.5 } });
  assert.equal(r.separation.length, 2);
  for (const [i, s] of r.separation.entries()) {
    assert.equal(s.has_other, true);
    assert.equal(s.other, 1 - i);
    assert.equal(s.distance, 0.5);
    assert.equal(Math.abs(s.point.x - s.other_point.x), 0.5);
  }
  assert.equal(r.separation[0].point.x, 1);
  assert.equal(r.separation[0].other_point.x, 1.5);
  assert.ok(r.tolerance.length > 0 && r.tolerance.every((p) => p.distance === 0.5 && p.object === 0 && p.other === 1));
  assert.equal(r.stats.culler.length > 0, true);

  // New positions by id, float32 this time: b moves 0.75 towards a and overlaps it by 0.25.
  const moved = shifted(b, [-0.75, 0, 0]);
  const hit = await unary(c.proximity, 'Query', {
    scene_id: scene.scene_id, frame: 1,
    positions: [{ object_id: '2', vertices: packVertices(moved.vertices, 'SCALAR_TYPE_FLOAT32') }],
    queries: { separation: true, collisions: true, penetration: true },
  });
  assert.equal(hit.separation[0].distance, 0);
  assert.equal(hit.collisions.length, 52, 'the page\'s C++ example: 52 colliding triangle pairs');
  assert.equal(hit.penetrations.length, 1);
  const p = hit.penetrations[0];
  assert.deepEqual([p.object, p.other, p.depth, p.isolated, p.closed], [0, 1, 0.25, true, true]);
  assert.deepEqual([p.direction.x, p.direction.y, p.direction.z], [-1, 0, 0]);

  const described = await unary(c.proximity, 'DescribeScene', { scene_id: scene.scene_id });
  assert.equal(described.frames, '3');
  assert.equal(described.triangle_count, '24');
  await unary(c.proximity, 'DeleteScene', { scene_id: scene.scene_id });
  await expectCode(unary(c.proximity, 'DescribeScene', { scene_id: scene.scene_id }), status.NOT_FOUND);
});

test('random scene: separation, self, collisions, tolerance and PNS equal a JavaScript brute force', async () => {
  const rand = mulberry32(20260118);
  const objects = Array.from({ length: 5 }, () => randomSoup(rand, 14, 1.2, 0.5));
  const scene = await unary(c.proximity, 'CreateScene', { objects: objects.map((m, i) => mesh(`o${i}`, m)) });
  // Every triangle pair, between objects and within each (no triangles are adjacent).
  const all = [];
  for (let i = 0; i < objects.length; ++i) {
    for (let j = i; j < objects.length; ++j) {
      objects[i].triangles.forEach((_, t) => objects[j].triangles.forEach((_, u) => {
        if (i === j && u <= t) return;
        all.push({ object: i, triangle: t, other: j, other_triangle: u, d: triangleDistance(corners(objects[i], t), corners(objects[j], u)) });
      }));
    }
  }
  const between = all.filter((p) => p.object !== p.other);
  const sorted = all.map((p) => p.d).filter((d) => d > 0).sort((x, y) => x - y);
  const k = Math.floor(sorted.length / 10);
  const tolerance = (sorted[k] + sorted[k + 1]) / 2;  // a gap: no pair within rounding of it
  assert.ok(sorted[k + 1] - sorted[k] > 1e-9);

  for (const culler of ['CULLER_AUTO', 'CULLER_BRUTE', 'CULLER_BVH', 'CULLER_VORONOI_CPU']) {
    const r = await unary(c.proximity, 'Query', {
      scene_id: scene.scene_id,
      queries: { separation: true, self: true, self_points: true, collisions: true, tolerance, pns: true, culler },
    });
    // Separation: per object the least distance to any other object, and the pair it names.
    objects.forEach((m, i) => {
      const mine = between.filter((p) => p.object === i || p.other === i);
      const best = Math.min(...mine.map((p) => p.d));
      const s = r.separation[i];
      close(s.distance, best, `${culler}: separation of object ${i}`);
      const o = objects[s.other];
      close(triangleDistance(corners(m, s.triangle), corners(o, s.other_triangle)), s.distance, `${culler}: its triangle pair`);
      close(dist([s.point.x, s.point.y, s.point.z], [s.other_point.x, s.other_point.y, s.other_point.z]), s.distance, `${culler}: its points`);
    });
    // Self: per triangle the closest other triangle of the same object (none are adjacent).
    objects.forEach((m, i) => {
      const self = r.self[i];
      assert.equal(self.distance.length, m.triangles.length);
      assert.equal(self.points.length, 6 * m.triangles.length);
      m.triangles.forEach((_, t) => {
        const ds = m.triangles.map((__, u) => (u === t ? Infinity : triangleDistance(corners(m, t), corners(m, u))));
        close(self.distance[t], Math.min(...ds), `${culler}: self distance of object ${i} triangle ${t}`);
        close(ds[Number(self.closest[t])], self.distance[t], `${culler}: its closest triangle`);
      });
    });
    // Collisions, tolerance: exactly the brute force's pair sets, within objects too.
    const touching = new Set(all.filter((p) => p.d === 0).map(pairKey));
    const within = new Set(all.filter((p) => p.d <= tolerance).map(pairKey));
    assert.ok(between.some((p) => p.d === 0), 'the random scene has intersecting objects');
    assert.ok(all.some((p) => p.d === 0 && p.object === p.other), 'and self-intersecting ones');
    assert.deepEqual(new Set(r.collisions.map(pairKey)), touching, `${culler}: collisions`);
    assert.deepEqual(new Set(r.tolerance.map(pairKey)), within, `${culler}: tolerance pairs`);
    const byKey = new Map(all.map((p) => [pairKey(p), p.d]));
    for (const p of r.tolerance) close(p.distance, byKey.get(pairKey(p)), `${culler}: tolerance distance`);
    // PNS: the culler's candidates, a superset of the tolerance pairs.
    const pns = new Set(r.pns.map(pairKey));
    for (const key of within) assert.ok(pns.has(key), `${culler}: PNS holds ${key}`);
  }
  await unary(c.proximity, 'DeleteScene', { scene_id: scene.scene_id });
});

test('UploadObject: header, vertex and index chunks; a short upload adds nothing', async () => {
  const scene = await unary(c.proximity, 'CreateScene', { objects: [mesh('a', box([0, 0, 0], [1, 1, 1]))] });
  const b = shifted(box([0, 0, 0], [1, 1, 1]), [0, 3, 0]);
  const v = packVertices(b.vertices).data;
  const ix = packTriangles(b.triangles);
  const upload = (chunks) => new Promise((resolve, reject) => {
    const call = c.proximity.UploadObject((err, res) => (err ? reject(err) : resolve(res)));
    for (const chunk of chunks) call.write(chunk);
    call.end();
  });
  const header = { scene_id: scene.scene_id, name: 'up', type: 'SCALAR_TYPE_FLOAT64', vertex_count: 8, triangle_count: 12 };
  const info = await upload([{ header }, { vertex_bytes: v.subarray(0, 100) }, { vertex_bytes: v.subarray(100) },
                             { index_bytes: ix.subarray(0, 7) }, { index_bytes: ix.subarray(7) }]);
  assert.deepEqual([info.id, info.name, info.vertex_count, info.triangle_count], ['2', 'up', 8, 12]);
  await expectCode(upload([{ header }, { vertex_bytes: v }, { index_bytes: ix.subarray(12) }]), status.INVALID_ARGUMENT);
  const described = await unary(c.proximity, 'DescribeScene', { scene_id: scene.scene_id });
  assert.deepEqual(described.objects.map((o) => o.name), ['a', 'up']);
  const r = await unary(c.proximity, 'Query', { scene_id: scene.scene_id, queries: { separation: true } });
  assert.equal(r.separation[0].distance, 2);
  await unary(c.proximity, 'DeleteScene', { scene_id: scene.scene_id });
});

test('StreamFrames: a stream-owned scene, ids in the first result, one scene per stream', async () => {
  const a = box([0, 0, 0], [1, 1, 1]);
  const b = box([1.5, 0, 0], [2.5, 1, 1]);
  const s = openStream(c.proximity.StreamFrames());
  s.send({ additions: [mesh('a', a), mesh('b', b)], queries: { separation: true } });
  const first = await s.next();
  assert.match(first.scene_id, /^[0-9a-f]{16}$/);
  assert.deepEqual(first.added_ids, ['1', '2']);
  assert.equal(first.separation[0].distance, 0.5);
  // Private to the stream.
  await expectCode(unary(c.proximity, 'DescribeScene', { scene_id: first.scene_id }), status.NOT_FOUND);
  // Pipelined: three frames sent before reading, answered in order; b closes in by 0.125 each.
  for (let k = 1; k <= 3; ++k) {
    s.send({ frame: k, positions: [{ object_id: first.added_ids[1], vertices: packVertices(shifted(b, [-0.125 * k, 0, 0]).vertices) }],
             queries: { separation: true } });
  }
  for (let k = 1; k <= 3; ++k) {
    const r = await s.next();
    assert.equal(r.frame, String(k));
    assert.equal(r.separation[0].distance, 0.5 - 0.125 * k);
  }
  // Unset queries: nothing computed.
  s.send({ frame: 4, scene_id: first.scene_id });
  assert.equal((await s.next()).separation.length, 0);
  // Another scene on the same stream: the stream ends with INVALID_ARGUMENT.
  const other = await unary(c.proximity, 'CreateScene', { objects: [mesh('x', a)] });
  s.send({ frame: 5, scene_id: other.scene_id, queries: { separation: true } });
  await expectCode(s.next(), status.INVALID_ARGUMENT);
  assert.equal((await s.finished).code, status.INVALID_ARGUMENT);
  await unary(c.proximity, 'DeleteScene', { scene_id: other.scene_id });
  // The owned scene went with its stream.
  for (let i = 0; i < 50; ++i) {
    const info = await unary(c.proximity, 'GetServerInfo', {});
    if (info.live_scenes === '0' && info.live_streams === '0') return;
    await new Promise((res) => setTimeout(res, 20));
  }
  assert.fail('the stream-owned scene outlived its stream');
});

test('StreamFrames on an existing scene; a bad frame ends the stream, earlier results come first', async () => {
  const scene = await unary(c.proximity, 'CreateScene', { objects: [mesh('a', box([0, 0, 0], [1, 1, 1])), mesh('b', box([2, 0, 0], [3, 1, 1]))] });
  const s = openStream(c.proximity.StreamFrames());
  s.send({ scene_id: scene.scene_id, frame: 1, queries: { separation: true } });
  s.send({ scene_id: scene.scene_id, frame: 2, positions: [{ object_id: '2', vertices: { type: 'SCALAR_TYPE_FLOAT64', data: Buffer.alloc(25) } }] });
  assert.equal((await s.next()).separation[0].distance, 1);
  await expectCode(s.next(), status.INVALID_ARGUMENT, /not a multiple of 24/);
  const described = await unary(c.proximity, 'DescribeScene', { scene_id: scene.scene_id });
  assert.equal(described.frames, '1', 'the rejected frame changed nothing');
  await unary(c.proximity, 'DeleteScene', { scene_id: scene.scene_id });
});

test('errors: NOT_FOUND, INVALID_ARGUMENT', async () => {
  await expectCode(unary(c.proximity, 'DescribeScene', { scene_id: 'abc' }), status.NOT_FOUND);
  await expectCode(unary(c.proximity, 'Query', { scene_id: 'abc' }), status.NOT_FOUND);
  await expectCode(unary(c.proximity, 'DeleteScene', { scene_id: 'abc' }), status.NOT_FOUND);
  const bad = { vertices: box([0, 0, 0], [1, 1, 1]).vertices, triangles: [[0, 1, 40]] };
  await expectCode(unary(c.proximity, 'CreateScene', { objects: [mesh('bad', bad)] }), status.INVALID_ARGUMENT, /vertex index 40/);
  const nan = { vertices: [[0, 0, 0], [1, NaN, 0], [0, 1, 0]], triangles: [[0, 1, 2]] };
  await expectCode(unary(c.proximity, 'CreateScene', { objects: [mesh('nan', nan)] }), status.INVALID_ARGUMENT, /non-finite/);
  await expectCode(unary(c.proximity, 'CreateScene', { objects: [{ name: 'untyped', vertices: { data: Buffer.alloc(24) }, indices: Buffer.alloc(0) }] }), status.INVALID_ARGUMENT);
  const scene = await unary(c.proximity, 'CreateScene', { objects: [mesh('a', box([0, 0, 0], [1, 1, 1]))] });
  await expectCode(unary(c.proximity, 'Query', { scene_id: scene.scene_id, queries: { tolerance: -1 } }), status.INVALID_ARGUMENT, /tolerance/);
  await expectCode(unary(c.proximity, 'Query', { scene_id: scene.scene_id, removals: ['42'] }), status.NOT_FOUND);
  await expectCode(unary(c.proximity, 'Query', { scene_id: scene.scene_id, additions: [mesh('b', box([2, 0, 0], [3, 1, 1]))], queries: { ccd: true } }), status.INVALID_ARGUMENT);
  assert.equal((await unary(c.proximity, 'DescribeScene', { scene_id: scene.scene_id })).objects.length, 1);
  await unary(c.proximity, 'DeleteScene', { scene_id: scene.scene_id });
  const models = await unary(c.proximity, 'ListModels', {});
  assert.deepEqual([models.models.length, models.models_dir], [0, '']);
  const verify = openStream(c.proximity.VerifyModel({ model: 'nope', tolerance: 0 }));
  await expectCode(verify.next(), status.NOT_FOUND);
  const region = openStream(c.proximity.FetchRegion({ model: 'nope', center: { x: 0, y: 0, z: 0 }, radius: 1 }));
  await expectCode(region.next(), status.NOT_FOUND);
});

test('deadline: a long query ends with DEADLINE_EXCEEDED and the daemon goes on', async () => {
  const rand = mulberry32(7);
  const big = randomSoup(rand, 20000, 0, 2);
  const scene = await unary(c.proximity, 'CreateScene', { objects: [mesh('big', big)] });
  const start = Date.now();
  await expectCode(unary(c.proximity, 'Query', { scene_id: scene.scene_id, queries: { self: true, culler: 'CULLER_BRUTE' } }, { deadline: 200 }),
                   status.DEADLINE_EXCEEDED);
  assert.ok(Date.now() - start < 5000);
  await unary(c.proximity, 'DeleteScene', { scene_id: scene.scene_id });
  // A cancelled stream: CANCELLED on the client, and the daemon frees it.
  const s = openStream(c.proximity.StreamFrames());
  s.send({ additions: [mesh('a', box([0, 0, 0], [1, 1, 1]))] });
  await s.next();
  s.call.cancel();
  assert.equal((await s.finished).code, status.CANCELLED);
});

test('message sizes: grpc-js refuses a result over its 4 MiB default, a raised limit takes it', async () => {
  // Two objects of 700 triangles each with every triangle pair within the tolerance: 979,300
  // FeaturePairs (700 x 700 between the objects, 2 x 700 x 699 / 2 within them), about 18 MB.
  const rand = mulberry32(11);
  const objects = [randomSoup(rand, 700, 0, 0.1), randomSoup(rand, 700, 0, 0.1)];
  const scene = await unary(c.proximity, 'CreateScene', { objects: objects.map((m, i) => mesh(`o${i}`, m)) });
  const frame = { scene_id: scene.scene_id, queries: { tolerance: 100 } };
  await expectCode(unary(c.proximity, 'Query', frame), status.RESOURCE_EXHAUSTED, /max/i);
  const raised = new proxima.Proximity(daemon.address, grpc.credentials.createInsecure(),
                                       { 'grpc.max_receive_message_length': 64 << 20 });
  const r = await unary(raised, 'Query', frame);
  assert.equal(r.tolerance.length, 700 * 700 + 700 * 699);
  raised.close();
  await unary(c.proximity, 'DeleteScene', { scene_id: scene.scene_id });

  // The daemon's own limit (--max-message-bytes), both directions.
  const small = await startDaemon('--max-message-bytes', '64K');
  const s = clientsFor(small.address);
  try {
    assert.equal((await unary(s.proximity, 'GetServerInfo', {})).limits.max_message_bytes, '65536');
    const tooBig = randomSoup(rand, 2000, 0, 1);  // 2000 x 84 bytes
    await expectCode(unary(s.proximity, 'CreateScene', { objects: [mesh('big', tooBig)] }), status.RESOURCE_EXHAUSTED);
    const two = await unary(s.proximity, 'CreateScene', { objects: [mesh('a', randomSoup(rand, 150, 0, 0.1)), mesh('b', randomSoup(rand, 150, 0, 0.1))] });
    await expectCode(unary(s.proximity, 'Query', { scene_id: two.scene_id, queries: { tolerance: 100 } }), status.RESOURCE_EXHAUSTED,
                     /over the limit max-message-bytes = 65536/);
  } finally {
    s.close();
    assert.equal(await small.stop(), 0);
  }
});

test('tokens: authorization metadata; health needs none', async () => {
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'proxima-grpcjs-'));
  const token = crypto.randomBytes(24).toString('hex');
  const file = path.join(dir, 'tokens.json');
  fs.writeFileSync(file, JSON.stringify({ tokens: [{ name: 'node', token, scenes: ['*'] }] }), { mode: 0o600 });
  const d = await startDaemon('--tokens', file);
  const t = clientsFor(d.address);
  try {
    await expectCode(unary(t.proximity, 'GetServerInfo', {}), status.UNAUTHENTICATED);
    const wrong = new grpc.Metadata();
    wrong.set('authorization', 'Bearer not-the-token-0123456789');
    await expectCode(unary(t.proximity, 'GetServerInfo', {}, { metadata: wrong }), status.UNAUTHENTICATED);
    const metadata = new grpc.Metadata();
    metadata.set('authorization', `Bearer ${token}`);
    assert.equal((await unary(t.proximity, 'GetServerInfo', {}, { metadata })).principal, 'node');
    assert.equal((await unary(t.health, 'Check', { service: '' })).status, 'SERVING');
  } finally {
    t.close();
    assert.equal(await d.stop(), 0);
    fs.rmSync(dir, { recursive: true, force: true });
  }
});

test("docs/api.md's grpc-js example runs as printed", async () => {
  const doc = fs.readFileSync(path.join(ROOT, 'docs', 'api.md'), 'utf8');
  const block = /```js\n([\s\S]*?)```/.exec(doc);
  assert.ok(block, 'docs/api.md has a ```js block');
  const script = `const address = ${JSON.stringify(daemon.address)};\n${block[1]}`;
  const out = await new Promise((resolve, reject) => {
    const child = spawn(process.execPath, ['-e', script], {
      cwd: ROOT, env: { ...process.env, NODE_PATH: path.join(__dirname, 'node_modules') },
      stdio: ['ignore', 'pipe', 'pipe'],
    });
    let stdout = '';
    let stderr = '';
    child.stdout.on('data', (d) => { stdout += d; });
    child.stderr.on('data', (d) => { stderr += d; });
    child.on('exit', (code) => (code === 0 ? resolve(stdout) : reject(new Error(`exit ${code}: ${stderr}`))));
  });
  assert.equal(out, 'distance 0.5\n');
});
