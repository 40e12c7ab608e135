// The hack-render viewer: an exported person (glTF) with sliders for the expressions, the
// 8 neck joints, the larynx and the animation's timeline. The pose-corrective morph
// targets follow the joints as in the model: weight = (R - I) of each joint's rotation
// (times its gate in a gated model).
// URL parameters (used by the tests): ?set=NAME:VALUE,... sets sliders (expression names,
// JOINT.x|y|z in degrees, larynx.size, larynx.slide_mm), ?frame=K selects a frame, and
// ?dump=weights writes the morph weights, once the sliders are applied, as JSON into
// <pre id="dump"> (tests/test_export_viewer.py compares them with the exporter's).
import * as THREE from 'three-bundle';

const status = document.getElementById('status');
const view = document.getElementById('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.toneMapping = THREE.ACESFilmicToneMapping;
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x3a3a3a);
const pmrem = new THREE.PMREMGenerator(renderer);
scene.environment = pmrem.fromScene(new THREE.RoomEnvironment(), 0.04).texture;
const key = new THREE.DirectionalLight(0xffffff, 1.5);
key.position.set(0.5, 0.6, 1.0);
scene.add(key);
const camera = new THREE.PerspectiveCamera(20, 1, 0.01, 10);
const controls = new THREE.OrbitControls(camera, renderer.domElement);

let meshes = [], bones = {}, hack = {}, names = [], mixer = null, action = null, clip = null;
const sliders = {};   // id -> input element
const state = { weights: null, joints: {}, size: 0, slide_mm: 0 };

function resize() {
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h); camera.aspect = w / h; camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);

function row(parent, id, label, min, max, step, value, onInput) {
  const div = document.createElement('div'); div.className = 'row';
  const lab = document.createElement('label'); lab.textContent = label; lab.title = label;
  const inp = document.createElement('input');
  Object.assign(inp, { type: 'range', min, max, step, value, id: 's_' + id });
  const out = document.createElement('output'); out.textContent = (+value).toFixed(2);
  inp.addEventListener('input', () => { out.textContent = (+inp.value).toFixed(2); onInput(+inp.value); });
  div.append(lab, inp, out); parent.appendChild(div);
  sliders[id] = inp;
  return inp;
}

function stopClip() {
  if (action && action.isRunning()) { action.stop(); document.getElementById('play').textContent = 'play'; }
  if (action) action.stop();
}

function slideWeights(tau) {   // linear interpolation between the in-between targets
  const grid = hack.larynx_slide_m || [];
  const full = [...grid, 0].sort((a, b) => a - b);
  const t = Math.min(Math.max(tau, full[0]), full[full.length - 1]);
  const w = new Array(grid.length).fill(0);
  for (let j = 0; j < full.length - 1; j++) {
    if (t >= full[j] && t <= full[j + 1]) {
      const a = (t - full[j]) / (full[j + 1] - full[j]);
      const i0 = grid.indexOf(full[j]), i1 = grid.indexOf(full[j + 1]);
      if (i0 >= 0) w[i0] = 1 - a;
      if (i1 >= 0) w[i1] = a;
      break;
    }
  }
  return w;
}

function applySliders() {   // sliders -> bones and morph weights
  const s = hack.target_slots;
  const w = state.weights;
  if (s.larynx_size) w[s.larynx_size[0]] = state.size;
  if (s.larynx_slide) slideWeights(state.slide_mm / 1000).forEach((v, i) => { w[s.larynx_slide[0] + i] = v; });
  for (const [name, e] of Object.entries(state.joints)) {
    const b = bones[name];
    if (b) b.quaternion.setFromEuler(new THREE.Euler(...e.map(THREE.MathUtils.degToRad), 'XZY'));
  }
  for (const m of meshes) m.morphTargetInfluences.splice(0, w.length, ...w);
}

