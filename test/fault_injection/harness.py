"""Fault injection on a node's logic: a clean recording, a fault spliced in, clean data again.

The processor of a node (``<pkg>.processing``) is driven directly, ROS-free and fast, with the
messages of a shipped bag in recorded order — decoded rosbags messages, or the CDR bytes for a
raw input, exactly as the offline engine and the node deliver them — with one fault class
applied to one input over a window of data time. The run's outputs and the processor's status
over time are returned for the assertions of each node's test: alive, the fault named in the
status, no fault/warning flag raised by it, nothing non-finite published as valid, estimates
back within tolerance of a clean run within the documented recovery time.

A fault is a function of the stream (list of :class:`Sample`) and the window's indices, so it
can corrupt values, stamps, order, sizes or drop samples; :data:`FAULTS` holds the classes of
issue 20 that apply to any numeric input.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
import copy
from dataclasses import dataclass, field
import math
from pathlib import Path
import struct
from typing import Any

import numpy as np

from vehicle_monitor_common.bag_io import iter_raw, typestore
from vehicle_monitor_common.processing import Output, Processor, Status

ROOT = Path(__file__).resolve().parents[2]
BAGS = ROOT / 'bags'


@dataclass
class Sample:
    """One input message of the stream: its topic (relative, as the processor names it), the
    message type, the log time and the message (decoded) — serialised only when delivered to a
    raw input."""

    topic: str
    msgtype: str
    log_ns: int
    message: Any
    raw_override: bytes | None = None   # a payload that is not a valid message (wrong size)


def stamp_of(message: Any) -> int:
    """header.stamp in ns."""
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


def set_stamp(message: Any, stamp_ns: int) -> None:
    """Set header.stamp from ns."""
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)


def recorded_stream(bag: str | Path, topics: dict[str, str], seconds: float | None = None,
                    start_s: float = 0.0) -> list[Sample]:
    """The messages of ``topics`` (absolute bag topic -> the processor's relative name) from
    ``start_s`` for ``seconds`` of the recording, decoded, in log-time order."""
    store = typestore()
    out: list[Sample] = []
    first: int | None = None
    for topic, msgtype, log_ns, data in iter_raw(bag, list(topics)):
        first = log_ns if first is None else first
        offset_s = (log_ns - first) * 1e-9
        if offset_s < start_s:
            continue
        if seconds is not None and offset_s > start_s + seconds:
            break
        out.append(Sample(topics[topic], msgtype, log_ns,
                          store.deserialize_cdr(data, msgtype)))
    return out


def window(stream: Sequence[Sample], topic: str, start_s: float,
           duration_s: float) -> list[int]:
    """Indices of the samples of ``topic`` within [start_s, start_s + duration_s) of data time
    (from the stream's first sample)."""
    t0 = stream[0].log_ns
    return [i for i, s in enumerate(stream) if s.topic == topic
            and start_s <= (s.log_ns - t0) * 1e-9 < start_s + duration_s]


# -- fault classes ----------------------------------------------------------------------------

Fault = Callable[[list[Sample], list[int]], list[Sample]]


def set_values(path: str, value: Callable[[Any, int], Any]) -> Fault:
    """Replace the field at ``path`` (``omega``, ``linear_acceleration.y``) of every sample in
    the window by ``value(old, k)`` (k: index within the window)."""

    def apply(stream: list[Sample], indices: list[int]) -> list[Sample]:
        out = list(stream)
        for k, i in enumerate(indices):
            sample = copy.deepcopy(stream[i])
            owner, name = _resolve(sample.message, path)
            setattr(owner, name, value(getattr(owner, name), k))
            out[i] = sample
        return out

    return apply


def _resolve(message: Any, path: str) -> tuple[Any, str]:
    *parents, name = path.split('.')
    owner = message
    for part in parents:
        owner = getattr(owner, part)
    return owner, name


def _like(old: Any, value: float) -> Any:
    """``value`` in the shape of the field it replaces (scalar or array)."""
    if isinstance(old, np.ndarray):
        return np.full_like(old, value, dtype=float)
    return value


def stuck(path: str) -> Fault:
    """The field holds its value from the first sample of the window (a frozen sensor)."""

    def apply(stream: list[Sample], indices: list[int]) -> list[Sample]:
        if not indices:
            return stream
        owner, name = _resolve(stream[indices[0]].message, path)
        held = copy.deepcopy(getattr(owner, name))
        return set_values(path, lambda old, k: copy.deepcopy(held))(stream, indices)

    return apply


def shift_stamps(offset_s: float) -> Fault:
    """Every stamp (header and log time) in the window moves by ``offset_s``: a far-future
    offset over one sample is a corrupt stamp; over the rest of the run, a time jump."""

    def apply(stream: list[Sample], indices: list[int]) -> list[Sample]:
        out = list(stream)
        for i in indices:
            sample = copy.deepcopy(stream[i])
            set_stamp(sample.message, stamp_of(sample.message) + round(offset_s * 1e9))
            sample.log_ns += round(offset_s * 1e9)
            out[i] = sample
        return out

    return apply


def repeat_stamps(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """Each sample of the window is delivered twice (repeated stamps)."""
    out: list[Sample] = []
    chosen = set(indices)
    for i, sample in enumerate(stream):
        out.append(sample)
        if i in chosen:
            out.append(copy.deepcopy(sample))
    return out


def reverse_order(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """The window's samples arrive in reverse order (out-of-order stamps)."""
    out = list(stream)
    for i, j in zip(indices, reversed(indices), strict=True):
        out[i] = stream[j]
    return out


def loop(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """From the window's start on, the recording is replayed from its beginning (the player's
    ``loop:=true``, or a second replay into running nodes): the stamps jump back by the
    window's start."""
    first = min(indices)
    return stream[:first] + [copy.deepcopy(s) for s in stream[:len(stream) - first]]


def on_wheel(fault: Fault, wheel: int = 0) -> Fault:
    """A value fault of the ``omega`` field on one wheel only (one sensor fails, the others
    carry on)."""

    def apply(stream: list[Sample], indices: list[int]) -> list[Sample]:
        faulted = fault(stream, indices)
        out = list(stream)
        for i in indices:
            sample = copy.deepcopy(stream[i])
            omega = np.array(sample.message.omega, dtype=float)
            omega[wheel] = np.asarray(faulted[i].message.omega, dtype=float)[wheel]
            sample.message.omega = omega
            out[i] = sample
        return out

    return apply


def drop(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """The window's samples never arrive (a gap)."""
    chosen = set(indices)
    return [s for i, s in enumerate(stream) if i not in chosen]


def burst(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """Each sample of the window arrives with 9 more of stamps 1/10 of its interval apart
    (a rate burst: ten times the rate)."""
    out: list[Sample] = []
    chosen = set(indices)
    # the next sample of the same topic: topics may share stamps (the rail IMUs)
    following: dict[int, int] = {}
    last_of: dict[str, int] = {}
    for i, sample in enumerate(stream):
        if sample.topic in last_of:
            following[last_of[sample.topic]] = i
        last_of[sample.topic] = i
    for i, sample in enumerate(stream):
        out.append(sample)
        if i in chosen and i in following:
            step = (stamp_of(stream[following[i]].message) - stamp_of(sample.message)) // 10
            for k in range(1, 10):
                extra = copy.deepcopy(sample)
                set_stamp(extra.message, stamp_of(sample.message) + k * step)
                extra.log_ns += k * step
                out.append(extra)
    return out


def truncated_payload(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """The window's samples arrive as CDR bytes cut short (a wrong array size on the wire; for
    raw inputs) — delivered as bytes whatever the input's kind."""
    store = typestore()
    out = list(stream)
    for i in indices:
        data = bytes(store.serialize_cdr(stream[i].message, stream[i].msgtype))
        out[i] = Sample(stream[i].topic, stream[i].msgtype, stream[i].log_ns,
                        stream[i].message, raw_override=data[:len(data) // 2])
    return out


def values_fault(path: str, value: float) -> Fault:
    """The field reads ``value`` (NaN, inf, negative, absurd, zero) over the window."""
    return set_values(path, lambda old, k: _like(old, value))


def value_faults(path: str, typical: float) -> dict[str, Fault]:
    """The value fault classes of issue 20 for a field whose typical magnitude is ``typical``."""
    return {
        'nan': values_fault(path, math.nan),
        'inf': values_fault(path, math.inf),
        'negative': values_fault(path, -abs(typical)),
        'absurd': values_fault(path, 1e6 * abs(typical)),
        'dead': values_fault(path, 0.0),
        'stuck': stuck(path),
    }


TIMING_FAULTS: dict[str, Fault] = {
    'repeated_stamps': repeat_stamps,
    'out_of_order': reverse_order,
    'gap': drop,
    'rate_burst': burst,
}


# -- running ----------------------------------------------------------------------------------

@dataclass
class Run:
    """What a processor did over a stream: every output, and its status after each input."""

    outputs: list[Output] = field(default_factory=list)
    statuses: list[tuple[int, Status]] = field(default_factory=list)

    def of(self, topic: str) -> list[Output]:
        """The outputs on one topic."""
        return [o for o in self.outputs if o.topic == topic]


def run(processor: Processor, stream: Iterable[Sample], status_every: int = 1) -> Run:
    """Deliver the stream to the processor (bytes to raw inputs), collecting outputs and the
    status (``status(log time)``) after every ``status_every``-th input."""
    store = typestore()
    result = Run()
    for n, sample in enumerate(stream):
        spec = processor.inputs[sample.topic]
        if sample.raw_override is not None:
            payload: Any = sample.raw_override
        elif spec.raw:
            payload = bytes(store.serialize_cdr(sample.message, sample.msgtype))
        else:
            payload = sample.message
        result.outputs.extend(processor.process(sample.topic, payload))
        if n % status_every == 0:
            result.statuses.append((sample.log_ns, processor.status(sample.log_ns)))
    return result


def learned_calibration(make_processor: Callable[[dict[str, Any], str], Any],
                        values: dict[str, Any], fqn: str, stream: Iterable[Sample]
                        ) -> dict[str, Any]:
    """The calibration a calibrating processor learns on a clean stream (calibrate_on_start)."""
    processor = make_processor({**values, 'calibrate_on_start': True}, fqn)
    run(processor, stream, status_every=10**9)
    state = processor.calibration_state()
    assert state is not None, processor.calibration.detail
    return dict(state)


def restarted(make_processor: Callable[[dict[str, Any], str], Any], values: dict[str, Any],
              fqn: str, calibration: dict[str, Any]) -> Any:
    """A processor with a stored calibration loaded, as a node after a restart."""
    processor = make_processor(values, fqn)
    processor.load_calibration_state(calibration)
    return processor


def non_finite_valid(outputs: Iterable[Output], value: str, valid: str) -> list[Output]:
    """Outputs publishing a non-finite ``value`` element where ``valid`` says it is valid."""
    bad = []
    for o in outputs:
        v = np.asarray(o.fields[value], dtype=float)
        ok = np.asarray(o.fields[valid], dtype=bool)
        if np.any(ok & ~np.isfinite(v)):
            bad.append(o)
    return bad


def wheel_speeds_raw(stamp_ns: int, omega: Sequence[float], frame_id: str = '') -> bytes:
    """A little-endian classic-CDR WheelSpeeds payload (for hand-made raw inputs)."""
    name = frame_id.encode() + b'\0'
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    head = b'\x00\x01\x00\x00' + struct.pack('<iII', sec, nanosec,
                                             len(name)) + name
    head += b'\0' * (-(len(head) - 4) % 8)
    return head + struct.pack('<4d', *omega)
