// StableMo's page: a prompt box, a 3D skeleton (three.js, vendored), playback and downloads.
// Generation follows typing: a request is sent once typing pauses for DEBOUNCE_MS, and a newer
// request cancels the one in flight (AbortController), so a 39-character prompt typed at speed is
// one request, not 37, and an answer never replaces a newer prompt's.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { Body } from './body.js';

const $ = (id) => document.getElementById(id);
const COLOURS = { left: 0x1f6fd1, right: 0xd62f2f, center: 0x444444 };  // as stablemo.outputs.render
const PATH_COLOUR = 0x2a9d5c;
const DEBOUNCE_MS = 300;  // a pause in typing, not a keystroke gap
const CAMERA_OFFSET = new THREE.Vector3(2.4, 1.1, 3.4);  // from the pelvis: front-left, above

// Everything the browser test and the latency measurement read (window.stablemo).
const S = window.stablemo = {
  ready: false,        // /api/info loaded and the renderer running
  info: null,
  motion: null,        // the motion on screen: {spec, text, seed, frames, fps, J, joints: Float32Array (T*J*3)}
  frame: 0,            // the frame drawn last
  playing: true,
  speed: 1,
  drawCount: 0,        // frames drawn with a motion
  error: null,         // the error shown, or null
  warnings: [],        // the server's warnings about the motion's downloads, shown beside them
  timings: [],         // per motion: {id, text, model, input, send, response, rendered, drawn} (performance.now ms)
  screenPose: null,    // canvas pixel [x, y] of each joint of the frame drawn last
  worldPose: null,     // world [x, y, z] (metres) of each joint of the frame drawn last
};

// ---- scene --------------------------------------------------------------------------------

// Without a GPU the browser renders WebGL in software on the same cores that generate. Measured
// in headless Chromium (SwiftShader) on 2 busy cores: ~140 ms of CPU per frame with 4x MSAA and
// anisotropic floor filtering, ~50 ms without either; so software WebGL gets the cheap settings.
function softwareWebGL() {
  try {
    const gl = document.createElement('canvas').getContext('webgl2');
    const ext = gl.getExtension('WEBGL_debug_renderer_info');
    const name = ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
    gl.getExtension('WEBGL_lose_context')?.loseContext();
    return /swiftshader|llvmpipe|softpipe|software/i.test(name);
  } catch (err) {
    return false;
  }
}
const SOFTWARE = softwareWebGL();
S.softwareWebGL = SOFTWARE;
S.holdWhileComputing = SOFTWARE;
const canvas = $('canvas');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: !SOFTWARE });
renderer.setPixelRatio(SOFTWARE ? 1 : window.devicePixelRatio);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xf4f4f2);
const camera = new THREE.PerspectiveCamera(40, 1, 0.05, 200);
const controls = new OrbitControls(camera, canvas);
controls.target.set(0, 0.9, 0);
camera.position.copy(controls.target).add(CAMERA_OFFSET);
controls.update();

// Cheap to draw on purpose: without a GPU the browser renders in software on the cores that also
// generate (a shadow map and a lit floor cost ~3x per frame there), so the floor is unlit and the
// shadow is the skeleton flattened onto it.
scene.add(new THREE.HemisphereLight(0xffffff, 0x8c8c84, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.2);
sun.position.set(3, 8, 4);
scene.add(sun);
// The floor's 0.5 m grid (as in the GIFs) is a repeated texture drawn here: one draw call, and
// no long lines through the camera plane (software WebGL drops those whole)
const FLOOR_SIZE = 60;
const tile = document.createElement('canvas');
tile.width = tile.height = 64;
const ctx = tile.getContext('2d');
ctx.fillStyle = '#e9e9e4';
ctx.fillRect(0, 0, 64, 64);
ctx.fillStyle = '#b4b4ae';
ctx.fillRect(0, 0, 64, 2);
ctx.fillRect(0, 0, 2, 64);
const floorTexture = new THREE.CanvasTexture(tile);
floorTexture.wrapS = floorTexture.wrapT = THREE.RepeatWrapping;
floorTexture.repeat.set(FLOOR_SIZE / 0.5, FLOOR_SIZE / 0.5);
floorTexture.anisotropy = SOFTWARE ? 1 : renderer.capabilities.getMaxAnisotropy();
floorTexture.colorSpace = THREE.SRGBColorSpace;
// polygon offset: the floor's depth is pushed back so the path and shadow lines drawn just above it
// win the depth test even with a 16-bit depth buffer
const floor = new THREE.Mesh(new THREE.PlaneGeometry(FLOOR_SIZE, FLOOR_SIZE), new THREE.MeshBasicMaterial(
  { map: floorTexture, polygonOffset: true, polygonOffsetFactor: 2, polygonOffsetUnits: 2 }));
floor.rotation.x = -Math.PI / 2;
scene.add(floor);

let figure = null;     // {group, joints: Mesh[], bones: [{mesh, a, b}], key}
let pathLine = null;   // the pelvis path on the floor
const pathMarker = new THREE.Mesh(new THREE.RingGeometry(0.06, 0.09, 24),
                                  new THREE.MeshBasicMaterial({ color: PATH_COLOUR, side: THREE.DoubleSide }));
pathMarker.rotation.x = -Math.PI / 2;
pathMarker.visible = false;
scene.add(pathMarker);

function buildFigure(skeleton) {
  const key = skeleton.name;
  if (figure && figure.key === key) return;
  if (figure) scene.remove(figure.group);
  const group = new THREE.Group();
  const side = new Array(skeleton.parents.length).fill('center');
  skeleton.chains.forEach((chain, c) => chain.slice(1).forEach((j) => { side[j] = skeleton.sides[c]; }));
  const materials = Object.fromEntries(Object.entries(COLOURS).map(([k, v]) => [k, new THREE.MeshLambertMaterial({ color: v })]));
  const head = skeleton.chains.find((c, i) => skeleton.sides[i] === 'center').at(-1);
  const joints = skeleton.parents.map((_, j) => {
    const r = j === head ? 0.085 : j === 0 ? 0.05 : 0.032;
    const m = new THREE.Mesh(new THREE.SphereGeometry(r, 16, 12), materials[side[j]]);
    group.add(m);
    return m;
  });
  const bones = [];
  skeleton.chains.forEach((chain, c) => {
    for (let i = 1; i < chain.length; i++) {
      const mesh = new THREE.Mesh(new THREE.CylinderGeometry(0.022, 0.022, 1, 10), materials[skeleton.sides[c]]);
      group.add(mesh);
      bones.push({ mesh, a: chain[i - 1], b: chain[i] });
    }
  });
  const shadowGeometry = new THREE.BufferGeometry();
  shadowGeometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(bones.length * 6), 3));
  const shadow = new THREE.LineSegments(shadowGeometry, new THREE.LineBasicMaterial({ color: 0x7a7a7a }));
  group.add(shadow);
  scene.add(group);
  figure = { group, joints, bones, shadow, key };
}

