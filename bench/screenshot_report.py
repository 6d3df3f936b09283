"""Screenshots of a bimcap report (``report.html``) in a real headless browser, page by page, to
look at what a reader sees: layout, figures, captions, tables.

Needs Chromium (Debian: ``apt-get install --no-install-recommends chromium``; not a bimcap
dependency, and ``scripts/setup.sh`` does not install it). Without it the script says so and
exits 0, taking nothing.

Each shot is the browser's viewport (``--width`` × ``--height`` CSS pixels) at one scroll position
of the report: the report is shown in a full-width iframe shifted up by the scroll offset (the
browser's command line cannot scroll), so ``shot_00.png`` is the top of the page,
``shot_01.png`` the next screen, and so on until a screen is blank (or ``--max-shots``).

Usage::

    python bench/screenshot_report.py OUT/refine/report.html -o /tmp/shots
    python bench/screenshot_report.py --demo /tmp/demo -o /tmp/shots --width 900
        # first runs `bimcap demo --building tiny --frames 12 --scale 0.125 -o /tmp/demo`
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_browser(name: str | None = None) -> str | None:
    """The path of a Chromium-like browser: ``name`` if given and found, else the first of
    :data:`BROWSERS` on the PATH, else None."""
    for candidate in ([name] if name else BROWSERS):
        path = shutil.which(candidate)
        if path:
            return path
    return None


def screenshot(browser: str, url: str, png: Path, width: int, height: int,
               timeout_s: float = 120.0) -> None:
    """One headless screenshot of ``url`` with a ``width`` × ``height`` window into ``png``."""
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           "--allow-file-access-from-files", f"--screenshot={png}",
           f"--window-size={width},{height}", url]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    if not png.is_file():
        raise RuntimeError(f"{browser} wrote no screenshot (exit {r.returncode}): "
                           f"{r.stderr.strip()[-500:]}")


def is_blank(png: Path, threshold: int = 250) -> bool:
    """Whether every pixel of ``png`` is (near) white: the page has ended."""
    import numpy as np
    from PIL import Image

    return bool((np.asarray(Image.open(png).convert("L")) >= threshold).all())


def shoot_report(report: Path, out: Path, width: int = 1400, height: int = 1800,
                 max_shots: int = 30, browser: str | None = None) -> list[Path]:
    """Screenshots of ``report`` at successive scroll offsets (0, ``height``, 2 ``height``, ...)
    into ``out/shot_NN.png``; returns their paths (the blank one past the end is removed)."""
    exe = find_browser(browser)
    if exe is None:
        raise FileNotFoundError("no headless browser")
    out.mkdir(parents=True, exist_ok=True)
    url = report.resolve().as_uri()
    shots: list[Path] = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(max_shots):
            offset = k * height
            wrapper = Path(tmp) / f"wrap_{k}.html"
            wrapper.write_text(
                "<!doctype html><html><body style='margin:0;overflow:hidden'>"
                f"<iframe src='{url}' style='border:0;display:block;width:{width}px;"
                f"height:{offset + height}px;margin-top:-{offset}px'></iframe></body></html>",
                encoding="utf-8")
            png = out / f"shot_{k:02d}.png"
            screenshot(exe, wrapper.as_uri(), png, width, height)
            if k > 0 and is_blank(png):
                png.unlink()
                break
            shots.append(png)
    return shots


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("report", nargs="?", type=Path, help="the report.html to shoot")
    ap.add_argument("--demo", type=Path, metavar="DIR",
                    help="first run the tiny demo into DIR and shoot DIR/refine/report.html")
    ap.add_argument("-o", "--out", type=Path, required=True, help="folder for the PNGs")
    ap.add_argument("--width", type=int, default=1400, help="window width, CSS px (1400)")
    ap.add_argument("--height", type=int, default=1800, help="window height, CSS px (1800)")
    ap.add_argument("--max-shots", type=int, default=30, help="at most this many screens (30)")
    ap.add_argument("--browser", help="the browser's executable (default: chromium, ...)")
    args = ap.parse_args(argv)
    if find_browser(args.browser) is None:
        print("screenshot_report: no headless Chromium found (tried "
              f"{args.browser or ', '.join(BROWSERS)}); install Debian's chromium "
              "(apt-get install --no-install-recommends chromium) to take the screenshots. "
              "Nothing taken.")
        return 0
    report = args.report
    if args.demo is not None:
        from bimcap.cli import main as bimcap

        rc = bimcap(["demo", "--building", "tiny", "--frames", "12", "--scale", "0.125", "-o",
                     str(args.demo), "-q"])
        if rc:
            return rc
        report = args.demo / "refine" / "report.html"
    if report is None or not report.is_file():
        print(f"screenshot_report: error: {report}: no such report", file=sys.stderr)
        return 2
    shots = shoot_report(report, args.out, args.width, args.height, args.max_shots,
                         args.browser)
    for p in shots:
        print(p)
    print(f"{len(shots)} screenshot(s) of {report} at {args.width}x{args.height}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
