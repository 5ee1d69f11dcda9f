// The review page (clients/web) in a real browser: playwright-core drives Debian's chromium
// (/usr/bin/chromium, headless, WebGL on SwiftShader) against a live proximad behind the gateway
// (clients/web/gateway.js). Two pages join one room on a small store made here; page A drags its
// avatar into an object with the mouse and page B sees the avatar move and turn red (state and
// pixels); clicking a triangle shows the object, triangle id and the daemon's closest pair and
// distance, checked against the daemon asked directly through grpc-js; screenshots are compared
// with a tolerance to tests/web/reference/*.png. A second daemon with a token file checks the
// token: a wrong one is refused, the right one joins, and it never appears in a URL. A third
// daemon with mutual TLS checks the gateway's --tls-ca / --tls-cert / --tls-key.
//
//   PROXIMAD=build/release/server/proximad PROXIMA=build/release/clients/cli/proxima \
//     node --test tests/web/review.test.mjs
//   UPDATE_REFERENCES=1 ... rewrites the reference screenshots (docs/review.md shows them).
//
// Needs clients/web/node_modules (`npm ci`) and clients/web/dist (`npx vite build`): both made by
// deploy/setup.sh; a dist/ older than the page's sources is rebuilt first.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { spawn, execFileSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { createRequire } from 'node:module';
import { fileURLToPath, pathToFileURL } from 'node:url';

const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..', '..');
const WEB = path.join(ROOT, 'clients', 'web');
const REFERENCES = path.join(ROOT, 'tests', 'web', 'reference');
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
for (const [what, file, hint] of [
  ['PROXIMAD', process.env.PROXIMAD, 'set PROXIMAD to the proximad binary'],
  ['PROXIMA', process.env.PROXIMA, 'set PROXIMA to the proxima CLI binary'],
  ['chromium', CHROMIUM, 'install Debian\'s chromium (deploy/setup.sh does)'],
  ['clients/web/node_modules', path.join(WEB, 'node_modules', 'playwright-core'), 'run deploy/setup.sh (npm ci in clients/web)'],
  ['clients/web/dist', path.join(WEB, 'dist', 'index.html'), 'run deploy/setup.sh (vite build in clients/web)'],
]) {
  if (!file || !fs.existsSync(file)) throw new Error(`tests/web: ${what} missing (${file}): ${hint}`);
}
// A page built before its sources last changed is rebuilt (vite from clients/web/node_modules).
{
  const built = fs.statSync(path.join(WEB, 'dist', 'index.html')).mtimeMs;
  const sources = [path.join(WEB, 'index.html'), path.join(WEB, 'vite.config.js'),
                   ...fs.readdirSync(path.join(WEB, 'src')).map((f) => path.join(WEB, 'src', f))];
  if (sources.some((f) => fs.statSync(f).mtimeMs > built)) {
    execFileSync(path.join(WEB, 'node_modules', '.bin', 'vite'), ['build', '--logLevel', 'warn'],
                 { cwd: WEB, stdio: ['ignore', 'inherit', 'inherit'], timeout: 120000 });
  }
}
const require = createRequire(path.join(WEB, 'package.json'));
const { chromium } = require('playwright-core');
const { PNG } = require('pngjs');
const grpc = require('@grpc/grpc-js');
const protoLoader = require('@grpc/proto-loader');
const pixelmatch = (await import(pathToFileURL(require.resolve('pixelmatch')).href)).default;
const { startGateway } = await import(pathToFileURL(path.join(WEB, 'gateway.js')).href);

const TOLERANCE = 0.5;
const TOKEN = 'right-token-0123456789';

// --- the model: three unit boxes in a row (OFF files, one object each) ---------------------

