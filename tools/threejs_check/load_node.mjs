// three.js GLTFLoader without a browser: parse a .glb (meshopt streams decoded by three's
// MeshoptDecoder; images replaced by empty textures, node has no image decoder), play its
// first clip with an AnimationMixer for T s (default 1); print one JSON line (morph influences
// per glTF node). Used by tests/test_real_files.py.
//   node load_node.mjs PATH.glb [T]
import { readFileSync } from 'node:fs';
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'three/examples/jsm/libs/meshopt_decoder.module.js';
globalThis.self = globalThis;
const file = process.argv[2];
const data = readFileSync(file);
const loader = new GLTFLoader();
loader.setMeshoptDecoder(MeshoptDecoder);
// No DOM: textures become empty Textures.
loader.register((parser) => { parser.loadTexture = async () => new THREE.Texture(); parser.loadImageSource = async () => new THREE.Texture(); return { name: 'notex' }; });
loader.parse(data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength), '', (gltf) => {
  let meshes = 0, morphs = 0;
  gltf.scene.traverse((o) => { if (o.isMesh) { meshes++; morphs += (o.morphTargetInfluences || []).length; } });
  const clip = gltf.animations[0];
  const mixer = new THREE.AnimationMixer(gltf.scene);
  mixer.clipAction(clip).play();
  mixer.update(Number(process.argv[3] ?? 1.0));
  // Influences per glTF node (a multi-primitive mesh is a group of three.js meshes).
  const weights = {};
  gltf.scene.traverse((o) => {
    if (!o.isMesh || !o.morphTargetInfluences) return;
    let n = o;
    while (n && !(gltf.parser.associations.get(n) || {}).hasOwnProperty('nodes')) n = n.parent;
    if (n) weights[gltf.parser.associations.get(n).nodes] = Array.from(o.morphTargetInfluences);
  });
  console.log(JSON.stringify({ file, meshes, morphs, clip: clip && clip.name, tracks: clip ? clip.tracks.length : 0,
    duration: clip && clip.duration, weights }));
}, (err) => { console.log(JSON.stringify({ file, error: String(err) })); process.exit(1); });
