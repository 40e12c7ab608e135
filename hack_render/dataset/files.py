"""The dataset's file writer: encodes and writes a sample's files in the order they are
queued, on one background thread (the serial executor: while the next sample renders) or
in the caller's thread; each writing function writes under a temporary name and renames
(``hack_render.io.atomic_path``)."""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor, wait


class FileWriter:
    """Runs file writes in the order they are submitted: on one background thread
    (``background=True``), or at once in the caller's thread. Returns futures; a failed
    write's exception is raised by its future."""

    def __init__(self, background: bool = False):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="dataset-writer") \
            if background else None
        self._records: deque[Future] = deque()

    @property
    def background(self) -> bool:
        return self._pool is not None

    def submit(self, fn, *args, **kwargs) -> Future:
        if self._pool is not None:
            fut = self._pool.submit(fn, *args, **kwargs)
        else:
            fut = Future()
            try:
                fut.set_result(fn(*args, **kwargs))
            except Exception as err:  # noqa: BLE001 - kept in the future, as a thread would
                fut.set_exception(err)
        return fut

    def submit_record(self, fn, *args, **kwargs) -> Future:
        """:meth:`submit` a sample's completion mark (``sample.json``): the samples whose
        mark is still pending are what :meth:`wait_below` counts."""
        fut = self.submit(fn, *args, **kwargs)
        self._records.append(fut)
        return fut

    def wait_below(self, n: int) -> None:
        """Block until fewer than ``n`` samples' records are still pending (memory bound)."""
        while self._records and (self._records[0].done() or len(self._records) >= n):
            f = self._records.popleft()
            if not f.done():
                wait([f])

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        self._records.clear()