// Box i spans [x0, x0 + 1] x [0, 1] x [0, 1]; its 12 triangles in this order (ids 0..11):
// z=0 (0,1), z=1 (2,3), y=0 (4,5), y=1 (6,7), x=x0 (8,9), x=x0+1 (10,11).
function boxOff(x0) {
  const v = [];
  for (let i = 0; i < 8; i++) v.push([x0 + (i & 1 ? 1 : 0), i & 2 ? 1 : 0, i & 4 ? 1 : 0]);
  const f = [[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
             [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]];
  return `OFF\n8 12 0\n${v.map((p) => p.join(' ')).join('\n')}\n${f.map((t) => `3 ${t.join(' ')}`).join('\n')}\n`;
}
const BOX_X = [0, 3, 6];
const SLIDE_X = [2, 1.5, 1.25, 0.9];

let tmp;
let models;

function makeModels() {
  tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'proxima-web-'));
  const meshes = path.join(tmp, 'meshes');
  fs.mkdirSync(meshes);
  BOX_X.forEach((x, i) => fs.writeFileSync(path.join(meshes, `box-${i}.off`), boxOff(x)));
  // A recording: two unit boxes in each frame file (two components), the second at x = SLIDE_X[f]:
  // 1.0, 0.5 and 0.25 apart, then overlapping the first by 0.1.
  const rec = path.join(tmp, 'recordings', 'slide');
  fs.mkdirSync(rec, { recursive: true });
  SLIDE_X.forEach((x, f) => {
    const a = boxOff(0).split('\n');
    const b = boxOff(x).split('\n');
    const verts = [...a.slice(2, 10), ...b.slice(2, 10)];
    const faces = [...a.slice(10, 22), ...b.slice(10, 22).map((l) => l.replace(/\d+/g, (n, i) => (i === 0 ? n : String(Number(n) + 8))))];
    fs.writeFileSync(path.join(rec, `frame_${f}.off`), `OFF\n16 24 0\n${verts.join('\n')}\n${faces.join('\n')}\n`);
  });
  models = path.join(tmp, 'models');
  execFileSync(process.env.PROXIMA, ['import', '--store', path.join(models, 'row'), '--quiet', meshes],
               { stdio: ['ignore', 'pipe', 'pipe'], timeout: 60000 });
}

// --- processes -----------------------------------------------------------------------------

function startDaemon(...flags) {
  return new Promise((resolve, reject) => {
    const proc = spawn(process.env.PROXIMAD, ['--listen', '127.0.0.1:0', '--models', models,
                                              '--log-level', 'warn', ...flags],
                       { stdio: ['ignore', 'pipe', 'pipe'] });
    let out = '';
    let err = '';
    const timer = setTimeout(() => { proc.kill('SIGKILL'); reject(new Error(`proximad: no address; ${err}`)); }, 30000);
    proc.stderr.on('data', (d) => { err += d; });
    proc.on('exit', (code) => { clearTimeout(timer); reject(new Error(`proximad exited with ${code}: ${err}`)); });
    proc.stdout.on('data', (d) => {
      out += d;
      const m = /^listening on (\S+:\d+)\n/.exec(out);
      if (!m) return;
      clearTimeout(timer);
      proc.removeAllListeners('exit');
      resolve({ proc, address: m[1], stop: () => new Promise((res) => {
        if (proc.exitCode !== null) return res(proc.exitCode);
        proc.on('exit', (code) => res(code));
        proc.kill('SIGTERM');
      }) });
    });
  });
}

const daemons = [];
const gateways = [];
let browser;

async function serve(...flags) {
  const d = await startDaemon(...flags);
  daemons.push(d);
  const g = await startGateway({ daemon: d.address, listen: '127.0.0.1:0', dist: path.join(WEB, 'dist'),
                                 recordings: path.join(tmp, 'recordings') });
  gateways.push(g);
  return { daemon: d, url: g.url };
}

before(async () => {
  makeModels();
  browser = await chromium.launch({
    executablePath: CHROMIUM,
    args: ['--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist',
           '--no-sandbox', '--disable-dev-shm-usage', '--font-render-hinting=none'],
  });
});

after(async () => {
  if (browser) await browser.close();
  for (const g of gateways) g.close();
  for (const d of daemons) assert.equal(await d.stop(), 0, 'proximad exit status after SIGTERM');
  if (tmp) fs.rmSync(tmp, { recursive: true, force: true });
});

// --- page helpers --------------------------------------------------------------------------

