"""Headless Chromium driven by Selenium, for the viewer's tests and the README's screenshot.

Debian's ``chromium`` and ``chromium-driver`` (``apt-get install -y chromium chromium-driver``;
``.ci/run`` installs them) give the browser and its driver at the same version; Selenium is told
both paths, so it downloads nothing. The flags keep a root, offline, display-less Chromium quiet:
no sandbox (root), no GPU, and none of its background connections.

``python tests/service/browser.py docs/viewer.png`` starts a server with the demo teapot, opens
the viewer, orbits it by a drag and saves a screenshot of the page.
"""

from __future__ import annotations

import base64
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--force-device-scale-factor=1",
    "--window-size=1000,860",
)


def missing() -> str | None:
    """Why the browser cannot start here, or None."""
    for path in (CHROMIUM, CHROMEDRIVER):
        if shutil.which(path) is None:
            return f"{path} is not installed (apt-get install -y chromium chromium-driver)"
    return None


@contextmanager
def chromium() -> Iterator:
    """A Selenium WebDriver of a new headless Chromium with an empty profile."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    with tempfile.TemporaryDirectory(prefix="dacrt-chromium-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for flag in (*FLAGS, f"--user-data-dir={profile}"):
            options.add_argument(flag)
        options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # console errors
        driver = webdriver.Chrome(options=options, service=Service(executable_path=CHROMEDRIVER))
        try:
            yield driver
        finally:
            driver.quit()


#: Resolves to the shown picture's PNG bytes, base64 (the viewer keeps it as a blob: URL).
SHOWN_PNG = """
const done = arguments[arguments.length - 1];
fetch(document.getElementById("view").src)
  .then((r) => r.arrayBuffer())
  .then((b) => {
    let s = "";
    new Uint8Array(b).forEach((x) => { s += String.fromCharCode(x); });
    done(btoa(s));
  })
  .catch((e) => done("error: " + e));
"""


def shown_png(driver) -> bytes:
    """The PNG the viewer shows now, as the server sent it."""
    encoded = driver.execute_async_script(SHOWN_PNG)
    assert not encoded.startswith("error"), encoded
    return base64.b64decode(encoded)


def wait_for_picture(driver, after: int = 0, timeout: float = 60) -> int:
    """Wait until the viewer has shown more than ``after`` pictures and has none on its way;
    answers how many it has shown."""
    from selenium.webdriver.support.ui import WebDriverWait

    def settled(d):
        renders = d.execute_script(
            "const v = window.viewer; const n = Number(document.getElementById('view')"
            ".dataset.renders || 0); return v && v.idle() && n > arguments[0] ? n : 0;",
            after,
        )
        return renders or False

    return WebDriverWait(driver, timeout, poll_frequency=0.05).until(settled)


def drag(driver, dx: int, dy: int, *, shift: bool = False, steps: int = 4) -> None:
    """Press on the picture, move by (dx, dy) in ``steps`` moves, release (holding shift if
    asked)."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    picture = driver.find_element("id", "view")
    actions = ActionChains(driver, duration=20)
    if shift:
        actions.key_down(Keys.SHIFT)
    actions.move_to_element(picture).click_and_hold()
    for _ in range(steps):
        actions.move_by_offset(dx // steps, dy // steps)
    actions.release()
    if shift:
        actions.key_up(Keys.SHIFT)
    actions.perform()


def screenshot(path: Path) -> None:
    """Start ``python -m service`` with the demo scene, open the viewer, orbit it, save a
    screenshot of the whole window to ``path``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from server_process import ServerProcess

    server = ServerProcess({"DACRT_LOAD_DEMO": "true"})
    try:
        url = server.wait_ready()
        with chromium() as driver:
            driver.get(url + "/#scene=demo&up=y")
            count = wait_for_picture(driver)
            drag(driver, -40, 12)
            wait_for_picture(driver, count)
            driver.save_screenshot(str(path))
    finally:
        server.stop()


if __name__ == "__main__":
    screenshot(Path(sys.argv[1]))
