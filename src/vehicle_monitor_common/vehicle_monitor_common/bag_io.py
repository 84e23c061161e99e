"""rosbag2 reading and writing on the vehicle_monitor_msgs contract: the one module that does it.

The typestore is ROS 2 Jazzy's with every ``msg_defs/msg/*.msg`` file registered from the files
themselves, so the bags, rclpy and the offline tools agree on one definition. Bags are written
with MCAP storage (sqlite3 on request) whose chunks are zstd-compressed inside the file, as
``ros2 bag record -s mcap`` with chunk compression writes them: a plain ``.mcap`` file carrying
its message definitions, so any reader (rosbags, ``ros2 bag``, the ``mcap`` tools and library,
Foxglove) opens and decodes it without this package. Bags written earlier as rosbag2
file-compressed ``.mcap.zstd`` are still read.

Writes are atomic: a bag is written under a temporary name beside its destination and moved into
place only when complete, so a failed run never leaves a half-written bag behind.
"""

from __future__ import annotations

from collections.abc import Generator, Iterable, Iterator, Mapping
from contextlib import closing
from dataclasses import dataclass
import functools
import heapq
import os
from pathlib import Path
import shutil
import tempfile
from typing import Any, cast

import numpy as np
from rosbags.interfaces import Connection, Nodetype
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from vehicle_monitor_common.series import TopicSeries

MSG_PACKAGE = 'vehicle_monitor_msgs'

# numpy dtypes of the ROS primitive types, for arrays built from columns.
_NUMPY_DTYPES = {
    'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'int8': np.int8, 'uint8': np.uint8,
    'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32, 'uint32': np.uint32,
    'int64': np.int64, 'uint64': np.uint64, 'float32': np.float32, 'float64': np.float64,
}


class BagError(ValueError):
    """A bag cannot be used; the message is one line naming the problem."""


def msg_definition_dir() -> Path:
    """Directory holding the ``vehicle_monitor_msgs`` ``.msg`` files.

    The installed package's share directory when the workspace is built (on a ROS install that
    is all there is), else the source tree's ``msg_defs/msg`` (offline tools before a build).
    """
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            share = Path(get_package_share_directory(MSG_PACKAGE)) / 'msg'
            if share.is_dir():
                return share
        except (PackageNotFoundError, ValueError, OSError):
            pass  # not built/installed, or AMENT_PREFIX_PATH unset: use the source tree
    except ImportError:
        pass
    source = Path(__file__).resolve().parents[3] / 'msg_defs' / 'msg'
    if source.is_dir():
        return source
    raise BagError(f'cannot find the {MSG_PACKAGE} .msg files (build the workspace first)')


