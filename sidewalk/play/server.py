"""The local web server of ``sidewalk-play``: its page, its assets and a small JSON API over one ``Game``.

Routes (nothing else is served; every other path is a 404):

- ``GET /``, ``/play.js``, ``/play.css``: the page (``sidewalk/play/static``, a fixed allow-list);
- ``GET /api/game``: domain, partner, keys and step rate; ``GET /api/state``: the episode as it stands;
  ``POST /api/reset``: a new episode;
- ``POST /api/step``: one step with the keys held (``Game.action``); a malformed message is a 400 whose JSON
  ``error`` names the problem, and the server goes on.

A message must say it is JSON (``Content-Type: application/json``), which another site's page cannot send without
the browser asking first (a CORS preflight, refused here); on a loopback address a request must name this machine
(``Host``), so that a site whose name is pointed at 127.0.0.1 (DNS rebinding) reads and drives nothing.

The partner, the world and the datasets folder come from the command line only; a request names none of them.
"""

from __future__ import annotations

import json
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any

from sidewalk.play.game import Game, GameError

ASSETS = {"/": ("index.html", "text/html"), "/index.html": ("index.html", "text/html"),
          "/play.js": ("play.js", "text/javascript"), "/play.css": ("play.css", "text/css")}
MAX_MESSAGE_BYTES = 4096  # a step message is a few keys
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")


def asset(name: str) -> bytes:
    return resources.files("sidewalk.play").joinpath("static", name).read_bytes()


class PlayHandler(BaseHTTPRequestHandler):
    """One request: an asset, or a game message answered with the game's state as JSON."""

    server: PlayServer
    server_version = "sidewalk-play"

    def log_message(self, format: str, *args: Any) -> None:
        if self.server.verbose:
            super().log_message(format, *args)

    def do_GET(self) -> None:
        path = self.path.split("?", 1)[0]
        if not self._host_allowed():
            return
        if path in ("/api/game", "/api/state"):
            game = self.server.game
            with game.lock:
                self._json(HTTPStatus.OK, game.describe() if path == "/api/game" else game.state())
        elif path in ASSETS:
            name, kind = ASSETS[path]
            self._send(HTTPStatus.OK, asset(name), f"{kind}; charset=utf-8")
        else:
            self._json(HTTPStatus.NOT_FOUND, {"error": f"no such page: {path}"})

    def do_POST(self) -> None:
        path = self.path.split("?", 1)[0]
        if not self._host_allowed():
            return
        if path not in ("/api/reset", "/api/step"):
            self._json(HTTPStatus.NOT_FOUND, {"error": f"no such endpoint: {path}"})
            return
        try:
            message = self._message()
            game = self.server.game
            with game.lock:
                state = game.reset() if path == "/api/reset" else game.step(message)
        except GameError as error:
            self._json(HTTPStatus.BAD_REQUEST, {"error": str(error)})
            return
        self._json(HTTPStatus.OK, state)

    def _host_allowed(self) -> bool:
        """Whether the request names this server (always, off loopback); else a 403 is sent."""
        allowed = self.server.allowed_hosts
        host = self.headers.get("Host", "")
        if allowed is None or host in allowed:
            return True
        self._json(HTTPStatus.FORBIDDEN, {"error": f"Host {host!r} is not this server; valid: {', '.join(allowed)}"})
        return False

    def _message(self) -> Any:
        kind = self.headers.get("Content-Type", "").split(";", 1)[0].strip().lower()
        if kind != "application/json":
            raise GameError(f"a message of Content-Type {kind!r} is not valid; valid: application/json")
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            raise GameError("Content-Length is not a number") from None
        if not 0 <= length <= MAX_MESSAGE_BYTES:
            raise GameError(f"a message of {length} bytes is not valid; valid: up to {MAX_MESSAGE_BYTES}")
        body = self.rfile.read(length) if length else b"{}"
        try:
            return json.loads(body)
        except (UnicodeDecodeError, json.JSONDecodeError) as error:
            raise GameError(f"the message is not JSON: {error}") from None

    def _json(self, status: HTTPStatus, payload: dict[str, Any]) -> None:
        self._send(status, json.dumps(payload).encode(), "application/json")

    def _send(self, status: HTTPStatus, body: bytes, kind: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)


class PlayServer(ThreadingHTTPServer):
    """The page and the API of one ``game`` on ``(host, port)`` (port 0: any free one; ``url`` says which)."""

    daemon_threads = True

    def __init__(self, game: Game, host: str = "127.0.0.1", port: int = 8765, verbose: bool = False) -> None:
        self.game, self.verbose = game, verbose
        super().__init__((host, port), PlayHandler)
        port = self.server_address[1]
        loopback = host in LOOPBACK_NAMES or host == "::1" or host.startswith("127.")
        # Off loopback the server answers to any of the machine's names, as its user asked with --host.
        self.allowed_hosts = (*(f"{name}:{port}" for name in LOOPBACK_NAMES), f"{host}:{port}") if loopback else None

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        return f"http://{host}:{port}/"

    def server_close(self) -> None:
        """Stop listening and end the game (the episode under way is saved)."""
        super().server_close()
        with self.game.lock:
            self.game.close()

    def start(self) -> threading.Thread:
        """Serve in a background thread (tests, notebooks); ``shutdown()`` stops it."""
        thread = threading.Thread(target=self.serve_forever, daemon=True)
        thread.start()
        return thread