async function openPage(url, { member, room, start, token = '' }) {
  // The TLS test's page certificate is signed by a CA made there, which chromium does not trust.
  const context = await browser.newContext({ viewport: { width: 800, height: 600 }, deviceScaleFactor: 1,
                                             ignoreHTTPSErrors: url.startsWith('https:') });
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  const q = new URLSearchParams({ model: 'row', room, member, start: start.join(','), tolerance: String(TOLERANCE) });
  await page.goto(`${url}?${q}`);
  await page.fill('#join [name=token]', token);
  await page.click('#join button[type=submit]');
  page.errors = errors;
  return page;
}

// Waits until the page joined and loaded its region; on a timeout, says what the page shows.
async function loaded(page) {
  try {
    await page.waitForFunction(() => window.__proxima.loaded === true, null, { timeout: 20000 });
  } catch (e) {
    const shown = await page.evaluate(() => JSON.stringify({ phase: window.__proxima.phase, error: window.__proxima.error,
      form: document.getElementById('join-error').textContent, status: document.getElementById('status').textContent }));
    throw new Error(`${e.message}; the page: ${shown}`);
  }
}
const proxima = (page, fn, arg) => page.evaluate(fn, arg);

// Waits until the page's state satisfies `fn` (evaluated in the page).
const until = (page, fn, arg, timeout = 15000) => page.waitForFunction(fn, arg, { timeout, polling: 50 });

function comparePng(name, actual) {
  const file = path.join(REFERENCES, `${name}.png`);
  if (process.env.UPDATE_REFERENCES === '1' || !fs.existsSync(file)) {
    if (process.env.UPDATE_REFERENCES !== '1') {
      throw new Error(`no reference ${file}: run with UPDATE_REFERENCES=1 and commit it`);
    }
    fs.mkdirSync(REFERENCES, { recursive: true });
    fs.writeFileSync(file, actual);
    return;
  }
  const a = PNG.sync.read(actual);
  const b = PNG.sync.read(fs.readFileSync(file));
  assert.deepEqual([a.width, a.height], [b.width, b.height], `${name}: size`);
  const diff = new PNG({ width: a.width, height: a.height });
  const bad = pixelmatch(a.data, b.data, diff.data, a.width, a.height, { threshold: 0.15 });
  const frac = bad / (a.width * a.height);
  if (frac > 0.01) {
    const out = path.join(os.tmpdir(), `proxima-web-${name}`);
    fs.writeFileSync(`${out}-actual.png`, actual);
    fs.writeFileSync(`${out}-diff.png`, PNG.sync.write(diff));
    assert.fail(`${name}: ${(frac * 100).toFixed(2)}% of the pixels differ from ${file} ` +
                `(more than 1%); see ${out}-actual.png and ${out}-diff.png`);
  }
}

// The daemon asked directly (grpc-js): a fresh room, the same avatar at the same pose.
function daemonAnswer(address, position) {
  const def = protoLoader.loadSync(path.join(ROOT, 'proto', 'proxima', 'v1', 'proxima.proto'),
    { keepCase: true, longs: Number, enums: String, defaults: true, oneofs: true });
  const pkg = grpc.loadPackageDefinition(def).proxima.v1;
  const client = new pkg.Proximity(address, grpc.credentials.createInsecure());
  const h = 0.5;
  const p = [];
  for (let i = 0; i < 8; i++) p.push(i & 1 ? h : -h, i & 2 ? h : -h, i & 4 ? h : -h);
  const idx = [0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
               2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5];
  return new Promise((resolve, reject) => {
    const call = client.Review();
    call.on('data', (e) => {
      if (e.event === 'joined') {
        call.write({ pose: { sequence: 1, transform: { m: [1, 0, 0, position[0], 0, 1, 0, position[1], 0, 0, 1, position[2]] } } });
      } else if (e.event === 'result') {
        call.end();
        client.close();
        resolve(e.result);
      }
    });
    call.on('error', reject);
    call.write({ join: { room: 'direct', model: 'row', member: 'grpcjs', tolerance: TOLERANCE, nearest: true,
      avatar: { name: 'avatar', vertices: { type: 'SCALAR_TYPE_FLOAT32', data: Buffer.from(new Float32Array(p).buffer) },
                indices: Buffer.from(new Uint32Array(idx).buffer) } } });
  });
}

