"""`hack-render view`: a local web page for an exported person.

A small HTTP server bound to 127.0.0.1 serves exactly these paths: the page
(``index.html``, ``viewer.js``), the three.js bundle shipped in ``viewer_static/`` (MIT, see
``LICENSE-three.js.txt``), ``config.json`` (where the model is) and the model itself
(a ``.glb``, or a ``.gltf`` and the buffers and images its JSON names beside it). Any other
path is a 404: the server shows no other file of the machine.
"""

from __future__ import annotations

import json
import signal
import threading
import time
import webbrowser
from functools import partial
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path

import typer

from hack_render.errors import HackError

STATIC = ("index.html", "viewer.js", "three.bundle.min.js", "LICENSE-three.js.txt")
_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
          ".json": "application/json", ".glb": "model/gltf-binary",
          ".gltf": "model/gltf+json", ".bin": "application/octet-stream",
          ".png": "image/png", ".jpg": "image/jpeg", ".txt": "text/plain; charset=utf-8"}


def routes(model: str | Path) -> dict[str, Path | bytes]:
    """URL path -> file (or bytes) for the page, the bundle and the model's files."""
    model = Path(model)
    if not model.is_file():
        raise HackError(f"{model}: file not found; pass an exported .glb or .gltf "
                        "(`hack-render export -o person.glb`).")
    suffix = model.suffix.lower()
    if suffix not in (".glb", ".gltf"):
        raise HackError(f"{model}: expected a .glb or .gltf file, found {suffix or 'no suffix'}.")
    static = resources.files("hack_render.export") / "viewer_static"
    table: dict[str, Path | bytes] = {f"/{n}": Path(str(static / n)) for n in STATIC}
    table["/"] = table["/index.html"]
    table[f"/model{suffix}"] = model
    table["/config.json"] = json.dumps({"model": f"./model{suffix}"}).encode()
    if suffix == ".gltf":  # its buffers and images, by the relative names its JSON gives
        try:
            doc = json.loads(model.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise HackError(f"{model}: not valid glTF JSON ({exc}).") from exc
        for item in doc.get("buffers", []) + doc.get("images", []):
            uri = item.get("uri", "")
            if uri and not uri.startswith("data:"):
                if "/" in uri or "\\" in uri or uri.startswith("."):
                    raise HackError(f"{model}: resource {uri!r} is not beside the file; the "
                                    "viewer serves files from the model's folder only.")
                table[f"/{uri}"] = model.parent / uri
    return table


class _Handler(BaseHTTPRequestHandler):
    def __init__(self, table, *args, **kwargs):
        self.table = table
        super().__init__(*args, **kwargs)

    def do_GET(self):  # noqa: N802 - the http.server API
        item = self.table.get(self.path.split("?", 1)[0])
        if item is None:
            self.send_error(404, "not one of the viewer's files")
            return
        data = item if isinstance(item, bytes) else item.read_bytes()
        name = "x.json" if isinstance(item, bytes) else item.name
        self.send_response(200)
        self.send_header("Content-Type", _TYPES.get(Path(name).suffix.lower(),
                                                    "application/octet-stream"))
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(data)

    def log_message(self, fmt, *args):  # quiet: one line per request is noise here
        pass


def _serve_without_signals(server: ThreadingHTTPServer) -> None:
    """The serving thread blocks Ctrl-C and SIGTERM, so the kernel hands them to the main
    thread: a signal taken by this thread would leave the main thread asleep (Python runs
    handlers in the main thread only when it wakes) and the viewer would not stop."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    server.serve_forever()


def start(model: str | Path, port: int = 0) -> tuple[ThreadingHTTPServer, str]:
    """Start serving in a background thread; returns the server and the page's URL."""
    table = routes(model)
    try:
        server = ThreadingHTTPServer(("127.0.0.1", port), partial(_Handler, table))
    except OSError as exc:
        raise HackError(f"--port {port}: cannot listen on 127.0.0.1 ({exc.strerror or exc}); "
                        "pick another port, or 0 for any free one.") from exc
    threading.Thread(target=_serve_without_signals, args=(server,), daemon=True).start()
    return server, f"http://127.0.0.1:{server.server_address[1]}/"


def serve(model: str | Path, port: int = 8023, open_browser: bool = True) -> None:
    """Serve until interrupted (Ctrl-C), printing the URL; open it in a browser if asked."""

    server, url = start(model, port)
    typer.echo(f"serving {Path(model).name} at {url} (127.0.0.1 only; Ctrl-C to stop)",
               err=False)
    if open_browser:
        webbrowser.open(url)
    try:
        while True:
            time.sleep(3600)
    finally:  # Ctrl-C stops the server and goes on to the CLI (exit 130, like every command)
        server.shutdown()
