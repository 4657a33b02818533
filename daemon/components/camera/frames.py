# The latest camera frame for many readers on the event loop: each waits for one newer than its own.
from __future__ import annotations

import asyncio

from drivers.camera import Frame


class LatestFrame:
    """Holds one frame (the newest) and its sequence number; :meth:`next_after` waits for a
    newer one. A reader that falls behind skips to the newest: nobody queues frames."""

    def __init__(self) -> None:
        self.frame: Frame | None = None
        self.seq = 0
        self._event = asyncio.Event()

    def put(self, frame: Frame) -> None:
        self.frame, self.seq = frame, self.seq + 1
        event, self._event = self._event, asyncio.Event()
        event.set()

    async def next_after(self, seq: int, timeout_s: float) -> tuple[Frame, int] | None:
        """The newest frame once its number is above ``seq``; None after ``timeout_s``."""
        if self.frame is not None and self.seq > seq:
            return self.frame, self.seq
        try:
            async with asyncio.timeout(timeout_s):
                await self._event.wait()
        except TimeoutError:
            return None
        assert self.frame is not None
        return self.frame, self.seq


def mjpeg_part(frame: Frame, boundary: str) -> bytes:
    """One part of a multipart/x-mixed-replace MJPEG stream."""
    head = (f"--{boundary}\r\nContent-Type: image/jpeg\r\n"
            f"Content-Length: {len(frame.jpeg)}\r\n\r\n").encode("ascii")
    return head + frame.jpeg + b"\r\n"