// --- the tests -----------------------------------------------------------------------------

test('two pages in one room: drag into an object, the other sees it; pick a triangle', async (t) => {
  const { daemon, url } = await serve('--cache-bytes', String(1 << 20));
  const startA = [1.8, 0.4, 0.5];   // 0.3 from box 0, 0.7 from box 1: box 0 within the tolerance
  const a = await openPage(url, { member: 'ann', room: 'design', start: startA });
  await loaded(a);
  t.after(() => a.context().close());
  const b = await openPage(url, { member: 'bob', room: 'design', start: [4.5, 3, 0.5] });
  t.after(() => b.context().close());
  await loaded(b);
  for (const p of [a, b]) {
    const s = await proxima(p, () => ({ error: window.__proxima.error, region: window.__proxima.region }));
    assert.equal(s.error, null, 'no error on the page');
    assert.equal(s.region.done, true);
    assert.equal(s.region.triangles, 36, 'the three boxes (36 triangles) loaded from the daemon');
  }
  // B sees A at its start; A sees box 0 within the tolerance (amber).
  await until(b, () => window.__proxima.members.ann?.transform?.[3] === 1.8);
  await until(a, () => window.__proxima.lastResult?.sequence >= 1);
  const r0 = await proxima(a, () => window.__proxima.lastResult);
  assert.equal(r0.collisions.length, 0);
  assert.deepEqual(r0.within.map((h) => h.object), [0]);
  assert.ok(Math.abs(r0.within[0].distance - 0.3) < 1e-6, `distance ${r0.within[0].distance}`);
  assert.deepEqual((await proxima(a, () => window.__proxima.coloured)).amber, [{ object: 0, triangle: r0.within[0].object_triangle }]);

  // Click the top face of box 0 near (0.75, 0.75, 1): triangle 3 of box 0 (x + y > 1 half).
  const at = await proxima(a, () => window.__proxima.project(0.8, 0.8, 1));
  await a.mouse.click(at.x, at.y);
  const pick = await proxima(a, () => window.__proxima.pick);
  assert.equal(pick.object, 0);
  assert.equal(pick.name, r0.within[0].object_name);
  assert.equal(pick.triangle, 3);
  const direct = await daemonAnswer(daemon.address, startA);
  assert.equal(direct.within.length, 1);
  assert.equal(pick.pair.distance, direct.within[0].distance, 'the distance shown is the daemon\'s');
  assert.equal(pick.pair.object_triangle, direct.within[0].object_triangle);
  assert.equal(pick.pair.avatar_triangle, direct.within[0].avatar_triangle);
  const panel = await a.textContent('#pick');
  assert.ok(panel.includes(`object 0 (${r0.within[0].object_name})`), panel);
  assert.match(panel, /triangle 3\n/);
  assert.match(panel, new RegExp(`distance ${String(direct.within[0].distance).replace('.', '\\.')}`));
  // The amber triangle is amber on screen (its centre, unless the avatar hides it).
  comparePng('ann-start', await a.screenshot());

  // A drags its avatar (mouse) into box 1.
  const from = await proxima(a, () => window.__proxima.project(1.8, 0.4, 0.5));
  const to = await proxima(a, () => window.__proxima.project(2.7, 0.4, 0.5));
  await a.mouse.move(from.x, from.y);
  await a.mouse.down();
  for (let i = 1; i <= 10; i++) await a.mouse.move(from.x + ((to.x - from.x) * i) / 10, from.y + ((to.y - from.y) * i) / 10);
  await a.mouse.up();
  await until(a, () => window.__proxima.lastResult?.collisions?.length > 0 && !window.__proxima.pending);
  const r1 = await proxima(a, () => window.__proxima.lastResult);
  assert.deepEqual(r1.collisions.map((h) => h.object), [1]);
  const posA = await proxima(a, () => window.__proxima.members.ann.transform);
  assert.ok(posA[3] > 2.5 && posA[3] < 2.9, `ann dragged to x=${posA[3]}`);
  assert.deepEqual((await proxima(a, () => window.__proxima.coloured)).red,
                   [{ object: 1, triangle: r1.collisions[0].object_triangle }]);

  // B sees A's avatar move there and its collision: the avatar turns red, on screen too.
  await until(b, (x) => window.__proxima.members.ann?.transform?.[3] === x && window.__proxima.members.ann.colour === 'red', posA[3]);
  // A point of the avatar's front face (y = -0.5 from its centre) outside box 1 (x < 3).
  const centre = await proxima(b, (p) => window.__proxima.project(p[3] - 0.3, p[7] - 0.5, p[11]), posA);
  await b.waitForTimeout(100);
  const [r, g, bl] = await proxima(b, (c) => window.__proxima.pixel(c.x, c.y), centre);
  assert.ok(r > 120 && g < 80 && bl < 80, `B sees ann's avatar red at its centre, got rgb(${r}, ${g}, ${bl})`);
  comparePng('bob-sees-collision', await b.screenshot());

  // Keys move the own avatar too: A steps left (0.25), out of box 1; B sees it.
  await a.keyboard.press('ArrowLeft');
  await until(a, () => !window.__proxima.pending && window.__proxima.lastResult?.collisions?.length === 0);
  const posKey = await proxima(a, () => window.__proxima.members.ann.transform);
  assert.ok(Math.abs(posKey[3] - (posA[3] - 0.25)) < 1e-9, `ann at x=${posKey[3]} after ArrowLeft`);
  await until(b, (x) => window.__proxima.members.ann?.transform?.[3] === x && window.__proxima.members.ann.colour === 'amber', posKey[3]);

  // An edit by B appears for A: B deletes box 2 (picked by clicking it).
  const box2 = await proxima(b, () => window.__proxima.project(6.5, 0, 0.5));
  await b.mouse.click(box2.x, box2.y);
  assert.equal((await proxima(b, () => window.__proxima.pick)).object, 2);
  await b.click('#edit-delete');
  await until(a, () => window.__proxima.objects[2]?.deleted === true);
  await until(b, () => window.__proxima.objects[2]?.deleted === true);

  // B moves box 0 by +1 in x (picked, then its Move button): both pages show it moved.
  const box0 = await proxima(b, () => window.__proxima.project(0.5, 0, 0.5));
  await b.mouse.click(box0.x, box0.y);
  assert.equal((await proxima(b, () => window.__proxima.pick)).object, 0);
  await b.click('#edit-move');
  for (const p of [a, b]) {
    await until(p, () => window.__proxima.objects[0]?.currentT?.[3] === 1);
    assert.deepEqual(await proxima(p, () => window.__proxima.triangleCentre(0, 3)).then((c) => c.map((x) => +x.toFixed(4))),
                     [1 + 2 / 3, 2 / 3, 1].map((x) => +x.toFixed(4)), 'box 0 drawn where it moved');
  }

  // A adds a box next to its avatar: both pages fetch it from the daemon (FetchRegion, the room).
  await a.click('#edit-add');
  await until(a, () => window.__proxima.edits.length === 3);
  const added = (await proxima(a, () => window.__proxima.edits))[2];
  assert.equal(added.what, 'EDIT_ADD');
  for (const p of [a, b]) {
    await until(p, (o) => window.__proxima.objects[o]?.pieces?.length > 0, added.object);
    assert.equal(await proxima(p, (o) => window.__proxima.objects[o].pieces.reduce((n, x) => n + x.triangleIds.length, 0), added.object), 12);
  }
  assert.deepEqual(await proxima(b, () => window.__proxima.edits.map((e) => [e.member, e.what, e.object])),
                   [['bob', 'EDIT_DELETE', 2], ['bob', 'EDIT_MOVE', 0], ['ann', 'EDIT_ADD', added.object]]);

  // A third page that takes a name already in the room is refused: back to the form, which
  // gives the daemon's status and message; the room is unchanged.
  const c = await openPage(url, { member: 'ann', room: 'design', start: [0, 3, 0.5] });
  t.after(() => c.context().close());
  await until(c, () => window.__proxima.phase === 'form' && window.__proxima.error !== null);
  assert.match(await c.textContent('#join-error'), /FAILED_PRECONDITION.*already has a member named 'ann'/);
  assert.equal(await c.isVisible('#join'), true);
  assert.deepEqual(Object.keys(await proxima(b, () => window.__proxima.members)).sort(), ['ann', 'bob']);
  assert.deepEqual(a.errors, []);
  assert.deepEqual(b.errors, []);
  assert.deepEqual(c.errors, []);
});

