"""The pictures of docs/gltf.md: our GLB in Blender (a Cycles render) and on the page (headless Chromium).

    .venv/bin/python scripts/gltf/pictures.py [--out docs/data/gltf]

Needs Blender and Chromium + chromedriver on PATH (as the tests), and the vendored three.js. The
motion is the README's prompt, generated as a user does (`stablemo generate --format glb`, the demo
teacher, seed 0); the page runs the demo student, as tests/test_serve_browser.py does.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from stablemo.io import write_bytes

ROOT = Path(__file__).resolve().parents[2]
PROMPT = "a person walks forward, then waves their right hand"
FRAME = 100  # 5 s in: the wave

# runs inside Blender: the GLB at a frame, on a floor, lit by a sun, seen from its front left
RENDER = """
import bpy, math, mathutils, sys
src, dst, frame, site_packages = sys.argv[sys.argv.index("--") + 1:]
""" + "{numpy_fallback}" + """
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps = 20
bpy.ops.import_scene.gltf(filepath=src)
scene.frame_set(int(frame))
arm = next(o for o in scene.objects if o.type == "ARMATURE")
bones = arm.pose.bones
hips = arm.matrix_world @ bones["Hips"].head
# the body's facing in Blender's ground plane (z up): its left (LeftUpLeg - RightUpLeg) turned by -90 degrees
left = (arm.matrix_world @ bones["LeftUpLeg"].head) - (arm.matrix_world @ bones["RightUpLeg"].head)
front = mathutils.Vector((left.y, -left.x, 0.0)).normalized()
side = mathutils.Vector((left.x, left.y, 0.0)).normalized()
bpy.ops.mesh.primitive_plane_add(size=40, location=(hips.x, hips.y, 0))
floor = bpy.context.object
material = bpy.data.materials.new("floor")
material.use_nodes = True
material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.75, 0.75, 0.72, 1)
floor.data.materials.append(material)
camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
scene.collection.objects.link(camera)
scene.camera = camera
camera.location = hips + 3.6 * front + 2.0 * side + mathutils.Vector((0, 0, 0.7))
camera.rotation_euler = (mathutils.Vector((hips.x, hips.y, 0.85)) - camera.location).to_track_quat("-Z", "Y").to_euler()
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
scene.collection.objects.link(sun)
sun.data.energy = 3.0
sun.rotation_euler = (math.radians(40), math.radians(10), math.radians(30))
scene.world = bpy.data.worlds.new("world")
scene.world.use_nodes = True
scene.world.node_tree.nodes["Background"].inputs[0].default_value = (0.9, 0.9, 0.9, 1)
scene.world.node_tree.nodes["Background"].inputs[1].default_value = 0.6
scene.render.engine = "CYCLES"
scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", 32, False
scene.render.resolution_x, scene.render.resolution_y = 560, 420
scene.render.filepath = dst
bpy.ops.render.render(write_still=True)
"""


def blender_picture(glb: Path, png: Path) -> None:
    from stablemo.bench.blender import blender
    from stablemo.gltf.fbx import NUMPY_FALLBACK, site_packages

    with tempfile.TemporaryDirectory() as tmp:
        blender(RENDER.replace("{numpy_fallback}", NUMPY_FALLBACK), Path(tmp), str(glb), str(png), str(FRAME),
                site_packages(), timeout=600)


def page_pictures(out: Path) -> None:
    """The page before any motion (the body at rest) and paused on a motion, the canvas cropped."""
    from selenium.webdriver.common.by import By

    from stablemo.bench.browser import chrome_driver, wait_for
    from stablemo.inference.bundle import DEMO_STUDENT
    from stablemo.serve.api import create_app
    from stablemo.serve.local import serving
    from stablemo.serve.models import ModelSet

    def canvas_shot(driver, path: Path) -> None:
        write_bytes(path, driver.find_element(By.ID, "canvas").screenshot_as_png)  # the canvas alone

    with serving(create_app(ModelSet({"student": DEMO_STUDENT}))) as url, tempfile.TemporaryDirectory() as tmp:
        driver = chrome_driver(Path(tmp))
        try:
            driver.get(url + "/")
            wait_for(driver, "const s = window.stablemo; return s.ready && s.bodyShown")
            time.sleep(0.5)
            canvas_shot(driver, out / "page_rest.png")
            driver.find_element(By.ID, "prompt").send_keys(PROMPT)
            wait_for(driver, f"const s = window.stablemo; return s.motion && s.motion.text === {PROMPT!r} "
                             "&& s.body.holds(s.motion.spec) && s.bodyShown", 90)
            driver.execute_script("const s = document.getElementById('scrub'); s.value = arguments[0];"
                                  "s.dispatchEvent(new Event('input'))", FRAME)
            time.sleep(0.8)
            canvas_shot(driver, out / "page_body.png")
        finally:
            driver.quit()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "docs" / "data" / "gltf"))
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from stablemo.cli import main as cli

    with tempfile.TemporaryDirectory() as tmp:
        assert cli(["generate", PROMPT, "--format", "glb", "--out", tmp, "--seed", "0"]) == 0
        glb = Path(tmp) / "a-person-walks-forward-then-waves-their-right-hand.glb"
        blender_picture(glb, out / "blender.png")
    page_pictures(out)
    print(f"pictures in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
