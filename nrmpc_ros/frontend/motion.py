"""Why the pipeline judged a frame not at rest: a kind (counted) and the numbers of this frame (shown).

The kinds are those of :meth:`Pipeline._still <nrmpc_ros.frontend.pipeline.Pipeline>` (docs/PIPELINE.md,
Holds): the IMU's stillness test, a camera's tracks lost, its image moving between two frames, or its image
leaving the open hold's radius. The sentence is made only where it is shown (``str(motion)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum


class MotionKind(Enum):
    """What says the rig moved; the value is the phrase shown."""

    IMU_MOVED = "the IMU says the rig moved"
    TRACKS_LOST = "tracks lost"
    IMAGE_MOVED = "image moved"
    LEFT_HOLD = "image left the hold"


@dataclass(frozen=True)
class Motion:
    """One frame judged not at rest: the kind, the camera that showed it ("" for the IMU) and its image motion
    (px: the step between two frames, or the offset from the hold's first frame)."""

    kind: MotionKind
    camera: str = ""
    px: float = math.nan

    def __str__(self) -> str:
        k = self.kind
        if k is MotionKind.IMU_MOVED:
            return k.value
        if k is MotionKind.TRACKS_LOST:
            return f"{self.camera}: {k.value}"
        if k is MotionKind.IMAGE_MOVED:
            return f"{self.camera}: {k.value} {self.px:.2f} px"
        return f"{self.camera}: {k.value} ({self.px:.1f} px from its first frame)"


__all__ = ["Motion", "MotionKind"]
