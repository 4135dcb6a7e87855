"""Headless Chromium (Debian's ``/usr/bin/chromium``) driven over the DevTools protocol.

For the monitor's page test and bench/bench_monitor.py: :class:`Chromium` opens a URL,
:meth:`Chromium.evaluate` runs JavaScript in the page and returns its (JSON) value,
:meth:`Chromium.screenshot` returns the page as an ``[h, w, 3]`` uint8 array. The DevTools
WebSocket is aiohttp's client (the monitor's own dependency). Every wait has a generous deadline.
"""

import asyncio
import base64
import io
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import aiohttp
import numpy as np

CHROMIUM = '/usr/bin/chromium'
WAIT_S = 120
FLAGS = (
    '--headless',
    '--no-sandbox',
    '--disable-gpu',
    '--disable-quic',
    '--no-first-run',
    '--disable-background-networking',
    '--disable-component-update',
    '--disable-sync',
    '--hide-scrollbars',
    '--force-device-scale-factor=1',
    '--remote-debugging-port=0',
)


class Chromium:
    """One headless Chromium showing ``url`` in a ``size`` window (pixels)."""

    def __init__(self, url: str, size=(1400, 800)):
        self.profile = Path(tempfile.mkdtemp(prefix='knode_chromium_'))
        self.proc = subprocess.Popen(
            [CHROMIUM, *FLAGS, f'--user-data-dir={self.profile}', f'--window-size={size[0]},{size[1]}', url],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        self.ids = itertools.count(1)
        self.target = self._page_target()
        # One DevTools session for the browser's life: Chromium drops a session's overrides (the
        # viewport's size below) when that session closes.
        self.loop = asyncio.new_event_loop()
        self.http = self.loop.run_until_complete(_session())
        self.ws = self.loop.run_until_complete(self.http.ws_connect(self.target, max_msg_size=0))
        # The viewport itself, not the window (whose frame takes some of it), is ``size``.
        self.call(
            'Emulation.setDeviceMetricsOverride',
            width=size[0],
            height=size[1],
            deviceScaleFactor=1,
            mobile=False,
        )

    def _page_target(self) -> str:
        """The page's DevTools WebSocket address (Chromium writes its port once listening)."""
        port_file = self.profile / 'DevToolsActivePort'
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline and self.proc.poll() is None:
            if port_file.is_file() and port_file.read_text().strip():
                port = int(port_file.read_text().split()[0])
                targets = asyncio.run(_get_json(f'http://127.0.0.1:{port}/json/list'))
                pages = [t for t in targets if t.get('type') == 'page']
                if pages:
                    return pages[0]['webSocketDebuggerUrl']
            time.sleep(0.2)
        raise RuntimeError(f'chromium did not start (status {self.proc.poll()})')

    def call(self, method: str, **params):
        """One DevTools command's result."""
        return self.loop.run_until_complete(asyncio.wait_for(self._call(method, params), WAIT_S))

    async def _call(self, method, params):
        mid = next(self.ids)
        await self.ws.send_str(json.dumps({'id': mid, 'method': method, 'params': params}))
        async for msg in self.ws:
            reply = json.loads(msg.data)
            if reply.get('id') == mid:
                if 'error' in reply:
                    raise RuntimeError(f'{method}: {reply["error"]}')
                return reply['result']
        raise RuntimeError(f'{method}: no reply')

    def evaluate(self, expression: str):
        """The JSON value of ``expression`` in the page (None when undefined)."""
        result = self.call('Runtime.evaluate', expression=f'JSON.stringify({expression})', returnByValue=True)
        value = result['result'].get('value')
        return None if value is None else json.loads(value)

    def wait_until(self, expression: str, timeout: float = WAIT_S):
        """Poll ``expression`` until it is truthy; returns its value."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.2)
        raise AssertionError(f'{expression} still false after {timeout:g} s')

    def screenshot(self) -> np.ndarray:
        """The page as pixels ``[h, w, 3]`` uint8."""
        from PIL import Image

        data = base64.b64decode(self.call('Page.captureScreenshot', format='png')['data'])
        return np.asarray(Image.open(io.BytesIO(data)).convert('RGB'))

    def close(self) -> None:
        if not self.loop.is_closed():
            self.loop.run_until_complete(self.ws.close())
            self.loop.run_until_complete(self.http.close())
            self.loop.close()
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, 15)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, 9)
                self.proc.wait()
        shutil.rmtree(self.profile, ignore_errors=True)


async def _session() -> aiohttp.ClientSession:
    return aiohttp.ClientSession()  # made inside the loop that will use it


async def _get_json(url: str):
    async with aiohttp.ClientSession() as session:
        async with session.get(url) as response:
            return await response.json(content_type=None)
