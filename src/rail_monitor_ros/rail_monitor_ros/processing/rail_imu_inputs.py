"""What both rail processors do with their inputs before their method sees a sample: the
bogie/body IMU pairing and saturation limits (node parameters of the same meaning in both), the
input-rate meters, the stamp check of every input, whose confirmed time jump restarts the
processor (``_restart``) and whose corrupt stamps it counts (``_reject_stamp``), the train's
speed from ``rail/speed`` (:class:`SpeedInput`), and what their statuses report alike: how long
the input has been silent and the rejections since the previous status.

Streams held in data time (:class:`HeldStream`): the value for a sample is the latest message
not newer than its stamp, and a sample waits until the stream has reached its stamp or fallen
silent, so a live node, whose inputs come from different publishers, and the offline engine
see the same values.

An IMU pair's measurement is (bogie lateral acceleration, bogie yaw rate, body lateral
acceleration), as :class:`vehicle_monitor_common.imu_pairing.ImuPairer` pairs them in both.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any, Generic, TypeVar

import numpy as np

from rail_monitor_ros.core.rail_model import MAX_SPEED_MPS
from vehicle_monitor_common.imu_pairing import ImuPairer
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.processing import Input, ProcessorParams, header_stamp_ns


@dataclass(frozen=True)
class RailImuNodeParams(ProcessorParams):
    """The node parameters both rail processors have for their IMU inputs."""

    pair_tolerance_s: float = param(1e-3, 'largest stamp difference of a bogie/body IMU pair '
                                    '(and of the parts of one sample), s', low=0.0, high=1.0)
    pair_timeout_s: float = param(0.1, 'an IMU sample still unpaired when the newest stamp is '
                                  'this much later is given up, s', low=1e-3, high=10.0)
    accel_limit_mps2: float = param(50.0, 'an IMU acceleration at or beyond this is saturated, '
                                    'm/s^2', low=0.1, high=1e4)
    gyro_limit_rad_s: float = param(5.0, 'an IMU yaw rate at or beyond this is saturated, rad/s',
                                    low=0.01, high=1e3)
    use_speed_input: bool = param(True, 'follow rail/speed (the train\'s forward speed) as the '
                                  'model\'s speed when it is published; else vehicle.speed',
                                  read_only=True)
    speed_max_age_s: float = param(0.5, 'the speed is stale when its last stamp is this much '
                                   'older than the sample (the model keeps the last speed), s',
                                   low=0.001, high=60.0)
    min_speed_mps: float = param(5.0, 'below this speed (from rail/speed) nothing is estimated: '
                                 'the estimates are held, m/s', low=0.1, high=200.0)
    speed_scale: float = param(1.0, 'the model\'s speed is rail/speed times this: the '
                               'tachometer\'s scale correction (its wheel\'s true diameter over '
                               'the one it assumes: a worn wheel reads high)', low=0.5, high=1.5)

    def imu_saturated(self, pair: np.ndarray) -> bool:
        """Whether an IMU pair (bogie ay, bogie yaw rate, body ay) reaches a sensor's limit."""
        return bool(abs(pair[0]) >= self.accel_limit_mps2
                    or abs(pair[2]) >= self.accel_limit_mps2
                    or abs(pair[1]) >= self.gyro_limit_rad_s)


SPEED = 'rail/speed'
SPEED_TYPE = 'geometry_msgs/msg/TwistStamped'


