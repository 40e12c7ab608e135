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
import struct
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
    doc = check_model(model)
    static = resources.files("hack_render.export") / "viewer_static"
    table: dict[str, Path | bytes] = {f"/{n}": Path(str(static / n)) for n in STATIC}
    table["/"] = table["/index.html"]
    table[f"/model{suffix}"] = model
    table["/config.json"] = json.dumps({"model": f"./model{suffix}"}).encode()
    if suffix == ".gltf":  # its buffers and images, by the relative names its JSON gives
        for item in doc.get("buffers", []) + doc.get("images", []):
            uri = item.get("uri", "")
            if uri and not uri.startswith("data:"):
                if "/" in uri or "\\" in uri or uri.startswith("."):
                    raise HackError(f"{model}: resource {uri!r} is not beside the file; the "
                                    "viewer serves files from the model's folder only.")
                table[f"/{uri}"] = model.parent / uri
    return table


_GLB_MAGIC, _JSON_CHUNK, _BIN_CHUNK = b"glTF", 0x4E4F534A, 0x004E4942
_EXPORT_HINT = "Export it again: hack-render export -o person.glb"


def _glb_chunks(model: Path, size: int) -> tuple[bytes, int | None]:
    """(JSON chunk, BIN chunk's length or None) of a .glb whose header and chunks are
    whole; else a HackError saying what is wrong."""
    def bad(what: str) -> HackError:
        return HackError(f"{model}: {what}. {_EXPORT_HINT}.")

    with model.open("rb") as fh:
        head = fh.read(20)
        if head[:4] != _GLB_MAGIC:
            found = "an empty file" if not size else f"a file starting {head[:4]!r}"
            raise bad(f"expected a binary glTF (a .glb starts with b'glTF'), found {found}")
        if len(head) < 12:
            raise bad(f"expected a 12-byte header, found {size} bytes")
        version, length = struct.unpack("<II", head[4:12])
        if version != 2:
            raise bad(f"expected glTF version 2, found version {version}")
        if length != size:
            raise bad(f"the header declares {length:,} bytes but the file holds {size:,}: it "
                      f"was cut short or damaged (copied while it was written?)")
        n_json, kind = struct.unpack("<II", head[12:20]) if len(head) == 20 else (0, 0)
        if kind != _JSON_CHUNK or 20 + n_json > size:
            raise bad("expected a JSON chunk after the header, found "
                      + ("none" if kind != _JSON_CHUNK else f"one of {n_json:,} bytes past "
                         f"the end"))
        text = fh.read(n_json)
        rest = size - 20 - n_json
        if not rest:
            return text, None
        chunk = fh.read(8)
        n_bin, kind = struct.unpack("<II", chunk) if len(chunk) == 8 else (0, 0)
        if kind != _BIN_CHUNK or 28 + n_json + n_bin != size:
            raise bad(f"expected a BIN chunk filling the {rest:,} bytes after the JSON, found "
                      + ("none" if kind != _BIN_CHUNK else f"one of {n_bin:,} bytes"))
        return text, n_bin


def check_model(model: str | Path) -> dict:
    """The glTF JSON of a ``.glb`` or ``.gltf`` the page can load, else a HackError saying
    what is wrong, before a server starts (the page would only show nothing).

    A ``.glb``: the magic ``glTF``, version 2, the declared length equal to the file's
    size (a copy cut short is refused), a JSON chunk, then at most a BIN chunk, filling
    the file exactly. A ``.gltf``: JSON text. Either: an object with an ``asset`` object,
    ``buffers`` and ``images`` lists of objects, and every buffer present with at least its
    ``byteLength`` (the ``.glb``'s BIN chunk, or a file beside the ``.gltf``)."""
    model = Path(model)
    size = model.stat().st_size
    bin_size = None
    if model.suffix.lower() == ".glb":
        text, bin_size = _glb_chunks(model, size)
    else:
        text = model.read_bytes()
    try:
        doc = json.loads(text.decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        found = "an empty file" if not text.strip() else f"text that is not JSON ({str(exc)[:100]})"
        raise HackError(f"{model}: expected glTF JSON, found {found}. {_EXPORT_HINT}.") from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("asset"), dict):
        found = "an object without one" if isinstance(doc, dict) else {
            "list": "an array", "str": "a string", "NoneType": "null", "bool": "a boolean"}.get(
            type(doc).__name__, "a number")
        raise HackError(f"{model}: expected a glTF object with an 'asset' object, found "
                        f"{found}. {_EXPORT_HINT}.")
    for key in ("buffers", "images"):
        items = doc.get(key, [])
        if not isinstance(items, list) or not all(isinstance(x, dict) for x in items):
            raise HackError(f"{model}: expected '{key}' to be a list of objects, found "
                            f"{type(items).__name__}. {_EXPORT_HINT}.")
    for k, buf in enumerate(doc.get("buffers", [])):
        uri, need = buf.get("uri"), buf.get("byteLength", 0)
        need = need if isinstance(need, int) and not isinstance(need, bool) else 0
        if uri is None:  # the .glb's own BIN chunk
            have, where = bin_size, "the file's BIN chunk"
        elif isinstance(uri, str) and not uri.startswith(("data:", ".")) \
                and "/" not in uri and "\\" not in uri:
            beside = model.parent / uri
            have, where = (beside.stat().st_size if beside.is_file() else None), str(beside)
        else:
            continue  # embedded (data:), or not beside the file (routes refuses it)
        if have is None or have < need:
            found = "no such file" if have is None and uri else \
                "none" if have is None else f"{have:,} bytes"
            raise HackError(f"{model}: buffer {k} expects {need:,} bytes in {where}, found "
                            f"{found}. Keep a .gltf's .bin beside it, or export it again: "
                            f"hack-render export -o person.glb.")
    return doc


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
