"""The web station's server (Starlette on uvicorn): one page, one WebSocket per page; with a token
(gcs.web.auth) every route needs it (`GET /login`, `POST /login`, `POST /logout` log a browser in and out).

- `GET /`: the page (static/: plain HTML and JS, no build step); `GET /api/drones`: the drone list as JSON.
- `WS /ws`, server -> page: binary messages are preview samples as the daemon sent them (32-byte "JFR1" header
  + JPEG); text messages JSON `{"type": "events", "events": [...]}` (the watched drone's track samples with
  the station's confidence, its 275 status, command outcomes, camera texts) and `{"type": "drones", ...}`
  (every second). Page -> server, JSON: `{"type": "watch", "prefix"}`, `{"type": "point", "prefix", "x", "y",
  "radius", "id"}`, `{"type": "rect", "prefix", "x0", "y0", "x1", "y1", "id"}`, `{"type": "stop", "prefix",
  "id"}` (normalised 0..1, top-left origin); anything else closes the socket (1003).
The newest frame wins towards each page (missed ones: `dropped_frames` in /api/drones' `pages`); a WebSocket
from another Origin is refused (another site in the operator's browser must not drive the drone).
"""
from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import logging
import math
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, AsyncIterator
from urllib.parse import urlsplit

from starlette.applications import Starlette
from starlette.endpoints import WebSocketEndpoint
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.types import Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect

from gcs.confidence import ConfidenceGauge
from gcs.drones import DroneDirectory, ZenohSettings
from gcs.mavlink_station import CommandOutcome, ImageStatus, MavlinkStation
from gcs.preview import PreviewFrame
from gcs.web.auth import TokenAuth

log = logging.getLogger("gcs.web")
STATIC = resources.files("gcs.web") / "static"
EVENT_LIMIT = 600  # queued events per page (20 s of 30 Hz telemetry): the oldest go first when a page stalls


def finite(value: Any) -> Any:
    """A copy of a JSON-like value with NaN / infinities as None (JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(item) for item in value]
    return value


def same_origin(origin: str | None, host: str | None) -> bool:
    """True if a WebSocket's Origin header names the host it connected to (or there is no Origin: not a
    browser page, e.g. a script on this machine)."""
    if origin is None:
        return True
    if host is None:
        return False
    return urlsplit(origin).netloc.lower() == host.lower()


@dataclass(eq=False)
class Page:
    """One connected page: what it watches, its newest unsent frame, its queued events."""

    websocket: WebSocket
    watching: str | None = None
    frame: bytes | None = None
    events: collections.deque = field(default_factory=lambda: collections.deque(maxlen=EVENT_LIMIT))
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    frames_sent: int = 0
    dropped_frames: int = 0
    tasks: set = field(default_factory=set)  # commands in flight (referenced until done)


class Feed:
    """The connected pages and what goes to each: filled from the Zenoh / MAVLink threads through `hop`,
    everything else runs on the event loop."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None  # the server's, while it runs
        self.pages: set[Page] = set()
        self.gauges: dict[str, ConfidenceGauge] = {}  # per drone prefix, fed every track sample (on the loop)

    def hop(self, callback: Any, *args: Any) -> None:
        """From another thread: call back on the loop (dropped while no server runs)."""
        loop = self.loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(callback, *args)

    # the Zenoh directory's callbacks (on Zenoh's threads)
    def on_track(self, prefix: str, sample: dict[str, Any]) -> None:
        self.hop(self._track, prefix, finite(sample))

    def on_preview(self, prefix: str, frame: PreviewFrame, payload: bytes) -> None:
        self.hop(self._frame_for, prefix, payload)

    # on the loop
    def _track(self, prefix: str, sample: dict[str, Any]) -> None:
        confidence = self.gauges.setdefault(prefix, ConfidenceGauge()).update(sample)
        self.event_for(prefix, {"type": "track", "prefix": prefix, "sample": sample, "confidence": confidence})

    def new_lock(self, prefix: str) -> None:
        """This station's track command was accepted: the drone's confidence starts a new reference."""
        self.gauges.setdefault(prefix, ConfidenceGauge()).new_lock()

    def event_for(self, prefix: str, event: dict[str, Any]) -> None:
        """Queue an event for the pages watching `prefix`."""
        for page in self.pages:
            if page.watching == prefix:
                page.events.append(event)
                page.wake.set()

    def event_for_all(self, event: dict[str, Any]) -> None:
        for page in self.pages:
            page.events.append(event)
            page.wake.set()

    def _frame_for(self, prefix: str, payload: bytes) -> None:
        for page in self.pages:
            if page.watching == prefix:
                if page.frame is not None:
                    page.dropped_frames += 1
                page.frame = payload
                page.wake.set()