class HeldStream:
    """A stream sampled and held at another stream's stamps, decided in data time: the value
    for a sample is the latest not newer than its stamp (plus the tolerance), and a sample is
    settled once the stream has delivered a stamp at or after it, or has fallen silent (its
    newest stamp a wait horizon behind the newest sample; a stream not heard yet, the wait
    horizon after the first sample that asked for it)."""

    def __init__(self) -> None:
        self.samples: deque[tuple[int, Any]] = deque()
        self.latest: int | None = None      # newest stamp seen (valid or not)
        self._first_asked: int | None = None  # the first sample's stamp while nothing was seen

    def seen(self, stamp_ns: int) -> None:
        self.latest = stamp_ns

    def add(self, stamp_ns: int, value: Any) -> None:
        self.samples.append((stamp_ns, value))

    def settled(self, stamp_ns: int, newest_ns: int, tolerance_ns: int, wait_ns: int) -> bool:
        """Whether the value for ``stamp_ns`` is known: the stream delivered that stamp or a
        later one, or it is silent (``wait_ns`` behind the newest sample ``newest_ns``).

        A stream not heard yet is waited for as one that fell silent at the first sample: in
        a live graph another node's first outputs come after the IMU samples they answer (the
        offline engine delivers them in log order), so treating it as absent at once made the
        live suspension monitor start without the creep factor the engine had
        (rail_creep_steps: its first 100 pairs, while the full-car creep model was confident
        after 70).
        """
        if self.latest is None:
            if self._first_asked is None:
                self._first_asked = stamp_ns
            return self._first_asked < newest_ns - wait_ns
        return self.latest >= stamp_ns - tolerance_ns or self.latest < newest_ns - wait_ns

    def at(self, stamp_ns: int, tolerance_ns: int) -> tuple[int, Any] | None:
        """The latest sample not newer than ``stamp_ns + tolerance_ns`` (older ones are
        forgotten: the samples come in stamp order)."""
        while len(self.samples) > 1 and self.samples[1][0] <= stamp_ns + tolerance_ns:
            self.samples.popleft()
        if self.samples and self.samples[0][0] <= stamp_ns + tolerance_ns:
            return self.samples[0]
        return None

    def clear(self) -> None:
        self.samples.clear()
        self.latest = None
        self._first_asked = None


class SpeedInput:
    """The train's forward speed from ``rail/speed`` (geometry_msgs/TwistStamped: twist.linear.x,
    m/s; a tachometer or odometry), held at the samples' stamps.

    Why a topic: the models' creep forces scale with 1 / v, the track's bandwidth with v and
    its delays with 1 / v, so a train that accelerates or brakes needs its speed per sample (a
    speed 0.2 % wrong reads the creep factor 1.6 % wrong: docs/methods/creep_estimator.md);
    the ``vehicle.speed`` parameter is for a constant speed.

    A tachometer's scale error (a wheel worn smaller than the odometer assumes reads high)
    moves the creep factor by several times as much (up to ten times at 20 m/s:
    docs/methods/creep_estimator.md, "The tachometer's scale"), so the published speed is
    multiplied by ``speed_scale``.

    Per sample (:meth:`at`): a fresh speed (scaled) is the model's; a stale one (older than
    ``speed_max_age_s``) leaves the model at the last speed (the status says so); a speed
    below ``min_speed_mps`` is an input fault, the estimates are held (standing at a station,
    the models and their excitation mean nothing). A non-finite or negative speed, or one
    above ``MAX_SPEED_MPS``, is rejected and counted (``speed_invalid``). Never heard, or not
    subscribed (``enabled`` false: ``use_speed_input``): ``vehicle.speed`` is used as before.
    """

    def __init__(self, enabled: bool) -> None:
        self.held = HeldStream()
        self.invalid = 0
        self.stale = False
        self._idle = 'not received: vehicle.speed used' if enabled else 'disabled'
        self.state = self._idle

    def add(self, stamp_ns: int, message: Any) -> None:
        """A speed message (its stamp already checked)."""
        self.held.seen(stamp_ns)
        speed = float(message.twist.linear.x)
        if math.isfinite(speed) and 0.0 <= speed <= MAX_SPEED_MPS:
            self.held.add(stamp_ns, speed)
        else:
            self.invalid += 1

    def at(self, stamp_ns: int, node_params: RailImuNodeParams, model_speed: float,
           ) -> tuple[float | None, str]:
        """For the sample at ``stamp_ns``: (the speed to give the model, or None to keep
        ``model_speed``; the input fault, '' or 'below_min_speed')."""
        n = node_params
        held = self.held.at(stamp_ns, round(n.pair_tolerance_s * 1e9))
        if held is None:
            self.stale = False
            if self.held.latest is not None:
                self.state = f'none yet for this sample: model keeps {model_speed:.2f} m/s'
            return None, ''
        age_s = (stamp_ns - held[0]) * 1e-9
        self.stale = age_s > n.speed_max_age_s
        if self.stale:
            self.state = f'stale ({age_s:.2f} s): model keeps {model_speed:.2f} m/s'
            return None, ''
        speed = held[1] * n.speed_scale
        if speed < n.min_speed_mps:
            self.state = f'{speed:.2f} m/s, below min_speed_mps: estimates held'
            return None, 'below_min_speed'
        # The scale in the status, so a diagnostics reader sees which correction is applied.
        self.state = ('following' if n.speed_scale == 1.0
                      else f'following x {n.speed_scale:g} (speed_scale)')
        return speed, ''

    def clear(self) -> None:
        self.held.clear()
        self.stale = False
        self.state = self._idle