@functools.cache
def typestore() -> Typestore:
    """ROS 2 Jazzy typestore with every vehicle_monitor_msgs message registered (cached)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for path in sorted(msg_definition_dir().glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'{MSG_PACKAGE}/msg/{path.stem}'))
    store.register(types)
    return store


# ---------------------------------------------------------------------------------------------
# Columns <-> messages


def _default_value(store: Typestore, node: tuple[Any, Any]) -> Any:
    nodetype, detail = node
    if nodetype == Nodetype.BASE:
        name = detail[0]
        return '' if name == 'string' else _NUMPY_DTYPES[name](0).item()
    if nodetype == Nodetype.NAME:
        return default_message(detail, store)
    inner, length = detail
    if nodetype == Nodetype.ARRAY:
        if inner[0] == Nodetype.BASE and inner[1][0] in _NUMPY_DTYPES:
            return np.zeros(length, dtype=_NUMPY_DTYPES[inner[1][0]])
        return [_default_value(store, inner) for _ in range(length)]
    if inner[0] == Nodetype.BASE and inner[1][0] in _NUMPY_DTYPES:
        return np.zeros(0, dtype=_NUMPY_DTYPES[inner[1][0]])
    return []


def default_message(msgtype: str, store: Typestore | None = None) -> Any:
    """A rosbags message of ``msgtype`` with every field at its default (zeros, empty)."""
    store = store or typestore()
    cls = store.types[msgtype]
    _, fields = store.fielddefs[msgtype]
    return cls(**{name: _default_value(store, node) for name, node in fields})


def build_message(store: Typestore, msgtype: str, values: Mapping[str, Any]) -> Any:
    """A rosbags message whose dotted-path fields (``header.stamp.sec``) are taken from
    ``values`` (numbers, sequences, numpy arrays), the rest defaulted.

    Raises:
        ValueError: a field the message does not have, or a value of the wrong shape.
    """
    nested: dict[str, Any] = {}
    for path, value in values.items():
        *heads, leaf = path.split('.')
        target = nested
        for head in heads:
            target = target.setdefault(head, {})
            if not isinstance(target, dict):
                raise ValueError(f'{msgtype}: {path!r} sets a sub-field of a value given whole')
        target[leaf] = value
    return message_from_fields(store, msgtype, nested)


def message_from_fields(store: Typestore, msgtype: str, fields: Mapping[str, Any]) -> Any:
    """A rosbags message whose fields are taken from ``fields``, nested as the message is
    (``{'header': {'stamp': {'sec': 1}}}``; numbers, sequences, numpy arrays), the rest
    defaulted. (The offline engine builds every output this way, without dotted paths.)

    Raises:
        ValueError: a field the message does not have, or a value of the wrong shape, type or
            range, naming the field.
    """
    cls, plan = _build_plan(store, msgtype)
    kwargs: dict[str, Any] = {}
    given = 0
    for name, node, convert in plan:
        if name not in fields:
            kwargs[name] = _default_value(store, node)
            continue
        given += 1
        value = fields[name]
        if isinstance(value, Mapping):
            if node[0] != Nodetype.NAME:
                raise ValueError(f'{msgtype}.{name} is not a message, cannot set sub-fields')
            kwargs[name] = message_from_fields(store, node[1], value)
            continue
        try:
            kwargs[name] = convert(value)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ValueError(f'{msgtype}.{name}: {exc}') from None
    if given < len(fields):
        unknown = sorted(set(fields) - {name for name, _, _ in plan})
        raise ValueError(f'{msgtype} has no field {unknown[0]!r}')
    return cls(**kwargs)


# (id of the typestore, message type) -> the typestore itself (kept alive, so that its id is
# never another store's), the message class and, per field, its name, type node and the
# conversion of a given value, decided once per field: the engine builds every output message
# through here, tens of thousands per recording.
_BUILD_PLANS: dict[tuple[int, str], tuple[Typestore, Any, list[tuple[str, Any, Any]]]] = {}


def _build_plan(store: Typestore, msgtype: str,
                ) -> tuple[Any, list[tuple[str, Any, Any]]]:
    key = (id(store), msgtype)
    cached = _BUILD_PLANS.get(key)
    if cached is None:
        _, definitions = store.fielddefs[msgtype]
        cached = (store, store.types[msgtype],
                  [(name, node, _converter(store, node)) for name, node in definitions])
        _BUILD_PLANS[key] = cached
    return cached[1], cached[2]


def _converter(store: Typestore, node: tuple[Any, Any]) -> Any:
    """The conversion of a given value (a number, a sequence, a numpy array) to the field's
    rosbags representation, decided once per field. Raises ValueError (or TypeError) for a
    value the field cannot take."""
    nodetype, detail = node
    if nodetype == Nodetype.BASE:
        name = detail[0]
        if name == 'string':
            return str
        if name == 'float64':
            return float      # np.float64(value).item() for every real value, cheaper
        if name == 'bool':
            return bool
        if name in _NUMPY_DTYPES:
            dtype = _NUMPY_DTYPES[name]
            if not np.issubdtype(dtype, np.integer):
                return lambda value: dtype(value).item()
            low, high = int(np.iinfo(dtype).min), int(np.iinfo(dtype).max)

            def integer(value: Any) -> Any:
                # an int in range is its own value; numpy refuses one out of range
                if type(value) is int and low <= value <= high:
                    return value
                return dtype(value).item()

            return integer
    elif nodetype in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        inner, length = detail
        if inner[0] == Nodetype.BASE and inner[1][0] in _NUMPY_DTYPES:
            item_dtype = _NUMPY_DTYPES[inner[1][0]]
            shape = (length,) if nodetype == Nodetype.ARRAY else None

            def array(value: Any) -> np.ndarray:
                converted: np.ndarray = np.ascontiguousarray(value, dtype=item_dtype)
                if shape is not None and converted.shape != shape:
                    raise ValueError(f'expected {shape[0]} values, got shape {converted.shape}')
                return converted

            return array
        convert_item = _converter(store, inner)
        return lambda value: [convert_item(item) for item in value]

    def refuse(value: Any) -> Any:
        raise ValueError(f'cannot set a {detail} field from a column')

    return refuse


def series_messages(series: TopicSeries, store: Typestore | None = None) -> Iterator[Any]:
    """The rosbags messages of a column-wise series, one per stamp."""
    store = store or typestore()
    if series.msgtype not in store.types:
        raise BagError(f'unknown message type {series.msgtype!r}')
    _, fields = store.fielddefs[series.msgtype]
    has_header = any(name == 'header' for name, _ in fields)
    columns = {name: np.asarray(values) if not isinstance(values, list) else values
               for name, values in series.fields.items()}
    for i, stamp in enumerate(np.asarray(series.stamps_ns, dtype=np.int64)):
        values = {name: column[i] for name, column in columns.items()}
        if has_header:
            values['header.stamp.sec'] = int(stamp // 1_000_000_000)
            values['header.stamp.nanosec'] = int(stamp % 1_000_000_000)
            values['header.frame_id'] = series.frame_id
        yield build_message(store, series.msgtype, values)


def _flatten(store: Typestore, msgtype: str, msg: Any, prefix: str, out: dict[str, Any]) -> None:
    _, fields = store.fielddefs[msgtype]
    for name, node in fields:
        value = getattr(msg, name)
        if node[0] == Nodetype.NAME:
            _flatten(store, node[1], value, f'{prefix}{name}.', out)
        else:
            out[f'{prefix}{name}'] = value


def messages_to_series(msgtype: str, stamps_ns: list[int], messages: list[Any],
                       store: Typestore | None = None) -> TopicSeries:
    """Column-wise series from messages: every leaf field under its dotted path.

    Numeric fields and fixed arrays become numeric arrays ((N,) or (N, k)); strings and
    variable-length sequences become (N,) object arrays.
    """
    store = store or typestore()
    rows: list[dict[str, Any]] = []
    for msg in messages:
        row: dict[str, Any] = {}
        _flatten(store, msgtype, msg, '', row)
        rows.append(row)
    fields: dict[str, np.ndarray] = {}
    frame_id = ''
    if rows:
        frame_id = str(rows[0].get('header.frame_id', ''))
        for name in rows[0]:
            column = [row[name] for row in rows]
            if name.startswith('header.'):
                continue
            first = column[0]
            is_fixed = isinstance(first, np.ndarray) and all(
                isinstance(v, np.ndarray) and v.shape == first.shape for v in column)
            if isinstance(first, (bool, int, float)) or is_fixed:
                fields[name] = np.array(column)
            else:
                fields[name] = np.empty(len(column), dtype=object)
                fields[name][:] = [list(v) if isinstance(v, (list, np.ndarray)) else v
                                   for v in column]
    return TopicSeries(msgtype, np.asarray(stamps_ns, dtype=np.int64), fields, frame_id)


# ---------------------------------------------------------------------------------------------
# Writing


class BagWriter:
    """Writes a rosbag2 (MCAP by default) atomically, with definitions embedded.

    Use as a context manager; the bag appears at ``path`` only when the ``with`` block exits
    without an exception. An existing bag at ``path`` is replaced only if ``overwrite``.
    ``compress`` (default: on for MCAP, off for sqlite3) zstd-compresses the MCAP chunks (about
    1 MiB of messages each) inside a plain ``.mcap`` file, which every MCAP reader opens
    directly; sqlite3 storage has no compression of its own.
    """

    def __init__(self, path: str | os.PathLike[str], *, storage: str = 'mcap',
                 overwrite: bool = False, compress: bool | None = None) -> None:
        self.path = Path(path)
        if storage not in ('mcap', 'sqlite3'):
            raise BagError(f'storage must be mcap or sqlite3, got {storage!r}')
        if compress and storage != 'mcap':
            raise BagError(f'{storage} storage cannot be compressed (only mcap chunks can)')
        if self.path.exists() and not overwrite:
            raise BagError(f'{self.path} exists (pass overwrite=True to replace it)')
        self._storage = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._compress = storage == 'mcap' if compress is None else compress
        self._store = typestore()
        self._connections: dict[str, Connection] = {}
        self._tmpdir: Path | None = None
        self._writer: Writer | None = None

    def __enter__(self) -> BagWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmpdir = Path(tempfile.mkdtemp(prefix=f'.{self.path.name}.', dir=self.path.parent))
        # The inner bag keeps the final name, so its storage file is named after the bag.
        self._writer = Writer(self._tmpdir / self.path.name, version=9,
                              storage_plugin=self._storage)
        if self._compress:
            # STORAGE: the MCAP storage plugin compresses each chunk (zstd), the file stays .mcap
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()
        return self

    def write(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        """Serialize and write one message (a rosbags message of ``msgtype``)."""
        self.write_raw(topic, msgtype, stamp_ns, self._store.serialize_cdr(msg, msgtype))

    def write_raw(self, topic: str, msgtype: str, stamp_ns: int,
                  data: bytes | memoryview) -> None:
        """Write one already CDR-serialized message."""
        assert self._writer is not None, 'BagWriter used outside its with block'
        connection = self._connections.get(topic)
        if connection is None:
            if msgtype not in self._store.types:
                raise BagError(f'unknown message type {msgtype!r} for topic {topic}')
            connection = self._writer.add_connection(topic, msgtype, typestore=self._store)
            self._connections[topic] = connection
        elif connection.msgtype != msgtype:
            raise BagError(f'topic {topic} already has type {connection.msgtype}, not {msgtype}')
        self._writer.write(connection, int(stamp_ns), data)

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        assert self._writer is not None and self._tmpdir is not None
        try:
            self._writer.close()
            if exc_type is None:
                if self.path.exists():
                    shutil.rmtree(self.path)
                os.replace(self._tmpdir / self.path.name, self.path)
        finally:
            shutil.rmtree(self._tmpdir, ignore_errors=True)


def write_bag(path: str | os.PathLike[str], series: Mapping[str, TopicSeries], *,
              storage: str = 'mcap', overwrite: bool = False, compress: bool | None = None,
              ) -> Path:
    """Write topics given as column-wise series to a bag, merged in time order.

    Ties in time keep the caller's topic order, so a replay publishes e.g. the inputs of an
    instant before its ground truth. ``storage``, ``overwrite`` and ``compress`` are
    ``BagWriter``'s.
    """
    store = typestore()

    def stream(order: int, topic: str, topic_series: TopicSeries,
               ) -> Iterator[tuple[int, int, str, TopicSeries, Any]]:
        messages = series_messages(topic_series, store)
        for stamp, msg in zip(topic_series.stamps_ns, messages, strict=True):
            yield int(stamp), order, topic, topic_series, msg

    streams = [stream(order, topic, s) for order, (topic, s) in enumerate(series.items())]
    with BagWriter(path, storage=storage, overwrite=overwrite, compress=compress) as writer:
        for stamp, _, topic, topic_series, msg in heapq.merge(
                *streams, key=lambda item: (item[0], item[1])):
            writer.write(topic, topic_series.msgtype, stamp, msg)
    return Path(path)


# ---------------------------------------------------------------------------------------------
# Reading


@dataclass(frozen=True)
class TopicInfo:
    """What a bag holds on one topic."""

    name: str
    msgtype: str
    count: int


def open_reader(path: str | os.PathLike[str]) -> Reader:
    """An opened rosbags Reader, or a one-line BagError naming why the path is not a bag."""
    bag = Path(path)
    if not bag.exists():
        raise BagError(f'no such bag: {bag}')
    if bag.is_file():
        # A bare storage file: rosbag2 bags are directories holding metadata.yaml.
        if bag.suffix in ('.mcap', '.db3') and (bag.parent / 'metadata.yaml').is_file():
            bag = bag.parent
        else:
            raise BagError(f'not a rosbag2 bag (expected a directory with metadata.yaml): {bag}')
    if not (bag / 'metadata.yaml').is_file():
        raise BagError(f'not a rosbag2 bag (no metadata.yaml): {bag}')
    reader = Reader(bag)
    try:
        reader.open()
    except Exception as exc:  # rosbags raises several types for corrupt storage
        raise BagError(f'cannot read bag {bag}: {str(exc).splitlines()[0]}') from None
    _register_bag_types(reader)
    return reader


def _register_bag_types(reader: Reader) -> None:
    """Register message types the bag defines but the typestore lacks (foreign bags)."""
    store = typestore()
    for connection in reader.connections:
        if connection.msgtype in store.types or connection.msgdef is None:
            continue
        if connection.msgdef.format != 'msg' or not connection.msgdef.data:
            continue
        try:
            store.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
        except Exception:  # an unparsable definition: reported when the type is used
            continue


def bag_topics(path: str | os.PathLike[str]) -> dict[str, TopicInfo]:
    """Topics of a bag with their types and message counts."""
    reader = open_reader(path)
    try:
        info: dict[str, TopicInfo] = {}
        for connection in reader.connections:
            known = info.get(connection.topic)
            count = connection.msgcount + (known.count if known else 0)
            info[connection.topic] = TopicInfo(connection.topic, connection.msgtype, count)
        return info
    finally:
        reader.close()


def iter_raw(path: str | os.PathLike[str], topics: Iterable[str] | None = None,
             start_ns: int | None = None) -> Generator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log time ns, CDR bytes) in log-time order, optionally filtered."""
    reader = open_reader(path)
    try:
        wanted = None if topics is None else set(topics)
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if wanted is not None:
            missing = sorted(wanted - {c.topic for c in reader.connections})
            if missing:
                raise BagError(f'topic {missing[0]} is not in bag {path}')
        try:
            for connection, stamp, data in reader.messages(connections, start=start_ns):
                yield connection.topic, connection.msgtype, stamp, data
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f'cannot read bag {path}: {str(exc).splitlines()[0]}') from None
    finally:
        reader.close()


