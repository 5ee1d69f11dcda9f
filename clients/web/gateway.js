#!/usr/bin/env node
// The review page's gateway: one HTTP address that serves the built page (dist/, `vite build`)
// and a WebSocket endpoint (/ws) bridging the page's JSON messages to proximad's gRPC calls with
// @grpc/grpc-js (proto/proxima/v1/proxima.proto loaded by @grpc/proto-loader; no generated code,
// no hand-written HTTP/2). Browsers cannot speak gRPC; this process does it for them.
//
//   node clients/web/gateway.js --daemon 127.0.0.1:50051 [--listen 127.0.0.1:8080]
//        [--tls-ca ca.pem [--tls-cert me.pem --tls-key me.key]]
//        [--https-cert page.pem --https-key page.key | --allow-insecure] [--dist DIR]
//        [--recordings DIR]
//
// The first line on standard output is "listening on http://HOST:PORT/" (https with
// --https-cert; port 0 picks one). Tokens cross the page's connection, so an address beyond
// loopback needs --https-cert/--https-key (or an explicit --allow-insecure, e.g. behind a
// TLS-terminating proxy).
// The token: the page asks for it once and sends it in its first WebSocket message
// ({"type": "hello", "token": ...}); it is never in a URL. The gateway sends it to the daemon as
// the metadata `authorization: Bearer TOKEN` on every call of that socket, and never logs it.
//
// Messages (JSON, one per WebSocket message), page -> gateway:
//   {type: "hello", token}                        -> {type: "hello", models: [...]} or error
//   {type: "join", room, model, member, tolerance, nearest, avatar: {name, positions, indices}}
//   {type: "pose", sequence, m: [12 numbers]}
//   {type: "edit", sequence, move: {object, m}} | {add: {name, positions, indices}}
//                                                | {remove: {object}}
//   {type: "region", id, model, center: [x,y,z], radius, room, objects, max_triangles}
//   {type: "watch", recording, tolerance}  -> {type: "watch", frames, objects: [mesh...]}
//   {type: "frame", index}                 -> {type: "frame", index, positions, result}
// A recording (--recordings DIR: each subdirectory) is a folder of numbered .obj / .off files,
// one per frame, each connected component an object (as `proxima play --split-components`);
// watching it makes a scene on the daemon (deleted when the socket closes) and each frame asked
// for is one Query on it with the frame's positions (so frames may be visited in any order).
// gateway -> page: {type: "review", event: {...}} (the ReviewEvent, oneof name in `kind`),
//   {type: "region", id, piece | progress | summary}, {type: "error", call, code, message}.
// Mesh coordinates travel as base64 of little-endian float32 (positions) / uint32 (indices).
import fs from 'node:fs';
import http from 'node:http';
import https from 'node:https';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import grpc from '@grpc/grpc-js';
import protoLoader from '@grpc/proto-loader';
import { WebSocketServer } from 'ws';

const HERE = path.dirname(fileURLToPath(import.meta.url));
const PROTO = path.resolve(HERE, '..', '..', 'proto', 'proxima', 'v1', 'proxima.proto');
const LOAD_OPTIONS = { keepCase: true, longs: Number, enums: String, defaults: true, oneofs: true };

function usage(message) {
  process.stderr.write(`gateway: ${message}\nusage: node gateway.js --daemon HOST:PORT ` +
                       '[--listen HOST:PORT] [--tls-ca FILE [--tls-cert FILE --tls-key FILE]] ' +
                       '[--https-cert FILE --https-key FILE | --allow-insecure] [--dist DIR] ' +
                       '[--recordings DIR]\n');
  process.exit(2);
}