function correctives() {   // pose-corrective weights from the joints' current rotations
  const s = hack.target_slots;
  flexWeights();
  if (!s.pose || s.pose[1] <= s.pose[0]) return;
  const feat = [];
  // a gated model (pose_gate_deg): each joint's block times g = u^2 / (u^2 + c^4),
  // u = s + l |n|^2, s = 3 - trace R, n the sum of the joints' axial vectors (R - R^T) / 2
  // and l = pose_gate_chain (geometry.lbs.pose_gate); ungated: g = 1
  const c4 = hack.pose_gate_deg == null ? null : Math.pow(THREE.MathUtils.degToRad(hack.pose_gate_deg), 4);
  const chain = hack.pose_gate_chain || 0;
  const mats = hack.joints.map((name) => new THREE.Matrix4().makeRotationFromQuaternion(bones[name].quaternion).elements);
  const n = [0, 0, 0];
  for (const e of mats) {  // column-major: R[r][c] = e[4 c + r]
    n[0] += 0.5 * (e[6] - e[9]); n[1] += 0.5 * (e[8] - e[2]); n[2] += 0.5 * (e[1] - e[4]);
  }
  const net = chain * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  mats.forEach((e, j) => {
    const t = 3 - (e[0] + e[5] + e[10]) + net;  // 2 (1 - cos angle) + l |n|^2
    const g = c4 == null ? 1 : t * t / (t * t + c4);
    for (let r = 0; r < 3; r++) for (let c = 0; c < 3; c++) feat[9 * j + 3 * r + c] = g * (e[c * 4 + r] - (r === c ? 1 : 0));
  });
  // each feature's target split by sign: weight = max(sign * feature, 0)
  hack.pose_targets.forEach(([f, sign], i) => {
    const v = Math.max(sign * feat[f], 0);
    for (const mesh of meshes) mesh.morphTargetInfluences[s.pose[0] + i] = v;
  });
}

function flexWeights() {   // the flexion block (format 5; geometry.flex_block): its hats
  const f = hack.flex, s = hack.target_slots;
  if (!f || !s.flex) return;
  // phi: axis-angle of the joints' net rotation R_1 R_2 ... R_8 (the head against the thorax)
  const q = new THREE.Quaternion();
  for (const name of hack.joints) q.multiply(bones[name].quaternion);
  const sg = q.w < 0 ? -1 : 1;
  const x = sg * q.x, y = sg * q.y, z = sg * q.z, w = sg * q.w;
  const sn = Math.sqrt(x * x + y * y + z * z);
  const k = sn > 1e-12 ? 2 * Math.atan2(sn, w) / sn : 2 / w;
  const phi = [k * x, k * y, k * z];
  const rad = THREE.MathUtils.degToRad;
  let purity = Math.exp(-(phi[1] * phi[1] + phi[2] * phi[2]) / Math.pow(rad(f.purity_deg), 2));
  if (f.coherence) {  // c = |sum a_k| / sum |a_k|, a_k = x of (R_k - R_k^T) / 2 = 2 w x
    let sum = 0, abs = 0;
    for (const name of hack.joints) {
      const b = bones[name].quaternion, a = 2 * b.w * b.x;
      sum += a; abs += Math.abs(a);
    }
    purity *= Math.pow(Math.abs(sum) / (abs + 1e-9), f.coherence);
  }
  f.knots_deg.forEach((knot, i) => {
    const v = Math.max(0, 1 - Math.abs(phi[0] - rad(knot)) / rad(f.width_deg)) * purity;
    for (const mesh of meshes) mesh.morphTargetInfluences[s.flex[0] + i] = v;
  });
}

function buildPanel() {
  const ex = document.getElementById('expressions');
  const ne = hack.target_slots.expression[1];
  for (let i = 0; i < ne; i++) {
    row(ex, names[i], names[i], 0, 1, 0.01, state.weights[i], (v) => { stopClip(); state.weights[i] = v; applySliders(); });
  }
  const jp = document.getElementById('joints');
  const axes = ['x', 'y', 'z'], axisName = { x: 'flexion', y: 'axial', z: 'lateral' };
  hack.joints.forEach((name, j) => {
    const lim = hack.joint_limits_deg[j];
    const e = new THREE.Euler().setFromQuaternion(bones[name].quaternion, 'XZY');
    state.joints[name] = [e.x, e.y, e.z].map(THREE.MathUtils.radToDeg);
    axes.forEach((a, k) => row(jp, `${name}.${a}`, `${name} ${axisName[a]}`, lim[k][0], lim[k][1], 0.1,
      state.joints[name][k], (v) => { stopClip(); state.joints[name][k] = v; applySliders(); }));
  });
  const lp = document.getElementById('larynx');
  const grid = hack.larynx_slide_m || [];
  if (hack.target_slots.larynx_size) {
    row(lp, 'larynx.size', 'size change (eta)', -1, 1, 0.01, 0, (v) => { stopClip(); state.size = v; applySliders(); });
    const r = grid.length ? 1000 * Math.max(...grid.map(Math.abs)) : 0;
    row(lp, 'larynx.slide_mm', 'slide (mm)', -r, r, 0.1, 0, (v) => { stopClip(); state.slide_mm = v; applySliders(); });
  }
  document.getElementById('reset').onclick = () => {
    stopClip();
    for (const inp of Object.values(sliders)) { inp.value = 0; inp.dispatchEvent(new Event('input')); }
  };
}

