// The page side of check.mjs: load /model.glb with three's GLTFLoader, play its clip with an
// AnimationMixer, sample it, render two frames, and return findings (window.runCheck).
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

// three reports loader problems through console.warn / console.error: keep every one.
const messages = [];
for (const level of ['warn', 'error']) {
  const original = console[level].bind(console);
  console[level] = (...args) => { messages.push(`${level}: ${args.map(String).join(' ')}`); original(...args); };
}

const finite = (a) => Array.from(a).every(Number.isFinite);
const maxAbs = (a, b) => a.reduce((m, x, i) => Math.max(m, Math.abs(x - b[i])), 0);
const round = (x, d = 6) => Number(x.toFixed(d));

// Yaw, pitch (degrees) of a rotation's gaze, the convention of capture2face's
// eye_rotation: gaze = R (0, 0, 1); yaw = atan2(x, z), pitch = asin(-y).
function yawPitch(q) {
  const d = new THREE.Vector3(0, 0, 1).applyQuaternion(q);
  return [THREE.MathUtils.radToDeg(Math.atan2(d.x, d.z)), THREE.MathUtils.radToDeg(Math.asin(Math.max(-1, Math.min(1, -d.y))))];
}

function classify(track) {
  const property = track.name.slice(track.name.lastIndexOf('.') + 1);
  return property; // position | quaternion | scale | morphTargetInfluences
}