function parseArgs(argv) {
  const o = { listen: '127.0.0.1:8080', dist: path.join(HERE, 'dist') };
  const keys = { '--daemon': 'daemon', '--listen': 'listen', '--tls-ca': 'tlsCa',
                 '--tls-cert': 'tlsCert', '--tls-key': 'tlsKey', '--dist': 'dist',
                 '--https-cert': 'httpsCert', '--https-key': 'httpsKey', '--recordings': 'recordings' };
  for (let i = 0; i < argv.length; i += 2) {
    if (argv[i] === '--allow-insecure') {
      o.allowInsecure = true;
      i -= 1;
      continue;
    }
    const key = keys[argv[i]];
    if (!key) usage(`unknown option ${argv[i]}`);
    if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
    o[key] = argv[i + 1];
  }
  if (!o.daemon) usage('--daemon HOST:PORT is required');
  if (!!o.tlsCert !== !!o.tlsKey) usage('--tls-cert and --tls-key go together');
  if (o.tlsCert && !o.tlsCa) usage('--tls-cert needs --tls-ca');
  if (!!o.httpsCert !== !!o.httpsKey) usage('--https-cert and --https-key go together');
  const host = o.listen.slice(0, o.listen.lastIndexOf(':')).replace(/^\[|\]$/g, '');
  const loopback = ['127.0.0.1', '::1', 'localhost'].includes(host) || host.startsWith('127.');
  if (!loopback && !o.httpsCert && !o.allowInsecure) {
    usage(`--listen ${o.listen} is beyond loopback: tokens would cross it in the clear; ` +
          'give --https-cert and --https-key, or --allow-insecure behind a TLS proxy');
  }
  if (!/^[^:]+:\d+$/.test(o.listen) && !/^\[.*\]:\d+$/.test(o.listen)) {
    usage(`--listen must be HOST:PORT, got ${o.listen}`);
  }
  return o;
}

// --- conversions between the page's JSON and the proto messages ----------------------------

function meshToProto(mesh, field) {
  if (!mesh || !mesh.positions || !mesh.indices) throw new Error(`${field} needs positions and indices`);
  const pos = Buffer.from(mesh.positions, 'base64');
  const idx = Buffer.from(mesh.indices, 'base64');
  if (pos.length % 12 !== 0) throw new Error(`${field}.positions is not whole float32 vertices`);
  if (idx.length % 12 !== 0) throw new Error(`${field}.indices is not whole uint32 triangles`);
  return { name: String(mesh.name || ''),
           vertices: { type: 'SCALAR_TYPE_FLOAT32', data: pos }, indices: idx };
}

function meshFromProto(mesh) {
  let data = mesh.vertices ? mesh.vertices.data : Buffer.alloc(0);
  if (mesh.vertices && mesh.vertices.type === 'SCALAR_TYPE_FLOAT64') {
    const f = new Float32Array(data.length / 8);
    for (let i = 0; i < f.length; i++) f[i] = data.readDoubleLE(i * 8);
    data = Buffer.from(f.buffer);
  }
  return { name: mesh.name, positions: Buffer.from(data).toString('base64'),
           indices: Buffer.from(mesh.indices).toString('base64') };
}

const transformToProto = (m, field) => {
  if (!Array.isArray(m) || m.length !== 12 || !m.every(Number.isFinite)) {
    throw new Error(`${field} must be 12 finite numbers`);
  }
  return { m };
};

// ReviewEvent -> plain JSON (oneof name as `kind`, transforms as arrays).
function reviewEventToJson(e) {
  const kind = e.event;
  const body = JSON.parse(JSON.stringify(e[kind], (k, v) =>
    (v && typeof v === 'object' && Array.isArray(v.m) && Object.keys(v).length === 1 ? v.m : v)));
  return { kind, ...body };
}

// --- recordings: numbered mesh files, each connected component an object --------------------

