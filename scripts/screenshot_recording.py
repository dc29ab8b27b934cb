"""Renders a Rerun recording in Rerun's own web viewer, in headless Chromium, and saves a PNG,
so that what a recording shows (the world, the series, the events) can be checked by eye.

    python scripts/screenshot_recording.py RECORDING.rrd OUT.png [--wait 45]

Needs Chromium (Debian: apt-get install -y chromium) and Playwright (pip install playwright; its
own browsers are not needed) in the Python that runs this, and `rerun` from the venv that holds
hritest. Not part of CI. Chromium draws with its software rasteriser, so the viewer takes a while
to start: --wait is how many seconds to give it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import quote


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--wait", type=float, default=45.0, help="seconds for the viewer to load and draw")
    parser.add_argument("--size", default="1600,1000", help="window WIDTH,HEIGHT")
    parser.add_argument(
        "--rerun",
        default=str(Path(__file__).resolve().parent.parent / ".venv/bin/rerun"),
        help="the rerun executable (default: the repository's .venv)",
    )
    args = parser.parse_args()
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("Playwright is missing: pip install playwright (Chromium comes from Debian's package)", file=sys.stderr)
        return 2
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None or not args.recording.is_file():
        print(f"need Chromium (apt-get install -y chromium) and a recording; got {args.recording}", file=sys.stderr)
        return 2
    web, grpc = free_port(), free_port()
    viewer = subprocess.Popen(
        [args.rerun, str(args.recording), "--serve-web", "--web-viewer-port", str(web), "--port", str(grpc)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )  # .venv/bin/rerun is a wrapper: stop its whole group
    try:
        time.sleep(3)
        url = f"http://127.0.0.1:{web}/?url={quote(f'rerun+http://localhost:{grpc}/proxy', safe='')}"
        width, height = map(int, args.size.split(","))
        with sync_playwright() as playwright:
            chromium = playwright.chromium.launch(
                executable_path=browser,
                args=[
                    "--no-sandbox",
                    "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader",
                    "--ignore-gpu-blocklist",
                ],
            )
            page = chromium.new_page(viewport={"width": width, "height": height})
            page.goto(url)
            time.sleep(args.wait)
            page.screenshot(path=str(args.out))
            chromium.close()
    finally:
        os.killpg(viewer.pid, signal.SIGTERM)
        viewer.wait()
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
