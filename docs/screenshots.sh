#!/bin/sh
# Regenerates the screenshots in docs/images from `make demo`'s output, as a reader sees the pages at 1400 px:
#   docs/images/report_<camera>.png  the top of each camera's report.html (summary, key figures, suitability)
#   docs/images/compare.png          the whole comparison page (compare.html)
#   docs/images/suitability_d455.png the D455 report's Suitability section, whose pixel aspect check is marginal
#
# Needs:
#   - the output of `make demo` (default demo-output/, or give its directory as the first argument);
#   - Debian's chromium (`apt-get install chromium`; any Chromium or Chrome works: set CHROMIUM=/path/to/it), and
#     for the section screenshot its chromedriver (`apt-get install chromium-driver`);
#   - the project's virtual environment (`make .venv/.installed`): its Pillow reduces the PNGs to 256 colours.
#
# Usage: docs/screenshots.sh [DEMO_DIR]       (run from the repository root)
set -eu

DEMO_DIR=${1:-demo-output}
OUT=docs/images
CHROMIUM=${CHROMIUM:-chromium}
PYTHON=${PYTHON:-.venv/bin/python}
WIDTH=1400
REPORT_HEIGHT=2400    # the first read: summary, key figures, suitability
COMPARE_HEIGHT=6000   # the comparison page in full (the blank space below it is cut)

if ! command -v "$CHROMIUM" >/dev/null 2>&1; then
    echo "screenshots.sh needs chromium: apt-get install chromium (or set CHROMIUM=/path/to/chromium)" >&2
    exit 1
fi
if [ ! -x "$PYTHON" ]; then
    echo "screenshots.sh needs the virtual environment: make .venv/.installed (or set PYTHON=...)" >&2
    exit 1
fi
if [ ! -d "$OUT" ]; then
    echo "run screenshots.sh from the repository root (no $OUT here)" >&2
    exit 1
fi

shot() {  # page.html output.png height
    if [ ! -f "$1" ]; then
        echo "$1 is missing: run 'make demo' first (or give the demo's directory as the first argument)" >&2
        exit 1
    fi
    "$CHROMIUM" --headless --no-sandbox --disable-gpu --disable-background-networking --no-first-run \
        --hide-scrollbars --window-size="$WIDTH,$3" --screenshot="$2" "file://$(realpath "$1")" >/dev/null 2>&1
    "$PYTHON" -c 'import sys; from PIL import Image, ImageOps
image = Image.open(sys.argv[1]).convert("RGB")
box = ImageOps.invert(image).getbbox()  # blank space below the page: cut 40 px under the last content
image = image.crop((0, 0, image.width, min(image.height, box[3] + 40))) if box else image
image.quantize(256).save(sys.argv[1], optimize=True)' "$2"
    echo "$2"
}

for camera in blaze101 amt100 flexx2 d455; do
    shot "$DEMO_DIR/$camera/report.html" "$OUT/report_$camera.png" "$REPORT_HEIGHT"
done
shot "$DEMO_DIR/comparison/compare.html" "$OUT/compare.png" "$COMPARE_HEIGHT"

# one section of a page (from its <h2> to the next): the whole page at 1400 px through chromedriver, cut
"$PYTHON" - "$DEMO_DIR/d455/report.html" "$OUT/suitability_d455.png" "Suitability" <<'PY'
import os, pathlib, shutil, sys, tempfile
from PIL import Image
from selenium import webdriver
from selenium.webdriver.chrome.service import Service

page, output, heading = sys.argv[1:]
if not pathlib.Path(page).is_file():
    sys.exit(f"{page} is missing: run 'make demo' first (or give the demo's directory as the first argument)")
if shutil.which("chromedriver") is None:
    sys.exit("the section screenshot needs chromedriver: apt-get install chromium-driver")
options = webdriver.ChromeOptions()
for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1400,900"):
    options.add_argument(argument)
scratch = tempfile.TemporaryDirectory()  # Chromium's own temporary directories, removed after
driver = webdriver.Chrome(service=Service(shutil.which("chromedriver"), env={**os.environ, "TMPDIR": scratch.name}),
                          options=options)
try:
    driver.get(pathlib.Path(page).resolve().as_uri())
    top, bottom, height = driver.execute_script("""
        const h2 = [...document.querySelectorAll('h2')];
        const i = h2.findIndex(h => h.textContent.startsWith(arguments[0]));
        const y = e => e.getBoundingClientRect().top + window.scrollY;
        return [y(h2[i]), i + 1 < h2.length ? y(h2[i + 1]) : document.body.scrollHeight, document.body.scrollHeight];
    """, heading)
    driver.set_window_size(1400, int(height) + 200)
    with tempfile.TemporaryDirectory() as tmp:
        whole = pathlib.Path(tmp) / "page.png"
        driver.save_screenshot(str(whole))
        image = Image.open(whole).convert("RGB")
finally:
    driver.quit()
    scratch.cleanup()
image.crop((0, max(0, int(top) - 20), image.width, int(bottom))).quantize(256).save(output, optimize=True)
print(output)
PY
