// Every Kubernetes manifest in deploy/k8s validated offline against the Kubernetes API schema
// (the npm package kubernetes-models carries the OpenAPI schemas of every built-in kind; unknown
// fields and wrong types are errors), plus the project's own rules: a proximad pod's grace period
// outlasts its --drain-seconds, its probes are gRPC probes, it has requests and limits; a
// verification Job is Indexed and runs shard JOB_COMPLETION_INDEX of N = completions. Broken
// manifests (below) must fail, so the check itself is checked.
//
//   node tests/k8s/validate.js [DIR]     (default: deploy/k8s next to this repository's tests/)
'use strict';
const fs = require('fs');
const path = require('path');
const yaml = require('js-yaml');


function modelAndDeclaration(doc) {
  if (!doc || typeof doc.apiVersion !== 'string' || typeof doc.kind !== 'string') {
    throw new Error('not a Kubernetes object (no apiVersion and kind)');
  }
  const [group, version] = doc.apiVersion.includes('/') ? doc.apiVersion.split('/') : [null, doc.apiVersion];
  const module = path.posix.join('kubernetes-models', ...(group ? [group] : []), version, doc.kind);
  let models;
  try {
    models = require(module);
  } catch (e) {
    throw new Error(`unknown kind ${doc.apiVersion} ${doc.kind}`);
  }
  const Model = models[doc.kind] || models.default;
  if (!Model) throw new Error(`unknown kind ${doc.apiVersion} ${doc.kind}`);
  return { Model, dts: declarationOf(module) };
}

// The schemas that kubernetes-models validates with accept unknown fields (the API server drops
// them, or rejects them under strict field validation): the known fields of each object come
// from the package's type declarations (one interface per schema, a line per field).
const declared = new Map();
const declarationOf = (module) => require.resolve(module).replace(/\.js$/, '.d.ts');
function fieldsOf(dts) {
  if (declared.has(dts)) return declared.get(dts);
  const text = fs.readFileSync(dts, 'utf8');
  const imports = new Map();
  for (const m of text.matchAll(/^import \{ (\w+) \} from "([^"]+)";$/gm)) {
    const spec = m[2].startsWith('.') ? path.resolve(path.dirname(dts), m[2]) : m[2];
    imports.set(m[1], spec.startsWith('/') ? `${spec}.d.ts` : declarationOf(spec));
  }
  const body = text.match(/^export interface \w+(?: extends [\w, ]+)? \{\n([\s\S]*?)^\}/m);
  if (!body) throw new Error(`no interface in ${dts}`);
  const fields = new Map();
  for (const m of body[1].matchAll(/^ {4}"([^"]+)"\??: (.+?);?$/gm)) {
    const ref = m[2].match(/^(?:Array<)?(\w+)>?$/);
    fields.set(m[1], ref && imports.has(ref[1]) ? imports.get(ref[1]) : null);
  }
  declared.set(dts, fields);
  return fields;
}

function checkFields(value, dts, where) {
  if (Array.isArray(value)) {
    value.forEach((v, i) => checkFields(v, dts, `${where}[${i}]`));
    return;
  }
  if (!value || typeof value !== 'object') return;
  const fields = fieldsOf(dts);
  for (const [key, v] of Object.entries(value)) {
    if (!fields.has(key)) throw new Error(`${where}.${key}: unknown field`);
    if (fields.get(key)) checkFields(v, fields.get(key), `${where}.${key}`);
  }
}

