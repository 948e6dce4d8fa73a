"""Open a page in headless Chromium (Debian's ``chromium``) over the DevTools protocol.

:func:`open_page` loads a file, gathers console messages, uncaught exceptions and log entries
(CSP violations and failed loads are log entries), evaluates a JavaScript expression in the
page and saves a screenshot. The browser runs with a fresh profile, no network services and no
sandbox (tests run as root), and is killed when done. :func:`chromium_or_skip` skips a test
with the reason when there is no ``chromium``.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    "--remote-debugging-port=0",
    "--window-size=1280,900",
]


def chromium_or_skip() -> str:
    """The ``chromium`` executable, or skip the test saying how to install it."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("no chromium on PATH (apt-get install chromium; .ci/run installs it)")
    pytest.importorskip("websockets", reason="the DevTools client needs websockets (dev extra)")
    return exe


@dataclass
class PageResult:
    """What the page did: its console errors and log entries, and the expression's value."""

    errors: list[str] = field(default_factory=list)
    value: Any = None
    screenshot: Path | None = None


class _Session:
    def __init__(self, ws: Any) -> None:
        self.ws, self.next_id, self.events = ws, 0, []  # type: ignore[var-annotated]
        self.session: str | None = None

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        self.next_id += 1
        msg: dict[str, Any] = {"id": self.next_id, "method": method, "params": params}
        if self.session is not None:
            msg["sessionId"] = self.session
        self.ws.send(json.dumps(msg))
        while True:
            reply = json.loads(self.ws.recv(timeout=60))
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return dict(reply.get("result", {}))
            self.events.append(reply)

    def wait_for(self, method: str, timeout: float = 60) -> None:
        deadline = time.monotonic() + timeout
        if any(e.get("method") == method for e in self.events):
            return
        while time.monotonic() < deadline:
            event = json.loads(self.ws.recv(timeout=deadline - time.monotonic()))
            self.events.append(event)
            if event.get("method") == method:
                return
        raise TimeoutError(method)


def _errors(events: list[dict[str, Any]]) -> list[str]:
    out = []
    for e in events:
        method, params = e.get("method"), e.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "warning"):
            out.append(f"console.{params['type']}: {params.get('args')}")
        elif method == "Runtime.exceptionThrown":
            out.append(f"exception: {params.get('exceptionDetails')}")
        elif method == "Log.entryAdded" and params["entry"].get("level") in ("error", "warning"):
            out.append(f"log: {params['entry'].get('text')}")
    return out


def _port(profile: Path, proc: subprocess.Popen[bytes]) -> str:
    """The browser's DevTools websocket path (``ws://127.0.0.1:PORT/devtools/browser/ID``)."""
    active = profile / "DevToolsActivePort"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if active.exists() and len(lines := active.read_text().split()) >= 2:
            return f"ws://127.0.0.1:{lines[0]}{lines[1]}"
        if proc.poll() is not None:
            raise RuntimeError(f"chromium exited {proc.returncode}")
        time.sleep(0.1)
    raise TimeoutError("chromium did not open its DevTools port")


def open_page(
    page: Path, expression: str, screenshot: Path | None = None, *, width: int | None = None
) -> PageResult:
    """Load ``page``, evaluate ``expression`` (JSON-able value), save a full-page screenshot.

    ``width``: the viewport's width in CSS pixels (default: the window's, 1280).
    """
    from websockets.sync.client import connect

    exe = chromium_or_skip()
    # the profile is Chromium's temporary directory too: it makes org.chromium.Chromium.*
    # there (its singleton socket), which it leaves when killed (a short prefix: the socket's
    # path must fit in 107 bytes)
    with tempfile.TemporaryDirectory(prefix="chromium-", ignore_cleanup_errors=True) as profile:
        proc = subprocess.Popen(
            [exe, *FLAGS, f"--user-data-dir={profile}", "about:blank"],
            env={**os.environ, "TMPDIR": profile},
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # its own process group: its helpers end with it
        )
        try:
            with connect(_port(Path(profile), proc), max_size=2**28) as ws:
                s = _Session(ws)
                target = s.call("Target.createTarget", url="about:blank")["targetId"]
                s.session = s.call("Target.attachToTarget", targetId=target, flatten=True)[
                    "sessionId"
                ]
                for domain in ("Runtime", "Log", "Page"):
                    s.call(f"{domain}.enable")
                if width is not None:
                    s.call(
                        "Emulation.setDeviceMetricsOverride",
                        width=width,
                        height=900,
                        deviceScaleFactor=1,
                        mobile=False,
                    )
                s.call("Page.navigate", url=page.resolve().as_uri())
                s.wait_for("Page.loadEventFired")
                value = s.call("Runtime.evaluate", expression=expression, returnByValue=True)[
                    "result"
                ].get("value")
                result = PageResult(value=value)
                if screenshot is not None:
                    size = s.call("Page.getLayoutMetrics")["cssContentSize"]
                    shot = s.call(
                        "Page.captureScreenshot",
                        format="png",
                        captureBeyondViewport=True,
                        clip={"x": 0, "y": 0, "width": size["width"], "height": size["height"],
                              "scale": 1},
                    )  # fmt: skip
                    screenshot.write_bytes(base64.b64decode(shot["data"]))
                    result.screenshot = screenshot
                result.errors = _errors(s.events)
                return result
        finally:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
