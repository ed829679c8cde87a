"""The work items the front end passes from its input (the feeder, the service's requests) to the pipeline runner:
one :class:`Work` per step, its :class:`WorkKind` saying what the step is."""

from __future__ import annotations

import math
from enum import Enum
from typing import NamedTuple


class WorkKind(Enum):
    """What a work item asks of the pipeline; the value is the word shown in logs."""

    IMU = "imu"  # data = (accel, gyro, covariances or None)
    FRAMES = "frames"  # data = (FrameSet, arrival time on the feeder's clock)
    FLUSH = "flush"  # the input ended: the open hold is estimated
    RESTART = "restart"  # data = why: time jumped back (a new pipeline)
    RESET = "reset"  # data = why: a new sequence on request
    METHOD = "method"  # data = the estimation method to restart with (the service's request)

    @property
    def ends_sequence(self) -> bool:
        """Whether the item ends the open hold (restart and reset also the sequence): the next frame set is
        compared with nothing."""
        return self in (WorkKind.FLUSH, WorkKind.RESTART, WorkKind.RESET)


class Work(NamedTuple):
    """One step for the pipeline: what it is (``kind``, see :class:`WorkKind` for ``data``) and its stamp."""

    kind: WorkKind
    stamp: float = math.nan
    data: object = None


__all__ = ["Work", "WorkKind"]