window.runCheck = async function runCheck(expected) {
  const failures = [];
  const fail = (msg) => failures.push(msg);
  const out = { three: THREE.REVISION, failures };

  let gltf;
  const t0 = performance.now();
  try {
    gltf = await new GLTFLoader().loadAsync('/model.glb');
  } catch (e) {
    fail(`GLTFLoader failed: ${e && e.message ? e.message : e}`);
    out.messages = messages;
    return out;
  }
  out.load_ms = Math.round(performance.now() - t0);
  const scene = gltf.scene;
  scene.updateMatrixWorld(true);

  // ---- what the loader built ----------------------------------------------------------
  const meshes = [], skinned = [], morphMeshes = [];
  scene.traverse((o) => {
    if (!o.isMesh) return;
    meshes.push(o);
    if (o.isSkinnedMesh) skinned.push(o);
    if (o.morphTargetInfluences && o.morphTargetInfluences.length) morphMeshes.push(o);
  });
  out.meshes = meshes.length;
  out.skinned_meshes = skinned.length;
  out.vertices = meshes.reduce((n, m) => n + m.geometry.attributes.position.count, 0);
  out.morph_meshes = morphMeshes.map((m) => ({ name: m.name, targets: m.morphTargetInfluences.length,
    named: Object.keys(m.morphTargetDictionary || {}).length }));
  out.morphs = morphMeshes.reduce((n, m) => n + m.morphTargetInfluences.length, 0);
  const skeleton = skinned.length ? skinned[0].skeleton : null;
  out.joints = skeleton ? skeleton.bones.length : 0;
  out.clips = gltf.animations.length;
  if (!gltf.animations.length) { fail('no animation clip'); out.messages = messages; return out; }
  const clip = gltf.animations[0];
  out.clip = clip.name;
  out.duration = round(clip.duration);
  out.tracks = {};
  for (const tr of clip.tracks) out.tracks[classify(tr)] = (out.tracks[classify(tr)] || 0) + 1;
  out.keyframes = Math.max(...clip.tracks.map((tr) => tr.times.length));
  out.track_values_finite = clip.tracks.every((tr) => finite(tr.values) && finite(tr.times));
  out.clip_valid = clip.validate();
  if (!out.track_values_finite) fail('a track has non-finite times or values');
  if (!out.clip_valid) fail('AnimationClip.validate() failed');

  // The frame the bones and eyes are measured in: the skeleton root (head coordinates),
  // whose rotation is the head's.
  const root = scene.getObjectByName(expected.root || 'capture2face_root') || (skeleton && skeleton.bones[0].parent) || scene;
  const eyeNames = expected.eye_joints || ['eye_R', 'eye_L'];
  const eyes = eyeNames.map((n) => scene.getObjectByName(n)).filter(Boolean);
  out.eye_joints = eyes.map((e) => e.name);
  const boneNames = skeleton ? skeleton.bones.map((b) => b.name).filter((n) => !eyeNames.includes(n)) : [];
  // Which object each track drives, found the way the mixer finds it (by node name).
  const target = (tr) => THREE.PropertyBinding.findNode(scene, THREE.PropertyBinding.parseTrackName(tr.name).nodeName);
  const unbound = clip.tracks.filter((tr) => !target(tr)).map((tr) => tr.name);
  if (unbound.length) fail(`tracks that find no node: ${unbound}`);
  // The nodes the clip turns (head root, eyes; a third-party character's head joint).
  const turned = clip.tracks.filter((tr) => classify(tr) === 'quaternion').map(target).filter(Boolean);
  out.turned = turned.map((o) => `${o.name} (${o.type})`);
  // Every 16th vertex of every mesh, for how far the surface moves (world space, cm).
  const everyNth = meshes.map((m) => Array.from({ length: Math.ceil(m.geometry.attributes.position.count / 16) }, (_, i) => i * 16));

  // ---- play it --------------------------------------------------------------------------
  const mixer = new THREE.AnimationMixer(scene);
  const action = mixer.clipAction(clip);
  action.setLoop(THREE.LoopOnce, 1);
  action.clampWhenFinished = true; // the last key stays instead of wrapping to the first
  const rootInv = new THREE.Matrix4();
  const v = new THREE.Vector3();
  const q = new THREE.Quaternion();
  const rootQ = new THREE.Quaternion();
  function setTime(t) {
    action.reset(); action.play();
    mixer.setTime(t);
    scene.updateMatrixWorld(true);
    rootInv.copy(root.matrixWorld).invert();
    root.getWorldQuaternion(rootQ);
  }
  function state(ids) {
    const s = { morph: morphMeshes.map((m) => Array.from(m.morphTargetInfluences)) };
    s.bones_cm = boneNames.map((n) => {
      const b = scene.getObjectByName(n);
      return b.getWorldPosition(v).applyMatrix4(rootInv).multiplyScalar(100).toArray();
    });
    s.eyes_deg = eyes.map((e) => yawPitch(e.getWorldQuaternion(q).premultiply(rootQ.clone().invert())));
    s.root_quat = root.quaternion.toArray();
    s.turned = turned.map((o) => o.quaternion.clone());
    s.surface_cm = meshes.map((m, j) => everyNth[j].map((i) => m.getVertexPosition(i, v).applyMatrix4(m.matrixWorld)
      .multiplyScalar(100).toArray())).flat(2);
    if (ids && skinned.length) {
      const m = skinned[0];
      s.vertices_cm = ids.map((i) => m.getVertexPosition(i, v).applyMatrix4(m.matrixWorld).applyMatrix4(rootInv)
        .multiplyScalar(100).toArray());
    }
    return s;
  }

  const frames = expected.keyframes || out.keyframes;
  const sampleTimes = (expected.samples || []).map((s) => s.t);
  if (!sampleTimes.length) for (const f of [0, 0.25, 0.5, 0.75, 1]) sampleTimes.push(f * clip.duration);
  const ids = expected.vertex_ids || null;
  const states = sampleTimes.map((t) => { setTime(t); return state(ids); });
  const flat = (s) => [...s.morph.flat(), ...s.bones_cm.flat(), ...s.eyes_deg.flat(), ...s.root_quat,
    ...(s.vertices_cm || []).flat(), ...s.surface_cm];
  out.samples = sampleTimes.length;
  out.sample_times = sampleTimes.map((t) => round(t, 4));
  out.all_finite = states.every((s) => finite(flat(s)));
  if (!out.all_finite) fail('non-finite morph influences, bone or eye transforms while playing');

  // How much each kind of value moves across the samples (the largest change from the first).
  const range = (get) => Math.max(0, ...states.map((s) => maxAbs(get(s), get(states[0]))));
  out.moved = {
    morph_influence: round(range((s) => s.morph.flat()), 4),
    bone_cm: round(range((s) => s.bones_cm.flat()), 4),
    eye_deg: round(range((s) => s.eyes_deg.flat()), 3),
    turn_deg: round(THREE.MathUtils.radToDeg(Math.max(0, ...states.flatMap((s) =>
      s.turned.map((qq, j) => qq.angleTo(states[0].turned[j]))))), 3),
    surface_cm: round(range((s) => s.surface_cm), 4),
  };
  if (states[0].vertices_cm) out.moved.vertex_cm = round(range((s) => s.vertices_cm.flat()), 4);
  if (out.morphs && !(out.moved.morph_influence > 0)) fail('morph influences do not change over time');
  if (out.tracks.position && !(out.moved.bone_cm > 0)) fail('bones do not move over time');
  if (turned.length && !(out.moved.turn_deg > 0)) fail('rotated nodes do not turn over time');
  if (!(out.moved.surface_cm > 0)) fail('the mesh surface does not move over time');
  if (eyes.length && !(out.moved.eye_deg > 0)) fail('eye joints do not turn over time');

  // ---- against what capture2face says -------------------------------------------------
  const counts = ['morphs', 'joints', 'skinned_meshes', 'clips', 'keyframes'];
  for (const k of counts) if (k in expected && expected[k] !== out[k]) fail(`${k}: three.js has ${out[k]}, expected ${expected[k]}`);
  if ('duration' in expected && Math.abs(expected.duration - clip.duration) > 1e-4)
    fail(`duration: three.js has ${clip.duration} s, expected ${expected.duration} s`);
  if (expected.tracks) for (const [k, n] of Object.entries(expected.tracks))
    if ((out.tracks[k] || 0) !== n) fail(`${k} tracks: three.js has ${out.tracks[k] || 0}, expected ${n}`);
  if (expected.eye_joints && out.eye_joints.length !== expected.eye_joints.length) fail(`eye joints: found ${out.eye_joints}`);
  if (expected.samples) {
    const err = { morph: 0, bone_cm: 0, eye_deg: 0, vertex_cm: 0 };
    expected.samples.forEach((e, i) => {
      const s = states[i];
      if (e.morph) { // {name: weight} on the first mesh with morphs
        const m = morphMeshes[0];
        for (const [name, w] of Object.entries(e.morph)) {
          const k = m.morphTargetDictionary[name];
          if (k === undefined) { fail(`morph ${name} missing from morphTargetDictionary`); continue; }
          err.morph = Math.max(err.morph, Math.abs(m.morphTargetInfluences.length ? s.morph[0][k] - w : w));
        }
      }
      if (e.bones_cm) for (const [name, p] of Object.entries(e.bones_cm)) {
        const k = boneNames.indexOf(name);
        if (k < 0) { fail(`bone ${name} missing`); continue; }
        err.bone_cm = Math.max(err.bone_cm, maxAbs(s.bones_cm[k], p));
      }
      if (e.eyes_deg) err.eye_deg = Math.max(err.eye_deg, maxAbs(s.eyes_deg.flat(), e.eyes_deg.flat()));
      if (e.vertices_cm) err.vertex_cm = Math.max(err.vertex_cm, maxAbs(s.vertices_cm.flat(), e.vertices_cm.flat()));
    });
    out.max_error = Object.fromEntries(Object.entries(err).map(([k, x]) => [k, Number(x.toPrecision(3))]));
    const tol = Object.assign({ morph: 1e-5, bone_cm: 1e-3, eye_deg: 1e-2, vertex_cm: 1e-3 }, expected.tolerance || {});
    for (const k of Object.keys(err)) if (!(err[k] <= tol[k])) fail(`${k} differs from capture2face by ${err[k]} (> ${tol[k]})`);
  }

  // ---- render two moments ------------------------------------------------------------
  if (expected.render !== false) {
    try { out.render = render(scene, setTime, expected.render_times || [0, clip.duration / 2], expected.render_size); } catch (e) {
      fail(`render failed: ${e && e.message ? e.message : e}`);
    }
    if (out.render) {
      if (out.render.drawn.some((n) => n < 0.02)) fail(`render: the head covers too little of a frame (${out.render.drawn})`);
      if (!(out.render.changed > 0)) fail('render: the two frames are identical');
    }
  }
  out.messages = messages;
  for (const m of messages) fail(`three.js ${m}`);
  return out;
};

