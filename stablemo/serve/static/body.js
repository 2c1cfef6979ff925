// The page's body: our skinned mannequin (stablemo.gltf), read by three.js's own glTF loader from
// the very GLB the server makes for the download button, and posed with that file's animation.
// Before the first motion it is the model's body standing at ease (/api/rest.glb).
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

export class Body {
  constructor(scene) {
    this.scene = scene;
    this.loader = new GLTFLoader();
    this.key = null;       // what is loaded: 'rest:<model>' or a motion's spec object
    this.wanted = null;    // what was asked for last (a slower, older answer is dropped)
    this.loaded = null;    // {root, mixer, clip, action, bones: {name: Bone}}
    this.error = null;
    this.loads = 0;        // files read so far
    this.bytes = 0;        // the size of the file on show
    this.onload = () => {};
  }

  rest(model) {
    return this._load(`rest:${model}`, `/api/rest.glb?model=${encodeURIComponent(model)}`);
  }

  // the motion of a /api/generate spec: the GLB download of the same spec (the server's cache
  // holds the motion, so this is the file's making, not a second generation)
  motion(spec) {
    return this._load(spec, '/api/download', {
      method: 'POST', headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({ ...spec, format: 'glb' }),
    });
  }

  async _load(key, url, init) {
    this.wanted = key;
    try {
      const res = await fetch(url, init);
      if (!res.ok) throw new Error(`HTTP ${res.status}`);
      const buffer = await res.arrayBuffer();
      const gltf = await this.loader.parseAsync(buffer, '');
      if (this.wanted !== key) return;  // a newer motion was asked for meanwhile
      this.bytes = buffer.byteLength;
      this._install(key, gltf);
      this.error = null;
    } catch (err) {
      if (this.wanted === key) this.error = String(err.message || err);
    }
  }

  _install(key, gltf) {
    if (this.loaded) this.scene.remove(this.loaded.root);
    const root = gltf.scene;
    const bones = {};
    root.traverse((o) => {
      if (o.isBone) bones[o.name] = o;
      if (o.isMesh) {
        // Lambert, as the stick figure: the file's PBR material costs more per pixel, which software
        // WebGL pays on the cores the model runs on; the file's own colour is kept
        o.material = new THREE.MeshLambertMaterial({ color: o.material.color });
        // a skinned mesh's bounds are its bind pose at the origin: the body walks away from them
        o.frustumCulled = false;
      }
    });
    const mixer = new THREE.AnimationMixer(root);
    const clip = gltf.animations[0];
    let action = null;
    if (clip) {
      // the page loops the motion itself: here time runs once and holds the last key at the end
      // (a repeating action wraps t = duration, the last frame, back to the first)
      action = mixer.clipAction(clip);
      action.setLoop(THREE.LoopOnce, 1);
      action.clampWhenFinished = true;
      action.play();
    }
    mixer.setTime(0);
    root.visible = false;
    this.scene.add(root);
    this.loaded = { root, mixer, clip, action, bones };
    this.key = key;
    this.loads++;
    this.onload();
  }

  // whether it holds `key` (and so can be shown for it)
  holds(key) { return this.loaded !== null && this.key === key; }

  setVisible(on) { if (this.loaded) this.loaded.root.visible = on; }

  get visible() { return this.loaded !== null && this.loaded.root.visible; }

  // the pose at `seconds` into the animation (frame f of a motion at fps: f / fps, a key exactly).
  // A one-shot action that reaches its end (the last frame, every loop of the page's playback) is
  // paused there by three.js, and a paused action ignores the time setTime gives it: it would show
  // its first frame from then on. So the action runs again before each pose.
  pose(seconds) {
    if (!this.loaded) return;
    if (this.loaded.action) { this.loaded.action.paused = false; this.loaded.action.enabled = true; }
    this.loaded.mixer.setTime(seconds);
  }

  // each bone's world position [x, y, z] (metres), for the tests and the console
  bonePositions() {
    if (!this.loaded) return null;
    this.loaded.root.updateMatrixWorld(true);
    const v = new THREE.Vector3();
    return Object.fromEntries(Object.entries(this.loaded.bones).map(([name, b]) => [name, b.getWorldPosition(v).toArray()]));
  }
}