test('token: a wrong one is refused, the right one joins; never in a URL', async () => {
  const tokens = path.join(tmp, 'tokens.json');
  fs.writeFileSync(tokens, JSON.stringify({ tokens: [{ name: 'reviewer', token: TOKEN, rooms: ['*'], models: ['*'] }] }));
  const { url } = await serve('--tokens', tokens);
  const wrong = await openPage(url, { member: 'eve', room: 'secure', start: [1.8, 0.5, 0.5], token: 'wrong-token-0123456789' });
  await until(wrong, () => window.__proxima.error !== null);
  assert.match(await wrong.textContent('#join-error'), /UNAUTHENTICATED/);
  assert.equal(await wrong.isVisible('#join'), true, 'the join form stays');
  await wrong.context().close();
  const right = await openPage(url, { member: 'ann', room: 'secure', start: [1.8, 0.5, 0.5], token: TOKEN });
  await loaded(right);
  assert.equal(await proxima(right, () => window.__proxima.error), null);
  assert.equal(await proxima(right, () => window.__proxima.region.triangles), 36);
  assert.ok(!right.url().includes(TOKEN), 'the token is not in the URL');
  await right.context().close();
});

test('TLS: the gateway reaches a mutual-TLS daemon with its CA and client certificate, serves HTTPS', async () => {
  const pki = path.join(tmp, 'pki');
  fs.mkdirSync(pki);
  const f = (name) => path.join(pki, name);
  const openssl = (...args) => execFileSync('openssl', args, { stdio: ['ignore', 'pipe', 'pipe'] });
  const key = ['-newkey', 'ec', '-pkeyopt', 'ec_paramgen_curve:prime256v1', '-nodes'];
  openssl('req', '-x509', ...key, '-keyout', f('ca.key'), '-out', f('ca.crt'), '-days', '2', '-subj', '/CN=proxima web test ca');
  fs.writeFileSync(f('san.ext'), 'subjectAltName=IP:127.0.0.1,DNS:localhost\n');
  for (const who of ['server', 'client']) {
    openssl('req', ...key, '-keyout', f(`${who}.key`), '-out', f(`${who}.csr`), '-subj', `/CN=proxima web test ${who}`);
    openssl('x509', '-req', '-in', f(`${who}.csr`), '-CA', f('ca.crt'), '-CAkey', f('ca.key'), '-CAcreateserial',
            '-out', f(`${who}.crt`), '-days', '2', ...(who === 'server' ? ['-extfile', f('san.ext')] : []));
  }
  const d = await startDaemon('--tls-cert', f('server.crt'), '--tls-key', f('server.key'), '--tls-client-ca', f('ca.crt'));
  daemons.push(d);
  // Without a client certificate the daemon refuses the connection: the form says so.
  const bare = await startGateway({ daemon: d.address, listen: '127.0.0.1:0', dist: path.join(WEB, 'dist'), tlsCa: f('ca.crt') });
  gateways.push(bare);
  const refused = await openPage(bare.url, { member: 'eve', room: 'tls', start: [1.8, 0.4, 0.5] });
  await until(refused, () => window.__proxima.error !== null, undefined, 30000);
  assert.match(await refused.textContent('#join-error'), /UNAVAILABLE/);
  await refused.context().close();
  // This one also serves the page over HTTPS (the WebSocket is then wss:).
  const g = await startGateway({ daemon: d.address, listen: '127.0.0.1:0', dist: path.join(WEB, 'dist'),
                                 tlsCa: f('ca.crt'), tlsCert: f('client.crt'), tlsKey: f('client.key'),
                                 httpsCert: f('server.crt'), httpsKey: f('server.key') });
  gateways.push(g);
  assert.match(g.url, /^https:\/\/127\.0\.0\.1:\d+\/$/);
  const page = await openPage(g.url, { member: 'ann', room: 'tls', start: [1.8, 0.4, 0.5] });
  await loaded(page);
  assert.equal(await proxima(page, () => window.__proxima.error), null);
  assert.equal(await proxima(page, () => window.__proxima.region.triangles), 36);
  await until(page, () => window.__proxima.lastResult?.within?.length === 1);
  await page.context().close();

  // The command line: beyond loopback without HTTPS is refused, naming the reason.
  const cli = spawn(process.execPath, [path.join(WEB, 'gateway.js'), '--daemon', d.address, '--listen', '0.0.0.0:0'],
                    { stdio: ['ignore', 'pipe', 'pipe'] });
  let err = '';
  cli.stderr.on('data', (x) => { err += x; });
  const code = await new Promise((res) => cli.on('exit', res));
  assert.equal(code, 2);
  assert.match(err, /beyond loopback: tokens would cross it in the clear/);
});