@dataclass(frozen=True)
class CameraRelay:
    """The MAVLink station's callbacks (on its threads): a camera's 275 status and texts go to the pages
    watching the drone with that camera's MAVLink ids."""

    feed: Feed
    directory: DroneDirectory

    def on_status(self, status: ImageStatus) -> None:
        self.feed.hop(self._deliver, status.system_id, status.component_id,
                      {"type": "status275", "status": finite(status.as_json())})

    def on_text(self, system_id: int, component_id: int, severity: int, text: str) -> None:
        self.feed.hop(self._deliver, system_id, component_id,
                      {"type": "text", "system_id": system_id, "component_id": component_id, "severity": severity,
                       "text": text})

    def _deliver(self, system_id: int, component_id: int, event: dict[str, Any]) -> None:
        for drone in self.directory.summaries():
            if (drone["system_id"], drone["component_id"]) == (system_id, component_id):
                self.feed.event_for(drone["prefix"], {**event, "prefix": drone["prefix"]})


@dataclass(frozen=True)
class Hub:
    """The station's Zenoh directory and MAVLink station, and the pages they feed (built by build_hub)."""

    feed: Feed
    directory: DroneDirectory
    station: MavlinkStation
    background: set[asyncio.Task] = field(default_factory=set)  # referenced until done (the loop keeps weak ones)

    def spawn(self, coroutine: Any) -> None:
        """Run a coroutine on the loop in the background."""
        task = asyncio.create_task(coroutine)
        self.background.add(task)
        task.add_done_callback(self.background.discard)

    def drones_message(self) -> dict[str, Any]:
        drones = self.directory.summaries()
        for drone in drones:
            drone["mavlink_heard"] = (drone["system_id"] is not None
                                      and self.station.heard(drone["system_id"], drone["component_id"]))
        # complete: every daemon that answers the status query is in the list (a page picks a lone drone by
        # itself only then, not the first of a fleet that happened to answer first)
        return {"type": "drones", "drones": finite(drones), "complete": self.directory.status_rounds > 0}


async def page_sender(page: Page) -> None:
    """Send the page its queued events (one message), then the newest frame; wait for more. Ends when the
    page goes away (the receiving side notices and cleans up)."""
    try:
        while True:
            await page.wake.wait()
            page.wake.clear()
            if page.events:
                events = list(page.events)
                page.events.clear()
                await page.websocket.send_text(json.dumps({"type": "events", "events": events}, allow_nan=False))
            frame, page.frame = page.frame, None
            if frame is not None:
                await page.websocket.send_bytes(frame)
                page.frames_sent += 1
    except (WebSocketDisconnect, RuntimeError, OSError):
        return  # closed under us