const UP = new THREE.Vector3(0, 1, 0);
const tmpA = new THREE.Vector3(), tmpB = new THREE.Vector3(), tmpD = new THREE.Vector3();

function jointAt(m, f, j, out) {
  const o = (f * m.J + j) * 3;
  return out.set(m.joints[o] * m.scale, m.joints[o + 1] * m.scale, m.joints[o + 2] * m.scale);
}

function pose(f) {
  const m = S.motion;
  placeFigure((j, out) => jointAt(m, f, j, out));
}

// The figure before any motion: the model's body at rest on the floor (not a post at the origin).
function restPose(skeleton) {
  const scale = skeleton.units === 'mm' ? 0.001 : 1;
  placeFigure((j, out) => out.fromArray(skeleton.rest[j]).multiplyScalar(scale));
  dirtyView = true;
}

// Joints and bones where at(j, out) puts each joint (world metres).
function placeFigure(at) {
  figure.joints.forEach((mesh, j) => at(j, mesh.position));
  const shadow = figure.shadow.geometry.attributes.position;
  figure.bones.forEach(({ mesh, a, b }, i) => {
    at(a, tmpA);
    at(b, tmpB);
    shadow.setXYZ(2 * i, tmpA.x, 0.002, tmpA.z);
    shadow.setXYZ(2 * i + 1, tmpB.x, 0.002, tmpB.z);
    tmpD.subVectors(tmpB, tmpA);
    const len = tmpD.length();
    mesh.position.addVectors(tmpA, tmpB).multiplyScalar(0.5);
    mesh.scale.set(1, Math.max(len, 1e-4), 1);
    if (len > 1e-6) mesh.quaternion.setFromUnitVectors(UP, tmpD.divideScalar(len));
  });
  shadow.needsUpdate = true;
  const pelvis = figure.joints[0].position;
  pathMarker.position.set(pelvis.x, 0.004, pelvis.z);
}

function buildPath(m) {
  if (pathLine) { scene.remove(pathLine); pathLine.geometry.dispose(); }
  const pts = [];
  for (let f = 0; f < m.available; f++) {
    const p = jointAt(m, f, 0, new THREE.Vector3());
    pts.push(new THREE.Vector3(p.x, 0.003, p.z));
  }
  pathLine = new THREE.Line(new THREE.BufferGeometry().setFromPoints(pts), new THREE.LineBasicMaterial({ color: PATH_COLOUR }));
  scene.add(pathLine);
  pathMarker.visible = true;
}

function followCamera() {
  const p = figure.joints[0].position;
  const goal = tmpA.set(p.x, 0.9, p.z);
  const delta = tmpB.subVectors(goal, controls.target);
  controls.target.add(delta);
  camera.position.add(delta);
}

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.floor(w * renderer.getPixelRatio()) || canvas.height !== Math.floor(h * renderer.getPixelRatio())) {
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
    return true;
  }
  return false;
}

S.three = { scene, camera, renderer, controls, floor };  // for debugging in the console

// A lost WebGL context (a GPU reset; software WebGL on a machine too busy to answer in time) leaves
// the canvas blank until the page draws again: let the browser restore it (preventDefault), and
// draw the scene again once it has (three.js rebuilds its own state on restore).
S.contextLosses = 0;
canvas.addEventListener('webglcontextlost', (e) => { e.preventDefault(); S.contextLosses++; });
canvas.addEventListener('webglcontextrestored', () => { dirtyView = true; });

