"""An offline Meshcat window: records scene commands and writes standalone HTML.

`meshcat.Visualizer(window=RecordingWindow())` behaves like a normal visualizer
but needs no server, no ZMQ socket and no network: every command is kept in a
scene tree with the same replacement rules as the Meshcat server (last object,
transform and value of each property win; `delete` drops a subtree), and
`static_html()` packs that tree together with the bundled `main.min.js` viewer
into one self-contained HTML page.

Unlike the server's `get_scene`, the page decodes the commands synchronously
(base64 -> bytes -> `viewer.handle_command_bytearray`), so they run in order and
work from `file://` URLs without `fetch`.
"""

from __future__ import annotations

import base64
from pathlib import Path as FsPath
from typing import Any

import meshcat
import umsgpack

_VIEWER_JS = FsPath(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"

_HTML = """<!DOCTYPE html>
<html>
<head><meta charset="utf-8"><title>{title}</title>
<style>body {{ margin: 0; }}
#meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}</style>
</head>
<body>
<div id="meshcat-pane"></div>
<script>
{viewer_js}
</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
function surestepCommand(b64) {{
  var raw = atob(b64);
  var bytes = new Uint8Array(raw.length);
  for (var i = 0; i < raw.length; i++) {{ bytes[i] = raw.charCodeAt(i); }}
  viewer.handle_command_bytearray(bytes);
}}
var surestepCommands = [
{commands}
];
surestepCommands.forEach(surestepCommand);
</script>
<script id="embedded-json"></script>
{overlay}
</body>
</html>
"""


class _Node:
    """Recorded state of one scene path (packed msgpack command blobs)."""

    __slots__ = ("object", "transform", "properties")

    def __init__(self) -> None:
        self.object: bytes | None = None
        self.transform: bytes | None = None
        self.properties: dict[str, bytes] = {}


class RecordingWindow:
    """Drop-in replacement for `meshcat.visualizer.ViewerWindow` that records commands.

    Attributes:
        nodes: scene path (e.g. "/meshcat/paths/ocp/line") -> recorded node state,
            in order of first use.
        animation: packed `set_animation` command, or None.
        decoded: scene path -> list of the lowered (unpacked) commands sent to it,
            for inspection in tests.
    """

    web_url: str | None = None

    def __init__(self) -> None:
        self.nodes: dict[str, _Node] = {}
        self.animation: bytes | None = None
        self.decoded: dict[str, list[dict[str, Any]]] = {}

    def send(self, command: Any) -> None:
        """Record one Meshcat command (set_object/transform/property, delete, set_animation)."""
        data = command.lower()
        kind, path = data["type"], data.get("path", "")
        packed = umsgpack.packb(data)
        if kind == "set_animation":
            self.animation = packed
            self.decoded.setdefault("<animation>", []).append(data)
            return
        if kind == "delete":
            for key in [k for k in self.nodes if k == path or k.startswith(path.rstrip("/") + "/")]:
                del self.nodes[key]
                self.decoded.pop(key, None)
            return
        node = self.nodes.setdefault(path, _Node())
        self.decoded.setdefault(path, []).append(data)
        if kind == "set_object":
            node.object = packed
            node.properties = {}
        elif kind == "set_transform":
            node.transform = packed
        elif kind == "set_property":
            node.properties[data["property"]] = packed
        else:
            raise ValueError(f"unsupported meshcat command {kind!r}")

    def commands(self) -> list[bytes]:
        """Packed commands that rebuild the recorded scene, animation last."""
        out: list[bytes] = []
        for node in self.nodes.values():
            if node.object is not None:
                out.append(node.object)
            out.extend(node.properties.values())
            if node.transform is not None:
                out.append(node.transform)
        if self.animation is not None:
            out.append(self.animation)
        return out

    def get_scene(self, title: str = "SURESTEP trajectories", overlay: str = "") -> str:
        """Standalone HTML page (viewer JavaScript inlined) showing the recorded scene, with
        `overlay` (HTML, e.g. a legend) over the viewer."""
        lines = ",\n".join('"' + base64.b64encode(c).decode("ascii") + '"' for c in self.commands())
        viewer_js = _VIEWER_JS.read_text(encoding="utf-8")
        # A literal "</script>" inside the bundle would end the script element early.
        viewer_js = viewer_js.replace("</script>", "<\\/script>")
        return _HTML.format(title=title, viewer_js=viewer_js, commands=lines, overlay=overlay)

    def open(self) -> "RecordingWindow":
        """No browser to open for an offline recording; present for API compatibility."""
        return self

    def close(self) -> None:
        """Nothing to release."""


def recording_visualizer() -> tuple[meshcat.Visualizer, RecordingWindow]:
    """A server-less `meshcat.Visualizer` and the `RecordingWindow` behind it."""
    window = RecordingWindow()
    return meshcat.Visualizer(window=window), window