function parseMeshFile(file) {
  const text = fs.readFileSync(file, 'utf8');
  const v = [];
  const t = [];
  if (file.endsWith('.off')) {
    const words = text.replace(/#.*$/gm, '').split(/\s+/).filter(Boolean);
    if (words[0] !== 'OFF') throw new Error(`${file}: not an OFF file`);
    const [nv, nf] = [Number(words[1]), Number(words[2])];
    let k = 4;
    for (let i = 0; i < 3 * nv; i++) v.push(Number(words[k++]));
    for (let f = 0; f < nf; f++) {
      const n = Number(words[k++]);
      const face = words.slice(k, k + n).map(Number);
      k += n;
      for (let i = 1; i + 1 < n; i++) t.push(face[0], face[i], face[i + 1]);
    }
  } else {
    for (const line of text.split('\n')) {
      const w = line.trim().split(/\s+/);
      if (w[0] === 'v') v.push(Number(w[1]), Number(w[2]), Number(w[3]));
      if (w[0] === 'f') {
        const face = w.slice(1).map((x) => Number(x.split('/')[0]) - 1);
        for (let i = 1; i + 1 < face.length; i++) t.push(face[0], face[i], face[i + 1]);
      }
    }
  }
  if (!v.every(Number.isFinite) || t.some((i) => !(i >= 0 && i < v.length / 3))) {
    throw new Error(`${file}: bad vertex or index`);
  }
  return { v, t };
}

// Connected components (triangles sharing a vertex), in the order of their first triangle; each
// with its vertices in first-use order and its triangles re-indexed.
function splitComponents({ v, t }) {
  const parent = Array.from({ length: v.length / 3 }, (_, i) => i);
  const find = (x) => { while (parent[x] !== x) x = parent[x] = parent[parent[x]]; return x; };
  for (let i = 0; i < t.length; i += 3) {
    parent[find(t[i + 1])] = find(t[i]);
    parent[find(t[i + 2])] = find(t[i]);
  }
  const comps = new Map();
  for (let i = 0; i < t.length; i += 3) {
    const root = find(t[i]);
    if (!comps.has(root)) comps.set(root, { map: new Map(), v: [], t: [] });
    const c = comps.get(root);
    for (const x of [t[i], t[i + 1], t[i + 2]]) {
      if (!c.map.has(x)) { c.map.set(x, c.v.length / 3); c.v.push(v[3 * x], v[3 * x + 1], v[3 * x + 2]); }
      c.t.push(c.map.get(x));
    }
  }
  return [...comps.values()].map((c) => ({ v: c.v, t: c.t }));
}

function readRecording(dir) {
  const natural = (a, b) => a.localeCompare(b, undefined, { numeric: true });
  const files = fs.readdirSync(dir).filter((f) => /\.(obj|off)$/.test(f)).sort(natural);
  if (!files.length) throw new Error(`recording ${path.basename(dir)} has no .obj / .off frames`);
  const frames = files.map((f) => splitComponents(parseMeshFile(path.join(dir, f))));
  for (let i = 1; i < frames.length; i++) {
    const same = frames[i].length === frames[0].length &&
      frames[i].every((c, k) => c.t.length === frames[0][k].t.length && c.t.every((x, j) => x === frames[0][k].t[j]));
    if (!same) throw new Error(`${files[i]}: its objects or triangles differ from ${files[0]}'s (the page plays moving vertices only)`);
  }
  return { files, frames };
}

const f32 = (a) => Buffer.from(new Float32Array(a).buffer);
const b64f32 = (a) => f32(a).toString('base64');
const b64u32 = (a) => Buffer.from(new Uint32Array(a).buffer).toString('base64');

// --- one WebSocket: its token, its review stream, its region fetches ------------------------

function bridge(ws, client, o) {
  let metadata = null;  // set by hello
  let review = null;
  let watch = null;     // {recording, scene, ids, tolerance}
  const regions = new Map();
  const send = (obj) => { if (ws.readyState === ws.OPEN) ws.send(JSON.stringify(obj)); };
  const fail = (call, err, extra = {}) => send({ type: 'error', call, ...extra,
    code: err.code !== undefined ? grpc.status[err.code] || String(err.code) : 'INVALID_ARGUMENT',
    message: err.details || err.message });

  const handlers = {
    hello(msg) {
      metadata = new grpc.Metadata();
      if (msg.token) metadata.set('authorization', `Bearer ${msg.token}`);
      client.ListModels({}, metadata, (err, res) => {
        if (err) {
          metadata = null;
          return fail('hello', err);
        }
        const recordings = o.recordings
          ? fs.readdirSync(o.recordings, { withFileTypes: true }).filter((e) => e.isDirectory()).map((e) => e.name).sort()
          : [];
        send({ type: 'hello', recordings, models: res.models.map((m) => ({
          name: m.name, objects: m.objects, triangles: m.triangles, generation: m.generation,
          box: m.box ? { lo: m.box.lo, hi: m.box.hi } : null })) });
      });
    },
    join(msg) {
      if (review) throw new Error('this socket already joined a room');
      const join = { room: String(msg.room || ''), model: String(msg.model || ''),
                     member: String(msg.member || ''), avatar: meshToProto(msg.avatar, 'avatar'),
                     tolerance: Number(msg.tolerance || 0), nearest: msg.nearest !== false };
      review = client.Review(metadata);
      // A `peers` message holds several updates: the page gets each as its own `peer` event.
      review.on('data', (e) => {
        const events = e.event === 'peers'
          ? e.peers.updates.map((peer) => ({ event: 'peer', peer }))
          : [e];
        for (const one of events) send({ type: 'review', event: reviewEventToJson(one) });
      });
      review.on('error', (err) => { fail('review', err); review = null; });
      review.on('end', () => { send({ type: 'review', event: { kind: 'end' } }); review = null; });
      review.write({ join });
    },
    pose(msg) {
      if (!review) throw new Error('pose before join');
      review.write({ pose: { sequence: Number(msg.sequence), transform: transformToProto(msg.m, 'pose.m') } });
    },
    edit(msg) {
      if (!review) throw new Error('edit before join');
      const edit = { sequence: Number(msg.sequence) };
      if (msg.move) {
        edit.move = { object: Number(msg.move.object), transform: transformToProto(msg.move.m, 'edit.move.m') };
      } else if (msg.add) {
        edit.add = meshToProto(msg.add, 'edit.add');
      } else if (msg.remove) {
        edit.remove = { object: Number(msg.remove.object) };
      } else {
        throw new Error('edit needs move, add or remove');
      }
      review.write({ edit });
    },
    watch(msg) {
      if (watch) throw new Error('this socket already watches a recording');
      const names = o.recordings ? fs.readdirSync(o.recordings) : [];
      if (!names.includes(String(msg.recording))) {
        throw new Error(`no recording ${JSON.stringify(msg.recording)} (have: ${names.join(', ') || 'none'})`);
      }
      const recording = readRecording(path.join(o.recordings, String(msg.recording)));
      const objects = recording.frames[0].map((c, k) => ({ name: `object-${k}`, positions: b64f32(c.v), indices: b64u32(c.t) }));
      watch = { recording, tolerance: Number(msg.tolerance || 0) };
      client.CreateScene({ name: `watch ${msg.recording}`, objects: objects.map((m) => meshToProto(m, 'object')) }, metadata, (err, info) => {
        if (err) { watch = null; return fail('watch', err); }
        watch.scene = info.scene_id;
        watch.ids = info.objects.map((x) => x.id);
        send({ type: 'watch', frames: recording.files.length, files: recording.files, objects });
      });
    },
    frame(msg) {
      if (!watch || !watch.scene) throw new Error('frame before watch');
      const index = Number(msg.index);
      const frame = watch.recording.frames[index];
      if (!frame) throw new Error(`frame ${msg.index} is not in 0..${watch.recording.frames.length - 1}`);
      const queries = { separation: true, collisions: true, penetration: true };
      if (watch.tolerance > 0) queries.tolerance = watch.tolerance;
      client.Query({ scene_id: watch.scene, frame: index, queries,
                     positions: frame.map((c, k) => ({ object_id: watch.ids[k], vertices: { type: 'SCALAR_TYPE_FLOAT32', data: f32(c.v) } })) },
                   metadata, (err, r) => {
        if (err) return fail('frame', err, { index });
        send({ type: 'frame', index, positions: frame.map((c) => b64f32(c.v)),
               result: { collisions: r.collisions, tolerance: r.tolerance, separation: r.separation,
                         penetrations: r.penetrations } });
      });
    },
    region(msg) {
      const c = msg.center || [0, 0, 0];
      const req = { model: String(msg.model || ''), center: { x: c[0], y: c[1], z: c[2] },
                    radius: Number(msg.radius || 0), room: String(msg.room || ''),
                    objects: (msg.objects || []).map(Number),
                    max_triangles: Number(msg.max_triangles || 0) };
      const id = msg.id;
      const call = client.FetchRegion(req, metadata);
      regions.set(id, call);
      call.on('data', (e) => {
        const ev = e[e.event];
        if (e.event === 'piece') {
          send({ type: 'region', id, piece: { object: ev.object, name: ev.object_name,
            mesh: meshFromProto(ev.mesh), triangle_ids: ev.triangle_ids, distance: ev.distance } });
        } else {
          send({ type: 'region', id, [e.event]: ev });
        }
      });
      call.on('error', (err) => { regions.delete(id); fail('region', err, { id }); });
      call.on('end', () => regions.delete(id));
    },
  };

  ws.on('message', (data) => {
    let msg;
    try {
      msg = JSON.parse(data.toString());
    } catch (e) {
      return fail('message', new Error(`not JSON: ${e.message}`));
    }
    if (msg.type !== 'hello' && !metadata) {
      return fail(msg.type || 'message', { code: grpc.status.UNAUTHENTICATED,
        details: 'send {"type": "hello", "token": ...} first' });
    }
    const h = Object.prototype.hasOwnProperty.call(handlers, msg.type) && handlers[msg.type];
    if (!h) return fail('message', new Error(`unknown message type ${JSON.stringify(msg.type)}`));
    try {
      h(msg);
    } catch (e) {
      fail(msg.type, e);
    }
  });
  ws.on('close', () => {
    if (review) review.end();
    if (watch && watch.scene) client.DeleteScene({ scene_id: watch.scene }, metadata, () => {});
    for (const call of regions.values()) call.cancel();
  });
}

// --- static files ------------------------------------------------------------------------

const TYPES = { '.html': 'text/html; charset=utf-8', '.js': 'text/javascript', '.css': 'text/css',
                '.png': 'image/png', '.svg': 'image/svg+xml', '.json': 'application/json' };

function serveStatic(dist, req, res) {
  const url = new URL(req.url, 'http://x');
  let file = path.normalize(path.join(dist, decodeURIComponent(url.pathname)));
  if (!file.startsWith(path.resolve(dist))) {
    res.writeHead(403).end();
    return;
  }
  if (url.pathname.endsWith('/')) file = path.join(file, 'index.html');
  fs.readFile(file, (err, body) => {
    if (err) {
      res.writeHead(404, { 'content-type': 'text/plain' }).end('not found\n');
      return;
    }
    res.writeHead(200, { 'content-type': TYPES[path.extname(file)] || 'application/octet-stream',
                         'cache-control': 'no-cache' }).end(body);
  });
}

export function startGateway(o) {
  const def = protoLoader.loadSync(PROTO, LOAD_OPTIONS);
  const proxima = grpc.loadPackageDefinition(def).proxima.v1;
  const creds = o.tlsCa
    ? grpc.credentials.createSsl(fs.readFileSync(o.tlsCa),
                                 o.tlsKey ? fs.readFileSync(o.tlsKey) : null,
                                 o.tlsCert ? fs.readFileSync(o.tlsCert) : null)
    : grpc.credentials.createInsecure();
  const client = new proxima.Proximity(o.daemon, creds,
    { 'grpc.max_receive_message_length': 256 << 20, 'grpc.max_send_message_length': 64 << 20 });
  if (!fs.existsSync(path.join(o.dist, 'index.html'))) {
    throw new Error(`${o.dist}/index.html is missing: run \`npx vite build\` in clients/web`);
  }
  const handler = (req, res) => serveStatic(o.dist, req, res);
  const server = o.httpsCert
    ? https.createServer({ cert: fs.readFileSync(o.httpsCert), key: fs.readFileSync(o.httpsKey) }, handler)
    : http.createServer(handler);
  const wss = new WebSocketServer({ server, path: '/ws', maxPayload: 64 << 20 });
  wss.on('connection', (ws) => bridge(ws, client, o));
  const sep = o.listen.lastIndexOf(':');
  const host = o.listen.slice(0, sep).replace(/^\[|\]$/g, '');
  return new Promise((resolve, reject) => {
    server.once('error', reject);
    server.listen(Number(o.listen.slice(sep + 1)), host, () => {
      const a = server.address();
      const shown = a.family === 'IPv6' ? `[${a.address}]` : a.address;
      resolve({ url: `${o.httpsCert ? 'https' : 'http'}://${shown}:${a.port}/`, close: () => { wss.close(); server.close(); client.close(); } });
    });
  });
}

if (process.argv[1] && path.resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
  const o = parseArgs(process.argv.slice(2));
  startGateway(o).then((g) => {
    process.stdout.write(`listening on ${g.url}\n`);
    const stop = () => { g.close(); process.exit(0); };
    process.on('SIGTERM', stop);
    process.on('SIGINT', stop);
  }, (e) => {
    process.stderr.write(`gateway: ${e.message}\n`);
    process.exit(1);
  });
}
