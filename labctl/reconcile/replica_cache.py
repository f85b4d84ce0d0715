"""Null replicas kept on disk, so that a second reconcile of a campaign against the same model reuses them
(docs/reconcile.md, *Null calibration*).

A replica's comparison depends on the model's text at the run's sensor size, the campaign as the replica runs
it (with its seed), the steps compared, the run's description that the comparison reads (``info``), and the
code that simulates, records, observes and compares. The key is a SHA-256 of all of them; the code enters as a
fingerprint of the source of labctl's packages, so a replica made by other code is never taken. One file per
replica (``<key>.pickle``), written to a temporary name and renamed: a reconcile stopped half-way leaves only
whole replicas, and a second one with more null runs reuses those it shares.

The directory is ``$LABCTL_CACHE_DIR/null-replicas``, else ``$XDG_CACHE_HOME/labctl/null-replicas``, else
``~/.cache/labctl/null-replicas``; an empty ``LABCTL_CACHE_DIR`` switches the cache off. The files are pickles
labctl wrote: a file that does not load as a replica is ignored and made again.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Any

#: environment variable naming the cache's parent directory (empty: no cache)
CACHE_ENV = "LABCTL_CACHE_DIR"
#: the packages whose source decides what a replica holds
PACKAGES = ("labctl", "sim", "metrics", "procedures", "drivers")


def cache_directory() -> Path | None:
    """Where the replicas are kept, or None when the cache is switched off (``LABCTL_CACHE_DIR=""``)."""
    configured = os.environ.get(CACHE_ENV)
    if configured is not None:
        return Path(configured) / "null-replicas" if configured else None
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "labctl" / "null-replicas"


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 over the path and content of every Python source file of :data:`PACKAGES`."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for package in PACKAGES:
        for source in sorted((root / package).rglob("*.py")):
            digest.update(str(source.relative_to(root)).encode())
            digest.update(source.read_bytes())
    return digest.hexdigest()


def replica_key(model_text: str, replica_toml: str, step_ids: list[str], info: dict[str, Any]) -> str:
    """The cache key of the replica that runs the campaign ``replica_toml`` (its seed included) on ``model_text``
    (see the module)."""
    described = json.dumps(info, sort_keys=True, default=repr)
    parts = [code_fingerprint(), model_text, replica_toml, *sorted(step_ids), described]
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()


def load(directory: Path, key: str) -> Any:
    """What is kept under ``key``, None when nothing is (or the file does not load)."""
    try:
        with open(directory / f"{key}.pickle", "rb") as f:
            return pickle.load(f)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError, ValueError):
        return None


def store(directory: Path, key: str, value: Any) -> None:
    """Keep ``value`` under ``key`` (written whole, then renamed); a cache that cannot be written is skipped."""
    temporary: str | None = None
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=directory, suffix=".tmp", delete=False) as f:
            temporary = f.name
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(temporary, directory / f"{key}.pickle")
    except OSError:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
