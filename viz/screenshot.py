"""A PNG of a served viewer page through headless Chromium (`fluidgs view --screenshot`).

The page draws with WebGL, so a picture needs a browser: Chromium runs headless with WebGL in software (ANGLE on
SwiftShader), is driven through its DevTools protocol (a websocket; the ``websockets`` package that viser brings),
waits until the page shows its canvas and colour bars, lets the splat settle for ``settle_s`` seconds, closes
viser's notifications and captures the page. Without Chromium, :func:`find_browser` returns None and
:func:`screenshot` raises :class:`ScreenshotUnavailable` with what to install.
"""

from __future__ import annotations

import base64
import contextlib
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

from fluidsim.files.atomic import write_bytes_atomic

__all__ = ["BROWSERS", "ScreenshotUnavailable", "find_browser", "screenshot"]

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
# WebGL in software: Chromium 1xx renders WebGL through ANGLE on SwiftShader (Vulkan) when headless
BROWSER_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--disable-gpu-sandbox",
    "--hide-scrollbars",
)
# the page is ready when it has a canvas and its colour-bar images have loaded
READY = (
    "(() => { const im = [...document.images].filter(i => i.getBoundingClientRect().width > 150); "
    "return !!document.querySelector('canvas') && im.length > 0 && im.every(i => i.complete && "
    "i.naturalWidth > 0); })()"
)
CLOSE_NOTIFICATIONS = "[...document.querySelectorAll('.mantine-Notification-closeButton')].forEach(b => b.click())"


class ScreenshotUnavailable(ValueError):
    """No Chromium on this machine, or it does not start: the message says what to install or do instead."""


def find_browser() -> str | None:
    """The path of the first Chromium of :data:`BROWSERS` on PATH, or None."""
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


class DevTools:
    """The smallest DevTools protocol client: one page, calls answered in order."""

    def __init__(self, ws):
        self.ws, self.next_id = ws, 0

    def call(self, method: str, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=60))
            if msg.get("id") == self.next_id:
                if "error" in msg:
                    raise ScreenshotUnavailable(f"Chromium: {method} failed: {msg['error']}")
                return msg["result"]

    def eval(self, expression: str):
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")


def screenshot(
    url: str, out: str | Path, size: tuple[int, int] = (1280, 800), settle_s: float = 5.0, timeout_s: float = 150.0
) -> Path:
    """Write a PNG of the page at ``url`` (a running viewer) as headless Chromium draws it.

    Args:
        url: the viewer's address. out: the PNG to write (atomically). size: (width, height) pixels.
        settle_s: seconds to wait after the page is ready (the splat streams in). timeout_s: the limit for it all.
    Returns:
        the path written.
    Raises:
        ScreenshotUnavailable: no Chromium, it does not start, or the page never became ready in time.
    """
    deadline = time.monotonic() + timeout_s
    with devtools_page(size, deadline) as tools:
        tools.call("Page.navigate", url=url)
        while not tools.eval(READY):
            if time.monotonic() > deadline:
                raise ScreenshotUnavailable(f"the viewer page at {url} never became ready in {timeout_s:g} s")
            time.sleep(0.5)
        time.sleep(settle_s)
        tools.eval(CLOSE_NOTIFICATIONS)
        time.sleep(0.5)
        png = base64.b64decode(tools.call("Page.captureScreenshot", format="png")["data"])
    return write_bytes_atomic(Path(out), png)


@contextlib.contextmanager
def devtools_page(size: tuple[int, int], deadline: float):
    """Headless Chromium showing a blank page of ``size`` (width, height) pixels, driven through :class:`DevTools` in
    the ``with`` block and stopped after it. Raises :class:`ScreenshotUnavailable` without Chromium or websockets, or
    when the browser has not started by ``deadline`` (a ``time.monotonic()``)."""
    browser = find_browser()
    if browser is None:
        raise ScreenshotUnavailable(
            f"--screenshot needs Chromium ({', '.join(BROWSERS)} on PATH), and none is installed; install it "
            "(Debian/Ubuntu: apt-get install chromium), or open the viewer's address in a browser and save the "
            "picture from there"
        )
    try:
        import websockets.sync.client  # noqa: PLC0415 - viser's dependency, only for a screenshot
    except ImportError as exc:
        raise ScreenshotUnavailable(
            f"--screenshot needs the websockets package ({exc}); pip install websockets"
        ) from None
    with browser_profile() as profile:
        flags = [*BROWSER_FLAGS, f"--window-size={size[0]},{size[1]}", "--remote-debugging-port=0"]
        proc = subprocess.Popen(
            [browser, *flags, f"--user-data-dir={profile}", "about:blank"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            port_file = Path(profile) / "DevToolsActivePort"
            while not (port_file.exists() and len(port_file.read_text().split()) >= 2):
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise ScreenshotUnavailable(f"{browser} did not start (exit status {proc.poll()})")
                time.sleep(0.1)
            port = port_file.read_text().split()[0]
            targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=30))
            page = next(t for t in targets if t.get("type") == "page")
            with websockets.sync.client.connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=30) as ws:
                tools = DevTools(ws)
                w, h = size
                tools.call("Emulation.setDeviceMetricsOverride", width=w, height=h, deviceScaleFactor=1, mobile=False)
                yield tools
        finally:
            stop_browser(proc)


@contextlib.contextmanager
def browser_profile():
    """A temporary Chromium profile folder, removed after the browser: its helper processes outlive the main one by a
    moment and may still write there, so the removal is retried for up to 2 s and never raises (a cleanup error
    ended a finished screenshot with a traceback)."""
    with tempfile.TemporaryDirectory(prefix="fluidgs-chromium-", ignore_cleanup_errors=True) as profile:
        try:
            yield profile
        finally:
            for _ in range(10):
                shutil.rmtree(profile, ignore_errors=True)
                if not Path(profile).exists():
                    break
                time.sleep(0.2)
            Path(profile).mkdir(exist_ok=True)  # TemporaryDirectory removes it (and whatever came back)


def stop_browser(proc: subprocess.Popen) -> None:
    """Terminate Chromium, killing it after 10 s."""
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
