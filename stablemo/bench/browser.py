"""Headless Chromium for the measurement scripts and the browser tests: a selenium driver on Debian's
chromium and chromium-driver (downloads into a given folder), and a wait on a condition the page's
own state answers (window.stablemo). selenium is imported by the functions, so this module loads
without it; callers check `chromium_paths()` first."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

__all__ = ["chrome_driver", "chromium_paths", "wait_for"]


def chromium_paths() -> tuple[str | None, str | None]:
    """(the Chromium binary, its driver) on PATH, None where absent."""
    return shutil.which("chromium") or shutil.which("chromium-browser"), shutil.which("chromedriver")


def chrome_driver(downloads: Path):
    """A headless Chromium with a 1100x750 window that saves downloads into `downloads`."""
    from selenium import webdriver

    chromium, driver = chromium_paths()
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    opts.add_experimental_option("prefs", {"download.default_directory": str(downloads),
                                           "download.prompt_for_download": False})
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1100,750",
                "--disable-gpu-sandbox", "--enable-unsafe-swiftshader"):
        opts.add_argument(arg)
    return webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=driver))


def wait_for(driver, script: str, timeout: float = 60.0):
    """Run `script` in the page until it returns a truthy value (returned); after `timeout` seconds
    an AssertionError naming the script and the page's state (its error, status line, requests)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    state = driver.execute_script("const s = window.stablemo; return {error: s.error, status:"
                                  " (document.getElementById('status') || {}).textContent,"
                                  " requests: s.requests, frame: s.frame, playing: s.playing}")
    raise AssertionError(f"timed out waiting for: {script} (page: {state})")
