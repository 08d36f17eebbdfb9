# SPDX-License-Identifier: Apache-2.0
"""
When to fuse: at the stamp of a head's solution, once every head awaited there has reported.

Heads exposed together (one sync pulse) deliver their solutions of one stamp a few
milliseconds apart. Fusing at the first one would use the others' previous solutions,
brought a whole frame period forward with the body rate; waiting for them fuses every head at
its own exposure. The schedule keeps one pending stamp:

- a solution stamped after the pending one closes it (fused with what came) and opens its own;
- one stamped before it, but after the last fused stamp, joins it;
- one stamped at or before the last fused stamp joins the next fusion (the caller counts it);
- the pending stamp is due as soon as every awaited head's latest solution is at or after it,
  or when the caller's wait runs out (expire).

The awaited heads (`awaited`): those of the last fusion, and any head whose latest solution
is at or after the last fused stamp: a head whose solution came just after a fusion had closed
is alive and in step, and waiting for it at the next stamp keeps it in (not awaiting it would
close every next fusion before it, again and again). None awaited means fuse at once.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping


class FusionSchedule:
    """The pending fusion stamp and the last one handled [ns] (module docstring)."""

    def __init__(self) -> None:
        self.pending_ns: int | None = None
        self.last_fused_ns: int | None = None

    def is_old(self, stamp_ns: int) -> bool:
        """Return True when stamp_ns is at or before the last fused stamp: that solution joins the next fusion."""
        return self.last_fused_ns is not None and stamp_ns <= self.last_fused_ns

    def add(self, stamp_ns: int, latest_ns: Mapping[str, int], awaited: Iterable[str]) -> list[int]:
        """
        Take an accepted solution at stamp_ns; return the stamps to fuse now, oldest first.

        latest_ns: each head's latest accepted solution's stamp (this one's included); awaited:
        the heads whose solution at the pending stamp is waited for.
        """
        if self.is_old(stamp_ns):
            return []
        due = []
        if self.pending_ns is not None and stamp_ns > self.pending_ns:
            due.append(self._close())
        if self.pending_ns is None:
            self.pending_ns = stamp_ns
        if all(latest_ns.get(head, -1) >= self.pending_ns for head in awaited):
            due.append(self._close())
        return due

    def awaited(self, latest_ns: Mapping[str, int], contributing: Iterable[str]) -> list[str]:
        """
        Return the heads to wait for at the next stamp (module docstring).

        latest_ns: each head's latest accepted solution's stamp [ns]; contributing: the heads
        fused last time.
        """
        wait = set(contributing)
        if self.last_fused_ns is not None:
            wait |= {head for head, stamp in latest_ns.items() if stamp >= self.last_fused_ns}
        return sorted(wait)

    def expire(self) -> int | None:
        """Return the pending stamp to fuse now, the wait having run out (None when nothing is pending)."""
        return self._close() if self.pending_ns is not None else None

    def reset(self) -> None:
        self.pending_ns = self.last_fused_ns = None

    def _close(self) -> int:
        stamp, self.pending_ns = self.pending_ns, None
        self.last_fused_ns = stamp
        return stamp