// The body (static/body.js: our mannequin from the server's GLB) is shown instead of the stick figure
// when it holds the motion on screen (or, before any motion, the model's body at rest), unless the
// stick figure is asked for, a joint is being dragged (the sticks' joints are the handles) or a
// timeline streams (its chunks come as joints only). Until a motion's GLB arrives, the sticks show it.
const body = new Body(scene);
S.body = body;
body.onload = () => { dirtyView = true; };

function bodyWanted() {
  if ($('sticks').checked || mode === 'pose') return false;
  const m = S.motion;
  return m ? Boolean(m.spec) && !m.streaming && body.holds(m.spec) : body.holds(`rest:${$('model').value}`);
}

// Show the body or the sticks, the body posed at frame f of the motion (f < 0: no motion).
function syncBody(f) {
  const on = bodyWanted();
  body.setVisible(on);
  if (figure) figure.group.visible = !on;
  if (on && S.motion && f >= 0) body.pose(f / S.motion.fps);
  S.bodyShown = on;
}

// ---- playback loop ------------------------------------------------------------------------

let framePos = 0, lastTick = performance.now(), dirtyView = true;
controls.addEventListener('change', () => { dirtyView = true; });
let firstDraw = null;   // timing record of a motion not drawn yet
let presented = null;   // timing record drawn by the previous tick (shown on screen by now)

function tick() {
  requestAnimationFrame(tick);
  const now = performance.now();
  if (presented) {  // the frame rendered before this callback has gone to the screen
    presented.drawn = now;
    showTiming(presented);
    presented = null;
  }
  const dt = Math.min((now - lastTick) / 1000, 0.1);
  lastTick = now;
  const m = S.motion;
  if (m && m.available > 0 && S.playing) framePos += dt * m.fps * S.speed;
  if (bodyWanted() !== body.visible) dirtyView = true;  // a GLB arrived, or a toggle changed
  draw();
}

// Pose the figure at the current frame and render, if anything changed. Called by the animation
// loop, and at once when a motion arrives (not a display frame later).
function draw() {
  // software WebGL renders on the cores the model runs on: from a keystroke until its motion is
  // drawn the figure holds still instead of taking CPU from the request (docs/serve.md, measured)
  if (S.holdWhileComputing && (inflight || pendingSend) && !firstDraw) return;
  if (resize()) dirtyView = true;
  const m = S.motion;
  let f = -1;
  if (m && m.available > 0) {
    // a stream still arriving holds at its last frame (buffering); a complete motion loops
    framePos = m.streaming ? Math.min(framePos, m.available - 1) : framePos % m.frames;
    f = Math.min(Math.floor(framePos), m.available - 1);
    if (f !== S.frame || firstDraw) {
      pose(f);
      // drawing a path or dragging a joint holds the camera: the floor stays under the cursor
      if ($('follow').checked && mode === null) followCamera();
      dirtyView = true;
    }
  }
  controls.update();
  // only when something moved: a 20 fps motion needs 20 renders a second, not the display's 60
  if (!dirtyView) return;
  dirtyView = false;
  syncBody(f);
  renderer.render(scene, camera);
  if (f >= 0) {
    S.frame = f;
    S.drawCount++;
    recordPose();
    if ($('scrub').value !== String(f)) $('scrub').value = f;
    $('clock').textContent = `frame ${f + 1} / ${m.frames} · ${(f / m.fps).toFixed(2)} s / ${(m.frames / m.fps).toFixed(2)} s`;
    if (firstDraw) { firstDraw.rendered = performance.now(); presented = firstDraw; firstDraw = null; }
  } else if (figure) {
    recordPose();  // the rest pose
  }
}

function recordPose() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  S.worldPose = figure.joints.map((j) => j.position.toArray());
  S.screenPose = figure.joints.map((j) => {
    const v = j.position.clone().project(camera);
    return [(v.x + 1) / 2 * w, (1 - v.y) / 2 * h];
  });
}

// ---- requests -----------------------------------------------------------------------------

let inflight = null, debounce = null, lastInput = performance.now(), seq = 0, pendingSend = false;
S.requests = 0;        // /api/generate requests sent
S.cancelled = 0;       // of those, cancelled by a newer one

function modelInfo(name) { return S.info.models.find((m) => m.name === name); }

// targets are per frame, so a path or keyframes need the length before the server chooses it: with
// no seconds given, that of the motion on screen (the text's own), else the model's default
function targetFrames(model) {
  const m = S.motion;
  const frames = m && !m.streaming && m.model === model.name ? m.frames : model.default_frames;
  return Math.min(Math.max(frames, model.min_frames), model.max_frames);
}