test('watch a recorded scene stream: timeline, colours, penetration arrows', async () => {
  const { url } = await serve();
  const context = await browser.newContext({ viewport: { width: 800, height: 600 }, deviceScaleFactor: 1 });
  const w = await context.newPage();
  const errors = [];
  w.on('pageerror', (e) => errors.push(e.message));
  await w.goto(`${url}?recording=slide&tolerance=0.5`);
  await w.click('#join button[type=submit]');
  await loaded(w);
  await until(w, () => window.__proxima.watch.index === 0);
  const at = (p) => proxima(p, () => {
    const x = window.__proxima.watch;
    return { index: x.index, frames: x.frames, segments: x.segments, arrows: x.arrows, colours: Object.values(x.colours),
             sep: x.result.separation.map((s) => s.distance), collisions: x.result.collisions.length,
             tolerance: x.result.tolerance.map((p) => p.distance) };
  });
  let s = await at(w);
  assert.equal(s.frames, 4);
  assert.deepEqual(s.sep, [1, 1]);
  assert.equal(s.segments, 1);
  assert.deepEqual(s.tolerance, [], '1.0 apart: nothing within 0.5 (non-adjacent triangles of one box are 0.577 apart)');
  // Step forward twice (the button, then the key): 0.25 apart, triangles coloured by distance.
  await w.click('#tl-fwd');
  await until(w, () => window.__proxima.watch.index === 1);
  await w.keyboard.press('ArrowRight');
  await until(w, () => window.__proxima.watch.index === 2);
  s = await at(w);
  assert.deepEqual(s.sep, [0.25, 0.25]);
  assert.ok(s.tolerance.length > 0 && s.tolerance.every((d) => d === 0.25), `tolerance pairs ${s.tolerance}`);
  assert.ok(s.colours.length > 0 && s.colours.every((c) => c === 'map'));
  assert.equal(s.collisions, 0);
  assert.equal(await w.textContent('#labels'), '0.2500');
  // Play: on to the last frame, then it pauses by itself; the overlap is red with an arrow.
  await w.click('#tl-play');
  await until(w, () => window.__proxima.watch.index === 3 && !window.__proxima.watch.playing);
  s = await at(w);
  assert.ok(s.collisions > 0);
  assert.ok(s.colours.includes('red'));
  assert.ok(s.arrows >= 1, 'a penetration arrow');
  assert.equal(s.segments, 0);
  assert.equal(await w.textContent('#tl-play'), 'play');
  comparePng('watch-overlap', await w.screenshot());
  // Step back (the button) to frame 2 again: the same answer as before.
  await w.click('#tl-back');
  await until(w, () => window.__proxima.watch.index === 2);
  assert.deepEqual((await at(w)).sep, [0.25, 0.25]);
  assert.deepEqual(errors, []);
  await context.close();
});
