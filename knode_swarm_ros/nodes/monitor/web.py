"""The monitor's web page and WebSocket (aiohttp), served from a thread of its own.

``GET /`` is ``page.html`` (the project's own HTML and JavaScript, nothing fetched from
elsewhere, so it works on a robot network without internet); ``GET /ws`` is a WebSocket that
sends the run's hello message, then the newest tick each time one is published. A slow browser
never holds anything up: each client is sent the newest tick once its previous send is done,
ticks published in between are skipped (no queue grows). Frames go uncompressed: deflating a
few kilobytes a tick cost the monitor more CPU than the bytes cost the network. No rclpy here.
"""

from __future__ import annotations

import asyncio
import ipaddress
import threading
from pathlib import Path
from typing import Optional, Set

from aiohttp import WSCloseCode, WSMsgType, web

__all__ = ['WebServer', 'is_loopback', 'PAGE']

PAGE = Path(__file__).with_name('page.html')


def is_loopback(host: str) -> bool:
    """Whether ``host`` names this machine only (localhost, 127.0.0.0/8, ::1)."""
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class WebServer:
    """The page and the WebSocket on ``host:port``; :meth:`publish` is thread-safe."""

    def __init__(self, host: str, port: int):
        self.host, self.port = host, int(port)
        self.hello: Optional[str] = None
        self.tick: Optional[str] = None
        self.sent = 0  # tick messages sent, over every client
        self.clients = 0
        self._loop = asyncio.new_event_loop()
        self._waiting: Set[asyncio.Event] = set()  # one per client waiting for a new tick
        self._sockets: Set[web.WebSocketResponse] = set()
        self._runner: Optional[web.AppRunner] = None
        self._thread = threading.Thread(target=self._loop.run_forever, name='monitor-web', daemon=True)

    def start(self) -> None:
        """Bind and serve (raises OSError when the port cannot be bound)."""
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self._loop).result(timeout=30)

    async def _start(self) -> None:
        app = web.Application()
        app.router.add_get('/', self._page)
        app.router.add_get('/ws', self._socket)
        app.on_shutdown.append(self._close_sockets)  # else the clean-up waits for open pages
        self._runner = web.AppRunner(app, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        self.port = int(self._runner.addresses[0][1])  # the bound port (asked 0: any free one)

    def publish(self, hello: str, tick: str) -> None:
        """Make ``tick`` the newest tick (``hello``: the first message of new clients)."""
        self.hello = hello
        self.tick = tick
        if self.clients:
            self._loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        for event in self._waiting:
            event.set()

    async def _page(self, _request) -> web.Response:
        return web.Response(text=PAGE.read_text(), content_type='text/html')

    async def _socket(self, request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=30.0, compress=False)
        await ws.prepare(request)
        self.clients += 1
        changed = asyncio.Event()
        self._waiting.add(changed)
        self._sockets.add(ws)
        reader = asyncio.ensure_future(self._drain(ws, changed))
        try:
            while self.hello is None and not ws.closed:
                await asyncio.sleep(0.1)
            if not ws.closed:
                await ws.send_str(self.hello)
            last = None
            while not ws.closed and not reader.done():
                if self.tick is last:
                    await changed.wait()  # a new tick, or the page gone (_drain sets it)
                    changed.clear()
                    continue
                last = self.tick
                await ws.send_str(last)
                self.sent += 1
        except ConnectionError:
            pass
        finally:
            self._waiting.discard(changed)
            self._sockets.discard(ws)
            self.clients -= 1
            reader.cancel()
        return ws

    async def _drain(self, ws, changed: asyncio.Event) -> None:
        """Read (and ignore) what the page sends, so that a close is noticed (``changed`` set)."""
        try:
            async for msg in ws:
                if msg.type in (WSMsgType.CLOSE, WSMsgType.ERROR):
                    break
        finally:
            changed.set()

    async def _close_sockets(self, _app) -> None:
        for ws in list(self._sockets):
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b'monitor stopping')

    def stop(self) -> None:
        if self._runner is not None and self._thread.is_alive():
            try:
                asyncio.run_coroutine_threadsafe(self._runner.cleanup(), self._loop).result(timeout=5)
            except Exception:  # the process is ending anyway
                pass
        self._loop.call_soon_threadsafe(self._loop.stop)
