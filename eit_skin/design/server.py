"""The local web server of ``eit-skin design``: aiohttp, one design session.

Routes: ``GET /`` the page (``static/index.html``, plain HTML/SVG/JS: no build step),
``GET /static/...`` its script and style, ``GET /api/design`` the design's data and model,
``POST /api/update`` new patch data -> validated model and predicted-accuracy preview,
``POST /api/save`` ``{"path"}`` -> the written file's path and content hash,
``POST /api/load`` ``{"path"}`` -> open another patch or drawing. The server runs its own
event loop in a background thread; the model work runs in a worker thread, one request at a
time (a design is one state).
"""

from __future__ import annotations

import asyncio
import socket
import threading
from pathlib import Path
from typing import Any

from eit_skin.design.session import DesignSession

STATIC = Path(__file__).resolve().parent / "static"
#: Seconds :func:`start_server` waits for the server to listen.
START_TIMEOUT_S = 60.0


def make_app(session: DesignSession) -> Any:
    """The aiohttp application serving ``session``."""
    from aiohttp import web

    lock = threading.Lock()

    async def work(fn, *args):
        def locked():
            with lock:
                return fn(*args)

        return await asyncio.get_running_loop().run_in_executor(None, locked)

    async def index(_: web.Request) -> web.FileResponse:
        return web.FileResponse(STATIC / "index.html")

    async def design(_: web.Request) -> web.Response:
        model = await work(session.update, session.data, 0)
        return web.json_response(_state(session, model))

    async def update(request: web.Request) -> web.Response:
        body = await request.json()
        model = await work(session.update, body.get("data"), body.get("layer_index", 0))
        return web.json_response(model)

    async def save(request: web.Request) -> web.Response:
        body = await request.json()
        try:
            answer = await work(session.save, body.get("path") or None)
        except (ValueError, OSError) as exc:
            return web.json_response({"ok": False, "error": str(exc)})
        return web.json_response({"ok": True, **answer})

    async def load(request: web.Request) -> web.Response:
        body = await request.json()
        try:
            opened = await work(
                DesignSession.open, str(body.get("path", "")), body.get("units") or None
            )
        except (ValueError, OSError) as exc:
            return web.json_response({"ok": False, "error": str(exc)})
        session.data, session.path, session.original = opened.data, opened.path, opened.original
        model = await work(session.update, session.data, 0)
        return web.json_response(_state(session, model))

    app = web.Application()
    app.router.add_get("/", index)
    app.router.add_get("/api/design", design)
    app.router.add_post("/api/update", update)
    app.router.add_post("/api/save", save)
    app.router.add_post("/api/load", load)
    app.router.add_static("/static", STATIC)
    return app


def _state(session: DesignSession, model: dict[str, Any]) -> dict[str, Any]:
    return {
        "data": session.data,
        "path": None if session.path is None else str(session.path),
        "model": model,
    }


class RunningServer:
    """A started server: ``url``, and :meth:`stop`."""

    def __init__(self, loop: asyncio.AbstractEventLoop, thread: threading.Thread, url: str):
        self.loop = loop
        self.thread = thread
        self.url = url

    def stop(self, timeout_s: float = 10.0) -> None:
        """Close the server and end its thread."""
        if self.thread.is_alive():
            self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout_s)


def start_server(session: DesignSession, host: str = "127.0.0.1", port: int = 0) -> RunningServer:
    """Serve ``session`` on ``host:port`` (0: a free port) from a background thread.

    Returns once the server listens. Raises ``OSError`` when the address cannot be bound.
    """
    from aiohttp import web

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    sock.listen(64)
    bound = sock.getsockname()[1]
    loop = asyncio.new_event_loop()
    runner = web.AppRunner(make_app(session), access_log=None)
    ready = threading.Event()
    failure: list[BaseException] = []

    def serve() -> None:
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(runner.setup())
            loop.run_until_complete(web.SockSite(runner, sock).start())
        except BaseException as exc:  # reported to the caller below
            failure.append(exc)
            ready.set()
            return
        ready.set()
        loop.run_forever()
        loop.run_until_complete(runner.cleanup())
        loop.close()

    thread = threading.Thread(target=serve, name="eit-skin-design", daemon=True)
    thread.start()
    if not ready.wait(START_TIMEOUT_S) or failure:
        raise OSError(f"design server did not start on {host}:{bound}: {failure or 'timeout'}")
    shown = f"[{host}]" if ":" in host else host
    return RunningServer(loop, thread, f"http://{shown}:{bound}/")
