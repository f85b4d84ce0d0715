"""Where the real data files of ../shared/data are (read in place, never copied into the project).

LABCTL_SHARED_DATA wins; otherwise the ``shared/data`` folder beside the
checkout, then the lab machines' /work/shared/data. A missing file is an
error naming every place looked in (a test that needs it must fail, not skip).
"""

from __future__ import annotations

import os
from pathlib import Path

CANDIDATES = [
    *([Path(os.environ["LABCTL_SHARED_DATA"])] if os.environ.get("LABCTL_SHARED_DATA") else []),
    Path(__file__).resolve().parents[2] / "shared" / "data",
    Path("/work/shared/data"),
]


def shared_data(name: str) -> Path:
    """Path of a shared data file."""
    for folder in CANDIDATES:
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(f"{name} not found in {', '.join(map(str, CANDIDATES))} (set LABCTL_SHARED_DATA)")