function currentSpec() {
  // an empty seconds field: the length the text asks for (the bundle's length predictor)
  const spec = { text: $('prompt').value, seed: Number($('seed').value), model: $('model').value,
                 footskate: $('footskate').checked };
  if ($('seconds').value !== '') spec.seconds = Number($('seconds').value);
  if ($('sampler').value) spec.sampler = $('sampler').value;
  if ($('steps').value !== '') spec.steps = Number($('steps').value);
  if ($('cfg').value !== '') spec.cfg = Number($('cfg').value);
  const model = modelInfo(spec.model);
  const frames = spec.seconds === undefined ? targetFrames(model) : Math.round(spec.seconds * model.fps);
  const targets = controlTargets(frames);
  if (targets.length) {  // targets are per frame: say the frame count rather than have it rounded twice
    delete spec.seconds;
    spec.frames = frames;
    spec.control = { targets };
  }
  return spec;
}

function schedule(delay = DEBOUNCE_MS) {
  lastInput = performance.now();
  clearTimeout(debounce);
  pendingSend = true;
  debounce = setTimeout(submit, delay);
}

async function submit() {
  pendingSend = false;
  if (inflight) { inflight.abort(); S.cancelled++; }  // stale: a newer prompt is on its way
  if (streamAbort) streamAbort.abort();  // a new prompt replaces a timeline being streamed
  const abort = new AbortController();
  inflight = abort;
  const spec = currentSpec();
  const rec = { id: ++seq, text: spec.text, model: spec.model, seed: spec.seed, input: lastInput, send: performance.now() };
  S.requests++;
  setStatus('generating…');
  try {
    const res = await fetch('/api/generate', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, signal: abort.signal,
      body: JSON.stringify({ ...spec, encoding: 'base64', features: false }),
    });
    const data = await res.json().catch(() => ({ error: `HTTP ${res.status}: the answer is not JSON` }));
    if (abort.signal.aborted) return;
    if (!res.ok) showError(data.error || `HTTP ${res.status}`);
    else { rec.response = performance.now(); rec.server = data.timing; setMotion(data, spec, rec); }
  } catch (err) {
    if (err.name !== 'AbortError') showError(`no answer from the server (${err.message})`);
  } finally {
    if (inflight === abort) inflight = null;
  }
}

function decode(arr) {
  const bytes = Uint8Array.from(atob(arr.base64), (c) => c.charCodeAt(0));
  return new Float32Array(bytes.buffer);  // little-endian, as every browser's platform
}

function setMotion(data, spec, rec) {
  if (spec) body.motion(spec);  // the GLB download of this motion, read as the body
  const model = modelInfo(data.model);
  const [T, J] = data.joints.shape;
  buildFigure(model.skeleton);
  S.motion = { spec, text: data.text, seed: data.seed, model: data.model, frames: T, J, fps: data.fps,
               lengthFrom: data.length_from,
               steps: data.steps, sampler: data.sampler, cfg: data.cfg, joints: decode(data.joints), control: data.control,
               available: T, streaming: false,
               scale: model.skeleton.units === 'mm' ? 0.001 : 1 };
  // an empty seconds field says the length the text got
  if (data.length_from !== 'given') $('seconds').placeholder = `auto (${(T / data.fps).toFixed(1)} s)`;
  // a prompt that says an order was made part by part: say the parts and their seconds
  // and a turn whose size the words say: the angle the body was turned by
  const turns = (data.turns || []).map((t) => `turning ${t.degrees}°${t.side ? ' to the ' + t.side : ''}`);
  $('plan-note').textContent = [
    data.plan ? 'in parts: ' + data.plan.map((p) => `${p.text} ${((p.end - p.start) / data.fps).toFixed(1)} s`).join(' → ') : '',
    ...turns].filter(Boolean).join('; ');
  buildPath(S.motion);
  // a new prompt plays from the start; an edit made while paused stays at the frame being edited;
  // the motion of a path just drawn plays from the start if the page was playing before the stroke
  framePos = S.playing || resumeAfterPath ? 0 : Math.min(framePos, T - 1);
  if (resumeAfterPath && !S.playing) togglePlay();
  resumeAfterPath = false;
  $('scrub').max = T - 1;
  firstDraw = rec;
  draw();
  S.error = null;
  setStatus('');
  document.querySelectorAll('#downloads button').forEach((b) => { b.disabled = false; });
  // the server says when a download would differ from the motion shown (a BVH more than 3 cm off)
  S.warnings = data.warnings || [];
  $('download-note').textContent = S.warnings.join(' ');
  showControlInfo();
}

function setStatus(text) {
  if (S.error && text === 'generating…') return;  // keep an error visible until a motion replaces it
  $('status').textContent = text;
  $('status').className = '';
}

function showError(message) {
  S.error = message;
  $('status').textContent = message;
  $('status').className = 'error';
}

function showTiming(rec) {
  S.timings.push(rec);
  const server = rec.server ? ` (model ${rec.server.compute_ms.toFixed(0)} ms)` : '';
  $('timing').textContent = `prompt → first frame: ${(rec.drawn - rec.send).toFixed(0)} ms${server}; `
    + `from the last keystroke: ${(rec.drawn - rec.input).toFixed(0)} ms`;
}

