"""Prepared frames, kept in a least-recently-used cache and prepared on demand in one
background thread (so the GUI never waits on a frame it does not show yet).

```python
cache = FrameCache(source.prepare, capacity=32)
future = cache.request((12, True))      # frame 12 with FPGO: cached, in progress, or queued
cache.prefetch([(13, True), (14, True)])
frame = future.result()
cache.close()                           # cancels what is queued, waits for the running one
```
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Generic, Hashable, TypeVar

Key = TypeVar("Key", bound=Hashable)
Value = TypeVar("Value")


def _failed(future: Future) -> bool:
    """Cancelled, or finished with an exception (never cached: asking again retries)."""
    return future.cancelled() or (future.done() and future.exception() is not None)


class FrameCache(Generic[Key, Value]):
    """LRU cache of ``prepare(*key)`` results computed by one worker thread.

    Futures of finished and pending work are both kept, so asking twice for the same frame
    never prepares it twice. A failed preparation is not cached (asking again retries it).
    """

    def __init__(self, prepare: Callable[..., Value], capacity: int = 32,
                 thread_name: str = "viewer-frames") -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._prepare = prepare
        self.capacity = capacity
        self._entries: OrderedDict[Key, Future] = OrderedDict()
        self._lock = threading.Lock()
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=thread_name)
        self._closed = False

    def _run(self, key: Key) -> Value:
        return self._prepare(*key)

    def _forget_failure(self, key: Key, future: Future) -> None:
        if _failed(future):
            with self._lock:
                if self._entries.get(key) is future:
                    del self._entries[key]

    def request(self, key: Key) -> Future:
        """The future of ``key``'s prepared frame (marked most recently used)."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the frame cache is closed")
            future = self._entries.get(key)
            if future is not None and not _failed(future):
                self._entries.move_to_end(key)
                return future
            future = self._executor.submit(self._run, key)
            self._entries[key] = future
            while len(self._entries) > self.capacity:
                _, evicted = self._entries.popitem(last=False)
                evicted.cancel()   # a queued frame nobody wants any more; running ones finish
        future.add_done_callback(lambda done: self._forget_failure(key, done))
        return future

    def prefetch(self, keys: Iterable[Key]) -> None:
        """Queue ``keys`` that are not cached yet (without touching the cached ones' order)."""
        for key in keys:
            with self._lock:
                known = key in self._entries or self._closed
            if not known:
                self.request(key)

    def cached(self, key: Key) -> bool:
        """True when ``key`` is prepared and waiting in the cache."""
        with self._lock:
            future = self._entries.get(key)
        return future is not None and future.done() and not _failed(future)

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Wait until no frame is being prepared or queued; True if that happened in time."""
        with self._lock:
            pending = [future for future in self._entries.values() if not future.done()]
        _, not_done = wait(pending, timeout=timeout)
        return not not_done

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def close(self) -> None:
        """Cancel queued work, wait for the frame in progress, and end the worker thread."""
        with self._lock:
            self._closed = True
            self._entries.clear()
        self._executor.shutdown(wait=True, cancel_futures=True)


__all__ = ["FrameCache"]
