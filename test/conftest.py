"""Test harness shared by every test: ROS isolation, per-test contexts, waiting with deadlines.

Each test that touches ROS gets its own rclpy Context, a SingleThreadedExecutor (it re-raises
callback exceptions from spin_once, so failures surface) and a node factory; everything is torn
down in reverse. The run uses its own ROS_DOMAIN_ID and localhost-only discovery, so parallel
runs on one machine do not hear each other.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import os
import time
from typing import Any

import pytest


def pytest_configure(config: pytest.Config) -> None:
    """Isolate this run's DDS traffic before any rclpy context exists."""
    os.environ['ROS_DOMAIN_ID'] = str(100 + os.getpid() % 100)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('RCUTILS_LOGGING_USE_STDOUT', '0')
    # Mirrors tools/env.sh for runs outside it: one BLAS thread for small matrices.
    os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')


@pytest.fixture(autouse=True)
def private_ros_home(tmp_path_factory: pytest.TempPathFactory,
                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test has its own ROS_HOME, so default calibration files (and logs) of one test are
    never found by another, nor written into the user's ~/.ros."""
    monkeypatch.setenv('ROS_HOME', str(tmp_path_factory.mktemp('ros_home')))


@pytest.fixture
def ros_context() -> Iterator[Any]:
    """A fresh, initialised rclpy Context for one test."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture
def executor(ros_context: Any) -> Iterator[Any]:
    """A SingleThreadedExecutor on the test's context."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=ros_context)
    try:
        yield ex
    finally:
        ex.shutdown()


@pytest.fixture
def make_node(ros_context: Any, executor: Any) -> Iterator[Callable[..., Any]]:
    """Factory: ``make_node(cls_or_name, **kwargs)`` adds the node to the executor.

    ``cls_or_name`` is a Node subclass (constructed with the test's context) or a plain name
    (a bare rclpy Node). Nodes are destroyed last-created first.
    """
    from rclpy.node import Node

    created: list[Any] = []

    def factory(cls_or_name: Any, **kwargs: Any) -> Any:
        if isinstance(cls_or_name, str):
            node = Node(cls_or_name, context=ros_context, **kwargs)
        else:
            node = cls_or_name(context=ros_context, **kwargs)
        created.append(node)
        executor.add_node(node)
        return node

    try:
        yield factory
    finally:
        for node in reversed(created):
            executor.remove_node(node)
            node.destroy_node()


@pytest.fixture
def spin_until(executor: Any) -> Callable[..., bool]:
    """``spin_until(predicate, timeout_s)``: spin until it holds (True) or the deadline passes."""

    def wait(predicate: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return True
            executor.spin_once(timeout_sec=0.02)
        return predicate()

    return wait


@pytest.fixture
def publish_clock(make_node: Callable[..., Any]) -> Callable[[int], None]:
    """``publish_clock(sec)``: publish that time on ``/clock`` (from a probe node of its own)."""
    from rosgraph_msgs.msg import Clock

    publisher = make_node('clock_probe').create_publisher(Clock, '/clock', 10)

    def publish(sec: int) -> None:
        message = Clock()
        message.clock.sec = sec
        publisher.publish(message)

    return publish


@pytest.fixture
def executable() -> Callable[[str, str], str]:
    """``executable(package, name)``: path of an installed executable, where ros2 run looks."""
    from ament_index_python.packages import get_package_prefix

    def path(package: str, name: str) -> str:
        return os.path.join(get_package_prefix(package), 'lib', package, name)

    return path


@pytest.fixture
def small_bag(tmp_path: Any) -> Any:
    """A 1 s bag: wheel speeds at 200 Hz, IMU at 50 Hz, one TPMS warning; starts at t = 1000 s.

    Values are seeded random so a reordered or altered message cannot pass for the original.
    """
    import numpy as np

    from vehicle_monitor_common.bag_io import write_bag
    from vehicle_monitor_common.series import TopicSeries

    rng = np.random.default_rng(7)
    start = 1000 * 10**9
    wheel_stamps = start + np.arange(200, dtype=np.int64) * 5_000_000
    imu_stamps = start + np.arange(50, dtype=np.int64) * 20_000_000 + 1_000_000
    series = {
        '/vehicle/wheel_speeds': TopicSeries(
            'vehicle_monitor_msgs/msg/WheelSpeeds', wheel_stamps,
            {'omega': 60.0 + rng.normal(size=(200, 4))}, 'base_link'),
        '/vehicle/imu': TopicSeries(
            'sensor_msgs/msg/Imu', imu_stamps,
            {'linear_acceleration.y': rng.normal(size=50),
             'angular_velocity.z': rng.normal(size=50)}, 'base_link'),
        '/tpms/warning': TopicSeries(
            'vehicle_monitor_msgs/msg/TpmsWarning', np.array([start + 500_000_000]),
            {'warning': np.array([[False, True, False, False]]),
             'reasons': np.array([['FR: two methods agree']], dtype=object)}),
    }
    path = tmp_path / 'small_bag'
    write_bag(path, series)
    return path, series