async function download(format) {
  const m = S.motion;
  if (!m || !m.spec) return;
  setStatus(`preparing ${format}…`);
  try {
    const res = await fetch('/api/download', { method: 'POST', headers: { 'Content-Type': 'application/json' },
                                               body: JSON.stringify({ ...m.spec, format }) });
    if (!res.ok) {
      const data = await res.json().catch(() => ({}));
      showError(data.error || `HTTP ${res.status}`);
      return;
    }
    const blob = await res.blob();
    const match = /filename="([^"]+)"/.exec(res.headers.get('Content-Disposition') || '');
    const a = document.createElement('a');
    a.href = URL.createObjectURL(blob);
    a.download = match ? match[1] : `motion.${format}`;
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 30000);
    setStatus('');
  } catch (err) {
    showError(`download failed (${err.message})`);
  }
}

// ---- joint control: a pelvis path drawn on the floor, keyframes by dragging joints --------------

const TARGET_COLOUR = 0xe08a00;  // as stablemo.outputs.render's targets
const raycaster = new THREE.Raycaster();
const pointer = new THREE.Vector2();
const floorPlane = new THREE.Plane(new THREE.Vector3(0, 1, 0), 0);
const targetMaterial = new THREE.MeshBasicMaterial({ color: TARGET_COLOUR });
let mode = null;            // 'path' | 'pose' | null
let resumeAfterPath = false;  // play the path's motion when it arrives (the page was playing)
let draft = null;           // the path being drawn: [[x, z], ...] world
let dragging = null;        // {joint, plane} while a joint is dragged
let pathObject = null;      // the drawn path on the floor
const keyGroup = new THREE.Group();
scene.add(keyGroup);
S.path = null;              // the path, starting at the origin: [[x, z], ...] metres
S.keyframes = [];           // [{frame, joint, position: [x, y, z]}]

function setPointer(e) {
  const r = canvas.getBoundingClientRect();
  pointer.set(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
  raycaster.setFromCamera(pointer, camera);
}

function setMode(next) {
  mode = mode === next ? null : next;
  if (mode === 'path') holdForStroke();
  $('draw-path').setAttribute('aria-pressed', String(mode === 'path'));
  $('edit-pose').setAttribute('aria-pressed', String(mode === 'pose'));
  controls.enabled = mode === null;  // the left button draws or drags instead of orbiting
  $('view').classList.toggle('drawing', mode !== null);
  if (mode === 'pose' && S.playing) togglePlay();
  showControlInfo();
}

// Before a stroke: pause at frame 0, where the motion (and so the path) starts, with the camera on
// the figure; the camera then holds until the mode ends, so the floor stays under the cursor.
// recentre: move the camera onto the figure once (entering the mode); a stroke starting keeps the
// camera where it is, so the press and the moves are read through the same view.
function holdForStroke(recentre = true) {
  if (S.playing) { togglePlay(); resumeAfterPath = true; }
  framePos = 0;
  if (S.motion && S.motion.available > 0) {
    pose(0);
    S.frame = 0;  // shown now, not at the next animation frame (which a busy page may run late)
    if (recentre) followCamera();
    dirtyView = true;
  }
}

// Canvas pixel -> the floor point [x, z] under it (null above the horizon), with the camera as it is.
S.floorAt = (px, py) => {
  pointer.set((px / canvas.clientWidth) * 2 - 1, -(py / canvas.clientHeight) * 2 + 1);
  raycaster.setFromCamera(pointer, camera);
  const p = raycaster.ray.intersectPlane(floorPlane, new THREE.Vector3());
  return p ? [p.x, p.z] : null;
};
// World [x, y, z] -> canvas pixel [x, y].
S.toScreen = (xyz) => {
  const v = new THREE.Vector3(...xyz).project(camera);
  return [(v.x + 1) / 2 * canvas.clientWidth, (1 - v.y) / 2 * canvas.clientHeight];
};

function showPath(points, y = 0.004) {
  if (pathObject) { scene.remove(pathObject); pathObject.geometry.dispose(); pathObject = null; }
  if (!points || points.length < 2) return;
  const geometry = new THREE.BufferGeometry().setFromPoints(points.map(([x, z]) => new THREE.Vector3(x, y, z)));
  pathObject = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color: TARGET_COLOUR }));
  scene.add(pathObject);
  dirtyView = true;
}

function showKeyframes() {
  keyGroup.clear();
  for (const k of S.keyframes) {
    const marker = new THREE.Mesh(new THREE.OctahedronGeometry(0.045), targetMaterial);
    marker.position.fromArray(k.position);
    keyGroup.add(marker);
  }
  $('clear-keys').disabled = S.keyframes.length === 0;
  dirtyView = true;
}

