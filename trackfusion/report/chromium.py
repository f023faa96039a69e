"""Headless Chromium: screenshot and PDF of a local HTML file (the report's render check).

The browser is found as ``$TRACKFUSION_CHROMIUM`` or the first of ``chromium``,
``chromium-browser``, ``google-chrome`` on ``PATH``. It runs with a throw-away profile, no
sandbox (CI containers run as root), no GPU and every background network feature off, so a
render touches nothing but the given file.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from ..errors import ReportError

CANDIDATES = ("chromium", "chromium-browser", "google-chrome")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", "--disable-dev-shm-usage")


def find_chromium() -> str | None:
    """Path of a Chromium executable, or None."""
    env = os.environ.get("TRACKFUSION_CHROMIUM")
    if env:
        return env if shutil.which(env) else None
    return next((p for p in map(shutil.which, CANDIDATES) if p), None)


def _run(args: list[str], timeout_s: float) -> None:
    exe = find_chromium()
    if exe is None:
        raise ReportError("chromium not found on PATH (install it, e.g. 'apt-get install chromium', "
                          "or set TRACKFUSION_CHROMIUM)")
    with tempfile.TemporaryDirectory(prefix="trackfusion-chromium-") as profile:
        cmd = [exe, *FLAGS, f"--user-data-dir={profile}", *args]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise ReportError(f"chromium did not finish within {timeout_s:g} s") from None
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise ReportError(f"chromium failed (exit {proc.returncode}): {last}")


def screenshot(html_path: str | Path, png_path: str | Path, width_px: int = 1200, height_px: int = 3000,
               timeout_s: float = 120.0) -> None:
    """Render ``html_path`` into a PNG of ``width_px`` x ``height_px`` pixels."""
    _run([f"--screenshot={Path(png_path).resolve()}", f"--window-size={width_px},{height_px}",
          Path(html_path).resolve().as_uri()], timeout_s)
    if not Path(png_path).is_file():
        raise ReportError(f"chromium wrote no screenshot to {png_path}")


def print_pdf(html_path: str | Path, pdf_path: str | Path, timeout_s: float = 120.0) -> None:
    """Print ``html_path`` to ``pdf_path`` (A4, no header or footer)."""
    _run([f"--print-to-pdf={Path(pdf_path).resolve()}", "--no-pdf-header-footer",
          Path(html_path).resolve().as_uri()], timeout_s)
    if not Path(pdf_path).is_file() or Path(pdf_path).stat().st_size == 0:
        raise ReportError(f"chromium wrote no PDF to {pdf_path}")
