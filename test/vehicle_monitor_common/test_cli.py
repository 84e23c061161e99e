"""The failure contract of the command-line tools: one line and 2, Ctrl-C 130, bugs raise."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from vehicle_monitor_common.cli import run_cli
from vehicle_monitor_common.parameters import ConfigurationError


def _raising(exc: BaseException) -> Callable[[], int]:
    def body() -> int:
        raise exc
    return body


def test_expected_failure_prints_one_line_and_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_cli(_raising(ConfigurationError('bad rate')), (ConfigurationError,)) == 2
    assert capsys.readouterr().err == 'error: bad rate\n'
    assert run_cli(lambda: 1, (ConfigurationError,)) == 1


def test_interrupt_exits_130_and_a_bug_keeps_its_traceback() -> None:
    assert run_cli(_raising(KeyboardInterrupt()), (ConfigurationError,)) == 130
    with pytest.raises(KeyError):
        run_cli(_raising(KeyError('bug')), (ConfigurationError,))