// The motion on screen's progress along its own pelvis path at each of `frames` frames spread over
// its duration (0 -> 1, never decreasing; a constant ramp when it stands): a drawn path has no timing
// of its own, and walked at one speed from frame 0 it drags a body whose text starts and ends
// standing, its stance feet sliding (stablemo/control/pace.py does the same; docs/control.md).
const PACE_SMOOTH = 5;    // frames the pelvis steps are averaged over (pace.py's SMOOTH_FRAMES)
const PACE_STILL_M = 0.2; // a motion moving less than this stands (pace.py's STILL_M)
function motionProgress(frames) {
  const ramp = Array.from({ length: frames }, (_, f) => (frames > 1 ? f / (frames - 1) : 0));
  const m = S.motion;
  if (!m || m.frames < 2) return ramp;
  const step = [];
  for (let f = 1; f < m.frames; f++) {
    const a = (f - 1) * m.J * 3, b = f * m.J * 3;
    step.push(Math.hypot(m.joints[b] - m.joints[a], m.joints[b + 2] - m.joints[a + 2]) * m.scale);
  }
  const k = Math.min(PACE_SMOOTH, step.length), lo = Math.floor(k / 2);
  const walked = [0];
  for (let i = 0; i < step.length; i++) {  // a moving average of the steps, edges repeated
    let sum = 0;
    for (let d = -lo; d < k - lo; d++) sum += step[Math.min(Math.max(i + d, 0), step.length - 1)];
    walked.push(walked[i] + sum / k);
  }
  const total = walked.at(-1);
  if (total < PACE_STILL_M) return ramp;
  return ramp.map((u) => {
    const at = u * (m.frames - 1), i = Math.min(Math.floor(at), m.frames - 2), w = at - i;
    return (walked[i] + w * (walked[i + 1] - walked[i])) / total;
  });
}

// The path as T pelvis targets: walked as the motion on screen walks its own (motionProgress), by
// arc length, at that motion's pelvis heights (the root's height is a target too; this keeps its jumps).
function pathTargets(frames) {
  const pts = S.path;
  const cum = [0];
  for (let i = 1; i < pts.length; i++) cum.push(cum[i - 1] + Math.hypot(pts[i][0] - pts[i - 1][0], pts[i][1] - pts[i - 1][1]));
  const total = cum.at(-1);
  const share = motionProgress(frames);
  const out = [];
  let seg = 1;
  for (let f = 0; f < frames; f++) {
    const s = total * share[f];
    while (seg < pts.length - 1 && cum[seg] < s) seg++;
    const a = pts[seg - 1], b = pts[seg];
    const u = cum[seg] > cum[seg - 1] ? Math.min(Math.max((s - cum[seg - 1]) / (cum[seg] - cum[seg - 1]), 0), 1) : 0;
    const m = S.motion;
    const y = m ? m.joints[(Math.min(f, m.frames - 1) * m.J) * 3 + 1] * m.scale : 0.95;
    out.push([f, 0, a[0] + u * (b[0] - a[0]), y, a[1] + u * (b[1] - a[1])]);
  }
  out[0][2] = 0;  // the motion starts at the origin
  out[0][4] = 0;
  return out;
}

function controlTargets(frames) {
  const targets = new Map();
  if (S.path) for (const t of pathTargets(frames)) targets.set(`${t[0]},${t[1]}`, t);
  for (const k of S.keyframes) targets.set(`${k.frame},${k.joint}`, [k.frame, k.joint, ...k.position]);
  return [...targets.values()].map((t) => t.map((v, i) => (i < 2 ? v : Math.round(v * 1e4) / 1e4)));
}

function showControlInfo() {
  const parts = [];
  if (mode === 'path') parts.push('drag on the floor to draw the pelvis path (it starts where the motion starts)');
  if (mode === 'pose') parts.push('pick a frame (scrub), then drag a joint to where it should be');
  if (S.path) {
    let length = 0;
    for (let i = 1; i < S.path.length; i++) length += Math.hypot(S.path[i][0] - S.path[i - 1][0], S.path[i][1] - S.path[i - 1][1]);
    parts.push(`path ${length.toFixed(2)} m`);
  }
  if (S.keyframes.length) parts.push(`${S.keyframes.length} keyframe${S.keyframes.length > 1 ? 's' : ''}`);
  const control = S.motion && S.motion.control;
  // the server says when the targets ask for more than a body follows, or were missed
  if (control && !control.note) {
    parts.push(`targets reached within ${(100 * control.mean_error_m).toFixed(1)} cm on average `
               + `(worst ${(100 * control.max_error_m).toFixed(1)} cm)`);
  }
  $('control-info').textContent = parts.join(' · ');
  $('control-note').textContent = control && control.note ? control.note : '';
}

// The joint the user pressed on: the one drawn nearest the pointer (S.screenPose, recorded at each
// render), within PICK_PX of its centre. Screen distance, not the first sphere a ray meets: a wrist
// drawn over the hip is picked at its centre, and a joint drawn a few pixels wide is still easy to grab.
const PICK_PX = 14;
function jointUnderPointer(e) {
  const r = canvas.getBoundingClientRect();
  const px = e.clientX - r.left, py = e.clientY - r.top;
  let best = -1, bestDistance = PICK_PX;
  (S.screenPose || []).forEach(([x, y], i) => {
    const d = Math.hypot(x - px, y - py);
    if (d < bestDistance) { best = i; bestDistance = d; }
  });
  return best;
}