def read_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None,
                  ) -> Iterator[tuple[str, str, int, Any]]:
    """(topic, msgtype, log time ns, deserialized rosbags message) in log-time order."""
    store = typestore()
    for topic, msgtype, stamp, data in iter_raw(path, topics):
        if msgtype not in store.types:
            raise BagError(f'unknown message type {msgtype!r} on {topic} in {path}')
        yield topic, msgtype, stamp, store.deserialize_cdr(data, msgtype)


def read_series(path: str | os.PathLike[str],
                topics: Iterable[str] | None = None) -> dict[str, TopicSeries]:
    """Every (selected) topic of a bag as a column-wise series (the inverse of write_bag)."""
    collected: dict[str, tuple[str, list[int], list[Any]]] = {}
    for topic, msgtype, stamp, msg in read_messages(path, topics):
        entry = collected.setdefault(topic, (msgtype, [], []))
        entry[1].append(stamp)
        entry[2].append(msg)
    return {topic: messages_to_series(msgtype, stamps, msgs)
            for topic, (msgtype, stamps, msgs) in collected.items()}


# ---------------------------------------------------------------------------------------------
# Comparing

#: Default tolerance of ``compare_bags``, relative to the largest magnitude a field takes over
#: its topic in the expected bag. Far above the rounding differences of the simulators between
#: BLAS builds (~2e-13 of the signal) and far below any change of content (a 1e-6 change fails).
BAG_RTOL = 1e-9