function setupTimeline(gltf) {
  if (!gltf.animations.length) return;
  clip = gltf.animations[0];
  mixer = new THREE.AnimationMixer(gltf.scene);
  action = mixer.clipAction(clip);
  const track = clip.tracks[0];
  const n = track.times.length, fps = n > 1 ? (n - 1) / (track.times[n - 1] - track.times[0]) : 1;
  const frame = document.getElementById('frame'), info = document.getElementById('frameinfo');
  const play = document.getElementById('play');
  Object.assign(frame, { max: n - 1, disabled: false }); play.disabled = false;
  const show = (k) => { info.textContent = ` frame ${k} / ${n - 1} (${fps.toFixed(1)} fps)`; };
  frame.addEventListener('input', () => {
    action.play(); action.paused = true; mixer.setTime(track.times[+frame.value]); show(+frame.value);
  });
  play.onclick = () => {
    if (action.isRunning() && !action.paused) { action.paused = true; play.textContent = 'play'; }
    else { action.play(); action.paused = false; play.textContent = 'pause'; }
  };
  sliders.frame = frame; show(0);
}

function applyUrl() {
  const q = new URLSearchParams(location.search);
  for (const item of (q.get('set') || '').split(',').filter(Boolean)) {
    const i = item.lastIndexOf(':');
    const inp = sliders[item.slice(0, i)];
    if (inp) { inp.value = item.slice(i + 1); inp.dispatchEvent(new Event('input')); }
    else console.warn('no slider', item);
  }
  if (q.has('frame') && sliders.frame) { sliders.frame.value = q.get('frame'); sliders.frame.dispatchEvent(new Event('input')); }
}

const config = await (await fetch('./config.json')).json();
new THREE.GLTFLoader().load(config.model, (gltf) => {
  hack = (gltf.parser.json.asset.extras || {}).hack || {};
  const root = gltf.scene;
  scene.add(root);
  root.traverse((o) => {
    if (o.isSkinnedMesh && o.morphTargetInfluences) meshes.push(o);
    if (o.isBone || (o.type === 'Bone')) bones[o.name] = o;
  });
  names = Object.keys(meshes[0].morphTargetDictionary).sort((a, b) => meshes[0].morphTargetDictionary[a] - meshes[0].morphTargetDictionary[b]);
  hack.joints = hack.joints || [];
  state.weights = Array.from(meshes[0].morphTargetInfluences);
  for (const m of meshes) m.frustumCulled = false;
  buildPanel();
  setupTimeline(gltf);
  const box = new THREE.Box3().setFromObject(root);
  const c = box.getCenter(new THREE.Vector3());
  const target = new THREE.Vector3(c.x, box.max.y - 0.16, c.z);
  controls.target.copy(target);
  camera.position.set(target.x, target.y + 0.03, target.z + 1.5);
  const cam = (new URLSearchParams(location.search).get('camera') || '').split(',').map(Number);
  if (cam.length === 3 && cam.every(Number.isFinite)) {  // ?camera=azimuth_deg,elevation_deg,distance_m
    const [az, el, dist] = [cam[0] * Math.PI / 180, cam[1] * Math.PI / 180, cam[2]];
    camera.position.set(target.x + dist * Math.sin(az) * Math.cos(el), target.y + dist * Math.sin(el),
                        target.z + dist * Math.cos(az) * Math.cos(el));
  }
  controls.update();
  resize();
  applyUrl();
  if (new URLSearchParams(location.search).get('dump') === 'weights') {
    correctives();
    const pre = document.createElement('pre');
    pre.id = 'dump';
    pre.textContent = JSON.stringify(Array.from(meshes[0].morphTargetInfluences));
    document.body.appendChild(pre);
  }
  status.textContent = `${names.length} morph targets, ${hack.joints.length} joints` + (clip ? `, animation ${clip.duration.toFixed(2)} s` : '');
  document.title = 'hack-render view: ready';
}, undefined, (err) => { status.textContent = 'failed to load: ' + err; document.title = 'hack-render view: error'; });

const clock = new THREE.Clock();
renderer.setAnimationLoop(() => {
  const dt = clock.getDelta();
  if (mixer) mixer.update(action && !action.paused ? dt : 0);
  if (meshes.length) correctives();
  renderer.render(scene, camera);
});
