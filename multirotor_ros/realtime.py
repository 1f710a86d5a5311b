"""What a process that must answer on time does with Python's garbage collector.

Start-up (imports, compiled kernels, rclpy and its nodes) leaves a few hundred thousand objects alive for
good, and a full collection scans them all: the ones start-up itself triggers took 22-70 ms each in the
fleet's simulator and controller processes (``gc.callbacks`` timing each collection), more than ten 4 ms
control periods. One in flight would cost the same and make those periods late at once. What a control
period makes is freed by reference counting; the collector only needs to see the rare cycles made after
start-up.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def start_up_frozen() -> Iterator[None]:
    """Move every object alive now out of the collector's sight until the block ends.

    Blocks may overlap (the ``mavlink_bridge`` node's spin and its bridge thread's loop): the later one
    also freezes what was made since the first; the first to end unfreezes everything, at shutdown.
    """
    gc.collect()  # garbage of the start-up is freed, not kept for good
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()  # what became garbage meanwhile is collectable again
