"""``report.pdf``: the HTML report printed to an A4 PDF by headless Chromium, for the archive.

Chromium prints the very page the browser shows (the report's own print style: A4 pages, tables wrapped to
the page width, figures kept whole), with its text extractable. A Python PDF library would need its own
layout of every table and figure, a second report to keep in step with the HTML; the browser is a system
package the set-up installs (labctl/setup_check.py). Without Chromium the evaluation writes everything else
and says why there is no PDF.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

#: the browsers tried, in order (Debian's package installs ``chromium``)
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: seconds a print may take (a report prints in a few seconds)
TIMEOUT_S = 180.0


def find_browser() -> str | None:
    """The path of the first of :data:`BROWSERS` on PATH, None when there is none."""
    return next((path for name in BROWSERS if (path := shutil.which(name))), None)


def print_pdf(page: Path, pdf: Path) -> str | None:
    """Print the HTML file ``page`` to ``pdf`` with headless Chromium; None when it was written, else why not."""
    browser = find_browser()
    if browser is None:
        return "no Chromium on PATH (Debian: apt-get install chromium)"
    with tempfile.TemporaryDirectory(prefix="labctl-chromium-") as profile:
        options = ["--headless", "--disable-gpu", f"--user-data-dir={profile}", "--no-pdf-header-footer",
                   f"--print-to-pdf={pdf.resolve()}", page.resolve().as_uri()]
        if hasattr(os, "geteuid") and os.geteuid() == 0:  # Chromium refuses to run as root with its sandbox
            options.insert(0, "--no-sandbox")
        # Chromium reserves a large virtual address space at start and aborts (SIGTRAP) under a lower soft limit
        # on it (ulimit -v): the shell lifts the soft limit to the hard one for the browser alone
        command = ["sh", "-c", 'ulimit -S -v "$(ulimit -H -v)" && exec "$@"', "sh", browser, *options]
        pdf.unlink(missing_ok=True)
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            return f"Chromium did not print within {TIMEOUT_S:.0f} s"
    if not pdf.is_file() or pdf.stat().st_size == 0:
        return f"Chromium wrote no PDF (exit status {done.returncode}): {done.stderr.strip()[-300:]}"
    return None
