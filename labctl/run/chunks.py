"""Compressed frames written beside the capture, not in its path (docs/runfile.md, Storage).

Compressing a frame takes longer than writing it, so it does not run in the thread that
writes the run file: a small pool of worker threads compresses each chunk
(labctl.run.compression.compress_chunk, which releases the GIL) while the writer thread goes
on, and the writer thread writes the compressed chunks as they are (HDF5's direct chunk
write: no filter pipeline, no chunk cache), each whole and in the order they were queued.
Only the writer thread touches HDF5; the workers see numpy arrays only.

A step's commit first writes every chunk still queued (:meth:`ChunkWriter.drain`), so
``complete = True`` never precedes a frame. A compression that fails in a worker is raised
in the writer thread as CompressionFailed, naming the frame and channel, at the next write
or at the commit; the chunks queued after it are dropped and the step can no longer be
committed. Nothing of the failed chunk reached the file, which keeps every step committed
before it. The pool is shut down when the run file is closed (:meth:`ChunkWriter.close`).
"""

from __future__ import annotations

import os
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import h5py
import numpy as np

from labctl.run.compression import compress_chunk

WORKERS = max(1, min(4, os.cpu_count() or 1))
"""Compression threads: one per core, at most 4 (a frame has 5 chunks)."""
QUEUED = 2 * 5
"""Chunks queued (two frames of 5 channels) before queueing another waits for the oldest to be written."""
THREAD_NAME = "labctl-compress"


class CompressionFailed(RuntimeError):
    """Compressing a frame's chunk failed in a worker thread; nothing of that chunk reached the file."""


@dataclass(frozen=True)
class _Queued:
    dataset: h5py.h5d.DatasetID
    offset: tuple[int, ...]
    what: str
    chunk: Future[tuple[bytes | np.ndarray, int]]


class ChunkWriter:
    """Compresses chunks in a pool of worker threads and writes them, in order, from the caller's thread."""

    def __init__(self, compression: str, workers: int = WORKERS, queued: int = QUEUED) -> None:
        self.compression = compression
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix=THREAD_NAME)
        self._queue: deque[_Queued] = deque()
        self._limit = queued
        self._failure: str | None = None

    def put(self, dataset: h5py.h5d.DatasetID, offset: tuple[int, ...], data: np.ndarray, what: str) -> None:
        """Queue the chunk at ``offset`` of ``dataset`` (``data``: a contiguous array, unchanged until it is
        written; ``what``: its name in messages, e.g. ``frame 3's z of step 00004_depth_sweep``), then
        write the chunks already compressed; waits for the oldest when too many are queued."""
        self._check()
        self._queue.append(_Queued(dataset, offset, what, self._pool.submit(compress_chunk, data, self.compression)))
        while self._queue and (self._queue[0].chunk.done() or len(self._queue) > self._limit):
            self._write_oldest()

    def drain(self) -> None:
        """Write every queued chunk (CompressionFailed if one could not be compressed)."""
        self._check()
        while self._queue:
            self._write_oldest()

    def discard(self) -> None:
        """Drop the queued chunks unwritten (a step abandoned, or the file detached after a write error);
        the next step starts afresh."""
        for queued in self._queue:
            queued.chunk.cancel()
        self._queue.clear()
        self._failure = None

    def close(self) -> None:
        """Drop the queued chunks and stop the worker threads (waiting for a compression under way)."""
        self.discard()
        self._pool.shutdown(wait=True, cancel_futures=True)

    def _check(self) -> None:
        if self._failure is not None:
            raise CompressionFailed(f"{self._failure}; the step cannot be completed")

    def _write_oldest(self) -> None:
        queued = self._queue.popleft()
        try:
            chunk, mask = queued.chunk.result()
        except Exception as exc:
            self.discard()
            self._failure = f"compressing {queued.what} ({self.compression}) failed: {type(exc).__name__}: {exc}"
            raise CompressionFailed(self._failure) from exc
        queued.dataset.write_direct_chunk(queued.offset, chunk, filter_mask=mask)
