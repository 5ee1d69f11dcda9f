#!/usr/bin/env node
// The review page's gateway: one HTTP address that serves the built page (dist/, `vite build`)
// and a WebSocket endpoint (/ws) bridging the page's JSON messages to proximad's gRPC calls with
// @grpc/grpc-js (proto/proxima/v1/proxima.proto loaded by @grpc/proto-loader; no generated code,
// no hand-written HTTP/2). Browsers cannot speak gRPC; this process does it for them.
//
//   node clients/web/gateway.js --daemon 127.0.0.1:50051 [--listen 127.0.0.1:8080]
//        [--tls-ca ca.pem [--tls-cert me.pem --tls-key me.key]]
//        [--https-cert page.pem --https-key page.key | --allow-insecure] [--dist DIR]
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
                       '[--https-cert FILE --https-key FILE | --allow-insecure] [--dist DIR]\n');
  process.exit(2);
}

function parseArgs(argv) {
  const o = { listen: '127.0.0.1:8080', dist: path.join(HERE, 'dist') };
  const keys = { '--daemon': 'daemon', '--listen': 'listen', '--tls-ca': 'tlsCa',
                 '--tls-cert': 'tlsCert', '--tls-key': 'tlsKey', '--dist': 'dist',
                 '--https-cert': 'httpsCert', '--https-key': 'httpsKey' };
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

// --- one WebSocket: its token, its review stream, its region fetches ------------------------

function bridge(ws, client) {
  let metadata = null;  // set by hello
  let review = null;
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
        send({ type: 'hello', models: res.models.map((m) => ({
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
      review.on('data', (e) => send({ type: 'review', event: reviewEventToJson(e) }));
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
  wss.on('connection', (ws) => bridge(ws, client));
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
