"""The page in a real browser: headless Chromium (Debian's chromium + chromium-driver) driven by
selenium types a prompt, waits for the animation, and checks from a screenshot and from the
page's own state (window.stablemo) that the skeleton is drawn and moves; an empty prompt shows the
server's error. Skipped when Chromium, its driver, selenium or the vendored three.js is absent
(.ci/run installs Chromium; scripts/setup.sh vendors three.js)."""

from __future__ import annotations

import io
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fastapi")
webdriver = pytest.importorskip("selenium.webdriver")

from stablemo.serve.vendor import missing

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
if not (CHROMIUM and DRIVER):
    pytest.skip("Chromium and chromedriver are not installed (apt-get install chromium chromium-driver)",
                allow_module_level=True)
if missing():
    pytest.skip(missing(), allow_module_level=True)

from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys

from stablemo.serve.api import create_app
from stablemo.serve.local import serving
from stablemo.serve.models import ModelSet

DEMO = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_bundle"
PROMPT = "a person jumps, then turns left"
# the page's limb colours (stablemo.render): left, right, centre
LIMBS = np.array([[0x1F, 0x6F, 0xD1], [0xD6, 0x2F, 0x2F], [0x44, 0x44, 0x44]], dtype=float)


def chrome_driver():
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1100,750",
                "--disable-gpu-sandbox", "--enable-unsafe-swiftshader"):
        opts.add_argument(arg)
    return webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=DRIVER))


def wait_for(driver, script: str, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for: {script}")


@pytest.fixture(scope="module")
def page():
    models = ModelSet({"teacher": DEMO})
    with serving(create_app(models)) as url:
        driver = chrome_driver()
        try:
            driver.get(url + "/")
            wait_for(driver, "return window.stablemo && window.stablemo.ready")
            yield driver
        finally:
            driver.quit()


def limb_coloured(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) pixels -> (...,) bool: within shading distance of one of the limb colours."""
    dist = np.abs(rgb[..., None, :].astype(float) - LIMBS).max(-1)  # (..., 3)
    # lighting scales a colour; compare chroma for the coloured limbs, darkness for the spine
    return (dist < 70).any(-1)


def test_typed_prompt_is_drawn_and_moves_then_empty_prompt_shows_the_error(page, tmp_path):
    box = page.find_element(By.ID, "prompt")
    box.send_keys(PROMPT)
    # typing sends partial prompts too (generation follows typing): wait for the whole one
    wait_for(page, f"const s = window.stablemo; return s.motion && s.motion.text === {PROMPT!r} "
                   "&& s.timings.some(t => t.text === s.motion.text && t.drawn)")
    state = page.execute_script("const s = window.stablemo; return {frames: s.motion.frames, error: s.error, "
                                "fps: s.motion.fps, model: s.motion.model}")
    assert state == {"frames": 120, "error": None, "fps": 20, "model": "teacher"}

    # the figure moves: two poses drawn 0.5 s apart differ by more than a few centimetres
    first = page.execute_script("return [window.stablemo.frame, window.stablemo.worldPose]")
    time.sleep(0.5)
    second = page.execute_script("return [window.stablemo.frame, window.stablemo.worldPose]")
    assert first[0] != second[0]
    moved = np.linalg.norm(np.array(first[1]) - np.array(second[1]), axis=-1)  # (22,) metres
    assert moved.shape == (22,) and moved.max() > 0.03

    # pause, then compare the screenshot with where the page says it drew each joint
    page.find_element(By.ID, "play").click()
    wait_for(page, "return !window.stablemo.playing")
    time.sleep(0.3)
    drawn = page.execute_script("const r = document.getElementById('canvas').getBoundingClientRect();"
                                "return [r.left, r.top, window.devicePixelRatio, window.stablemo.screenPose]")
    from PIL import Image

    shot = np.asarray(Image.open(io.BytesIO(page.get_screenshot_as_png())).convert("RGB"))
    Image.fromarray(shot).save(tmp_path / "page.png")
    left, top, ratio, joints = drawn
    hits = 0
    for x, y in joints:
        px, py = round((left + x) * ratio), round((top + y) * ratio)
        patch = shot[max(py - 3, 0):py + 4, max(px - 3, 0):px + 4]
        hits += bool(limb_coloured(patch).any())
    assert hits >= 20, f"only {hits} of 22 joints are drawn where the page says (screenshot {tmp_path / 'page.png'})"
    # and the rest of the view is floor and sky, not skeleton
    canvas = shot[int(top * ratio):, :int((left + page.execute_script(
        "return document.getElementById('canvas').clientWidth")) * ratio)]
    assert 0.001 < limb_coloured(canvas).mean() < 0.2

    # an empty prompt: the server's one-line error is shown on the page
    box.send_keys(Keys.CONTROL, "a")
    box.send_keys(Keys.BACKSPACE)
    wait_for(page, "return window.stablemo.error")
    status = page.find_element(By.ID, "status")
    assert status.text == "text: empty prompt" and "error" in status.get_attribute("class")
