"""Column-wise time series of one topic: how simulators and offline tools hand data to bags.

A simulator produces arrays, not message objects. ``TopicSeries`` holds one topic's samples as
columns keyed by the message field path, so a 60 s, 1 kHz run is a handful of numpy arrays
until the bag writer turns it into messages.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class TopicSeries:
    """Samples of one topic.

    Attributes:
        msgtype: ROS message type name, e.g. ``'vehicle_monitor_msgs/msg/WheelSpeeds'``.
        stamps_ns: (N,) int64 sample times in nanoseconds; written as the bag log time and,
            when the message has a ``header``, as ``header.stamp``.
        fields: dotted field path -> array with first dimension N, e.g.
            ``{'omega': (N, 4)}`` or ``{'linear_acceleration.y': (N,)}``. Fields not given keep
            their default (zero, empty, or for ``sensor_msgs/Imu`` covariances zero).
            ``string[]`` fields take an (N,) object array of lists of str.
        frame_id: ``header.frame_id`` of every sample.
    """

    msgtype: str
    stamps_ns: np.ndarray
    fields: Mapping[str, np.ndarray] = field(default_factory=dict)
    frame_id: str = ''

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_ns)
        if stamps.ndim != 1 or not np.issubdtype(stamps.dtype, np.integer):
            raise ValueError(f'{self.msgtype}: stamps_ns must be a 1-D integer array')
        if stamps.size > 1 and np.any(np.diff(stamps) < 0):
            raise ValueError(f'{self.msgtype}: stamps_ns must be non-decreasing')
        for name, values in self.fields.items():
            if len(values) != stamps.size:
                raise ValueError(
                    f'{self.msgtype}: field {name!r} has {len(values)} samples, '
                    f'stamps have {stamps.size}')

    def __len__(self) -> int:
        return int(np.asarray(self.stamps_ns).size)


def stamps_from_seconds(t: np.ndarray) -> np.ndarray:
    """Seconds (float) -> int64 nanoseconds, rounded to the nearest nanosecond."""
    return np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)
