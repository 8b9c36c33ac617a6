"""Job slots and daily bytes held by uploads in flight, per key, in this API process (`Service.reserve`
grants them, `Service.accept` turns one into a job row)."""

from __future__ import annotations

import collections
import threading


class Hold:
    """One upload's reservation: a job slot and `bytes` of its key's daily quota, until released."""

    __slots__ = ("key_id", "bytes", "active")

    def __init__(self, key_id: str, nbytes: int):
        self.key_id, self.bytes, self.active = key_id, nbytes, False  # active once granted


class Holds:
    """The job slots and daily bytes that uploads in flight hold, per key, in this API process.

    `gate` orders the steps that must not interleave: a quota check and the grant of a hold
    (`Service.reserve`), and the commit of a job with the release of its hold (`Service.accept`). A
    check inside the gate therefore counts every slot exactly once: as a hold, or as the job row that
    replaced it. Refused uploads never got a hold, and every hold is released when its upload ends
    (accepted, refused, or cut off), so nothing is held for an upload that is gone. The counters have
    their own small lock: releasing (on the event loop) never waits for a database commit.
    """

    def __init__(self):
        self.gate = threading.Lock()
        self._lock = threading.Lock()
        self._slots: collections.Counter[str] = collections.Counter()
        self._bytes: collections.Counter[str] = collections.Counter()

    def grant(self, hold: Hold) -> None:
        with self._lock:
            hold.active = True
            self._slots[hold.key_id] += 1
            self._bytes[hold.key_id] += hold.bytes

    def release(self, hold: Hold | None) -> None:
        with self._lock:
            if hold is None or not hold.active:
                return
            hold.active = False
            self._slots[hold.key_id] -= 1
            self._bytes[hold.key_id] -= hold.bytes
            if not self._slots[hold.key_id]:
                del self._slots[hold.key_id], self._bytes[hold.key_id]

    def held(self, key_id: str, but: Hold | None = None) -> tuple[int, int]:
        """(slots, bytes) the key's holds take, but `but`'s own."""
        with self._lock:
            slots, nbytes = self._slots.get(key_id, 0), self._bytes.get(key_id, 0)
            if but is not None and but.active:
                slots, nbytes = slots - 1, nbytes - but.bytes
        return slots, nbytes