def _leaves(store: Typestore, msgtype: str, msg: Any, prefix: str,
            out: dict[str, Any]) -> None:
    """Every leaf field of a message under its dotted path; sequences of messages indexed."""
    _, fields = store.fielddefs[msgtype]
    for name, node in fields:
        value = getattr(msg, name)
        nodetype, detail = node[0], cast(Any, node[1])
        if nodetype == Nodetype.NAME:
            _leaves(store, detail, value, f'{prefix}{name}.', out)
        elif (nodetype in (Nodetype.ARRAY, Nodetype.SEQUENCE)
              and detail[0][0] == Nodetype.NAME):
            out[f'{prefix}{name}.len'] = len(value)
            for i, item in enumerate(value):
                _leaves(store, detail[0][1], item, f'{prefix}{name}[{i}].', out)
        else:
            out[f'{prefix}{name}'] = value


def _column_difference(topic: str, field: str, want: list[Any], got: list[Any],
                       rtol: float) -> str | None:
    """Why two columns of one field differ (None if they agree); floats to ``rtol`` of peak."""
    shapes = [np.shape(v) for v in want]
    for i, (shape, value) in enumerate(zip(shapes, got, strict=True)):
        if np.shape(value) != shape:
            return f'{topic} {field}: message {i} has shape {np.shape(value)}, expected {shape}'
    flat_want = [np.ravel(np.asarray(v)) for v in want]
    flat_got = [np.ravel(np.asarray(v)) for v in got]
    index = np.repeat(np.arange(len(want)), [v.size for v in flat_want])
    a = np.concatenate(flat_want) if flat_want else np.zeros(0)
    b = np.concatenate(flat_got) if flat_got else np.zeros(0)
    if a.dtype.kind == 'f' or b.dtype.kind == 'f':
        if a.dtype.kind not in 'fiu' or b.dtype.kind not in 'fiu':
            return f'{topic} {field}: {b.dtype} values where {a.dtype} expected'
        a, b = a.astype(np.float64), b.astype(np.float64)
        finite = np.isfinite(a)
        peak = float(np.max(np.abs(a[finite]), initial=0.0))
        tolerance = rtol * peak
        with np.errstate(invalid='ignore'):
            bad = ~((np.abs(a - b) <= tolerance) | (a == b) | (np.isnan(a) & np.isnan(b)))
        if bad.any():
            worst = int(np.argmax(np.where(bad, np.nan_to_num(np.abs(a - b), nan=np.inf), -1)))
            return (f'{topic} {field}: message {index[worst]} has {float(b[worst])!r}, '
                    f'expected {float(a[worst])!r} ({int(bad.sum())} values differ by more than '
                    f'{rtol:g} of the peak {peak:.6g})')
        return None
    if a.dtype.kind != b.dtype.kind and not (a.dtype.kind in 'iub' and b.dtype.kind in 'iub'):
        return f'{topic} {field}: {b.dtype} values where {a.dtype} expected'
    differs = np.flatnonzero(a != b)  # same shapes: checked message by message above
    if differs.size:
        first = int(differs[0])
        return (f'{topic} {field}: message {index[first]} has {b[first].item()!r}, expected '
                f'{a[first].item()!r} ({differs.size} values differ)')
    return None