P = TypeVar('P', bound=RailImuNodeParams)


class RailImuInputs(Generic[P]):
    """The input side shared by the rail processors (see the module docstring).

    Args:
        node_params: the node's parameters.
        inputs: the processor's inputs by topic.
    """

    def __init__(self, node_params: P, inputs: Mapping[str, Input]) -> None:
        self.node_params = node_params
        self.inputs = inputs
        self._pairer = ImuPairer(node_params.pair_tolerance_s, node_params.pair_timeout_s)
        self._stamp_checks = self._new_stamp_checks()
        self._rates = {topic: RateMeter() for topic in inputs}
        # Silence: the count of handled samples and the status time it last changed.
        self._progress: tuple[int, int | None] = (0, None)
        self._reported: dict[str, int] = {}     # rejections already in a status

    def _new_stamp_checks(self) -> dict[str, StampCheck]:
        # Gaps are the core's (max_gap_s infinite here); jumps are everybody's.
        return {topic: StampCheck(max_gap_s=math.inf,
                                  jump_horizon_s=self.node_params.jump_horizon_s)
                for topic in self.inputs}

    def update_node_params(self, node_params: P) -> None:
        """The node's runtime-settable parameters changed."""
        self.node_params = node_params
        self._pairer.tolerance_s = node_params.pair_tolerance_s
        self._pairer.timeout_s = node_params.pair_timeout_s

    def _received(self, topic: str, message: Any) -> int | None:
        """One input message counted at its topic's rate: its stamp, or None when the stamp
        is refused (repeated, out of order, in the future)."""
        self._rates[topic].tick()
        stamp = header_stamp_ns(message)
        check = self._stamp_checks[topic]
        verdict = check.check(stamp)
        if verdict == 'jump':
            self._restart(stamp, f'time jump of {check.last_jump_s:+.3f} s on {topic}')
            self._stamp_checks[topic].check(stamp)
        elif verdict in ('repeated', 'out_of_order', 'future_stamp'):
            self._reject_stamp(topic, verdict)
            return None
        return stamp

    def _input_rates(self, now_ns: int) -> dict[str, float]:
        """Each input's rate, Hz, by topic."""
        return {topic: meter.read(now_ns) for topic, meter in self._rates.items()}

    def _silent_s(self, handled: int, now_ns: int) -> float:
        """How long (status time, s) the count of handled samples has not changed."""
        count, since = self._progress
        if handled != count or since is None:
            self._progress = (handled, now_ns)
            return 0.0
        return (now_ns - since) * 1e-9

    def _new_rejections(self, counts: Mapping[str, int], sample_rate_hz: float) -> str:
        """The rejections since the previous status, by reason (a warning that clears), from
        the counts so far."""
        new = {k: v - self._reported.get(k, 0) for k, v in counts.items()
               if v > self._reported.get(k, 0)}
        self._reported = dict(counts)
        rate = f' (faster than {sample_rate_hz:g} Hz)'
        return ', '.join(f'{k}{rate if k == "rate_burst" else ""} {v}'
                         for k, v in sorted(new.items()))

    def _restart(self, stamp: int, why: str) -> None:
        """Data time jumped: the processor starts again (calling ``_new_stamp_checks``)."""
        raise NotImplementedError

    def _reject_stamp(self, topic: str, verdict: str) -> None:
        """Count an input refused for its stamp (``verdict``: StampCheck's reason)."""
        raise NotImplementedError
