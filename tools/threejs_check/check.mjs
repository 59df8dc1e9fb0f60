// Does a capture2face .glb play in three.js? Serves this folder and the .glb on localhost,
// opens index.html in headless Chromium (playwright-core, WebGL on SwiftShader), where
// page.mjs loads it with GLTFLoader, plays its clip with an AnimationMixer, samples it and
// renders two frames. Prints one JSON line of findings; exit 0 only if every check passed.
//
//   node check.mjs PATH.glb [--expect JSON|FILE] [--screenshot OUT.png] [--no-render]
//                           [--chromium /usr/bin/chromium] [--timeout SECONDS]
//
// --expect: what capture2face says the file holds (tests/test_threejs_playback.py writes it):
//   {"morphs": 27, "joints": 28, "keyframes": 120, "duration": 3.9667, "clips": 1,
//    "tracks": {"position": 26, "quaternion": 3, "morphTargetInfluences": 1},
//    "eye_joints": ["eye_R", "eye_L"], "render_times": [t0, t1],
//    "vertex_ids": [...], "samples": [{"t": s, "morph": {name: w}, "bones_cm": {name: [x, y, z]},
//    "eyes_deg": [[yaw, pitch], [yaw, pitch]], "vertices_cm": [[x, y, z], ...]}, ...]}
import { createServer } from 'node:http';
import { mkdtempSync, readFileSync, rmSync, statSync, writeFileSync, existsSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, extname, join, resolve, sep } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const HERE = dirname(fileURLToPath(import.meta.url));
const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript', '.glb': 'model/gltf-binary' };

function parseArgs(argv) {
  const a = { glb: null, expect: {}, screenshot: null, render: true, chromium: '/usr/bin/chromium', timeout: 300 };
  for (let i = 0; i < argv.length; i++) {
    const k = argv[i];
    if (k === '--expect') { const v = argv[++i]; a.expect = JSON.parse(v.trim().startsWith('{') ? v : readFileSync(v, 'utf8')); }
    else if (k === '--screenshot') a.screenshot = argv[++i];
    else if (k === '--no-render') a.render = false;
    else if (k === '--chromium') a.chromium = argv[++i];
    else if (k === '--timeout') a.timeout = Number(argv[++i]);
    else if (!a.glb && !k.startsWith('--')) a.glb = k;
    else throw new Error(`unknown argument ${k}`);
  }
  if (!a.glb) throw new Error('usage: node check.mjs PATH.glb [--expect JSON|FILE] [--screenshot OUT.png] [--no-render]');
  if (!existsSync(a.glb) || !statSync(a.glb).isFile()) throw new Error(`${a.glb}: no such file`);
  if (!a.render) a.expect.render = false;
  return a;
}

// Only this folder's files (three from node_modules included) and the .glb as /model.glb.
function serve(glb) {
  const server = createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    const file = url === '/model.glb' ? glb : resolve(HERE, '.' + (url === '/' ? '/index.html' : url));
    if (file !== glb && !file.startsWith(HERE + sep)) { res.writeHead(403).end(); return; }
    let body;
    try { body = readFileSync(file); } catch { res.writeHead(404).end(); return; }
    res.writeHead(200, { 'Content-Type': TYPES[extname(file)] || 'application/octet-stream' }).end(body);
  });
  return new Promise((ok) => server.listen(0, '127.0.0.1', () => ok(server)));
}

async function main() {
  const args = parseArgs(process.argv.slice(2));
  const glb = resolve(args.glb);
  const server = await serve(glb);
  const profile = mkdtempSync(join(tmpdir(), 'threejs-check-'));
  const browserMessages = [];
  let findings;
  let context;
  try {
    context = await chromium.launchPersistentContext(profile, {
      executablePath: args.chromium,
      headless: true,
      args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
        '--disable-background-networking', '--disable-component-update', '--disable-sync',
        // WebGL without a GPU: ANGLE on SwiftShader (CPU).
        '--use-angle=swiftshader', '--use-gl=angle', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
      timeout: args.timeout * 1000,
    });
    const page = context.pages()[0] || await context.newPage();
    page.setDefaultTimeout(args.timeout * 1000);
    page.on('console', (m) => { if (m.type() === 'error' || m.type() === 'warning') browserMessages.push(`${m.type()}: ${m.text()}`); });
    page.on('pageerror', (e) => browserMessages.push(`pageerror: ${e.message}`));
    page.on('requestfailed', (r) => browserMessages.push(`requestfailed: ${r.url()}`));
    const t0 = Date.now();
    await page.goto(`http://127.0.0.1:${server.address().port}/index.html`);
    // A page that fails to load (a syntax error, a missing module) fails now, not at the timeout.
    const broken = new Promise((_, no) => page.once('pageerror', (e) => no(new Error(`page: ${e.message}`))));
    broken.catch(() => {}); // a page error after this point is reported, not thrown
    await Promise.race([page.waitForFunction(() => typeof window.runCheck === 'function'), broken]);
    findings = await page.evaluate((e) => window.runCheck(e), args.expect);
    findings.seconds = Number(((Date.now() - t0) / 1000).toFixed(2));
    findings.browser = context.browser() ? context.browser().version() : null;
  } catch (e) {
    findings = { failures: [`browser: ${e.message.split('\n')[0]}`] };
  } finally {
    if (context) await context.close().catch(() => {});
    server.close();
    rmSync(profile, { recursive: true, force: true });
  }
  if (findings.render && findings.render.png) {
    if (args.screenshot) {
      writeFileSync(args.screenshot, Buffer.from(findings.render.png.split(',')[1], 'base64'));
      findings.render.screenshot = resolve(args.screenshot);
    }
    delete findings.render.png;
  }
  // Page errors and failed requests fail the check; other browser console lines (GPU
  // notices from Chromium itself) are only reported.
  const bad = browserMessages.filter((m) => m.startsWith('pageerror') || m.startsWith('requestfailed'));
  findings.failures = [...(findings.failures || []), ...bad];
  findings.browser_messages = browserMessages;
  findings.glb = glb;
  findings.ok = findings.failures.length === 0;
  process.stdout.write(JSON.stringify(findings) + '\n');
  process.exit(findings.ok ? 0 : 1);
}

main().catch((e) => {
  process.stdout.write(JSON.stringify({ ok: false, failures: [String(e.message || e)] }) + '\n');
  process.exit(2);
});