def compare_bags(expected: str | os.PathLike[str], actual: str | os.PathLike[str], *,
                 rtol: float = BAG_RTOL) -> list[str]:
    """What differs between the messages of two bags; an empty list when they agree.

    Exact: the topics, their types and message counts, the order of the messages, their log
    times, and every integer, boolean and string field (header stamps and frame ids included).
    To a tolerance: every floating-point field, which may differ by ``rtol`` times the largest
    magnitude that field (the same path, all array elements together) takes over its topic in
    ``expected``: the scale of the signal, so a field that crosses zero is not held to a
    relative error near zero. NaN matches NaN. Storage format, compression and chunking are not
    compared: two bags agree when their messages decode to the same values, so this holds across
    machines whose floating-point rounding (BLAS kernels) differs, where their bytes do not.

    Returns one line per differing topic field (or the first difference in order or structure).
    """
    want_topics, got_topics = bag_topics(expected), bag_topics(actual)
    if want_topics != got_topics:
        for name in sorted(set(want_topics) | set(got_topics)):
            if want_topics.get(name) != got_topics.get(name):
                return [f'topic {name}: {got_topics.get(name)}, expected {want_topics.get(name)}']
    store = typestore()
    columns: dict[str, dict[str, tuple[list[Any], list[Any]]]] = {}
    with closing(iter_raw(expected)) as wanted, closing(iter_raw(actual)) as gotten:
        for i, (want, got) in enumerate(zip(wanted, gotten, strict=True)):
            if want[:3] != got[:3]:
                return [f'message {i}: {got[:3]}, expected {want[:3]} (topic, type, log time)']
            problem = _collect(store, want, got, columns)
            if problem is not None:
                return [f'message {i} on {want[0]}: {problem}']
    problems = []
    for topic, topic_columns in columns.items():
        for field, (want_column, got_column) in topic_columns.items():
            problem = _column_difference(topic, field, want_column, got_column, rtol)
            if problem is not None:
                problems.append(problem)
    return problems


def _collect(store: Typestore, want: tuple[str, str, int, bytes],
             got: tuple[str, str, int, bytes],
             columns: dict[str, dict[str, tuple[list[Any], list[Any]]]]) -> str | None:
    """Append the leaf values of two messages to their topic's columns (or say why not)."""
    topic, msgtype = want[0], want[1]
    if msgtype not in store.types:
        return f'unknown message type {msgtype!r}'
    want_leaves: dict[str, Any] = {}
    got_leaves: dict[str, Any] = {}
    _leaves(store, msgtype, store.deserialize_cdr(want[3], msgtype), '', want_leaves)
    _leaves(store, msgtype, store.deserialize_cdr(got[3], msgtype), '', got_leaves)
    if want_leaves.keys() != got_leaves.keys():
        return f'fields {sorted(got_leaves)}, expected {sorted(want_leaves)}'
    topic_columns = columns.setdefault(topic, {})
    for field, value in want_leaves.items():
        pair = topic_columns.setdefault(field, ([], []))
        pair[0].append(value)
        pair[1].append(got_leaves[field])
    return None
