"""A page opened in headless Chromium (Debian's ``chromium``) over the DevTools protocol on a pipe: its console
messages, log entries (failed loads, blocked requests), uncaught exceptions, every request it makes, and a
screenshot. No browser download, no network: the page is a local file.

    with Chromium() as browser:
        page = browser.open(path)      # Page: .errors, .requests, .png (bytes)
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--remote-debugging-pipe", "--hide-scrollbars")


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser"):
        exe = shutil.which(name)
        if exe:
            return exe
    return None


@dataclass
class Page:
    errors: list = field(default_factory=list)  # console errors and warnings, error log entries, exceptions
    messages: list = field(default_factory=list)  # every console message and log entry, as text
    requests: list = field(default_factory=list)  # URLs the page asked for (the page itself included)
    png: bytes = b""


class Chromium:
    """One headless Chromium process, spoken to over fds 3 (commands) and 4 (replies) as --remote-debugging-pipe
    defines: JSON messages ended by a NUL byte."""

    def __init__(self, width: int = 1200, height: int = 900, timeout: float = 60.0):
        self.exe = find_chromium()
        if self.exe is None:
            raise FileNotFoundError("chromium is not installed (apt-get install chromium)")
        self.width, self.height, self.timeout = width, height, timeout
        self._id = 0
        self._buf = b""

    def __enter__(self) -> Chromium:
        self._profile = tempfile.mkdtemp(prefix="nrmpc_chromium_")
        to_chrome_r, self._w = os.pipe()
        self._r, from_chrome_w = os.pipe()
        # the child's fd 3 reads our commands and its fd 4 writes the replies
        cmd = [self.exe, *FLAGS, f"--user-data-dir={self._profile}", f"--window-size={self.width},{self.height}"]

        def fds():  # copies first: either pipe end may already sit on fd 3 or 4
            a, b = os.dup(to_chrome_r), os.dup(from_chrome_w)
            os.dup2(a, 3)
            os.dup2(b, 4)

        # fds 3 and 4 are kept open in the child (the fds closed after preexec_fn are all but these)
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, preexec_fn=fds, pass_fds=(3, 4),
                                     start_new_session=True)
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        return self

    def __exit__(self, *exc) -> None:
        try:
            self._send("Browser.close")
            self.proc.wait(10)
        except Exception:  # noqa: BLE001 - closing: kill below
            pass
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, 9)
            self.proc.wait(10)
        os.close(self._w)
        os.close(self._r)
        shutil.rmtree(self._profile, ignore_errors=True)

    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> int:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        return self._id

    def _next(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            if time.monotonic() > deadline:
                raise TimeoutError("chromium did not answer in time")
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise ConnectionError("chromium closed the pipe")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def _call(self, method: str, params: dict | None = None, session: str | None = None, events=None) -> dict:
        """Send one command and wait for its reply; events on the way go to ``events`` (a list)."""
        i = self._send(method, params, session)
        deadline = time.monotonic() + self.timeout
        while True:
            msg = self._next(deadline)
            if msg.get("id") == i:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            if events is not None:
                events.append(msg)

    def open(self, path: Path) -> Page:
        """Load ``path`` in a new tab, wait for its load event and a quiet moment, take a full-page screenshot."""
        events: list = []
        target = self._call("Target.createTarget", {"url": "about:blank"})["targetId"]
        s = self._call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Log", "Runtime", "Page", "Network"):
            self._call(f"{domain}.enable", session=s, events=events)
        self._call("Page.navigate", {"url": Path(path).resolve().as_uri()}, session=s, events=events)
        deadline = time.monotonic() + self.timeout
        while not any(e.get("method") == "Page.loadEventFired" for e in events):
            events.append(self._next(deadline))
        metrics = self._call("Page.getLayoutMetrics", session=s, events=events)
        size = metrics.get("cssContentSize") or metrics["contentSize"]
        shot = self._call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True, "clip": {
            "x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1}}, session=s, events=events)
        page = Page(png=base64.b64decode(shot["data"]))
        for e in events:
            m, p = e.get("method"), e.get("params", {})
            if m == "Runtime.consoleAPICalled":
                text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
                page.messages.append(f"console.{p['type']}: {text}")
                if p["type"] in ("error", "warning", "assert"):
                    page.errors.append(page.messages[-1])
            elif m == "Log.entryAdded":
                entry = p["entry"]
                page.messages.append(f"log {entry['level']}: {entry.get('text')} {entry.get('url', '')}")
                if entry["level"] in ("error", "warning"):
                    page.errors.append(page.messages[-1])
            elif m == "Runtime.exceptionThrown":
                page.errors.append(f"exception: {p['exceptionDetails'].get('text')}")
            elif m == "Network.requestWillBeSent":
                page.requests.append(p["request"]["url"])
        return page