canvas.addEventListener('pointerdown', (e) => {
  if (e.button !== 0 || mode === null) return;
  setPointer(e);
  if (mode === 'path') {
    const p = raycaster.ray.intersectPlane(floorPlane, new THREE.Vector3());
    if (!p) return;
    holdForStroke(false);  // a motion that arrived since plays on: stop it, back to where the path starts
    // the path starts at the figure (the motion's start, the origin), wherever the stroke begins
    draft = [[0, 0]];
    if (Math.hypot(p.x, p.z) > 0.03) draft.push([p.x, p.z]);
  } else if (mode === 'pose' && figure && S.motion) {
    const joint = jointUnderPointer(e);
    if (joint < 0) return;
    const normal = camera.getWorldDirection(new THREE.Vector3()).negate();
    dragging = { joint, plane: new THREE.Plane().setFromNormalAndCoplanarPoint(normal, figure.joints[joint].position.clone()) };
  } else {
    return;
  }
  canvas.setPointerCapture(e.pointerId);
  e.preventDefault();
});

canvas.addEventListener('pointermove', (e) => {
  if (!draft && !dragging) return;
  setPointer(e);
  if (draft) {
    const p = raycaster.ray.intersectPlane(floorPlane, new THREE.Vector3());
    const last = draft.at(-1);
    if (p && Math.hypot(p.x - last[0], p.z - last[1]) > 0.03) {
      draft.push([p.x, p.z]);
      showPath(draft);
    }
  } else {
    const p = raycaster.ray.intersectPlane(dragging.plane, new THREE.Vector3());
    if (p) {
      figure.joints[dragging.joint].position.copy(p);
      dragging.position = p.toArray();
      dirtyView = true;
    }
  }
});

canvas.addEventListener('pointerup', () => {
  if (draft) {
    const path = draft;
    draft = null;
    if (path.length >= 2) {
      S.path = path;
      $('clear-path').disabled = false;
      showPath(path);
      showControlInfo();
      schedule(0);
    } else {
      showPath(S.path);
    }
  } else if (dragging) {
    const { joint, position } = dragging;
    dragging = null;
    if (position) {
      const frame = S.frame;
      S.keyframes = S.keyframes.filter((k) => !(k.frame === frame && k.joint === joint));
      S.keyframes.push({ frame, joint, position });
      showKeyframes();
      showControlInfo();
      schedule(0);
    }
  }
});

// ---- timeline: prompts one after another, streamed as one long motion -------------------------

let streamAbort = null;

async function streamTimeline() {
  // the server reads the timeline (stablemo.timeline.spec, the CLI's parser) and names a bad line;
  // the page's shorthand lines come back written out in the one format
  const timeline = $('timeline').value;
  if (streamAbort) streamAbort.abort();
  const abort = new AbortController();
  streamAbort = abort;
  const model = modelInfo($('model').value);
  const body = { timeline, seed: Number($('seed').value), model: model.name, encoding: 'base64' };
  if ($('sampler').value) body.sampler = $('sampler').value;
  if ($('steps').value !== '') body.steps = Number($('steps').value);
  if ($('cfg').value !== '') body.cfg = Number($('cfg').value);
  const now = performance.now();
  const rec = { id: ++seq, text: 'timeline', model: model.name, seed: body.seed, input: now, send: now, stream: true };
  $('stop-stream').disabled = false;
  S.error = null;
  setStatus('streaming…');
  let m = null;
  try {
    const res = await fetch('/api/stream', { method: 'POST', headers: { 'Content-Type': 'application/json' },
                                             body: JSON.stringify(body), signal: abort.signal });
    if (!res.ok) {
      const data = await res.json().catch(() => ({}));
      showError(data.error || `HTTP ${res.status}`);
      return;
    }
    const reader = res.body.getReader();
    const decoder = new TextDecoder();
    let buffer = '';
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buffer += decoder.decode(value, { stream: true });
      let nl;
      while ((nl = buffer.indexOf('\n')) >= 0) {
        const line = buffer.slice(0, nl);
        buffer = buffer.slice(nl + 1);
        if (!line.trim()) continue;
        const msg = JSON.parse(line);
        if (msg.error) { showError(msg.error); return; }
        if (msg.done) {
          m.streaming = false;
          m.frames = m.available;
          m.spec = m.streamSpec;  // the whole stream downloads: the server kept it (/api/download)
          document.querySelectorAll('#downloads button').forEach((b) => { b.disabled = false; });
          rec.done = performance.now();
          $('stream-info').textContent = `${m.chunks} chunks, ${(m.frames / m.fps).toFixed(1)} s of motion `
            + `in ${(msg.elapsed_ms / 1000).toFixed(2)} s; first chunk after ${(rec.response - rec.send).toFixed(0)} ms`;
          setStatus('');
        } else if (msg.chunks !== undefined) {
          $('timeline').value = msg.timeline;  // the shorthand shown back as the format the CLI reads
          rec.text = msg.segments.map((s) => s.text).join(' → ');
          m = startStream(msg, model, rec, body);
        } else {
          appendChunk(m, msg, rec);
        }
      }
    }
  } catch (err) {
    if (err.name !== 'AbortError') showError(`streaming failed (${err.message})`);
  } finally {
    if (m && m.streaming) {  // stopped or failed: what arrived plays as a motion of its own
      m.streaming = false;
      m.frames = m.available;
    }
    if (streamAbort === abort) {
      streamAbort = null;
      $('stop-stream').disabled = true;
    }
  }
}

