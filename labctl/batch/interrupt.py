"""Ctrl-C while a batch talks to its Dask cluster: remembered, and acted on between the client's calls.

Every blocking call of a Dask client (starting a local cluster, connecting, a task's result, cancelling,
closing) runs a coroutine on the client's event-loop thread and waits for it in the calling thread
(``distributed.utils.sync``). A KeyboardInterrupt raised in that wait makes it schedule the coroutine's
cancellation on the loop; if the coroutine has not started yet, that callback fails with ``NameError:
cannot access free variable 'future'`` and the loop prints its traceback. So while the cluster is used,
SIGINT only sets a flag, and the batch checks it where it waits (between results, at most
:data:`POLL_S` apart) and then cancels and closes the cluster without being interrupted again.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

#: seconds between two looks at the flag while the batch waits for its tasks
POLL_S = 0.1


class CtrlC:
    """Whether Ctrl-C (SIGINT) was pressed while it was deferred by :func:`deferred_ctrl_c`."""

    def __init__(self) -> None:
        self.pressed = False

    def _record(self, signum: int, frame: FrameType | None) -> None:
        # runs in the main thread between two bytecodes: it only sets a flag (no lock, which the interrupted
        # code might hold)
        self.pressed = True

    def check(self) -> None:
        """Raise KeyboardInterrupt if Ctrl-C was pressed: the caller stops here, at a point of its choosing."""
        if self.pressed:
            raise KeyboardInterrupt


@contextmanager
def deferred_ctrl_c() -> Iterator[CtrlC]:
    """SIGINT sets the yielded flag instead of raising KeyboardInterrupt inside; on the way out the previous
    handler is back, and a Ctrl-C pressed inside raises KeyboardInterrupt (the command's exit 130). Outside
    the main thread, or where SIGINT is ignored (a background job started with ``nohup``), nothing changes."""
    ctrl_c = CtrlC()
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        yield ctrl_c
        return
    previous = signal.signal(signal.SIGINT, ctrl_c._record)
    try:
        yield ctrl_c
    finally:
        signal.signal(signal.SIGINT, previous)
        ctrl_c.check()
