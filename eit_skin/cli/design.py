"""``eit-skin design [PATCH.yaml | OUTLINE.dxf | OUTLINE.svg]``: the skin designer in the browser.

Starts a local web server (127.0.0.1 by default, a free port), prints its address and opens
it in the default browser (``--no-browser``: only print). Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "source",
        nargs="?",
        default="arm",
        help="patch file, shipped patch name (default: arm), or a DXF / SVG drawing",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (127.0.0.1)")
    parser.add_argument("--port", type=int, default=0, help="port (default 0: a free one)")
    parser.add_argument("--units", help="unit of a drawing that states none (mm, in, ...)")
    parser.add_argument(
        "--no-browser", action="store_true", help="print the address, do not open a browser"
    )


def run(args: argparse.Namespace) -> int:
    import threading
    import webbrowser

    from eit_skin.design.server import start_server
    from eit_skin.design.session import DesignSession

    try:
        session = DesignSession.open(args.source, args.units)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    server = start_server(session, args.host, args.port)
    print(f"eit-skin design: {args.source} at {server.url} (Ctrl-C stops)", flush=True)
    if not args.no_browser:
        webbrowser.open(server.url)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return 0