function startStream(head, model, rec, body) {
  buildFigure(model.skeleton);
  const J = model.skeleton.parents.length;
  S.motion = { spec: null, streamSpec: body, text: rec.text, seed: rec.seed, model: head.model, frames: head.frames, J, fps: head.fps,
               joints: new Float32Array(head.frames * J * 3), scale: model.skeleton.units === 'mm' ? 0.001 : 1,
               available: 0, streaming: true, chunks: 0, texts: head.texts, control: null };
  framePos = 0;
  if (!S.playing) togglePlay();  // a stream is there to be watched as it arrives
  $('scrub').max = head.frames - 1;
  document.querySelectorAll('#downloads button').forEach((b) => { b.disabled = true; });  // until the last chunk
  S.warnings = [];
  $('download-note').textContent = '';
  $('stream-info').textContent = `0 / ${head.chunks} chunks`;
  return S.motion;
}

function appendChunk(m, msg, rec) {
  m.joints.set(decode(msg.joints), msg.start * m.J * 3);
  m.available = msg.start + msg.frames;
  m.chunks = msg.index + 1;
  buildPath(m);
  if (msg.index === 0) {
    rec.response = performance.now();
    firstDraw = rec;
    draw();
  }
  $('stream-info').textContent = `${m.chunks} / ${m.texts.length} chunks · now: ${msg.text}`;
}

// ---- controls -----------------------------------------------------------------------------

function applyModel(name) {
  const model = modelInfo(name);
  const sampler = $('sampler');
  sampler.replaceChildren(new Option(`default (${model.defaults.sampler})`, ''),
                          ...model.samplers.map((s) => new Option(s, s)));
  $('steps').placeholder = `default ${model.defaults.steps}`;
  $('cfg').placeholder = `default ${model.defaults.cfg}`;
  const seconds = $('seconds');
  seconds.min = Math.ceil((model.min_frames / model.fps) * 2) / 2;
  seconds.max = Math.floor((model.max_frames / model.fps) * 2) / 2;
}

function togglePlay() {
  S.playing = !S.playing;
  $('play').textContent = S.playing ? 'Pause' : 'Play';
}

async function start() {
  try {
    const res = await fetch('/api/info');
    S.info = await res.json();
  } catch (err) {
    showError(`no answer from the server (${err.message})`);
    return;
  }
  const select = $('model');
  select.replaceChildren(...S.info.models.map((m) => new Option(m.label, m.name)));
  select.value = S.info.default;
  $('downloads').querySelector('[data-format=fbx]').hidden = !S.info.downloads.includes('fbx');
  applyModel(select.value);
  buildFigure(modelInfo(select.value).skeleton);
  body.rest(select.value);
  restPose(modelInfo(select.value).skeleton);
  $('prompt').addEventListener('input', () => { if ($('live').checked) schedule(); });
  $('prompt').addEventListener('keydown', (e) => { if (e.key === 'Enter') schedule(0); });
  $('generate').addEventListener('click', () => schedule(0));
  select.addEventListener('change', () => {
    applyModel(select.value);
    if (!S.motion) { buildFigure(modelInfo(select.value).skeleton); restPose(modelInfo(select.value).skeleton); }
    body.rest(select.value);  // the new model's body, shown until its first motion
    schedule(0);
  });
  for (const id of ['seconds', 'seed', 'sampler', 'steps', 'cfg', 'footskate']) {
    $(id).addEventListener('change', () => schedule(0));
  }
  $('reseed').addEventListener('click', () => { $('seed').value = Math.floor(Math.random() * 1e6); schedule(0); });
  $('stream').addEventListener('click', streamTimeline);
  $('stop-stream').addEventListener('click', () => { if (streamAbort) streamAbort.abort(); });
  $('draw-path').addEventListener('click', () => setMode('path'));
  $('edit-pose').addEventListener('click', () => setMode('pose'));
  $('clear-path').addEventListener('click', () => {
    S.path = null;
    showPath(null);
    $('clear-path').disabled = true;
    showControlInfo();
    schedule(0);
  });
  $('clear-keys').addEventListener('click', () => {
    S.keyframes = [];
    showKeyframes();
    showControlInfo();
    schedule(0);
  });
  $('play').addEventListener('click', togglePlay);
  $('speed').addEventListener('change', () => { S.speed = Number($('speed').value); });
  $('scrub').addEventListener('input', () => {
    if (S.playing) togglePlay();
    framePos = Number($('scrub').value);
  });
  document.addEventListener('keydown', (e) => {
    if (e.key === ' ' && !['INPUT', 'SELECT', 'TEXTAREA', 'BUTTON'].includes(document.activeElement.tagName)) {
      e.preventDefault();
      togglePlay();
    }
  });
  document.querySelectorAll('#downloads button').forEach((b) => b.addEventListener('click', () => download(b.dataset.format)));
  setStatus('type a motion above; it is generated as you type');
  requestAnimationFrame(tick);
  S.ready = true;
}

start();
