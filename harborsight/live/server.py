"""The live aid's web side: ``GET /api/state`` (the ``harborsight.live/1`` state as JSON),
``/ws`` (a WebSocket that pushes every new state), ``/video.mjpg`` (the annotated frames as
MJPEG) and ``/`` (the dashboard, one static page with no build step: ``dashboard.html``
beside this module).

The measuring loop calls :meth:`LiveServer.publish` from its own thread; the server's event
loop sends the state to every connected WebSocket. A client that disconnects or stalls is
dropped without stopping the others or the measurement."""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Callable
from pathlib import Path

DASHBOARD = Path(__file__).with_name("dashboard.html")


class LiveServer:
    """Starlette app on uvicorn in a background thread (``start``/``stop``)."""

    def __init__(self, get_state: Callable[[], dict], host: str = "127.0.0.1", port: int = 8080,
                 get_jpeg: Callable[[], tuple[int | None, bytes | None]] | None = None,
                 get_frame_index: Callable[[], int | None] | None = None):
        from starlette.applications import Starlette
        from starlette.responses import HTMLResponse, JSONResponse
        from starlette.routing import Route, WebSocketRoute

        self.get_state = get_state
        self.get_jpeg = get_jpeg or (lambda: (None, None))
        self.get_frame_index = get_frame_index or (lambda: None)
        self.host, self.port = host, port
        self._clients: set = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server = None

        async def state(_request):
            return JSONResponse(self.get_state())

        async def dashboard(_request):
            return HTMLResponse(DASHBOARD.read_text(encoding="utf-8"))

        async def video(_request):
            """The annotated frames as MJPEG (multipart/x-mixed-replace), each new measured
            frame once, drawn in a worker thread."""
            from starlette.responses import StreamingResponse

            async def frames():
                shown = None
                while True:
                    index = self.get_frame_index()
                    if index is not None and index != shown:
                        index, jpeg = await asyncio.to_thread(self.get_jpeg)
                        if jpeg is not None:
                            shown = index
                            yield (b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                   + str(len(jpeg)).encode() + b"\r\n\r\n" + jpeg + b"\r\n")
                    await asyncio.sleep(0.05)

            return StreamingResponse(frames(), media_type="multipart/x-mixed-replace; boundary=frame")

        async def socket(websocket):
            await websocket.accept()
            self._clients.add(websocket)
            try:
                await websocket.send_text(json.dumps(self.get_state()))
                while True:             # the page sends nothing; this notices the close
                    await websocket.receive_text()
            except Exception:           # disconnects end here, quietly
                pass
            finally:
                self._clients.discard(websocket)

        self.app = Starlette(routes=[Route("/", dashboard), Route("/api/state", state),
                                     Route("/video.mjpg", video), WebSocketRoute("/ws", socket)])

    def start(self, timeout_s: float = 10.0) -> None:
        """Serve in a background thread; returns once the socket listens (the port is
        then ``self.port``, also when 0 asked for a free one)."""
        import uvicorn

        # the video stream and the sockets never end by themselves: a second to close them
        config = uvicorn.Config(self.app, host=self.host, port=self.port, log_level="warning",
                                lifespan="off", ws="websockets-sansio", timeout_graceful_shutdown=1)
        self._server = uvicorn.Server(config)
        started = threading.Event()

        def serve() -> None:
            self._loop = asyncio.new_event_loop()
            asyncio.set_event_loop(self._loop)

            async def main() -> None:
                task = asyncio.create_task(self._server.serve())
                while not self._server.started and not task.done():
                    await asyncio.sleep(0.02)
                if self._server.started:
                    sockets = self._server.servers[0].sockets if self._server.servers else []
                    if sockets:
                        self.port = sockets[0].getsockname()[1]
                started.set()
                await task

            try:
                self._loop.run_until_complete(main())
            finally:
                started.set()

        self._thread = threading.Thread(target=serve, name="harborsight-live-http", daemon=True)
        self._thread.start()
        started.wait(timeout_s)
        if self._server is None or not self._server.started:
            raise OSError(f"cannot serve on {self.host}:{self.port} (in use, or not an address here)")

    def publish(self, state: dict) -> None:
        """Push ``state`` to every WebSocket client (from any thread)."""
        if self._loop is None or not self._clients:
            return
        text = json.dumps(state)

        async def send_all() -> None:
            for client in list(self._clients):
                try:
                    await asyncio.wait_for(client.send_text(text), timeout=1.0)
                except Exception:       # gone or stalled: drop it, keep the others
                    self._clients.discard(client)

        asyncio.run_coroutine_threadsafe(send_all(), self._loop)

    def stop(self) -> None:
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=5.0)
