"""Headless Chromium driven over the Chrome DevTools protocol (a websocket, `websockets`' sync
client, which viser already depends on): open a page, evaluate JavaScript, take screenshots,
without starting the browser again for each one (software WebGL is slow on 2 cores).

Used by `morphmimic studio --screenshot` (docs/img/studio.png) and tests/learner/live/test_studio.py.
"""

from __future__ import annotations

import base64
import io
import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
from websockets.sync.client import connect


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


class Chromium:
    """One headless browser with one page at `url`; use as a context manager."""

    def __init__(self, url: str, width: int = 1280, height: int = 800, timeout_s: float = 20.0):
        exe = find_chromium()
        if exe is None:
            raise RuntimeError("chromium is not installed (apt-get install chromium)")
        self._profile = tempfile.TemporaryDirectory(prefix="studio-chromium-")
        self.proc = subprocess.Popen(
            [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--mute-audio",
             "--no-first-run", "--disable-extensions", "--remote-debugging-port=0", "--remote-debugging-address=127.0.0.1",
             f"--user-data-dir={self._profile.name}", f"--window-size={width},{height}", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # its helpers in one group
        try:
            port_file = Path(self._profile.name) / "DevToolsActivePort"
            end = time.monotonic() + timeout_s
            while not (port_file.is_file() and port_file.read_text().count("\n") >= 1):
                if time.monotonic() > end or self.proc.poll() is not None:
                    raise RuntimeError("chromium did not open its DevTools port")
                time.sleep(0.1)
            port = int(port_file.read_text().split()[0])
            ws_url = None
            while ws_url is None:
                pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5))
                ws_url = next((p["webSocketDebuggerUrl"] for p in pages if p.get("type") == "page"), None)
                if ws_url is None:
                    if time.monotonic() > end:
                        raise RuntimeError("chromium opened no page")
                    time.sleep(0.1)
            self.ws = connect(ws_url, max_size=None, open_timeout=timeout_s)
        except BaseException:
            self.close()
            raise
        self._ids = itertools.count(1)

    def call(self, method: str, timeout_s: float = 30.0, **params) -> dict:
        i = next(self._ids)
        self.ws.send(json.dumps({"id": i, "method": method, "params": params}))
        end = time.monotonic() + timeout_s
        while True:
            msg = json.loads(self.ws.recv(timeout=max(0.1, end - time.monotonic())))
            if msg.get("id") == i:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def evaluate(self, js: str):
        return self.call("Runtime.evaluate", expression=js, returnByValue=True).get("result", {}).get("value")

    def screenshot(self) -> np.ndarray:
        """The page now, as an RGB array [H, W, 3]."""
        import imageio.v3 as iio  # lazy: heavy (imageio), only when taking a screenshot

        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return iio.imread(io.BytesIO(data))[..., :3]

    def screenshot_png(self, path: Path) -> None:
        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        Path(path).write_bytes(data)

    def close(self) -> None:
        ws = getattr(self, "ws", None)
        if ws is not None:
            try:
                ws.close()
            except Exception:  # noqa: BLE001
                pass
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        # NOTE: Chromium's helper processes (crashpad, renderers) can outlive the browser and still
        # write into the profile while it is removed ("Directory not empty", seen under load):
        # end the whole process group first, and retry the removal briefly.
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        for attempt in range(10):
            try:
                self._profile.cleanup()
                break
            except OSError:
                time.sleep(0.2)

    def __enter__(self) -> "Chromium":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def character_pixels(img: np.ndarray) -> int:
    """Pixels of the character's blue-grey in the studio's 3-D canvas, away from the panel (right),
    the notification (top left) and the axes widget (bottom left): the floor grid is neutral grey."""
    h, w = img.shape[:2]
    region = img[int(h * 0.3): h - 70, 80: w - 420].astype(int)
    return int(((region[..., 2] - region[..., 0] >= 12) & (region[..., 0] < 230)).sum())


DISMISS_NOTIFICATIONS_JS = """
(() => { let n = 0;
  for (const b of document.querySelectorAll('.mantine-Notification-root button, .mantine-Notification-closeButton')) { b.click(); n++; }
  return n; })()
"""