// Renders the scene at two times side by side (S x S each) and measures the picture:
// the share of pixels the head covers in each half and the share that differ between them.
function render(scene, setTime, times, S = 384) {
  if (times.length !== 2) throw new Error('render_times: two times');
  const canvas = document.createElement('canvas');
  document.body.appendChild(canvas);
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(S * times.length, S, false);
  renderer.setClearColor(0x000000, 1);
  renderer.autoClear = false;
  renderer.clear();
  const gl = renderer.getContext();
  const dbg = gl.getExtension('WEBGL_debug_renderer_info');
  const info = { webgl: renderer.capabilities.isWebGL2 ? 2 : 1,
    gpu: dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER) };

  scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 1.5));
  const key = new THREE.DirectionalLight(0xffffff, 2.0);
  key.position.set(0.3, 0.5, 1.0);
  scene.add(key);
  setTime(times[0]);
  const box = new THREE.Box3().setFromObject(scene);
  const centre = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3());
  const camera = new THREE.PerspectiveCamera(30, 1, 0.01, 100);
  const dist = 0.6 * Math.max(size.x, size.y) / Math.tan(THREE.MathUtils.degToRad(15));
  camera.position.set(centre.x, centre.y, centre.z + dist);
  camera.lookAt(centre);
  times.forEach((t, i) => {
    setTime(t);
    renderer.setViewport(i * S, 0, S, S);
    renderer.setScissor(i * S, 0, S, S);
    renderer.setScissorTest(true);
    renderer.render(scene, camera);
  });
  // Read back through a 2D canvas (the drawing buffer is preserved).
  const c2 = document.createElement('canvas');
  c2.width = canvas.width; c2.height = canvas.height;
  const ctx = c2.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const px = ctx.getImageData(0, 0, c2.width, c2.height).data;
  const drawn = times.map(() => 0);
  let changed = 0;
  for (let y = 0; y < S; y++) for (let x = 0; x < S; x++) {
    const a = (y * c2.width + x) * 4, b = a + S * 4;
    if (px[a] + px[a + 1] + px[a + 2] > 24) drawn[0]++;
    if (px[b] + px[b + 1] + px[b + 2] > 24) drawn[1]++;
    if (Math.abs(px[a] - px[b]) + Math.abs(px[a + 1] - px[b + 1]) + Math.abs(px[a + 2] - px[b + 2]) > 24) changed++;
  }
  renderer.setScissorTest(false);
  return Object.assign(info, {
    times: times.map((t) => round(t, 4)), size: [canvas.width, canvas.height],
    drawn: drawn.map((n) => round(n / (S * S), 4)), changed: round(changed / (S * S), 4),
    png: canvas.toDataURL('image/png'),
  });
}
