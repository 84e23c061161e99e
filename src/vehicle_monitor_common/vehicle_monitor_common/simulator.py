"""Simulator node: synthesises a scenario (or takes a recording) and replays it on the graph.

Both simulators are this node with their domain's scenario synthesis: ``scenario`` (a YAML path
or the name of a scenario the package ships) is simulated to a rosbag2 with inputs and
``/truth/*``, then replayed by the player in real (``rate: 1``) or accelerated time, or as fast as
the graph keeps up; ``bag`` replays a recording instead. ``output_bag`` keeps the synthesised
bag. One replay path for synthetic and recorded data: what a test drive recorded plays exactly
like a scenario.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
import shutil
import tempfile
import time
from typing import Any, ClassVar

from vehicle_monitor_common.bag_io import BagError, write_bag
from vehicle_monitor_common.parameters import ConfigurationError, param
from vehicle_monitor_common.player import PlayerParameters, ScenarioPlayer, run_player
from vehicle_monitor_common.resources import share_dir, shipped_file, workspace_bags
from vehicle_monitor_common.series import TopicSeries

# (scenario file, seed override or None) -> topics with their samples.
Synthesis = Callable[[Path, 'int | None'], Mapping[str, TopicSeries]]


@dataclass(frozen=True)
class SimulatorParameters(PlayerParameters):
    """Replay parameters plus the synthetic mode's."""

    scenario: str = param('', 'scenario to synthesise: a YAML path or the name of one the '
                          'package ships (exclusive with bag)', read_only=True)
    seed: int = param(-1, 'random seed replacing the scenario file\'s; -1 keeps the file\'s',
                      low=-1, high=2**31 - 1, read_only=True)
    output_bag: str = param('', 'keep the synthesised scenario as this rosbag2 (MCAP); empty: '
                            'a temporary bag', read_only=True)


class SimulatorNode(ScenarioPlayer):
    """A simulator, declared in its class statement: its default name, its package (where
    shipped scenarios live) and its synthesis."""

    parameters_class = SimulatorParameters
    default_name: ClassVar[str] = ''
    package: ClassVar[str] = ''
    synthesize: ClassVar[staticmethod[[Path, int | None], Mapping[str, TopicSeries]]]

    def __init_subclass__(cls, *, name: str = '', package: str = '',
                          synthesis: Synthesis | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if synthesis is not None:
            cls.default_name, cls.package = name, package
            cls.synthesize = staticmethod(synthesis)

    def __init__(self, node_name: str = '', **kwargs: Any) -> None:
        self._temporary: Path | None = None
        super().__init__(node_name or self.default_name, **kwargs)

    @classmethod
    def main(cls, args: list[str] | None = None) -> None:
        """Entry point of the simulator's executable (``ros2 run``)."""
        raise SystemExit(run_player(cls, args))

    def _prepare_bag(self, p: PlayerParameters) -> str:
        assert isinstance(p, SimulatorParameters)
        if p.bag and p.scenario:
            raise ConfigurationError('give either bag (replay) or scenario (synthesis), not both')
        if p.bag:
            return str(self._find_bag(p.bag))
        if not p.scenario:
            raise ConfigurationError(
                'parameter scenario (a scenario to synthesise) or bag (a recording to replay) '
                'is required')
        try:
            path = shipped_file(self.package, 'scenarios', p.scenario)
            # a long drive takes tens of seconds to synthesise: say so before, not only after
            self.get_logger().info(f'synthesising scenario {path.stem} (seed '
                                   f'{"of the file" if p.seed < 0 else p.seed}) ...')
            started = time.monotonic()
            series = self.synthesize(path, None if p.seed < 0 else p.seed)
        except (FileNotFoundError, ValueError) as exc:
            raise ConfigurationError(f'scenario {p.scenario}: {exc}') from None
        if p.output_bag:
            bag = Path(p.output_bag)
        else:
            self._temporary = Path(tempfile.mkdtemp(prefix='scenario_'))
            bag = self._temporary / path.stem
        try:
            write_bag(bag, series, overwrite=bool(p.output_bag))
        except BagError as exc:
            raise ConfigurationError(str(exc)) from None
        self.get_logger().info(
            f'synthesised {path.stem} ({sum(len(s) for s in series.values())} messages) in '
            f'{time.monotonic() - started:.1f} s -> {bag}')
        return str(bag)

    def _find_bag(self, bag: str) -> Path:
        """A recording to replay: a path as given, else a shipped bag by name
        (``road_puncture_15pct_fl`` or ``bags/road_puncture_15pct_fl``), from any directory.

        Raises:
            ConfigurationError: naming the shipped bags when there is no such recording.
        """
        given = Path(bag)
        if given.exists():
            return given
        # installed (share/vehicle_monitor_common/bags), else the workspace's bags/
        installed = share_dir('vehicle_monitor_common', 'bags')
        shipped = installed if installed.is_dir() else workspace_bags()
        candidate = shipped / given.name
        if candidate.is_dir():
            return candidate
        available = ', '.join(sorted(p.name for p in shipped.glob('*') if p.is_dir()))
        raise ConfigurationError(f'bag {bag}: no such bag, nor a shipped one '
                                 f'(available: {available or "none"})')

    def destroy_node(self) -> None:
        """Stop the replay, then remove a temporary bag."""
        super().destroy_node()
        if self._temporary is not None:
            shutil.rmtree(self._temporary, ignore_errors=True)
