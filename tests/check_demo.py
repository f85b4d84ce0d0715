"""The check `make demo` ends with: the files the demo wrote are what the documentation promises.

* every camera's keyfigures.json validates against docs/keyfigures.schema.json (JSON Schema draft 2020-12,
  Python's ``jsonschema``) and states the schema version of that file;
* the blaze-101's report.pdf (headless Chromium) has A4 pages, more than one, whose text extracts (``pypdf``)
  and holds the camera, the Conditions section and the key figures' names. Without Chromium on PATH the
  evaluation writes no PDF and says why; the check then says so too instead of failing.

Usage: ``python -m tests.check_demo DEMO_DIR [CAMERA ...]``; exit 1 with every problem listed.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from jsonschema import Draft202012Validator
from pypdf import PdfReader

from labctl.evaluation.keyfigures import SCHEMA_VERSION
from labctl.report.pdf import find_browser

SCHEMA = Path(__file__).resolve().parents[1] / "docs" / "keyfigures.schema.json"
A4_PT = (595.3, 841.9)
PDF_FIGURES = ("z_trueness_q90_mm", "z_precision_q90_mm", "ied_pixels_at_hyperfocal")


def keyfigures_problems(path: Path, validator: Draft202012Validator) -> list[str]:
    """What is wrong with the keyfigures.json at ``path`` against the schema (empty: nothing)."""
    if not path.is_file():
        return [f"{path}: missing"]
    document = json.loads(path.read_text())
    problems = [f"{path}: {'/'.join(map(str, e.absolute_path)) or '(root)'}: {e.message}"
                for e in validator.iter_errors(document)]
    if document.get("schema_version") != SCHEMA_VERSION:
        problems.append(f"{path}: schema_version {document.get('schema_version')!r}, expected {SCHEMA_VERSION!r}")
    return problems


def pdf_problems(report: Path, model: str) -> list[str]:
    """What is wrong with ``report`` (report.pdf) of a camera ``model`` (empty: nothing)."""
    if not report.is_file():
        return [] if find_browser() is None else [f"{report}: missing although Chromium is on PATH"]
    pdf = PdfReader(report)
    problems = [] if len(pdf.pages) > 1 else [f"{report}: {len(pdf.pages)} page(s), expected more than one"]
    box = pdf.pages[0].mediabox
    if abs(float(box.width) - A4_PT[0]) > 1.0 or abs(float(box.height) - A4_PT[1]) > 1.0:
        problems.append(f"{report}: page {float(box.width):.1f} x {float(box.height):.1f} pt, not A4")
    text = " ".join(page.extract_text() for page in pdf.pages)
    flat = text.replace("\n", "").replace(" ", "")
    missing = [word for word in (model.replace(" ", ""), "Conditions", *PDF_FIGURES) if word not in flat]
    if missing:
        problems.append(f"{report}: its text lacks {', '.join(missing)}")
    return problems


def main(argv: list[str]) -> int:
    if not argv:
        print("usage: python -m tests.check_demo DEMO_DIR [CAMERA ...]", file=sys.stderr)
        return 2
    demo = Path(argv[0])
    cameras = argv[1:] or sorted(p.name for p in demo.iterdir() if (p / "report.html").is_file())
    validator = Draft202012Validator(json.loads(SCHEMA.read_text()))
    problems = [p for camera in cameras for p in keyfigures_problems(demo / camera / "keyfigures.json", validator)]
    if "blaze101" in cameras:
        model = json.loads((demo / "blaze101" / "keyfigures.json").read_text())["camera"]["model"]
        problems += pdf_problems(demo / "blaze101" / "report.pdf", model)
    for problem in problems:
        print(f"demo check: {problem}", file=sys.stderr)
    if problems:
        return 1
    pdf = "" if find_browser() is not None else " (no Chromium on PATH: no report.pdf to check)"
    print(f"demo check: {len(cameras)} keyfigures.json valid against {SCHEMA.name} {SCHEMA_VERSION}; "
          f"blaze101/report.pdf A4 with its figures{pdf}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