// A verification Job (deploy/k8s/verify-job.yaml): Indexed, and its pod k runs shard k of N
// with N = completions, k from JOB_COMPLETION_INDEX (docs/massive.md, "Shards").
function verifyJobRules(doc) {
  const spec = doc.spec;
  if (spec.completionMode !== 'Indexed') {
    throw new Error(`a verification Job must be completionMode: Indexed (got ${spec.completionMode})`);
  }
  const containers = spec.template.spec.containers;
  const line = containers.map((c) => [...(c.command || []), ...(c.args || [])].join(' ')).join(' ');
  const shard = line.match(/--shard[ =]"?\$\{?JOB_COMPLETION_INDEX\}?\/(\d+)"?/);
  if (!shard) throw new Error('the verify container must pass --shard "${JOB_COMPLETION_INDEX}/N"');
  if (Number(shard[1]) !== spec.completions) {
    throw new Error(`--shard .../${shard[1]} but completions is ${spec.completions}: the shards would not cover the model`);
  }
  if (!/--out[ =]\S*\$\{?JOB_COMPLETION_INDEX/.test(line)) {
    throw new Error('each shard must write its own --out file (named by JOB_COMPLETION_INDEX)');
  }
}

function projectRules(doc) {
  if (doc.kind === 'Job' && /proxima verify/.test(JSON.stringify(doc.spec.template.spec.containers))) {
    verifyJobRules(doc);
  }
  const pod = ['StatefulSet', 'Deployment', 'Job'].includes(doc.kind) ? doc.spec.template.spec : null;
  if (!pod) return;
  for (const c of pod.containers) {
    if (!c.resources || !c.resources.requests || !c.resources.limits) {
      throw new Error(`container ${c.name}: requests and limits are required`);
    }
    const drainArg = (c.args || []).find((a) => a.startsWith('--drain-seconds='));
    if (c.name === 'proximad') {
      const drain = drainArg ? Number(drainArg.split('=')[1]) : 10;
      const grace = pod.terminationGracePeriodSeconds ?? 30;
      if (!(grace > drain)) {
        throw new Error(`terminationGracePeriodSeconds ${grace} must exceed --drain-seconds ${drain}`);
      }
      for (const probe of ['readinessProbe', 'livenessProbe']) {
        if (!c[probe] || !c[probe].grpc) throw new Error(`proximad: ${probe} must be a grpc probe`);
      }
    }
  }
}

function validateDoc(doc) {
  const { Model, dts } = modelAndDeclaration(doc);
  new Model(doc).validate();  // throws on a wrong type, a missing required field, a bad value
  checkFields(doc, dts, doc.kind);  // throws on an unknown field
  projectRules(doc);
}

function validateFile(file) {
  const docs = yaml.loadAll(fs.readFileSync(file, 'utf8')).filter((d) => d !== null);
  if (docs.length === 0) throw new Error(`${file}: no manifests`);
  docs.forEach((doc, i) => {
    try {
      validateDoc(doc);
    } catch (e) {
      throw new Error(`${file} document ${i + 1} (${doc && doc.kind}): ${e.message}`);
    }
  });
  return docs;
}

function mustFail(what, doc) {
  try {
    validateDoc(doc);
  } catch (e) {
    return;
  }
  throw new Error(`the validator accepted a broken manifest: ${what}`);
}

const dir = process.argv[2] || path.join(__dirname, '..', '..', 'deploy', 'k8s');
const files = fs.readdirSync(dir).filter((f) => /\.ya?ml$/.test(f)).sort();
if (files.length === 0) throw new Error(`no manifests in ${dir}`);
const all = [];
for (const f of files) {
  const docs = validateFile(path.join(dir, f));
  console.log(`ok ${f}: ${docs.map((d) => d.kind).join(', ')}`);
  all.push(...docs);
}
const kinds = new Set(all.map((d) => d.kind));
for (const k of ['StatefulSet', 'PodDisruptionBudget', 'Service', 'Deployment', 'ConfigMap', 'Job']) {
  if (!kinds.has(k)) throw new Error(`deploy/k8s has no ${k}`);
}

// Negative checks: each a copy of the real StatefulSet with one mistake.
const sts = all.find((d) => d.kind === 'StatefulSet');
const broken = (edit) => {
  const copy = JSON.parse(JSON.stringify(sts));
  edit(copy);
  return copy;
};
mustFail('a misspelled field (spec.replica)', broken((d) => { d.spec.replica = 3; }));
mustFail('a wrong type (replicas: "three")', broken((d) => { d.spec.replicas = 'three'; }));
mustFail('a probe with an unknown field', broken((d) => {
  d.spec.template.spec.containers[0].readinessProbe.grpc.path = '/healthz';
}));
mustFail('a missing required field (containers[0].name)', broken((d) => {
  delete d.spec.template.spec.containers[0].name;
}));
mustFail('an unknown kind', { apiVersion: 'apps/v1', kind: 'StatefulSetz', metadata: { name: 'x' } });
mustFail('a grace period shorter than the drain', broken((d) => {
  d.spec.template.spec.terminationGracePeriodSeconds = 5;
}));
// The verification Job, broken the same way.
const job = all.find((d) => d.kind === 'Job');
const brokenJob = (edit) => {
  const copy = JSON.parse(JSON.stringify(job));
  edit(copy);
  return copy;
};
mustFail('a verification Job that is not Indexed', brokenJob((d) => { d.spec.completionMode = 'NonIndexed'; }));
mustFail('a verification Job whose N is not its completions', brokenJob((d) => { d.spec.completions = 4; }));
mustFail('a verification Job without --shard', brokenJob((d) => {
  const c = d.spec.template.spec.containers[0];
  c.command = c.command.map((a) => a.replace(/--shard \S+/, ''));
}));
mustFail('a verification Job with an unknown field (spec.completionsMode)', brokenJob((d) => {
  d.spec.completionsMode = 'Indexed';
}));
console.log(`ok: ${all.length} manifests valid, 10 broken ones rejected`);
