"""A headless Chromium driven over the DevTools protocol, with the standard library only.

Chromium is started with `--remote-debugging-pipe`: it reads protocol messages (JSON, each ended
by a NUL byte) on file descriptor 3 and writes replies on 4. A `sh -c 'exec ... 3<&0 4>&1'`
wrapper maps our pipes onto those descriptors, so neither a websocket library nor `preexec_fn`
is needed. Flags follow docs/PLATFORM-NOTES (the viewer falls back to WebGL2 on SwiftShader).
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


def find_chromium() -> str | None:
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path is not None:
            return path
    return None


class DevToolsError(RuntimeError):
    pass


class HeadlessChromium:
    """One browser with one page; `close()` (or the context manager) ends it."""

    def __init__(self, executable: str, width_px: int = 1600, height_px: int = 900) -> None:
        self._profile = tempfile.mkdtemp(prefix="chromium-profile-")
        flags = [
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={self._profile}",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost, EXCLUDE 127.0.0.1",
            "--remote-debugging-pipe",
            f"--window-size={width_px},{height_px}",
        ]
        self._process = subprocess.Popen(
            ["sh", "-c", 'exec "$@" 3<&0 4>&1 </dev/null >/dev/null', "sh", executable, *flags],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        self._buffer = b""
        self._next_id = 0
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self._session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]
        self.resize(width_px, height_px)

    def resize(self, width_px: int, height_px: int) -> None:
        self.call(
            "Emulation.setDeviceMetricsOverride",
            {"width": width_px, "height": height_px, "deviceScaleFactor": 1, "mobile": False},
            page=True,
        )

    def call(
        self,
        method: str,
        params: dict[str, Any] | None = None,
        page: bool = False,
        timeout_s: float = 60.0,
    ) -> dict[str, Any]:
        """Send one command and wait for its reply (events in between are skipped)."""
        assert self._process.stdin is not None and self._process.stdout is not None
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if page:
            message["sessionId"] = self._session
        self._process.stdin.write(json.dumps(message).encode() + b"\0")
        self._process.stdin.flush()
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\0" in self._buffer:
                raw, self._buffer = self._buffer.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._next_id:
                    if "error" in reply:
                        raise DevToolsError(f"{method}: {reply['error']}")
                    result: dict[str, Any] = reply.get("result", {})
                    return result
            remaining = deadline - time.monotonic()
            ready, _, _ = select.select([self._process.stdout], [], [], max(0.0, remaining))
            if not ready:
                raise TimeoutError(f"{method}: no reply from Chromium within {timeout_s} s")
            chunk = os.read(self._process.stdout.fileno(), 1 << 20)
            if not chunk:
                raise DevToolsError(f"{method}: Chromium closed the DevTools pipe")
            self._buffer += chunk

    def navigate(self, url: str) -> None:
        self.call("Page.navigate", {"url": url}, page=True)

    def screenshot_png(self, timeout_s: float = 60.0) -> bytes:
        data = self.call(
            "Page.captureScreenshot", {"format": "png"}, page=True, timeout_s=timeout_s
        )
        return base64.b64decode(data["data"])

    def close(self) -> None:
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        for stream in (self._process.stdin, self._process.stdout):
            if stream is not None:
                stream.close()
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> HeadlessChromium:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def save(png: bytes, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png)