def number(message: dict[str, Any], name: str) -> float:
    """A finite number from a page's message; ValueError naming the field otherwise."""
    value = message.get(name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


async def run_command(hub: Hub, message: dict[str, Any]) -> dict[str, Any]:
    """Carry out a page's point / rect / stop on the drone it names; the outcome as an `ack` event."""
    prefix = str(message.get("prefix"))
    kind = message.get("type")
    base = {"type": "ack", "id": message.get("id"), "prefix": prefix,
            "command": {"point": "TRACK_POINT", "rect": "TRACK_RECTANGLE", "stop": "STOP_TRACKING"}[kind]}
    try:
        system_id, component_id = hub.directory.target(prefix)
        station = hub.station
        if kind == "point":
            args = (number(message, "x"), number(message, "y"), number(message, "radius"))
            outcome: CommandOutcome = await asyncio.to_thread(station.track_point, system_id, component_id, *args)
        elif kind == "rect":
            corners = tuple(number(message, name) for name in ("x0", "y0", "x1", "y1"))
            outcome = await asyncio.to_thread(station.track_rectangle, system_id, component_id, *corners)
        else:
            outcome = await asyncio.to_thread(station.stop_tracking, system_id, component_id)
    except (LookupError, ValueError) as exc:
        return {**base, "result": None, "result_name": "NOT_SENT", "reason": str(exc)}
    log.info("event=command prefix=%s command=%s result=%s reason=%s", prefix, base["command"],
             outcome.result_name, outcome.reason)
    if outcome.accepted and kind != "stop":
        hub.feed.new_lock(prefix)
        # as QGroundControl does after a track command: ask for the camera's 275 (2 Hz)
        await asyncio.to_thread(station.request_status, system_id, component_id, 0.5, 0.0)
    return {**base, **outcome.as_json(), "command": base["command"]}


async def ask_status(hub: Hub, prefix: str) -> None:
    """Ask the watched drone's camera for its 275 at 2 Hz (not more than every 10 s)."""
    try:
        system_id, component_id = hub.directory.target(prefix)
    except LookupError:
        return  # identity not known yet: the next drone-list tick asks again
    await asyncio.to_thread(hub.station.request_status, system_id, component_id)


async def index(_request: Request) -> Response:
    """GET /: the page."""
    return FileResponse(str(STATIC / "index.html"), headers={"Cache-Control": "no-store"})


async def drones(request: Request) -> Response:
    """GET /api/drones: the drone list and, per page, what it watches and its frames sent / dropped."""
    hub: Hub = request.app.state.hub
    body = hub.drones_message()
    body["pages"] = [{"watching": p.watching, "frames_sent": p.frames_sent, "dropped_frames": p.dropped_frames}
                     for p in hub.feed.pages]
    return JSONResponse(body)


class PageSocket(WebSocketEndpoint):
    """WS /ws: one page's WebSocket (messages in the module's docstring)."""

    encoding = None  # text or bytes as sent: a page sends JSON text, anything else closes the socket (1003)

    def __init__(self, scope: Scope, receive: Receive, send: Send) -> None:
        super().__init__(scope, receive, send)
        self.page: Page | None = None  # None until accepted (never, for a foreign Origin)
        self.sender: asyncio.Task | None = None

    async def on_connect(self, websocket: WebSocket) -> None:
        hub: Hub = websocket.app.state.hub
        if not same_origin(websocket.headers.get("origin"), websocket.headers.get("host")):
            log.warning("event=websocket_refused origin=%s host=%s", websocket.headers.get("origin"),
                        websocket.headers.get("host"))
            await websocket.close(code=1008)
            return
        await websocket.accept()
        page = self.page = Page(websocket)
        hub.feed.pages.add(page)
        page.events.append(hub.drones_message())
        page.wake.set()
        self.sender = asyncio.create_task(page_sender(page))

    async def on_receive(self, websocket: WebSocket, data: str | bytes) -> None:
        hub: Hub = websocket.app.state.hub
        page = self.page
        if page is None:
            return
        try:
            if not isinstance(data, str):
                raise ValueError("a binary message")
            message = json.loads(data)
        except ValueError:  # json.JSONDecodeError is one
            await websocket.close(code=1003)
            return
        kind = message.get("type") if isinstance(message, dict) else None
        if kind == "watch":
            await self.watch(hub, page, str(message.get("prefix")))
        elif kind in ("point", "rect", "stop"):
            async def answer() -> None:
                page.events.append(await run_command(hub, message))
                page.wake.set()
            task = asyncio.create_task(answer())
            page.tasks.add(task)
            task.add_done_callback(page.tasks.discard)
        else:
            log.warning("event=page_message_unknown message=%.200s", message)

    @staticmethod
    async def watch(hub: Hub, page: Page, prefix: str) -> None:
        """The page watches drone `prefix` from now on (a text event if there is no such drone)."""
        if prefix not in {d["prefix"] for d in hub.directory.summaries()}:
            page.events.append({"type": "text", "prefix": prefix, "severity": 4,
                                "text": f"no drone {prefix!r} on the Zenoh network"})
            page.wake.set()
            return
        if page.watching is not None:
            await asyncio.to_thread(hub.directory.unwatch, page.watching)
        page.watching, page.frame = prefix, None
        await asyncio.to_thread(hub.directory.watch, prefix)
        hub.spawn(ask_status(hub, prefix))

    async def on_disconnect(self, websocket: WebSocket, close_code: int) -> None:
        hub: Hub = websocket.app.state.hub
        page = self.page
        if page is None:
            return
        if self.sender is not None:
            self.sender.cancel()
        for task in page.tasks:
            task.cancel()
        hub.feed.pages.discard(page)
        if page.watching is not None:
            await asyncio.to_thread(hub.directory.unwatch, page.watching)


async def ticker(hub: Hub) -> None:
    """Every second: the drone list to every page, and the watched cameras' 275 asked for."""
    while True:
        await asyncio.sleep(1.0)  # a periodic refresh, not a synchronisation
        hub.feed.event_for_all(hub.drones_message())
        for prefix in {p.watching for p in hub.feed.pages if p.watching is not None}:
            hub.spawn(ask_status(hub, prefix))


@contextlib.asynccontextmanager
async def lifespan(app: Starlette) -> AsyncIterator[None]:
    """While the server runs: the hub's callbacks reach the loop, and the ticker ticks."""
    hub: Hub = app.state.hub
    hub.feed.loop = asyncio.get_running_loop()
    tick = asyncio.create_task(ticker(hub))
    try:
        yield
    finally:
        tick.cancel()
        hub.feed.loop = None


ROUTES = [Route("/", index), Route("/api/drones", drones), WebSocketRoute("/ws", PageSocket),
          Mount("/static", StaticFiles(directory=str(STATIC)), name="static")]


def create_app(hub: Hub, token: str | None = None) -> Starlette:
    """The Starlette app serving `hub` (built with build_hub; closed by its owner after the server stops);
    with a token, every request and the WebSocket need it (gcs.web.auth)."""
    middleware = [Middleware(TokenAuth, token=token)] if token is not None else []
    app = Starlette(routes=ROUTES, lifespan=lifespan, middleware=middleware)
    app.state.hub = hub
    return app


def build_hub(zenoh_settings: ZenohSettings, mavlink_urls: list[str], system_id: int = 255,
              component_id: int = 190, signing_key: bytes | None = None) -> Hub:
    """The Hub with its Zenoh directory and MAVLink station (signing what it sends with signing_key, if given)
    open; ConnectionError naming what failed."""
    feed = Feed()
    directory = DroneDirectory(zenoh_settings, on_track=feed.on_track, on_preview=feed.on_preview)
    cameras = CameraRelay(feed, directory)
    try:
        station = MavlinkStation(mavlink_urls, system_id, component_id, on_status=cameras.on_status,
                                 on_text=cameras.on_text, signing_key=signing_key)
    except BaseException:
        directory.close()
        raise
    return Hub(feed, directory, station)


def close_hub(hub: Hub) -> None:
    """Close the Zenoh session and the MAVLink links."""
    hub.directory.close()
    hub.station.close()
