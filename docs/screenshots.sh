#!/bin/sh
# Regenerates the screenshots in docs/images from `make demo`'s output, as a reader sees the pages at 1400 px:
#   docs/images/report_<camera>.png  the top of each camera's report.html (summary, key figures, suitability)
#   docs/images/compare.png          the whole comparison page (compare.html)
#
# Needs:
#   - the output of `make demo` (default demo-output/, or give its directory as the first argument);
#   - Debian's chromium (`apt-get install chromium`; any Chromium or Chrome works: set CHROMIUM=/path/to/it);
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
